"""Fixtures shared by the inference tests."""

import jax
import pytest

from jaxsr.config import ModelConfig
from jaxsr.io.checkpoint import save_model
from jaxsr.nn import Model, init_model

# A small network of the paper's shape (TR1): fast to compile, random weights
TINY = dict(base=8, growth=4, head=16, filter_hidden=16)


@pytest.fixture(scope="module")
def model_path(tmp_path_factory):
    """A TR1 checkpoint of `TINY` widths with random weights."""
    cfg = ModelConfig(tr=1, **TINY)
    model = Model(*init_model(jax.random.key(0), cfg), cfg)
    path = tmp_path_factory.mktemp("model") / "tiny.npz"
    save_model(path, model, card={"data": "none: random weights for tests"})
    return path

