"""Inference throughput: frames/s of `super_resolve` for TR0-TR4 at batch 1 (one device), the default batch
(one frame per device, split over the host's cores as CPU devices: benchmarks/conftest.py) and 8, end to end
from photon histograms, and the GFLOP/s it achieves against what this machine's matrix multiply reaches.
`test_forms_from_histograms` times the network's three forms side by side for TR0-TR4 on 32 frames, end to
end from histograms: window (the paper), sequence (`super_resolve` of a sequence-form model: chunks of
`DEFAULT_SEQUENCE_CHUNK` outputs) and stream (`Stream`, one frame at a time). `test_precision_from_histograms`
times TR0 and TR4 in the window and the sequence form with float32 and bfloat16 convolutions (`precision`), 32
frames and a 128-frame chunk of the sequence form (the goal: the sequence-form TR4 at 25 frames/s or more
on 2 CPU cores), each against the matrix-product ceiling of its precision.

Run: pytest benchmarks/bench_inference.py --benchmark-enable      (about 3 min on 2 CPU cores)

Weights are random (speed does not depend on them). 16 frames of 32 x 64 LR per call. `gflops_per_s` uses
`jaxsr.nn.duf.flops_per_frame` (convolutions and the dynamic filter); `test_matmul_peak[float32]` measures the
GFLOP/s of a large float32 matrix product, the practical ceiling for convolution-bound code on this XLA:CPU build,
and `[bfloat16]` the same product of bfloat16 operands with float32 sums (`preferred_element_type`), the ceiling
of `precision="bfloat16"`. The inference benchmarks record `share_of_matmul_peak`: their GFLOP/s over the ceiling
of their precision (measured once per run, `matmul_peak`).
"""

import dataclasses
import functools
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsr.config import DepthScale, ModelConfig, Sensor
from jaxsr.inference import (
    DEFAULT_BATCH_SIZE,
    Stream,
    fill_holes,
    iter_centre_of_mass,
    super_resolve,
    super_resolve_histograms,
)
from jaxsr.nn import Model, apply_model, flops_per_frame, init_model
from jaxsr.runtime import compiler_options

SENSOR = Sensor()
FRAMES = 16
MATMUL = 2048  # the side of the square matrices of the ceiling


def _matmul(precision):
    """A jitted MATMUL^2 product and its operand: float32 at full precision, or bfloat16 operands, float32 sums."""
    a = jax.random.normal(jax.random.key(3), (MATMUL, MATMUL), jnp.float32)
    if precision == "bfloat16":
        return jax.jit(lambda a: jax.lax.dot(a, a, preferred_element_type=jnp.float32)), a.astype(jnp.bfloat16)
    return jax.jit(lambda a: jnp.matmul(a, a, precision="highest")), a


@functools.cache
def matmul_peak(precision: str = "float32") -> float:
    """GFLOP/s of the MATMUL^2 product in `precision` ("float32" or "bfloat16"), best of 5 after a warm-up."""
    f, a = _matmul(precision)
    f(a).block_until_ready()
    best = float("inf")
    for _ in range(5):
        t0 = time.perf_counter()
        f(a).block_until_ready()
        best = min(best, time.perf_counter() - t0)
    return 2 * MATMUL**3 / best / 1e9


def _model(tr, temporal="window"):
    cfg = ModelConfig(tr=tr, temporal=temporal)
    return Model(*init_model(jax.random.key(0), cfg), cfg)


def _lr():
    return np.asarray(jax.random.uniform(jax.random.key(1), (FRAMES, *SENSOR.lr_shape)), np.float32)


def _record(benchmark, cfg, frames=FRAMES, precision="float32"):
    if benchmark.stats is not None:
        fps = frames / benchmark.stats.stats.mean
        gflops = fps * flops_per_frame(cfg, SENSOR.lr_shape) / 1e9
        benchmark.extra_info["gflops_per_s"] = gflops
        benchmark.extra_info["share_of_matmul_peak"] = gflops / matmul_peak(precision)


@pytest.mark.parametrize("batch", [1, None, 8])
@pytest.mark.parametrize("tr", [0, 1, 2, 3, 4])
def test_super_resolve(timed, benchmark, tr, batch):
    model, lr = _model(tr), _lr()
    timed(lambda: super_resolve(model, lr, batch_size=batch, form="model"), rounds=3, items=FRAMES)
    if benchmark.stats is not None:
        benchmark.extra_info["batch"] = batch or DEFAULT_BATCH_SIZE * jax.local_device_count()
    _record(benchmark, model.config)


@pytest.mark.parametrize("tr", [0, 4])
def test_super_resolve_histograms(timed, benchmark, tr):
    """End to end as a user runs it: counts -> centre of mass -> network, default batch."""
    model = _model(tr)
    counts = np.asarray(jax.random.poisson(jax.random.key(2), 2.0, (FRAMES, *SENSOR.lr_shape, SENSOR.bins)))
    timed(lambda: super_resolve_histograms(model, counts, form="model"), rounds=3, items=FRAMES)
    _record(benchmark, model.config)


def stream_histograms(model, counts, sensor=SENSOR):
    """End to end through `Stream`: (T, h, w, K) counts -> centre of mass -> one frame at a time -> (T, H, W)."""
    stream, out = Stream(model), []
    for lr in iter_centre_of_mass(counts, sensor):
        hr = stream.push(lr)
        if hr is not None:
            out.append(hr)
    return np.stack(out + stream.flush())


@pytest.mark.parametrize("form", ["window", "sequence", "stream"])
@pytest.mark.parametrize("tr", [0, 1, 2, 3, 4])
def test_forms_from_histograms(timed, benchmark, tr, form):
    """32 frames end to end from histograms in each of the network's forms, default batch / chunk."""
    frames = 32
    model = _model(tr, "window" if form == "window" else "sequence")
    counts = np.asarray(jax.random.poisson(jax.random.key(2), 2.0, (frames, *SENSOR.lr_shape, SENSOR.bins)))
    run = stream_histograms if form == "stream" else functools.partial(super_resolve_histograms, form="model")
    timed(lambda: run(model, counts), rounds=2, items=frames)
    _record(benchmark, model.config, frames)


@pytest.mark.parametrize("precision", ["float32", "bfloat16"])
@pytest.mark.parametrize("form,frames", [("window", 32), ("sequence", 32), ("sequence", 128)])
@pytest.mark.parametrize("tr", [0, 4])
def test_precision_from_histograms(timed, benchmark, tr, form, frames, precision):
    """End to end from histograms with the network's convolutions in `precision`, the bundled models' shapes:
    window form (default batch) or sequence form (one chunk of all the frames)."""
    model = _model(tr)
    counts = np.asarray(jax.random.poisson(jax.random.key(2), 2.0, (frames, *SENSOR.lr_shape, SENSOR.bins)))
    batch = frames if form == "sequence" else None
    timed(lambda: super_resolve_histograms(model, counts, batch_size=batch, precision=precision, form=form),
          rounds=2, items=frames)
    _record(benchmark, dataclasses.replace(model.config, temporal=form), frames, precision)
    if benchmark.stats is not None:
        benchmark.extra_info["precision"] = precision


@pytest.mark.parametrize("options", ["xla-defaults", "jaxsr"])
@pytest.mark.parametrize("impl", ["taps", "auto"])
def test_network_tr4_one_window(timed, benchmark, impl, options):
    """What `compiler_options` and the stacked temporal taps (`conv3d_impl="auto"`) are worth: one TR4 window
    through `apply_model` on one device, under XLA's default options or jaxsr's, with every tap convolved on
    its own ("taps") or stacked where `stacked_use` >= 0.7 ("auto")."""
    cfg = ModelConfig(tr=4)
    params, state = init_model(jax.random.key(0), cfg)
    windows = jax.random.uniform(jax.random.key(1), (1, cfg.frames, *SENSOR.lr_shape))
    opts = compiler_options() if options == "jaxsr" else {}
    f = jax.jit(lambda p, s, w: apply_model(p, s, w, cfg, conv3d_impl=impl), compiler_options=opts)
    timed(f, params, state, windows, rounds=5, items=1)
    if benchmark.stats is not None:
        benchmark.extra_info["gflops_per_s"] = flops_per_frame(cfg, SENSOR.lr_shape) / benchmark.stats.stats.mean / 1e9


@pytest.mark.parametrize("precision", ["float32", "bfloat16"])
def test_matmul_peak(timed, benchmark, precision):
    f, a = _matmul(precision)
    timed(f, a, rounds=5)
    if benchmark.stats is not None:
        benchmark.extra_info["gflops_per_s"] = 2 * MATMUL**3 / benchmark.stats.stats.mean / 1e9


@pytest.mark.parametrize("hole_lr_pixels", [1, 64])
def test_fill_holes(timed, hole_lr_pixels):
    """The depth of a quiet region that returns enclose (`fill_holes`, the last step of the default no-return
    decision) on HR frames of the sensor's size with one hole: a lone LR pixel, or the largest hole (8 x 8 LR
    pixels): frames per second, beside the network's above."""
    hr = jax.random.uniform(jax.random.key(3), (FRAMES, *SENSOR.hr_shape), minval=0.05, maxval=0.5)
    side = int(np.sqrt(hole_lr_pixels))
    holes = jnp.zeros((FRAMES, *SENSOR.lr_shape), bool).at[:, 10:10 + side, 20:20 + side].set(True)
    timed(jax.jit(lambda d, f: fill_holes(d, f, DepthScale())), hr, holes, items=FRAMES)
