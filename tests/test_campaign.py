"""The training campaign's turn-taking (experiments/campaign.py): which run goes next, when one is finished, and
the convergence measure, on fabricated metrics files (no training)."""

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))

import campaign  # noqa: E402
from jaxsr.config import PRESETS  # noqa: E402

CFG = PRESETS[campaign.PRESET]


def _write(root, seed, tr, val_losses, val_psnr=None):
    run = campaign.run_dir(root, seed, tr)
    run.mkdir(parents=True, exist_ok=True)
    psnr = val_psnr or [20.0 + i for i in range(len(val_losses))]
    lines = [json.dumps({"epoch": i + 1, "val_loss": v, "val_psnr": p})
             for i, (v, p) in enumerate(zip(val_losses, psnr, strict=True))]
    (run / "metrics.jsonl").write_text("".join(line + "\n" for line in lines))


def test_the_run_with_fewest_epochs_goes_next_in_priority_order(tmp_path):
    assert campaign.next_run(tmp_path, CFG, None) == campaign.RUNS[0]
    for seed, tr in campaign.RUNS[:3]:
        _write(tmp_path, seed, tr, [1.0])
    assert campaign.next_run(tmp_path, CFG, None) == campaign.RUNS[3]  # no epochs yet beats one
    assert campaign.next_run(tmp_path, CFG, {"s0/tr1", "s0/tr2"}) == (0, 1)
    assert campaign.next_run(tmp_path, CFG, {"s0/tr1", "s0/tr2"}, skip={(0, 1)}) == (0, 2)


def test_a_run_is_finished_by_its_epoch_budget_or_by_patience(tmp_path):
    assert not campaign.finished([], CFG)
    improving = [{"val_loss": 1.0 - 0.01 * i} for i in range(CFG.epochs - 1)]
    assert not campaign.finished(improving, CFG)
    assert campaign.finished(improving + [{"val_loss": 0.0}], CFG)
    stalled = [{"val_loss": 0.5}] + [{"val_loss": 0.5}] * CFG.patience  # ties do not count as lower, as in fit
    assert campaign.finished(stalled, CFG)
    assert not campaign.finished(stalled[:-1], CFG)
    _write(tmp_path, 0, 0, [r["val_loss"] for r in stalled])
    assert campaign.next_run(tmp_path, CFG, {"s0/tr0"}) is None


def test_gain_over_the_last_quarter():
    assert campaign.gain_last_quarter([{"val_psnr": 20.0}] * 3) is None
    records = [{"val_psnr": p} for p in (20.0, 22.0, 23.0, 23.1, 23.0, 23.3, 23.2, 23.4)]
    assert campaign.gain_last_quarter(records) == pytest.approx(23.4 - 23.3)  # last 2 of 8 against the best before
