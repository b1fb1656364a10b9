"""Training throughput: examples/s of the jitted train step for TR0 and TR4 at the `cpu` preset, the sequence
form's output frames/s against its clip length, the data pipeline on its own, and the three conv3d
implementations side by side.

    pytest benchmarks/bench_train.py --benchmark-only            (about 5 min on 2 CPU cores)
    pytest benchmarks/bench_train.py --benchmark-only -k today_vs_new -s   (the step against issue 14's baseline)

The train-step benchmarks draw windows from a fixed synthetic HR sequence with `sequence_batches` (sensor
simulation + centre of mass inside the step, no scene rendering), so they time the network and the sensor
model; `test_scene_batches` times the rendering path of the default data source on its own.
examples/s = batch_size / (mean step time); pytest-benchmark reports the step time. In the sequence form an
example is a clip of L = 2R + K frames that trains K outputs: `frames_per_s` = batch_size K / (mean step time).
"""

import dataclasses
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsr.config import PRESETS, ModelConfig, SensorConfig
from jaxsr.data import log_uniform, random_crop, scene_batches, sequence_batches, sequence_clips
from jaxsr.layers import conv3d_native, conv3d_stacked, conv3d_taps
from jaxsr.model import apply_model, flops_per_frame, init_model
from jaxsr.optim import adam_init
from jaxsr.peaks import centre_of_mass
from jaxsr.runtime import compiler_options
from jaxsr.sensor import normalise_depth, simulate_histograms
from jaxsr.train import data_mesh, make_train_step

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


# Issue 14: today's step (the data source as it was on 2026-11-22: every example's whole 32 x 64 clip
# simulated, then cropped; one device) beside the new one (photons drawn for the crop only, `jaxsr.data`), on
# one device and with the batch split over both cores as `fit` does. Interleaved rounds, so that a background
# load slows every variant alike; the network's forward pass at inference (BN from running statistics,
# `compiler_options`, same batch and crops) is timed in the same rounds as the reference arithmetic rate.
def _today_batches(depth, intensity, tr, train_cfg):
    """`sequence_batches` as it was before issue 14: the whole clip simulated, then a random crop kept."""
    frames, sensor = 2 * tr + 1, SensorConfig()

    def example(key):
        k_start, k_snr, k_sig, k_noise, k_crop = jax.random.split(key, 5)
        s = jax.random.randint(k_start, (), 0, depth.shape[0] - frames + 1)
        d = jax.lax.dynamic_slice(depth, (s, 0, 0), (frames, *depth.shape[1:]))
        a = jax.lax.dynamic_slice(intensity, (s, 0, 0), (frames, *depth.shape[1:]))
        snr = log_uniform(k_snr, *train_cfg.snr_range)
        mean_signal = log_uniform(k_sig, *train_cfg.mean_signal_range)
        counts = simulate_histograms(k_noise, d, a, sensor, snr=snr, mean_signal=mean_signal)
        clip, gt = random_crop(k_crop, centre_of_mass(counts, sensor), normalise_depth(d, sensor),
                               train_cfg.patch, sensor.scale)
        return clip, gt[tr]

    return lambda key: jax.vmap(example)(jax.random.split(key, train_cfg.batch_size))


def _step_variants(tr):
    """{name: (step function, its first arguments)} for today's and the new train step."""
    cfg = ModelConfig(tr=tr)
    depth, intensity = (jnp.asarray(a) for a in _hr_sequence())
    params, state = init_model(jax.random.key(0), cfg)
    args = (params, state, adam_init(params))
    new = sequence_batches(depth, intensity, tr, CPU)
    variants = {
        "today": (make_train_step(cfg, CPU, _today_batches(depth, intensity, tr, CPU), mesh=None), args),
        "new-1-device": (make_train_step(cfg, CPU, new, mesh=None), args),
    }
    if jax.device_count() > 1 and CPU.batch_size % jax.device_count() == 0:
        mesh = data_mesh()
        replicated = jax.device_put(args, jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec()))
        variants[f"new-{jax.device_count()}-devices"] = (make_train_step(cfg, CPU, new, mesh=mesh), replicated)
    return cfg, variants


@pytest.mark.benchmark(group="train_step_today_vs_new")
@pytest.mark.parametrize("tr", [0, 4])
def test_train_step_today_vs_new(benchmark, tr):
    cfg, variants = _step_variants(tr)
    windows, _ = jax.jit(sequence_batches(*_hr_sequence(), tr, CPU))(jax.random.key(0))
    params, state, _ = variants["today"][1]
    infer = jax.jit(lambda p, s, w: apply_model(p, s, w, cfg), compiler_options=compiler_options())
    carry = {k: [*a, 0] for k, (_, a) in variants.items()}
    times = {k: [] for k in [*variants, "inference"]}

    def one_round():
        for name, (step_fn, _) in variants.items():
            p, s, o, i = carry[name]
            t0 = time.perf_counter()
            p, s, o, m = step_fn(p, s, o, jax.random.key(i), i)
            jax.block_until_ready(m)
            times[name].append(time.perf_counter() - t0)
            carry[name] = [p, s, o, i + 1]
        t0 = time.perf_counter()
        jax.block_until_ready(infer(params, state, windows))
        times["inference"].append(time.perf_counter() - t0)

    one_round()  # compile
    for v in times.values():
        v.clear()
    benchmark.pedantic(one_round, rounds=4 if tr else 10, iterations=1)
    # the network's FLOPs per example: forward only at inference, forward + backward (3x) in training
    flops = flops_per_frame(cfg, CPU.patch)
    for name, ts in times.items():
        mean = float(np.mean(ts))
        info = {"step_s": mean, "examples_per_s": CPU.batch_size / mean,
                "gflop_per_s": (1 if name == "inference" else 3) * flops * CPU.batch_size / mean / 1e9}
        benchmark.extra_info[name] = info
        print(f"TR{tr} {name:16s} {1e3 * mean:8.1f} ms/step  {info['examples_per_s']:6.2f} examples/s  "
              f"{info['gflop_per_s']:6.1f} GFLOP/s")
    benchmark.extra_info["speed_up"] = {k: float(np.mean(times["today"]) / np.mean(v)) for k, v in times.items()}
    benchmark.extra_info["patch"] = CPU.patch
