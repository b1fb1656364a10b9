"""What training asks of an architecture is answered by its registry entry or its recipe, not by its name: the
learned baselines' published sizes, their validation sets, the DUF network's warm start."""

import jax
import pytest

from jaxsr.baselines import HistNetConfig, RBPNConfig
from jaxsr.config import ModelConfig, TrainConfig
from jaxsr.nn.model import Model
from jaxsr.training import baseline_validation_set, recipe
from jaxsr.training.baselines import _is_baseline
from jaxsr.training.duf import initial_weights


def test_the_recipes_say_which_networks_train_at_a_published_size():
    assert recipe("histnet").published == HistNetConfig() and recipe("iseebetter").published == RBPNConfig()
    assert recipe("duf").published is None  # the paper's network: train's options choose its size
    assert _is_baseline(Model({}, {}, HistNetConfig())) and not _is_baseline(Model({}, {}, ModelConfig(tr=0)))


def test_a_baseline_validation_set_refuses_another_kinds_config():
    with pytest.raises(ValueError, match="a RBPNConfig is not a histnet config"):
        baseline_validation_set(jax.random.key(0), "histnet", RBPNConfig(), TrainConfig())


def test_the_duf_network_starts_from_duf_weights_only():
    with pytest.raises(ValueError, match="init holds a histnet model; the DUF network starts from DUF weights"):
        initial_weights(jax.random.key(0), ModelConfig(tr=0), Model({}, {}, HistNetConfig()))
