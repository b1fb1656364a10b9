"""Super-resolution of LR depth frames, windowed or in the sequence form, in bounded memory.

Frames go through the network `batch_size` at a time. Each batch is sent to the device as the chunk of
`batch_size + 2 tr` LR frames it needs, and the windows are cut inside the compiled function, so a frame is
transferred once rather than 2 tr + 1 times. Every batch has the same shape (the last one is padded by
repeating the final frame), so a model compiles once per frame size. At most `batch_size + 2 tr` LR frames
and two batches of HR frames are held, however long the sequence is.

A model in the sequence form (`ModelConfig(temporal="sequence")`) runs the same loop with R = 3 + tr in place of
tr: each chunk of `batch_size + 2R` frames goes through `apply_model_sequence` ("valid") once, neighbouring chunks
overlapping by 2R frames.

With several devices (e.g. the host's cores exposed as CPU devices by `use_cpu_cores`), each batch of windows is
split over them (a sequence chunk runs on one device, its convolutions on all cores). The compiled call uses
`jaxsr.runtime.compiler_options()` (on CPU, XLA's own convolutions, which keep both cores busy on one frame;
benchmarks/bench_inference.py::test_network_tr4_one_window).
"""

from __future__ import annotations

import functools
from collections import deque
from collections.abc import Iterable, Iterator

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from ..checks import require_normalised_depth, require_numbers
from ..config import MIN_LR_SIDE, Sensor
from ..eval.metrics import psnr
from ..nn.duf import apply_model_raw, apply_model_sequence
from ..nn.model import Model
from ..runtime import compiler_options
from .forms import DEFAULT_FORM, DEFAULT_PRECISION, FORM_TOLERANCE_DB, check_precision, in_form
from .traced import refuse_tracing
from .units import check_units, lr_to_network, network_to_units

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
    if model.sequence_form:  # the DUF network's sequence form
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


def default_batch_size(frames, sequence_form: bool) -> int:
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


def _check_frame(frame, shape, index, inputs=("depth",), who: str = "super_resolve"):
    """One LR frame checked for a network reading `inputs`: (h, w) normalised depth, or (h, w, C) channels, depth
    first and photon channels finite and >= 0 (`jaxsr.nn.network_inputs`); `who` names the caller in messages."""
    refuse_tracing(frame, who, "jaxsr.apply_sequence(model, lr_seq)")
    if np.iscomplexobj(frame):
        raise ValueError(f"{who}: frame {index} holds complex values; expected real LR normalised depth")
    frame = np.asarray(require_numbers(who, f"frame {index}", frame), np.float32)
    ndim = 2 if len(inputs) == 1 else 3
    if (frame.ndim != ndim or (ndim == 3 and frame.shape[-1] != len(inputs))
            or (shape is not None and frame.shape != shape) or min(frame.shape[:2]) < MIN_LR_SIDE):
        want = str(shape) if shape is not None else (f"(h, w) with h, w >= {MIN_LR_SIDE}" if ndim == 2 else
                                                     f"(h, w, {len(inputs)}) with h, w >= {MIN_LR_SIDE}")
        what = "LR normalised depth" if ndim == 2 else (f"the channels {inputs} of jaxsr.nn.network_inputs; give "
                                                        "photon histograms to super_resolve_histograms")
        raise ValueError(f"{who}: frame {index} has shape {frame.shape}, expected {want} ({what})")
    if ndim == 2:
        return require_normalised_depth(f"{who}: frame {index}", frame)
    photons = frame[..., 1:]
    if not (np.all(np.isfinite(photons)) and photons.min() >= 0):
        raise ValueError(f"{who}: frame {index}'s channels {inputs[1:]} must be finite and >= 0 (encoded "
                         "photons, jaxsr.nn.encode_photons)")
    depth = require_normalised_depth(f"{who}: frame {index}'s depth", frame[..., 0])
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
    `jaxsr.nn.network_inputs` (`super_resolve_histograms` builds them). In the model's form (`model.form`, or `form`'s):
    frame t is computed from frames t - R .. t + R, R = the model's input radius (tr for the window form, 3 + tr for the
    sequence form), edge-replicated at both ends of the stream (as `jaxsr.temporal.windows`), so frame t is yielded once
    frame t + R has arrived (or the stream has ended), `batch_size` at a time. batch_size: frames per compiled call
    (None: `DEFAULT_BATCH_SIZE` per local device, `DEFAULT_ACCELERATOR_BATCH_SIZE` on an accelerator, split over the
    local devices when they divide it; sequence form: `DEFAULT_SEQUENCE_CHUNK`, or the length of a shorter list or
    array). conv3d_impl: how the convolutions run (see `apply_model`). tile: the largest side, in LR pixels, of the
    spatial tiles a larger frame is cut into (`tile_spans`: margins of the network's receptive radius,
    `jaxsr.nn.duf.spatial_radius`, so the output equals the whole frame's to float rounding), bounding device memory
    whatever the frame size; None runs whole frames. Any frame size h, w >= `MIN_LR_SIDE` runs, compiled once per size;
    the bundled models were trained on 32 x 64 frames of a 30 deg field of view (README "Frame size"). precision: how
    the network's convolutions multiply (`jaxsr.config.PRECISIONS`, default `DEFAULT_PRECISION`; "bfloat16": bfloat16
    operands, float32 sums; only "default" for the baselines).
    form: the temporal form the model runs in (`FORMS`, `in_form`; default "model": as its config says).
    raw: for a model with a no-return head, yield (h r, w r, 2) [depth, no-return logit] before the decision
    (`jaxsr.nn.apply_model_raw`), for a decision of one's own (`overrule_no_return`).
    Yields (h r, w r) float32 NumPy arrays of HR normalised depth (unclipped network output). NaN is read as
    no return (1.0) and values within 1e-6 of [0, 1] are clipped to it; raises ValueError for a frame of
    another shape than the first or smaller than `MIN_LR_SIDE`, or with values further outside [0, 1] (metres,
    negated, inf: the message names the range seen; `jaxsr.normalise_depth` converts metres).
    """
    _require_model(model, "super_resolve")
    if raw and not model.has_no_return_head:
        raise ValueError("super_resolve: raw gives the depth and the no-return logit of a model with a no-return "
                         "head (such as tr4-ambient); this one has none")
    precision = check_precision(model, precision)
    model = in_form(model, form)
    arch = model.architecture
    if frames is None or isinstance(frames, (str, bytes)):
        raise TypeError(f"super_resolve: frames must be an iterable of LR frames, got {type(frames).__name__}")
    if model.reads_histograms:
        raise ValueError(f"super_resolve: a {model.kind} model reads photon histograms, not depth; use "
                         "super_resolve_histograms(model, counts, intensity=...)")
    inputs = model.channels
    sequence_form = model.sequence_form
    if batch_size is not None and (isinstance(batch_size, bool) or not isinstance(batch_size, (int, np.integer))
                                   or batch_size < 1):
        raise ValueError(f"super_resolve: batch_size must be an integer >= 1, got {batch_size!r}")
    batch_size = default_batch_size(frames, sequence_form) if batch_size is None else int(batch_size)
    if hasattr(frames, "__len__") and len(frames):  # a batch beyond the frames would be padded copies of the last
        batch_size = min(batch_size, len(frames))
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


def super_resolve(model: Model, lr_seq, *, units: str = "normalised", sensor: Sensor | None = None,
                  batch_size: int | None = None, conv3d_impl: str = "auto", tile: int | None = DEFAULT_TILE,
                  precision: str = DEFAULT_PRECISION, form: str = DEFAULT_FORM) -> np.ndarray:
    """Super-resolve a whole LR depth sequence: (T, h, w) -> (T, h r, w r) depth in `units` (NumPy, float32), for
    any h, w >= `MIN_LR_SIDE` (large frames in spatial tiles of at most `tile` LR pixels a side, margins included,
    with the same result; see `iter_super_resolve`).

    In the form `form` picks (`in_form`; the default "auto" runs windowed weights measured equivalent in the
    sequence form, such as the bundled TR3 and TR4, in it, any other model in its own form): window form, each frame
    is the centre of an edge-replicated window of 2 tr + 1 frames (`jaxsr.temporal.windows`) and the result
    equals `apply_model` on those windows; sequence form, the result equals `apply_model_sequence` on the whole
    sequence (`conv3d_impl` and `precision` are passed on). Memory on the device is
    bounded by the batch (see `iter_super_resolve`); the HR result is assembled on the host. `lr_seq` is
    normalised depth in [0, 1] (1 or NaN = no return; checked as in `iter_super_resolve`), or (T, h, w, C) for a
    model reading photons too (`jaxsr.nn.network_inputs`). For a differentiable, traceable version, call
    `jaxsr.apply_sequence(model, lr_seq)`.
    units: "normalised" (default: the network's scale, as jaxsr always read and wrote it) or "m": `lr_seq` in radial
    metres (NaN, inf or beyond the depth span = no return) and the result in metres (inf = no return), converted on
    `sensor`'s depth scale (`jaxsr.Sensor.depth`; default `Sensor()`, 0-35 m; `sensor` is refused beside
    normalised depth, on which it would do nothing).
    precision: as in `iter_super_resolve`. form: the temporal form (`FORMS`, `in_form`), default `DEFAULT_FORM`.
    """
    _require_model(model, "super_resolve")
    refuse_tracing(lr_seq, "super_resolve", "jaxsr.apply_sequence(model, lr_seq)")
    sensor = check_units("super_resolve", units, sensor, depth_input=True)
    if lr_seq is None or isinstance(lr_seq, (str, bytes)):
        raise TypeError(f"super_resolve: expected an LR sequence array (T, h, w), got {type(lr_seq).__name__}")
    if np.iscomplexobj(lr_seq):
        raise ValueError("super_resolve: the LR sequence holds complex values; expected real normalised depth")
    lr_seq = np.asarray(require_numbers("super_resolve", "the LR sequence", lr_seq), np.float32)
    inputs = model.channels
    want = 3 if len(inputs) == 1 else 4
    if lr_seq.ndim != want or lr_seq.shape[0] < 1:
        shape = "(T, h, w)" if want == 3 else f"(T, h, w, {len(inputs)}) of jaxsr.nn.network_inputs"
        hint = "" if want == 3 else (f"; this model reads {inputs} per pixel: give it histograms with "
                                     "super_resolve_histograms")
        raise ValueError(f"super_resolve: expected an LR sequence {shape} with T >= 1, got shape {lr_seq.shape}"
                         + hint)
    if units != "normalised":
        lr_seq = np.asarray(lr_to_network(lr_seq, units, sensor, channels=want == 4))
    r = model.architecture.scale(model.config)
    out = np.empty((lr_seq.shape[0], lr_seq.shape[1] * r, lr_seq.shape[2] * r), np.float32)
    for t, hr in enumerate(iter_super_resolve(model, lr_seq, batch_size=batch_size, conv3d_impl=conv3d_impl,
                                              tile=tile, precision=precision, form=form)):
        if not np.all(np.isfinite(hr)):  # the input was checked: weights or a config that compute nothing
            raise ValueError(f"super_resolve: the model's output holds NaN or inf in frame {t} "
                             f"({1 - np.isfinite(hr).mean():.0%} of its pixels) from a usable input: it computes "
                             "nothing usable (check its config and weights: jaxsr info)")
        out[t] = hr if units == "normalised" else np.asarray(network_to_units(hr, units, sensor))
    return out



def measure_form_equivalence(model: Model, scenes: Iterable, *, form: str = "sequence",
                             tolerance_db: float = FORM_TOLERANCE_DB, batch_size: int | None = None,
                             precision: str = DEFAULT_PRECISION) -> dict:
    """Whether windowed weights keep their accuracy in the temporal form `form`: `model` run in its window form
    and in `form` (`super_resolve`) on each of `scenes`, scored by PSNR (dB, output clipped to [0, 1], the mean
    over a scene's frames, then over the scenes) over all their frames and over the first and last R frames alone
    (R: the input radius in `form`, 3 + tr in the sequence form), where the two forms pad a sequence differently.

    scenes: an iterable of (lr, gt) pairs, (T, h, w) LR normalised depth (or the (T, h, w, C) inputs of a model
    reading photons too) and (T, h r, w r) normalised ground truth. Returns the JSON-ready record that a card's
    "forms" entry holds (`jaxsr.io.save_model(card={"forms": {form: record}})`, read back by `jaxsr.io.load_model`
    into `Model.equivalent_forms`): {"equivalent": both differences within `tolerance_db`, "psnr_window_db",
    "psnr_db" (in `form`), "psnr_difference_db", "edges_psnr_window_db", "edges_psnr_db",
    "edges_difference_db" (`form` minus window), "tolerance_db", "scenes", "frames" (each scene's T)}. Raises
    ValueError for a form the model does not run in besides its window form, or for no scenes."""
    if "window" not in model.forms or form not in model.forms or form == "window":
        raise ValueError(f"measure_form_equivalence: compares a network's window form with another of its forms; "
                         f"a {model.kind} model runs in {model.forms or 'its own form only'}, form {form!r} asked")
    window, other = model.in_form("window"), model.in_form(form)
    r = other.architecture.input_radius(other.config)
    scores, frames = [], []  # per scene: window, form, edges window, edges form
    for lr, gt in scenes:
        gt = np.asarray(gt, np.float32)
        t = gt.shape[0]
        edges = np.unique(np.r_[0 : min(r, t), max(t - r, 0) : t])
        both = [np.clip(super_resolve(m, lr, batch_size=batch_size, precision=precision, form="model"), 0, 1)
                for m in (window, other)]
        scores.append([float(np.mean(psnr(sr, gt))) for sr in both] +
                      [float(np.mean(psnr(sr[edges], gt[edges]))) for sr in both])
        frames.append(int(t))
    if not scores:
        raise ValueError("measure_form_equivalence: no scenes given; expected (lr, gt) pairs")
    w, f, ew, ef = np.mean(scores, axis=0)
    within = abs(f - w) <= tolerance_db and abs(ef - ew) <= tolerance_db
    return {"equivalent": bool(within), "psnr_window_db": round(float(w), 4), "psnr_db": round(float(f), 4),
            "psnr_difference_db": round(float(f - w), 4), "edges_psnr_window_db": round(float(ew), 4),
            "edges_psnr_db": round(float(ef), 4), "edges_difference_db": round(float(ef - ew), 4),
            "tolerance_db": tolerance_db, "scenes": len(scores), "frames": frames}
