"""experiments/paper/selection.py: its two validations are the presets' (new) and the one before (old), and it reads
seed, steps and epoch from both kinds of checkpoint."""

from pathlib import Path

import numpy as np

import selection  # experiments/paper (pytest's pythonpath)
from jaxsr.io.checkpoint import save_tree
from jaxsr.config import PRESETS, TrainConfig


def test_new_validation_is_the_presets_and_old_the_moving_cameras():
    assert selection.VALIDATIONS["new"] == TrainConfig().val_sequences
    assert all(cfg.val_sequences == TrainConfig().val_sequences for cfg in PRESETS.values())
    assert set(selection.VALIDATIONS["old"]) - set(selection.VALIDATIONS["new"]) == {"val1_street", "val3_courtyard"}


def test_card_of_reads_a_model_card_and_a_train_state(tmp_path):
    budget = Path(__file__).resolve().parents[2] / "experiments" / "budget_weights" / "tr0.npz"
    assert selection.card_of(budget) == {"seed": 0, "steps": 1280, "epoch": 5}  # 5 epochs of 256 steps
    # a train state as fit writes it: the run's record; the card describes its best epoch so far
    state = save_tree(tmp_path / "last.npz", {"x": np.zeros(2)},
                      {"kind": "train_state", "train_config": {"seed": 3}, "run": {"epoch": 2, "step": 7750},
                       "card": {"seed": 3, "steps": 3875, "best_epoch": 0}})
    assert selection.card_of(state) == {"seed": 3, "steps": 7750, "epoch": 2}
