"""Super-resolution of depth video: whole sequences, streams and photon histograms, in bounded memory.

Frames go through the network `batch_size` at a time. Each batch is sent to the device as the chunk of
`batch_size + 2 tr` LR frames it needs, and the windows are cut inside the compiled function, so a frame is
transferred once rather than 2 tr + 1 times. Every batch has the same shape (the last one is padded by
repeating the final frame), so a model compiles once per frame size. At most `batch_size + 2 tr` LR frames
and two batches of HR frames are held, however long the sequence is.

A model in the sequence form (`ModelConfig(temporal="sequence")`) runs the same loop with R = 3 + tr in place of
tr: each chunk of `batch_size + 2R` frames goes through `apply_model_sequence` ("valid") once, neighbouring chunks
overlapping by 2R frames. `Stream` takes live input one frame at a time instead, with a latency of R frames.

With several devices (e.g. the host's cores exposed as CPU devices by `use_cpu_cores`), each batch of windows is
split over them (a sequence chunk runs on one device, its convolutions on all cores). The compiled call uses
`jaxsr.runtime.compiler_options()` (on CPU, XLA's own convolutions, which keep both cores busy on one frame;
benchmarks/bench_inference.py::test_network_tr4_one_window).
"""

from __future__ import annotations

import dataclasses
import functools
from collections import deque
from collections.abc import Iterable, Iterator

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from ..checks import require_normalised_depth
from ..config import MIN_LR_SIDE, PRECISIONS, SensorConfig
from ..nn.duf import apply_model_raw, apply_model_sequence, check_conv, sequence_radius
from ..nn.model import Model
from ..nn.inputs import network_inputs
from ..runtime import compiler_options
from ..sensor.peaks import ambient_only, capped_for_sum, check_ambient_settings, check_false_alarm_rate
from ..nn.streaming import stream_init, stream_step

# Frames per device and batch when `batch_size=None`: on XLA:CPU larger batches are no faster per frame
# (benchmarks/bench_inference.py), and one frame per device keeps the latency of a stream low.
DEFAULT_BATCH_SIZE = 1
# The same on an accelerator, whose kernels one 32 x 64 frame leaves mostly idle: on an H100, 8 frames per call
# ran 2.5-5.8x the frames/s of one (TR0 2516 against 581, TR4 1412 against 404;
# experiments/results/benchmarks_gpu_h100.md).
DEFAULT_ACCELERATOR_BATCH_SIZE = 8
# Output frames per compiled call of a sequence-form model when `batch_size=None` (fewer for a shorter array):
# a chunk computes 2R frames more than it returns, so longer chunks waste less. 32 frames from histograms in
# one chunk (TR4: 46 LR frames) ran 1.1-1.2x faster than `Stream`'s per-frame step (a `lax.scan` of that step
# no faster than the loop) and TR4 3.1x faster than the window form (experiments/results/sequence_form.md).
DEFAULT_SEQUENCE_CHUNK = 32
# How inference runs the network's convolutions when the caller does not say (`precision`, `jaxsr.config.PRECISIONS`):
# the backend's own products, float32 on CPU (TF32 for float32 operands on NVIDIA GPUs since Ampere, unchanged).
# bfloat16 kept the bundled models' PSNR within 0.05 dB on the test sequences but ran no faster on XLA:CPU here,
# on a CPU with AVX512-BF16, since XLA:CPU converts the convolutions' bfloat16 operands back to float32
# (experiments/results/inference_forms.md); it is not the default on an accelerator either, where it was not
# measured.
DEFAULT_PRECISION = "default"
# The form `super_resolve` and `super_resolve_histograms` (whole arrays) run a model in when the caller does not say.
DEFAULT_FORM = "auto"
# The temporal forms inference can run a DUF model in (`form`): "model" (as `model.config.temporal` says),
# "window", "sequence" (any weights run in either form), or "auto": the sequence form for a sequence-form model
# and for windowed depth-only weights whose TR is in `SEQUENCE_FORM_TRS` on at least `SEQUENCE_FORM_MIN_FRAMES`
# frames (or a stream of unknown length), else the model's own form.
FORMS = ("auto", "model", "window", "sequence")
# The TRs whose windowed weights (the bundled depth models) gave their windowed PSNR within 0.1 dB in the sequence
# form on the test sequences, edge frames included, and ran faster in it (experiments/results/inference_forms.md,
# 2026-11-26: TR3 -0.04, TR4 +0.02 dB; TR2 -0.07 but -0.10 at the edges, TR1 -0.60, TR0 -0.44).
SEQUENCE_FORM_TRS = (3, 4)
# "auto" keeps the window form on fewer frames: a sequence-form call computes 2R frames beyond its outputs at the
# first block, which a chunk of `DEFAULT_SEQUENCE_CHUNK` outputs pays for and a few frames do not.
SEQUENCE_FORM_MIN_FRAMES = 32
# Largest side of a spatial tile, in LR pixels, margins included, when `tile` is not given: frames up to 128 x 128
# LR pixels (16x the 32 x 64 sensor) run whole; larger ones in tiles, so device memory stays bounded whatever the
# frame size (a 160 x 160 frame: 2 x 2 tiles of 98 x 98 for TR4).
DEFAULT_TILE = 128


def _batch_sharding(batch_size: int) -> NamedSharding | None:
    """Split a batch over all local devices when there are several and they divide it evenly."""
    devices = jax.local_devices()
    if len(devices) < 2 or batch_size % len(devices):
        return None
    return NamedSharding(Mesh(np.asarray(devices), ("batch",)), P("batch"))


def _windows_through_model(model: Model, chunk, sharding=None, conv3d_impl="auto", precision="default", raw=False):
    """chunk (B + 2 R, h, w) -> (B, h r, w r), R = `input_radius`. Window form: the centre frame of each of the
    B windows of 2 tr + 1 frames, the windows split over `sharding`'s devices (the model and chunk are
    replicated). Sequence form: the B outputs of the chunk, "valid" (`apply_model_sequence`). precision: passed
    to the network only when it is not "default" (the baselines take none). raw (a DUF model with a no-return
    head): (B, h r, w r, 2) [depth, logit] before the decision (`apply_model_raw`)."""
    arch = model.architecture
    extra = {} if precision == "default" else {"precision": precision}
    if arch.sequence_form(model.config):  # the DUF network's sequence form
        return apply_model_sequence(model.params, model.state, chunk[None], model.config, padding="valid",
                                    conv3d_impl=conv3d_impl, raw=raw, **extra)[0]
    n = arch.frames(model.config)
    b = chunk.shape[0] - n + 1
    windows = chunk[jnp.arange(b)[:, None] + jnp.arange(n)[None, :]]
    if sharding is not None:
        windows = jax.lax.with_sharding_constraint(windows, sharding)
    apply = apply_model_raw if raw else arch.apply
    return apply(model.params, model.state, windows, model.config, conv3d_impl=conv3d_impl, **extra)


@functools.cache
def _infer_chunk():
    """`_windows_through_model`, jitted once the backend (and so its `compiler_options`) is known."""
    return jax.jit(_windows_through_model, static_argnames=("sharding", "conv3d_impl", "precision", "raw"),
                   compiler_options=compiler_options())


def check_precision(model: Model, precision, who: str = "super_resolve") -> str:
    """`precision` if it is one of `PRECISIONS` and applies to `model`: any of them for the DUF network, only
    "default" for a network without `precision` (the baselines). Raises ValueError naming the choices."""
    if not isinstance(precision, str) or precision not in PRECISIONS:
        raise ValueError(f"{who}: precision must be one of {', '.join(map(repr, PRECISIONS))}, got {precision!r}")
    if precision != "default" and model.kind != "duf":
        raise ValueError(f"{who}: precision {precision!r} applies to the DUF network's convolutions; a "
                         f"{model.kind} model runs with precision 'default'")
    return precision


def in_form(model: Model, form: str = "auto", who: str = "super_resolve", *, frames: int | None = None) -> Model:
    """`model` in the temporal form `form` asks for (`FORMS`): "model" leaves it as it is; "window" and
    "sequence" set the DUF config's `temporal` (the same weights; refused for another architecture); "auto"
    turns windowed depth-only DUF weights of a TR in `SEQUENCE_FORM_TRS` into the sequence form when `frames`
    (the sequence's length; None: unknown, a stream) is None or at least `SEQUENCE_FORM_MIN_FRAMES`, and leaves
    any other model as it is. Returns a `Model` (the same one when nothing changes); raises ValueError for an
    unknown form."""
    if not isinstance(form, str) or form not in FORMS:
        raise ValueError(f"{who}: form must be one of {', '.join(map(repr, FORMS))}, got {form!r}")
    cfg = model.config
    if model.kind != "duf":
        if form in ("window", "sequence"):
            raise ValueError(f"{who}: form {form!r} applies to the DUF network (window or sequence form); a "
                             f"{model.kind} model runs in its own form ('auto' or 'model')")
        return model
    if form == "model":
        return model
    if form == "auto":
        windowed_depth = cfg.temporal == "window" and tuple(cfg.inputs) == ("depth",) and not cfg.no_return_head
        long = frames is None or frames >= SEQUENCE_FORM_MIN_FRAMES
        if not (windowed_depth and cfg.tr in SEQUENCE_FORM_TRS and long):
            return model
        form = "sequence"
    return model if cfg.temporal == form else Model(model.params, model.state, dataclasses.replace(cfg, temporal=form))


def _default_batch_size(frames, sequence_form: bool) -> int:
    """Frames per compiled call when the caller gives none: per local device `DEFAULT_BATCH_SIZE` on CPU or
    `DEFAULT_ACCELERATOR_BATCH_SIZE` on an accelerator (window form), or a chunk of `DEFAULT_SEQUENCE_CHUNK` but
    no longer than `frames` when it has a length (sequence form)."""
    if not sequence_form:
        per_device = DEFAULT_BATCH_SIZE if jax.default_backend() == "cpu" else DEFAULT_ACCELERATOR_BATCH_SIZE
        return per_device * jax.local_device_count()
    n = len(frames) if hasattr(frames, "__len__") else DEFAULT_SEQUENCE_CHUNK
    return max(1, min(n, DEFAULT_SEQUENCE_CHUNK))


def _require_model(model, who: str) -> Model:
    """`model` if it is a loaded `Model`; a TypeError that says how to get one otherwise (None, a name, a path)."""
    if not isinstance(model, Model):
        raise TypeError(f"{who}: expected a jaxsr.Model (e.g. jaxsr.load_model('tr4')), got "
                        f"{type(model).__name__} {model!r:.60}")
    return model


def _check_frame(frame, shape, index, inputs=("depth",)):
    """One LR frame checked for a network reading `inputs`: (h, w) normalised depth, or (h, w, C) channels, depth
    first and photon channels finite and >= 0 (`jaxsr.nn.network_inputs`)."""
    frame = np.asarray(frame, np.float32)
    ndim = 2 if len(inputs) == 1 else 3
    if (frame.ndim != ndim or (ndim == 3 and frame.shape[-1] != len(inputs))
            or (shape is not None and frame.shape != shape) or min(frame.shape[:2]) < MIN_LR_SIDE):
        want = str(shape) if shape is not None else (f"(h, w) with h, w >= {MIN_LR_SIDE}" if ndim == 2 else
                                                     f"(h, w, {len(inputs)}) with h, w >= {MIN_LR_SIDE}")
        what = "LR normalised depth" if ndim == 2 else (f"the channels {inputs} of jaxsr.nn.network_inputs; give "
                                                        "photon histograms to super_resolve_histograms")
        raise ValueError(f"super_resolve: frame {index} has shape {frame.shape}, expected {want} ({what})")
    if ndim == 2:
        return require_normalised_depth(f"super_resolve: frame {index}", frame)
    photons = frame[..., 1:]
    if not (np.all(np.isfinite(photons)) and photons.min() >= 0):
        raise ValueError(f"super_resolve: frame {index}'s channels {inputs[1:]} must be finite and >= 0 (encoded "
                         "photons, jaxsr.nn.encode_photons)")
    depth = require_normalised_depth(f"super_resolve: frame {index}'s depth", frame[..., 0])
    return np.concatenate([depth[..., None], photons], axis=-1)


def tile_spans(n: int, radius: int, max_side: int | None) -> tuple[int, list[tuple[int, int, int]]]:
    """Cut one axis of n LR pixels into tiles of one length (one compiled shape) whose outputs, kept on their
    cores, equal the whole axis's output: each core [lo, hi) is computed in a tile [start, start + size) that
    extends `radius` (the network's receptive radius) beyond it, or reaches the frame's edge, where the whole-frame
    computation pads the same way.

    Returns (size, spans): the tiles' length and a list of (start, lo, hi), each tile's first pixel and its
    core; (n, [(0, 0, n)]) when n <= max_side (or max_side is None). Raises ValueError if max_side <= 2 radius
    (no core would fit)."""
    if max_side is None or n <= max_side:
        return n, [(0, 0, n)]
    if max_side <= 2 * radius:
        raise ValueError(f"super_resolve: tile must exceed twice the receptive radius ({2 * radius} LR pixels), "
                         f"got {max_side}")
    count = -(-n // (max_side - 2 * radius))  # fewest tiles whose cores (and margins) fit in max_side
    core = -(-n // count)
    size = core + 2 * radius
    return size, [(min(max(lo - radius, 0), n - size), lo, min(lo + core, n)) for lo in range(0, n, core)]


def iter_super_resolve(model: Model, frames: Iterable, *, batch_size: int | None = None,
                       conv3d_impl: str = "auto", tile: int | None = DEFAULT_TILE, precision: str = DEFAULT_PRECISION,
                       form: str = "model", raw: bool = False) -> Iterator[np.ndarray]:
    """Super-resolve a stream of LR frames, yielding HR frames in order, in bounded memory.

    frames: an iterable of (h, w) LR normalised depth frames (0..1, 1 or NaN = no return), e.g. a generator reading
    files one by one; for a model reading photons too (`ModelConfig.inputs`), (h, w, C) frames of
    `jaxsr.nn.network_inputs` (`super_resolve_histograms` builds them). In the model's form (`model.config.temporal`): frame t is computed from frames t - R ..
    t + R, R = `model.config.input_radius` (tr for the window form, 3 + tr for the sequence form),
    edge-replicated at both ends of the stream (as `jaxsr.temporal.windows`), so frame t is yielded once frame
    t + R has arrived (or the stream has ended), `batch_size` at a time. batch_size: frames per compiled call
    (None: `DEFAULT_BATCH_SIZE` per local device, `DEFAULT_ACCELERATOR_BATCH_SIZE` on an accelerator, split
    over the local devices when they divide it; sequence form: `DEFAULT_SEQUENCE_CHUNK`, or the length of a
    shorter list or array). conv3d_impl: how the convolutions run (see `apply_model`). tile: the largest side,
    in LR pixels, of the spatial tiles a larger frame is cut into (`tile_spans`: margins of the network's
    receptive radius, `jaxsr.nn.duf.spatial_radius`, so the output equals the whole frame's to float rounding),
    bounding device memory whatever the frame size; None runs whole frames. Any frame size h, w >= `MIN_LR_SIDE`
    runs, compiled once per size; the bundled models were trained on 32 x 64 frames of a 30 deg field of view
    (README "Frame size"). precision: how the network's convolutions multiply (`jaxsr.config.PRECISIONS`,
    default `DEFAULT_PRECISION`; "bfloat16": bfloat16 operands, float32 sums; only "default" for the baselines).
    form: the temporal form the model runs in (`FORMS`, `in_form`; default "model": as its config says).
    raw: for a model with a no-return head, yield (h r, w r, 2) [depth, no-return logit] before the decision
    (`jaxsr.nn.apply_model_raw`), for a decision of one's own (`overrule_no_return`).
    Yields (h r, w r) float32 NumPy arrays of HR normalised depth (unclipped network output). NaN is read as
    no return (1.0) and values within 1e-6 of [0, 1] are clipped to it; raises ValueError for a frame of
    another shape than the first or smaller than `MIN_LR_SIDE`, or with values further outside [0, 1] (metres,
    negated, inf: the message names the range seen; `jaxsr.normalise_depth` converts metres).
    """
    _require_model(model, "super_resolve")
    if raw and not getattr(model.config, "no_return_head", False):
        raise ValueError("super_resolve: raw gives the depth and the no-return logit of a model with a no-return "
                         "head (such as tr4-ambient); this one has none")
    precision = check_precision(model, precision)
    model = in_form(model, form, frames=len(frames) if hasattr(frames, "__len__") else None)
    arch = model.architecture
    if frames is None or isinstance(frames, (str, bytes)):
        raise TypeError(f"super_resolve: frames must be an iterable of LR frames, got {type(frames).__name__}")
    if arch.inputs != "depth":
        raise ValueError(f"super_resolve: a {arch.name} model reads photon histograms, not depth; use "
                         "super_resolve_histograms(model, counts, intensity=...)")
    inputs = getattr(model.config, "inputs", ("depth",))
    sequence_form = arch.sequence_form(model.config)
    batch_size = _default_batch_size(frames, sequence_form) if batch_size is None else int(batch_size)
    if batch_size < 1:
        raise ValueError(f"super_resolve: batch_size must be >= 1, got {batch_size}")
    sharding = None if sequence_form else _batch_sharding(batch_size)
    if sharding is not None:  # replicate the weights once, not on every call
        replicated = NamedSharding(sharding.mesh, P())
        model = jax.device_put(model, replicated)
    tr = arch.input_radius(model.config)  # the loop below needs only the radius: tr, or R in the sequence form
    margin = arch.receptive_radius(model.config)
    if margin is None:  # a network that reads the whole frame runs on whole frames
        margin, tile = 0, None
    if tile is not None and tile <= 2 * margin:
        raise ValueError(f"super_resolve: tile must exceed twice the receptive radius ({2 * margin} LR pixels for "
                         f"this model), got {tile}")
    held = deque()  # LR frames first_held .. ; frame `first_held` is the oldest any pending window needs
    first_held, next_out, n_seen, shape, pending = 0, 0, 0, None, None

    def frame(i, last):
        """LR frame i, edge-replicated: clipped to 0 and, once the stream has ended, to its last frame."""
        i = max(i, 0) if last is None else min(max(i, 0), last)
        return held[i - first_held]

    def run(count, last):
        """Dispatch (asynchronously) windows next_out .. next_out + count - 1, padded to batch_size by
        repeating the final frame so that every call has the same shape (sequence form: a last, shorter
        chunk to the next power of two, so that a long chunk does not run for a few frames)."""
        chunk = np.stack([frame(i, last) for i in range(next_out - tr, next_out + count + tr)])
        size = min(batch_size, 1 << (count - 1).bit_length()) if sequence_form else batch_size
        if count < size:
            chunk = np.concatenate([chunk, np.repeat(chunk[-1:], size - count, 0)])
        (th, rows), (tw, cols) = tile_spans(shape[0], margin, tile), tile_spans(shape[1], margin, tile)
        tiles = []  # every tile one shape: one compilation per frame size
        for y0, ylo, yhi in rows:
            for x0, xlo, xhi in cols:
                part = chunk[:, y0 : y0 + th, x0 : x0 + tw]
                part = jnp.asarray(part) if sharding is None else jax.device_put(part, replicated)
                tiles.append((_infer_chunk()(model, part, sharding, conv3d_impl, precision, raw), y0, ylo, yhi, x0,
                              xlo, xhi))
        return tiles, count

    def drain(result):
        tiles, count = result
        if len(tiles) == 1:
            yield from np.asarray(tiles[0][0])[:count]
            return
        r = arch.scale(model.config)
        out = np.empty((count, shape[0] * r, shape[1] * r, *tiles[0][0].shape[3:]), np.float32)
        for hr, y0, ylo, yhi, x0, xlo, xhi in tiles:
            out[:, ylo * r : yhi * r, xlo * r : xhi * r] = np.asarray(hr)[:count, (ylo - y0) * r : (yhi - y0) * r,
                                                                          (xlo - x0) * r : (xhi - x0) * r]
        yield from out

    for f in frames:
        f = _check_frame(f, shape, n_seen, inputs)
        shape = f.shape
        held.append(f)
        n_seen += 1
        # windows next_out .. next_out + batch_size - 1 are complete once frame next_out + batch_size - 1 + tr is in
        if n_seen - 1 >= next_out + batch_size - 1 + tr:
            result = run(batch_size, None)  # the stream goes on: nothing to replicate on the right
            if pending is not None:
                yield from drain(pending)
            pending = result
            next_out += batch_size
            while first_held < next_out - tr:
                held.popleft()
                first_held += 1
    last = n_seen - 1
    while next_out <= last:
        count = min(batch_size, last - next_out + 1)
        result = run(count, last)
        if pending is not None:
            yield from drain(pending)
        pending = result
        next_out += count
    if pending is not None:
        yield from drain(pending)


def super_resolve(model: Model, lr_seq, *, batch_size: int | None = None, conv3d_impl: str = "auto",
                  tile: int | None = DEFAULT_TILE, precision: str = DEFAULT_PRECISION,
                  form: str = DEFAULT_FORM) -> np.ndarray:
    """Super-resolve a whole LR depth sequence: (T, h, w) -> (T, h r, w r) normalised depth (NumPy, float32), for
    any h, w >= `MIN_LR_SIDE` (large frames in spatial tiles of at most `tile` LR pixels a side, margins included,
    with the same result; see `iter_super_resolve`).

    In the form `form` picks (`in_form`; the default "auto" runs the windowed depth TR3 and TR4 in the sequence
    form on `SEQUENCE_FORM_MIN_FRAMES` frames or more, any other model in its own form): window form, each frame
    is the centre of an edge-replicated window of 2 tr + 1 frames (`jaxsr.temporal.windows`) and the result
    equals `apply_model` on those windows; sequence form, the result equals `apply_model_sequence` on the whole
    sequence (`conv3d_impl` and `precision` are passed on). Memory on the device is
    bounded by the batch (see `iter_super_resolve`); the HR result is assembled on the host. `lr_seq` is
    normalised depth in [0, 1] (1 or NaN = no return; checked as in `iter_super_resolve`), or (T, h, w, C) for a
    model reading photons too (`jaxsr.nn.network_inputs`). For a differentiable, traceable version, call `apply_model(params, state, jaxsr.windows(lr_seq, tr), cfg)`.
    precision: as in `iter_super_resolve`. form: the temporal form (`FORMS`, `in_form`), default `DEFAULT_FORM`.
    """
    _require_model(model, "super_resolve")
    if lr_seq is None or isinstance(lr_seq, (str, bytes)):
        raise TypeError(f"super_resolve: expected an LR sequence array (T, h, w), got {type(lr_seq).__name__}")
    lr_seq = np.asarray(lr_seq, np.float32)
    inputs = getattr(model.config, "inputs", ("depth",))
    want = 3 if len(inputs) == 1 else 4
    if lr_seq.ndim != want or lr_seq.shape[0] < 1:
        shape = "(T, h, w)" if want == 3 else f"(T, h, w, {len(inputs)}) of jaxsr.nn.network_inputs"
        hint = "" if want == 3 else (f"; this model reads {inputs} per pixel: give it histograms with "
                                     "super_resolve_histograms")
        raise ValueError(f"super_resolve: expected an LR sequence {shape} with T >= 1, got shape {lr_seq.shape}"
                         + hint)
    r = model.architecture.scale(model.config)
    out = np.empty((lr_seq.shape[0], lr_seq.shape[1] * r, lr_seq.shape[2] * r), np.float32)
    for t, hr in enumerate(iter_super_resolve(model, lr_seq, batch_size=batch_size, conv3d_impl=conv3d_impl,
                                              tile=tile, precision=precision, form=form)):
        out[t] = hr
    return out


@functools.partial(jax.jit, static_argnames="inputs")
def _inputs_chunk(counts, sensor, inputs):
    return network_inputs(counts, sensor, inputs)


def iter_centre_of_mass(counts: Iterable, sensor: SensorConfig = SensorConfig(), *,
                        chunk: int = 16) -> Iterator[np.ndarray]:
    """Centre-of-mass depth of a stream of histogram frames, `chunk` frames per compiled call.

    counts: an iterable of (h, w, K) photon counts, or a (T, h, w, K) array. Yields (h, w) float32 LR
    normalised depth frames. Raises ValueError for a frame whose bin count is not `sensor.bins`, or with
    negative or non-finite counts."""
    return iter_network_inputs(counts, sensor, chunk=chunk)


def iter_network_inputs(counts: Iterable, sensor: SensorConfig = SensorConfig(), inputs=("depth",), *,
                        chunk: int = 16) -> Iterator[np.ndarray]:
    """A network's input frames from a stream of histogram frames (`jaxsr.nn.network_inputs`), `chunk` frames per
    compiled call: (h, w) depth for inputs ("depth",), else (h, w, len(inputs)); float32. Counts are checked as
    in `iter_centre_of_mass`."""
    inputs = tuple(inputs)
    buf = []

    def flush():
        block = np.stack(buf)
        n = block.shape[0]
        if n < chunk:  # keep one compiled shape
            block = np.concatenate([block, np.zeros((chunk - n, *block.shape[1:]), block.dtype)])
        yield from np.asarray(_inputs_chunk(jnp.asarray(block), sensor, inputs))[:n]
        buf.clear()

    for i, c in enumerate(counts):
        c = np.asarray(c, np.float32)
        if c.ndim != 3 or c.shape[-1] != sensor.bins:
            raise ValueError(f"super_resolve_histograms: frame {i} has shape {c.shape}, expected (h, w, "
                             f"{sensor.bins}) photon counts")
        if not np.all(np.isfinite(c)) or np.any(c < 0):
            raise ValueError(f"super_resolve_histograms: frame {i} has negative or non-finite counts")
        buf.append(c)
        if len(buf) == chunk:
            yield from flush()
    if buf:
        yield from flush()


@functools.partial(jax.jit, static_argnames=("sensor", "pixels", "frames"))
def _ambient_centre(window, alpha, sensor, pixels, frames):
    """`ambient_only` of the centre frame of a (frames, h, w, K) window, frames beyond the sequence zero: the
    window summed over its frames first (one frame's memory for the test, not the window's)."""
    summed = jnp.sum(capped_for_sum(window, pixels * pixels * frames), axis=0, keepdims=True)
    return ambient_only(summed, sensor, alpha=alpha, pixels=pixels, frames=1)[0]


def iter_ambient_only(counts: Iterable, sensor: SensorConfig = SensorConfig(), *, alpha: float = 1e-3,
                      pixels: int = 3, frames: int = 9) -> Iterator[np.ndarray]:
    """`jaxsr.sensor.ambient_only` over a stream of histogram frames, frame by frame: (h, w) bool per frame, True
    where the photons of the `pixels` x `pixels` pixels and `frames` frames around a pixel pass for ambient light
    alone at false-alarm rate `alpha` (no return to be seen). The same as `ambient_only` of the whole sequence,
    holding only `frames` frames at a time (frame t comes once frame t + frames // 2 has been read). Counts as
    `iter_network_inputs` checks them."""
    check_ambient_settings("iter_ambient_only", alpha, pixels, frames)  # before the first frame is read
    r = frames // 2
    held = deque()  # frames t - r .. t + r of the next frame t to flag (fewer at the start)
    t = first = 0  # the next frame to flag; the sequence frame held[0] is

    def flag(first):  # frame t from `held`, which starts at sequence frame `first`; missing frames are zero
        zero = np.zeros_like(held[0])
        window = [held[k - first] if 0 <= k - first < len(held) else zero for k in range(t - r, t + r + 1)]
        return np.asarray(_ambient_centre(jnp.asarray(np.stack(window)), alpha, sensor, pixels, frames))

    for i, c in enumerate(counts):
        c = np.asarray(c, np.float32)
        if c.ndim != 3 or c.shape[-1] != sensor.bins or (held and c.shape != held[-1].shape):
            want = f"{held[-1].shape}, as the frames before it" if held else f"(h, w, {sensor.bins}) photon counts"
            raise ValueError(f"iter_ambient_only: frame {i} has shape {c.shape}, expected {want}")
        if not np.all(np.isfinite(c)) or np.any(c < 0):
            raise ValueError(f"iter_ambient_only: frame {i} has negative or non-finite counts")
        held.append(c)
        if i == t + r:
            yield flag(first)
            t += 1
            if len(held) > 2 * r:
                held.popleft()
                first += 1
    while held and t <= first + len(held) - 1:  # the last r frames: the sequence ends before their windows do
        yield flag(first)
        t += 1


def check_keep_returns(keep_returns, ambient_alpha, has_head: bool, where: str = "") -> None:
    """Refuse, before any work, a `keep_returns` that is not None or a false-alarm rate, one given beside an
    `ambient_alpha` rate (one marks no return where the photons show none, the other keeps the returns they show:
    one decision at a time), and one for a model without a no-return head (nothing to overrule). `where` prefixes
    the messages (the caller's name)."""
    if keep_returns is None:
        return
    check_false_alarm_rate(f"{where}keep_returns (--keep-returns)", keep_returns)
    if ambient_alpha is not None:
        raise ValueError(f"{where}keep_returns (--keep-returns) and ambient_alpha (--ambient-alpha) are two decisions "
                         "on no return: give one (ambient_alpha None, --ambient-alpha off)")
    if not has_head:
        raise ValueError(f"{where}keep_returns (--keep-returns) overrules a no-return head's decision and this model "
                         "has no head: give one that has (tr4-ambient, tr0-ambient, tr4-photons, tr0-photons)")


def super_resolve_histograms(model: Model, counts, sensor: SensorConfig = SensorConfig(), *, intensity=None,
                             batch_size: int | None = None, conv3d_impl: str = "auto",
                             tile: int | None = DEFAULT_TILE, precision: str = DEFAULT_PRECISION,
                             form: str = DEFAULT_FORM, ambient_alpha: float | None = None,
                             keep_returns: float | None = None) -> np.ndarray:
    """Super-resolve photon histograms: (T, h, w, K) counts -> (T, h r, w r) normalised depth (NumPy, float32).

    A model that reads depth (the DUF network, iSeeBetter) gets the centre-of-mass depth of each frame
    (`jaxsr.centre_of_mass` with `sensor`, K = `sensor.bins` over the sensor's gate [0, d_max): the normalised
    depth is tau / K), and the photons behind it if its config lists more `inputs` (`jaxsr.nn.network_inputs`),
    `super_resolve`d, streaming (see `iter_super_resolve`; `batch_size`, `conv3d_impl`, `tile` and `precision`
    as there, `form` as in `super_resolve`). A model that reads histograms (HistNet) gets the counts themselves
    with `intensity` (T, h r, w r), the HR intensity in [0, 1] it is guided by (required for it, refused
    otherwise), frame by frame in batches of `batch_size`. Any h, w >= `MIN_LR_SIDE`; for histograms over
    another gate, see `jaxsr.Gate` and `jaxsr.sensor.gate_depth`.
    ambient_alpha: also output no return (1.0) wherever the photons around an LR pixel pass for ambient light
    alone at this false-alarm rate (`jaxsr.sensor.ambient_only`: 3 x 3 pixels, 9 frames; default None: off). It
    empties the insides of sky and absorbing regions that a model shows as depth, and drops returns too faint to
    stand out even summed: worth it from about 3 signal photons per pixel at SNR 1 and above, not at SNR 0.1
    (experiments/results/no_return_evidence.md).
    keep_returns: for a model with a no-return head, a false-alarm rate: its no return is kept only where each LR
    pixel's own photons over 9 frames pass for ambient light alone at it, elsewhere the network's depth
    (`overrule_no_return`; `jaxsr upscale --keep-returns`); default None: the head decides. Not with
    ambient_alpha."""
    _require_model(model, "super_resolve_histograms")
    precision = check_precision(model, precision, "super_resolve_histograms")
    if counts is None or isinstance(counts, (str, bytes)):
        raise TypeError(f"super_resolve_histograms: expected photon counts (T, h, w, {sensor.bins}), got "
                        f"{type(counts).__name__}")
    counts = np.asarray(counts)
    if counts.ndim != 4 or counts.shape[0] < 1 or min(counts.shape[1:3]) < MIN_LR_SIDE:
        raise ValueError(f"super_resolve_histograms: expected counts (T, h, w, {sensor.bins}) with T >= 1 and h, w >= "
                         f"{MIN_LR_SIDE}, got shape {counts.shape}")
    model = in_form(model, form, "super_resolve_histograms", frames=counts.shape[0])
    if ambient_alpha is not None:  # refused before any work
        check_false_alarm_rate("super_resolve_histograms: ambient_alpha", ambient_alpha)
    check_keep_returns(keep_returns, ambient_alpha, getattr(model.config, "no_return_head", False),
                       "super_resolve_histograms: ")
    arch = model.architecture
    r = arch.scale(model.config)
    if arch.inputs == "histograms":
        out = _histograms_through_model(model, counts, intensity, sensor, batch_size or DEFAULT_BATCH_SIZE)
        return out if ambient_alpha is None else _no_return_where_ambient(out, counts, sensor, ambient_alpha)
    if intensity is not None:
        raise ValueError(f"super_resolve_histograms: a {arch.name} model reads depth, not intensity; "
                         "pass intensity only to a model that reads histograms (HistNet)")
    out = np.empty((counts.shape[0], counts.shape[1] * r, counts.shape[2] * r), np.float32)
    if batch_size is None:  # the frames' count is known here, not in the stream of centre-of-mass frames
        batch_size = _default_batch_size(counts, arch.sequence_form(model.config))
    frames = iter_network_inputs(counts, sensor, getattr(model.config, "inputs", ("depth",)))
    options = dict(batch_size=batch_size, conv3d_impl=conv3d_impl, tile=tile, precision=precision)
    if keep_returns is None:
        stream = iter_super_resolve(model, frames, **options)
    else:
        stream = iter_returns_kept(model, frames, iter_ambient_only(counts, sensor, alpha=keep_returns, pixels=1),
                                   **options)
    for t, hr in enumerate(stream):
        out[t] = hr
    return out if ambient_alpha is None else _no_return_where_ambient(out, counts, sensor, ambient_alpha)


def no_return_where(hr, flags):
    """HR frames (T, H, W) or one (H, W), normalised, with 1.0 (no return) where LR `flags` ((T, h, w) or (h, w),
    H = r h) say so. Booleans (`jaxsr.sensor.ambient_only`; integers too) paint each LR pixel's r x r HR pixels;
    floating shares of no return in [0, 1] (`jaxsr.sensor.no_return_shares`) are interpolated bilinearly between the LR pixels'
    centres and mark the HR pixels where they reach one half, so that an edge falls inside its block."""
    r = np.shape(hr)[-1] // np.shape(flags)[-1]
    if not np.issubdtype(np.asarray(flags).dtype, np.floating):  # bool (or 0/1 integer) flags: blocks
        marked = lr_blocks(flags, r)
    else:
        marked = np.asarray(_shares_at_hr(jnp.asarray(flags, jnp.float32), r)) >= 0.5
    return np.where(marked, np.float32(1.0), hr)


def lr_blocks(flags, scale: int) -> np.ndarray:
    """LR pixel flags (..., h, w) painted onto their scale x scale HR pixels: (..., h scale, w scale) bool."""
    return np.repeat(np.repeat(np.asarray(flags, bool), scale, axis=-2), scale, axis=-1)


def iter_returns_kept(model: Model, frames: Iterable, quiet: Iterable, **options) -> Iterator[np.ndarray]:
    """`iter_super_resolve(model, frames, **options)` for a model with a no-return head, its no return kept only
    where `quiet` ((h, w) bool per frame, such as `iter_ambient_only(..., pixels=1)`: the pixel's own photons
    pass for ambient light alone) says so, elsewhere the network's depth (`overrule_no_return` at the model's
    threshold): the keep_returns decision of `super_resolve_histograms` and `jaxsr upscale`, streamed."""
    raw = iter_super_resolve(model, frames, raw=True, **options)
    threshold = model.config.no_return_logit
    return (overrule_no_return(hr, q, threshold) for hr, q in zip(raw, quiet, strict=True))


def overrule_no_return(raw, quiet, threshold: float) -> np.ndarray:
    """A no-return head's decision, kept only where the photons agree: HR (..., H, W) normalised depth from `raw`
    (..., H, W, 2) [depth, logit] (`iter_super_resolve(raw=True)`), 1.0 (no return) where the logit is above
    `threshold` AND the pixel's LR block is `quiet` (..., h, w) bool: its own photons pass for ambient light
    alone (`jaxsr.sensor.ambient_only` with pixels=1 over 9 frames). A head trained where ambient light is common
    can call a dim surface of a dark scene no return (a couple of photons in one bin and nothing around); summed
    over the frames those photons stand out, and the depth is kept. The price: a block that a sky edge crosses
    holds a return, so its sky part is output as depth."""
    raw = np.asarray(raw, np.float32)
    h, w = np.shape(quiet)[-2:]
    r = raw.shape[-2] // w if raw.ndim >= 3 else 0
    if raw.ndim < 3 or raw.shape[-1] != 2 or r < 1 or raw.shape[-3:-1] != (h * r, w * r):
        raise ValueError(f"overrule_no_return: raw must be (..., H, W, 2) [depth, logit] with H, W a multiple of "
                         f"quiet's (h, w) = {(h, w)}, got raw {raw.shape}")
    head = raw[..., 1] > np.float32(threshold)
    return np.where(head & lr_blocks(quiet, r), np.float32(1.0), raw[..., 0])


@functools.partial(jax.jit, static_argnames=("scale",))
def _shares_at_hr(shares, scale: int):
    *lead, h, w = shares.shape
    return jax.image.resize(shares, (*lead, h * scale, w * scale), "linear")


def _no_return_where_ambient(out, counts, sensor: SensorConfig, alpha: float) -> np.ndarray:
    for t, flags in enumerate(iter_ambient_only(counts, sensor, alpha=alpha)):
        out[t] = no_return_where(out[t], flags)
    return out


@functools.partial(jax.jit, static_argnames=("sensor",))
def _histogram_chunk(model: Model, counts, intensity, sensor):
    return model.architecture.apply(model.params, model.state, (counts, intensity), model.config, sensor=sensor)


def _histograms_through_model(model: Model, counts, intensity, sensor: SensorConfig, batch_size: int) -> np.ndarray:
    """A histogram-reading model over (T, h, w, K) counts and (T, H, W) intensity, `batch_size` frames per call
    (the last call padded by repeating its final frame, so that every call has one shape)."""
    r = model.architecture.scale(model.config)
    want = (counts.shape[0], counts.shape[1] * r, counts.shape[2] * r)
    if intensity is None or np.shape(intensity) != want:
        raise ValueError(f"super_resolve_histograms: a {model.kind} model needs intensity {want} (T, h r, w r) "
                         f"beside counts {counts.shape}, got {None if intensity is None else np.shape(intensity)}")
    intensity = np.asarray(intensity, np.float32)
    counts = np.asarray(counts, np.float32)
    out = np.empty(want, np.float32)
    for i in range(0, counts.shape[0], batch_size):
        c, f = counts[i : i + batch_size], intensity[i : i + batch_size]
        n = c.shape[0]
        if n < batch_size:
            c = np.concatenate([c, np.repeat(c[-1:], batch_size - n, 0)])
            f = np.concatenate([f, np.repeat(f[-1:], batch_size - n, 0)])
        out[i : i + n] = np.asarray(_histogram_chunk(model, c, f, sensor))[:n]
    return out


@functools.cache
def _stream_step():
    """`stream_step`, jitted once the backend (and so its `compiler_options`) is known."""
    return jax.jit(stream_step, static_argnames=("cfg", "conv3d_impl", "precision"),
                   compiler_options=compiler_options())


class Stream:
    """Live super-resolution in the sequence form: push LR frames one at a time, get each HR frame R frames later.

    `push(frame)` takes an (h, w) LR normalised depth frame and returns the (h r, w r) HR frame of R frames
    earlier (R = 3 + tr, `jaxsr.nn.duf.sequence_radius`), or None during the first R frames; `flush()` ends the
    stream and returns the last min(T, R) HR frames (a list), after which the next `push` starts a new stream.
    The ends are edge-replicated, so the frames equal `super_resolve` of a sequence-form model (and
    `apply_model_sequence`) to float32 rounding. Memory is a fixed set of per-layer buffers (`stream_init`),
    whatever the length of the stream. The weights run in the sequence form whatever `model.config.temporal`
    says (a windowed checkpoint streams too, with the sequence form's accuracy). Outputs are float32 NumPy,
    unclipped. Frames are checked as in `iter_super_resolve` (NaN = no return); raises ValueError for a frame of
    another shape than the first or with values outside [0, 1], and for a flush before any frame.
    precision: how the network's convolutions multiply (`jaxsr.config.PRECISIONS`, default `DEFAULT_PRECISION`),
    checked here.
    """

    def __init__(self, model: Model, *, conv3d_impl: str = "auto", precision: str = DEFAULT_PRECISION):
        self.model = _require_model(model, "Stream")
        if model.kind != "duf":
            raise ValueError(f"Stream: streams the DUF network's sequence form; got a {model.kind} model")
        check_conv(conv3d_impl, check_precision(model, precision, "Stream"), "Stream")
        self.conv3d_impl, self.precision = conv3d_impl, precision
        self.latency = sequence_radius(model.config)
        self._reset()

    def _reset(self):
        self._buffers, self._shape, self._last, self._fed = None, None, None, 0

    def _step(self, frame) -> np.ndarray | None:
        """Feed one padded-sequence frame; the output of step n is frame n - 2R of the sequence."""
        m = self.model
        self._buffers, hr = _stream_step()(m.params, m.state, self._buffers, jnp.asarray(frame)[None], m.config,
                                           conv3d_impl=self.conv3d_impl, precision=self.precision)
        self._fed += 1
        return np.asarray(hr[0]) if self._fed > 2 * self.latency else None

    def push(self, frame) -> np.ndarray | None:
        """Feed LR frame t (h, w); returns HR frame t - R (h r, w r), or None while t < R."""
        frame = _check_frame(frame, self._shape, self._fed - self.latency if self._shape else 0,
                             self.model.config.inputs)
        if self._shape is None:  # a new stream: R copies of the first frame before it (edge padding)
            self._shape = frame.shape
            self._buffers = stream_init(self.model.config, frame.shape[:2])
            for _ in range(self.latency):
                self._step(frame)
        self._last = frame
        return self._step(frame)

    def flush(self) -> list[np.ndarray]:
        """End the stream: R copies of the last frame (edge padding) give the HR frames still owed, a list of
        min(T, R) (h r, w r) arrays, T the frames pushed. Raises ValueError if no frame was pushed."""
        if self._shape is None:
            raise ValueError("Stream.flush: no frame was pushed; a stream needs at least one LR frame (h, w)")
        out = [hr for hr in (self._step(self._last) for _ in range(self.latency)) if hr is not None]
        self._reset()
        return out
