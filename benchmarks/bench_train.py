"""Training throughput: examples/s of the jitted train step for TR0 and TR4 at the `cpu` preset, the sequence
form's output frames/s against its clip length, the data pipeline on its own, and the three conv3d
implementations side by side.

    pytest benchmarks/bench_train.py --benchmark-only            (about 3 min on 2 CPU cores)

The train-step benchmarks draw windows from a fixed synthetic HR sequence with `sequence_batches` (sensor
simulation + centre of mass inside the step, no scene rendering), so they time the network and the sensor
model; `test_scene_batches` times the rendering path of the default data source on its own.
examples/s = batch_size / (mean step time); pytest-benchmark reports the step time. In the sequence form an
example is a clip of L = 2R + K frames that trains K outputs: `frames_per_s` = batch_size K / (mean step time).
"""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsr.config import PRESETS, ModelConfig, SensorConfig
from jaxsr.data import scene_batches, sequence_batches, sequence_clips
from jaxsr.layers import conv3d_native, conv3d_stacked, conv3d_taps
from jaxsr.model import init_model
from jaxsr.optim import adam_init
from jaxsr.train import make_train_step

CPU = PRESETS["cpu"]


def _hr_sequence(frames=12, seed=0):
    """A street-like synthetic HR sequence: a ground ramp, boxes moving 1 LR px/frame, sky on top."""
    h, w = SensorConfig().hr_shape
    yy, xx = np.mgrid[:h, :w]
    rng = np.random.default_rng(seed)
    depth = np.empty((frames, h, w), np.float32)
    for t in range(frames):
        d = np.where(yy > h // 3, 5.0 + 30.0 * (h - yy) / h, np.inf)
        for k in range(4):
            x0 = (40 + 60 * k + 4 * t) % w
            d[h // 4 : h // 4 + 50, x0 : x0 + 20] = 8.0 + 5.0 * k
        depth[t] = d
    intensity = rng.uniform(0.2, 1.0, depth.shape).astype(np.float32)
    return depth, intensity


def _bench_step(benchmark, tr, *, clip_outputs=None):
    """The train step of the window form, or (clip_outputs K) of the sequence form on clips of 2R + K frames."""
    train_cfg, frames = CPU, 1
    if clip_outputs is None:
        cfg = ModelConfig(tr=tr)
        depth, intensity = _hr_sequence()
        make_batch = sequence_batches(depth, intensity, tr, CPU)
    else:
        cfg = ModelConfig(tr=tr, temporal="sequence")
        train_cfg = dataclasses.replace(CPU, clip_frames=2 * (3 + tr) + clip_outputs)
        depth, intensity = _hr_sequence(train_cfg.clip_frames + 2)
        make_batch = sequence_clips(depth, intensity, train_cfg.clip_frames, train_cfg)
        frames = clip_outputs
    params, state = init_model(jax.random.key(0), cfg)
    carry = [params, state, adam_init(params), 0]
    step_fn = make_train_step(cfg, train_cfg, make_batch, mesh=None)

    def one():
        p, s, o, i = carry
        p, s, o, m = step_fn(p, s, o, jax.random.key(i), i)
        jax.block_until_ready(m)
        carry[:] = [p, s, o, i + 1]

    one()  # compile
    benchmark.pedantic(one, rounds=3 if tr else 10, iterations=1)
    benchmark.extra_info["examples_per_s"] = CPU.batch_size / benchmark.stats["mean"]
    benchmark.extra_info["frames_per_s"] = CPU.batch_size * frames / benchmark.stats["mean"]
    benchmark.extra_info["patch"] = CPU.patch
    benchmark.extra_info["backend"] = jax.default_backend()


@pytest.mark.benchmark(group="train_step")
def test_train_step_tr0(benchmark):
    _bench_step(benchmark, 0)


@pytest.mark.benchmark(group="train_step")
def test_train_step_tr4(benchmark):
    _bench_step(benchmark, 4)


@pytest.mark.benchmark(group="train_step")
@pytest.mark.parametrize("clip_outputs", [1, 8, 16])
def test_train_step_sequence_tr4(benchmark, clip_outputs):
    """The sequence form on clips of 2R + K frames (TR4: 15, 22, 30), loss on the K frames inside."""
    _bench_step(benchmark, 4, clip_outputs=clip_outputs)


@pytest.mark.benchmark(group="data")
def test_scene_batches(benchmark):
    """Rendering + simulation of one batch of TR4 windows (the default data source)."""
    make_batch = jax.jit(scene_batches(4, CPU))
    jax.block_until_ready(make_batch(jax.random.key(0)))
    keys = iter(range(1, 10**6))
    benchmark.pedantic(lambda: jax.block_until_ready(make_batch(jax.random.key(next(keys)))), rounds=3, iterations=1)


# A TR4 "valid" block's 3x3x3 convolution at the widest point (F = 128 -> 32 on 9 frames) of a batch of 4
# 16 x 32 LR patches (the cpu preset), forward and backward.
_X = jax.random.normal(jax.random.key(0), (4, 9, 16, 32, 128))
_W = jax.random.normal(jax.random.key(1), (3, 3, 3, 128, 32)) * 0.01
_PAD = ((1, 1), (1, 1), (1, 1))


_IMPLS = {"native": conv3d_native, "taps": conv3d_taps, "stacked": conv3d_stacked}


@pytest.mark.benchmark(group="conv3d")
@pytest.mark.parametrize("impl", list(_IMPLS))
def test_conv3d_forward(benchmark, impl):
    f = _IMPLS[impl]
    g = jax.jit(lambda x, w: f(x, w, padding=_PAD))
    jax.block_until_ready(g(_X, _W))
    benchmark.pedantic(lambda: jax.block_until_ready(g(_X, _W)), rounds=5, iterations=1)


@pytest.mark.benchmark(group="conv3d")
@pytest.mark.parametrize("impl", list(_IMPLS))
def test_conv3d_forward_backward(benchmark, impl):
    f = _IMPLS[impl]
    g = jax.jit(jax.grad(lambda x, w: jnp.sum(f(x, w, padding=_PAD) ** 2), argnums=(0, 1)))
    jax.block_until_ready(g(_X, _W))
    benchmark.pedantic(lambda: jax.block_until_ready(g(_X, _W)), rounds=5, iterations=1)
