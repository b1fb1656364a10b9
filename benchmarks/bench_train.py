"""Training throughput: examples/s of the jitted train step for TR0 and TR4 at the `cpu` preset, the sequence
form's output frames/s against its clip length, the data pipeline on its own, and the three conv3d
implementations side by side.

    pytest benchmarks/bench_train.py --benchmark-only            (about 5 min on 2 CPU cores)
    pytest benchmarks/bench_train.py --benchmark-only -k today_vs_new -s   (windowed TR0/TR4 and sequence TR4:
        the step of the 2026-11-22 baseline, of main, and the new one, in one run)

The train-step benchmarks draw windows from a fixed synthetic HR sequence with `sequence_batches` (sensor
simulation + centre of mass inside the step, no scene rendering), so they time the network and the sensor
model; `test_scene_batches` times the rendering path of the default data source on its own.
examples/s = batch_size / (mean step time); pytest-benchmark reports the step time. In the sequence form an
example is a clip of L = 2R + K frames that trains K outputs: `frames_per_s` = batch_size K / (mean step time).
"""

import contextlib
import dataclasses
import functools
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsr.nn import layers
from jaxsr.config import DEFAULT_CLIP_OUTPUTS, PRESETS, ModelConfig, Sensor
from jaxsr.training.data import log_uniform, random_crop, scene_batches, sequence_batches, sequence_clips
from jaxsr.nn.layers import conv3d_native, conv3d_stacked, conv3d_taps
from jaxsr.nn import apply_model, apply_model_sequence, flops_per_frame, init_model, sequence_radius
from jaxsr.training.optim import adam_init
from jaxsr.sensor.peaks import centre_of_mass
from jaxsr.runtime import compiler_options
from jaxsr.sensor.forward import normalise_depth, simulate_histograms
from jaxsr.training import data_mesh, make_train_step

CPU = PRESETS["cpu"]


def _hr_sequence(frames=12, seed=0):
    """A street-like synthetic HR sequence: a ground ramp, boxes moving 1 LR px/frame, sky on top."""
    h, w = Sensor().hr_shape
    yy = np.mgrid[:h, :w][0]
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
    if benchmark.stats is not None:  # None when benchmarks are disabled (a plain test run)
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


# Three train steps timed in interleaved rounds of one run, so that a
# background load slows them alike (only the ratios carry over to another machine):
# - "2026-11-22": the step of 2026-11-22, every example's whole 32 x 64 clip simulated, then cropped; the gradients
#   of the layers `conv3d(impl="auto")` stacks taken through the stacked form; one device;
# - "main": the step of 2026-11-23 (photons drawn for the crop only, `jaxsr.training.data`), still stacked gradients;
# - "new": main's data, the stacked layers' gradients through their temporal taps (`layers.STACKED_GRADIENT`),
#   on one device and with the batch split over both cores as devices (what `fit(mesh="auto")` does).
# The network's forward pass at inference (BN from running statistics, `compiler_options`, same inputs) is timed
# in the same rounds as the reference arithmetic rate.
def _clips_2026_11_22(depth, intensity, frames, train_cfg):
    """The data source of 2026-11-22: each clip of `frames` frames simulated whole, then a random crop kept.
    Returns make_batch: key -> (clips (B, frames, h, w), gt (B, frames, H, W))."""
    sensor = Sensor()

    def example(key):
        k_start, k_snr, k_sig, k_noise, k_crop = jax.random.split(key, 5)
        s = jax.random.randint(k_start, (), 0, depth.shape[0] - frames + 1)
        d = jax.lax.dynamic_slice(depth, (s, 0, 0), (frames, *depth.shape[1:]))
        a = jax.lax.dynamic_slice(intensity, (s, 0, 0), (frames, *depth.shape[1:]))
        snr = log_uniform(k_snr, *train_cfg.snr_range)
        mean_signal = log_uniform(k_sig, *train_cfg.mean_signal_range)
        counts = simulate_histograms(k_noise, d, a, sensor, snr=snr, mean_signal=mean_signal)
        return random_crop(k_crop, centre_of_mass(counts, sensor), normalise_depth(d, sensor), train_cfg.patch,
                           sensor.scale)

    return lambda key: jax.vmap(example)(jax.random.split(key, train_cfg.batch_size))


def _centre_gt(make_clips, tr):
    def make_batch(key):
        clips, gt = make_clips(key)
        return clips, gt[:, tr]

    return make_batch


@contextlib.contextmanager
def _stacked_gradient(how):
    """`layers.STACKED_GRADIENT` set to `how` while a step is traced (jit traces at the first call)."""
    old, layers.STACKED_GRADIENT = layers.STACKED_GRADIENT, how
    try:
        yield
    finally:
        layers.STACKED_GRADIENT = old


def _form_setup(form, tr):
    """(model config, train config, HR depth and intensity, frames per example, supervised frames per example)."""
    if form == "window":
        return ModelConfig(tr=tr), CPU, _hr_sequence(), 2 * tr + 1, 1
    cfg = ModelConfig(tr=tr, temporal="sequence")
    train_cfg = dataclasses.replace(CPU, clip_frames=2 * sequence_radius(cfg) + DEFAULT_CLIP_OUTPUTS)
    return cfg, train_cfg, _hr_sequence(train_cfg.clip_frames + 2), train_cfg.clip_frames, DEFAULT_CLIP_OUTPUTS


def _step_variants(form, tr):
    """{name: (compiled-on-first-call step, its first arguments, STACKED_GRADIENT)} of the three steps."""
    cfg, train_cfg, hr, frames, _ = _form_setup(form, tr)
    depth, intensity = (jnp.asarray(a) for a in hr)
    params, state = init_model(jax.random.key(0), cfg)
    args = (params, state, adam_init(params))
    old = _clips_2026_11_22(depth, intensity, frames, train_cfg)
    new = sequence_clips(depth, intensity, frames, train_cfg)
    if form == "window":  # the centre frame's ground truth only
        old, new = (_centre_gt(f, tr) for f in (old, new))

    def step(make_batch, mesh=None):  # a new make_batch function per variant: its own jitted step
        return make_train_step(cfg, train_cfg, lambda key: make_batch(key), mesh=mesh)

    variants = {"2026-11-22": (step(old), args, "stacked"), "main": (step(new), args, "stacked"),
                "new-1-device": (step(new), args, "taps")}
    if jax.device_count() > 1 and train_cfg.batch_size % jax.device_count() == 0:
        mesh = data_mesh()
        replicated = jax.device_put(args, jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec()))
        variants[f"new-{jax.device_count()}-devices"] = (step(new, mesh), replicated, "taps")
    return cfg, train_cfg, variants, jax.jit(new)(jax.random.key(0))[0]


@pytest.mark.benchmark(group="train_step_today_vs_new")
@pytest.mark.parametrize("form, tr", [("window", 0), ("window", 4), ("sequence", 4)])
def test_train_step_today_vs_new(benchmark, form, tr):
    cfg, train_cfg, variants, inputs = _step_variants(form, tr)
    params, state, _ = variants["main"][1]
    forward = apply_model if form == "window" else functools.partial(apply_model_sequence, padding="valid")
    infer = jax.jit(lambda p, s, x: forward(p, s, x, cfg), compiler_options=compiler_options())
    carry = {k: [*a, 0] for k, (_, a, _) in variants.items()}
    times = {k: [] for k in [*variants, "inference"]}

    def one_round():
        for name, (step_fn, _, how) in variants.items():
            p, s, o, i = carry[name]
            with _stacked_gradient(how):  # matters at the first call only, when the step is traced
                t0 = time.perf_counter()
                p, s, o, m = step_fn(p, s, o, jax.random.key(i), i)
                jax.block_until_ready(m)
                times[name].append(time.perf_counter() - t0)
            carry[name] = [p, s, o, i + 1]
        t0 = time.perf_counter()
        jax.block_until_ready(infer(params, state, inputs))
        times["inference"].append(time.perf_counter() - t0)

    one_round()  # compile
    for v in times.values():
        v.clear()
    benchmark.pedantic(one_round, rounds=4 if tr else 10, iterations=1)
    _, _, _, frames, outputs = _form_setup(form, tr)
    # the network's FLOPs per supervised frame: forward only at inference, forward + backward (3x) in training
    clip = {} if form == "window" else {"clip_frames": frames}
    flops = flops_per_frame(cfg, train_cfg.patch, **clip) * outputs * train_cfg.batch_size
    best = {k: min(ts) for k, ts in times.items()}  # the fastest round: the least disturbed by other work
    for name, t in best.items():
        info = {"step_s": t, "examples_per_s": train_cfg.batch_size / t,
                "frames_per_s": train_cfg.batch_size * outputs / t,
                "gflop_per_s": (1 if name == "inference" else 3) * flops / t / 1e9,
                "speed_up_vs_2026_11_22": best["2026-11-22"] / t, "speed_up_vs_main": best["main"] / t}
        benchmark.extra_info[name] = info
        print(f"{form} TR{tr} {name:16s} {1e3 * t:8.1f} ms/step  {info['examples_per_s']:6.2f} examples/s  "
              f"{info['frames_per_s']:6.2f} frames/s  {info['gflop_per_s']:6.1f} GFLOP/s  "
              f"x{info['speed_up_vs_2026_11_22']:.2f} "
              f"vs 2026-11-22  x{info['speed_up_vs_main']:.2f} vs main")
    benchmark.extra_info["patch"] = train_cfg.patch
