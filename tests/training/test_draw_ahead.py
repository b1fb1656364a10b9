"""Batches drawn ahead of the train step (`draw_batches`, `make_train_step` with make_batch None): the same
batches as the step draws inside itself for the same keys, and the same update from them."""

import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from test_train import TINY, tiny_train_cfg, toy_batches  # noqa: E402

from jaxsr.config import ModelConfig, Sensor, TrainConfig  # noqa: E402
from jaxsr.nn import init_model  # noqa: E402
from jaxsr.training import draw_batches, make_train_step, scene_batches  # noqa: E402
from jaxsr.training.optim import adam_init  # noqa: E402


def _same_batches(make_batch, key, steps):
    inputs, gt = draw_batches(make_batch, key, steps)
    assert inputs.shape[0] == gt.shape[0] == len(steps)
    draw = jax.jit(make_batch)  # compiled, as inside the step (op by op, XLA:CPU rounds a mean otherwise)
    for j, s in enumerate(steps):  # fit's key of step s: fold_in(the run's data key, s)
        one = draw(jax.random.fold_in(key, s))
        np.testing.assert_array_equal(inputs[j], one[0])
        np.testing.assert_array_equal(gt[j], one[1])


def test_drawn_batches_are_those_the_step_draws_and_give_the_same_update():
    cfg = tiny_train_cfg()
    make_batch = toy_batches(TINY.tr, cfg.batch_size)
    key = jax.random.key(3)
    _same_batches(make_batch, key, [0, 1, 7])
    inside = make_train_step(TINY, cfg, make_batch)
    ahead = make_train_step(TINY, cfg, None)
    params, state = init_model(jax.random.key(0), TINY)
    runs = [(params, state, adam_init(params)), (params, state, adam_init(params))]
    batches = draw_batches(make_batch, key, jnp.arange(3))
    for s in range(3):
        *runs[0], m_in = inside(*runs[0], jax.random.fold_in(key, s), s)
        *runs[1], m_ahead = ahead(*runs[1], jax.tree_util.tree_map(lambda a: a[s], batches), s)
        assert float(m_in["loss"]) == float(m_ahead["loss"])
    for a, b in zip(jax.tree_util.tree_leaves(runs[0]), jax.tree_util.tree_leaves(runs[1])):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


@pytest.mark.slow  # the scene renderer compiles in about a minute on 2 cores
def test_drawn_scene_batches_are_those_the_step_draws():
    sensor = Sensor()
    cfg = TrainConfig(batch_size=2, patch=(8, 16))
    _same_batches(scene_batches(ModelConfig(tr=0).tr, cfg, sensor=sensor), jax.random.key(5), [0, 4])
