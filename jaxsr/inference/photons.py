"""Super-resolution of photon histograms, streamed: the network's inputs from the counts, the ambient-light test
frame by frame, and the decisions on no return (the photons' and a no-return head's).
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
from collections import deque
from collections.abc import Iterable, Iterator

import jax
import jax.numpy as jnp
import numpy as np

from ..checks import require_numbers
from ..config import MIN_LR_SIDE, Sensor
from ..nn.inputs import network_inputs
from ..nn.model import Model
from ..sensor.peaks import (QUIET_POOLS, ambient_only, capped_for_sum, check_ambient_settings,
                            black_holes, check_false_alarm_rate, summed_histograms, without_holes)
from .forms import DEFAULT_FORM, DEFAULT_PRECISION, check_precision, in_form
from .traced import refuse_tracing
from .units import check_units, network_to_units
from .frames import DEFAULT_BATCH_SIZE, DEFAULT_TILE, _require_model, default_batch_size, iter_super_resolve
from .holes import filled_where_holes


@functools.partial(jax.jit, static_argnames="inputs")
def _inputs_chunk(counts, sensor, inputs):
    return network_inputs(counts, sensor, inputs)


def iter_centre_of_mass(counts: Iterable, sensor: Sensor = Sensor(), *,
                        chunk: int = 16) -> Iterator[np.ndarray]:
    """Centre-of-mass depth of a stream of histogram frames, `chunk` frames per compiled call.

    counts: an iterable of (h, w, K) photon counts, or a (T, h, w, K) array. Yields (h, w) float32 LR
    normalised depth frames. Raises ValueError for a frame whose bin count is not `sensor.bins`, or with
    negative or non-finite counts."""
    return iter_network_inputs(counts, sensor, chunk=chunk)


def iter_network_inputs(counts: Iterable, sensor: Sensor = Sensor(), inputs=("depth",), *,
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


@dataclasses.dataclass(frozen=True)
class QuietFrame:
    """One frame of the photons' no-return decision, each (h, w) bool: `quiet`, where no return may be output (the
    photons pass for ambient light alone, in a region that reaches the frame's edge or is larger than a hole);
    `holes`, the quiet pixels given back to a return (a quiet region that returns enclose, a lone quiet pixel);
    `black`, those of the holes whose photons fall short of the ambient light around them (`black_holes`), whose
    depth `fill_holes` takes from the surfaces around them. Not a sequence: code that took a frame's flags as one
    array is refused, not silently given three."""

    quiet: np.ndarray
    holes: np.ndarray
    black: np.ndarray


@functools.partial(jax.jit, static_argnames=("sensor", "pixels", "frames", "pools"))
def _ambient_centre(window, alpha, sensor, pixels, frames, pools):
    """`ambient_only` of the centre frame of a (frames, h, w, K) window, frames beyond the sequence zero: the
    window summed over its frames first (one frame's memory for the test, not the window's)."""
    summed = jnp.sum(capped_for_sum(window, summed_histograms(pixels, frames, pools)), axis=0, keepdims=True)
    return ambient_only(summed, sensor, alpha=alpha, pixels=pixels, frames=1, pools=pools)[0]


@functools.partial(jax.jit, static_argnames=("sensor", "frames"))
def _quiet_centre(window, alpha, sensor, frames):
    """`iter_quiet`'s (quiet, holes, black) of the centre frame of a (frames, h, w, K) window, as `_ambient_centre`."""
    summed = jnp.sum(capped_for_sum(window, summed_histograms(1, frames, QUIET_POOLS)), axis=0, keepdims=True)
    flags = ambient_only(summed, sensor, alpha=alpha, pixels=1, frames=1, pools=QUIET_POOLS)
    quiet = without_holes(flags)
    holes = flags & ~quiet  # `hole_pixels`, its regions labelled once
    return quiet[0], holes[0], black_holes(summed, holes, sensor, alpha=alpha)[0]


def _iter_windows(counts: Iterable, sensor: Sensor, frames: int, name: str) -> Iterator[np.ndarray]:
    """The (frames, h, w, K) window of histograms centred on each frame of a stream, frames beyond the sequence
    zero, holding only `frames` frames at a time (frame t comes once frame t + frames // 2 has been read). Counts
    as `iter_network_inputs` checks them."""
    r = frames // 2
    held = deque()  # frames t - r .. t + r of the next frame t (fewer at the start)
    t = first = 0  # the next frame; the sequence frame held[0] is

    def window(first):  # frame t's from `held`, which starts at sequence frame `first`; missing frames are zero
        zero = np.zeros_like(held[0])
        return np.stack([held[k - first] if 0 <= k - first < len(held) else zero for k in range(t - r, t + r + 1)])

    for i, c in enumerate(counts):
        c = np.asarray(c, np.float32)
        if c.ndim != 3 or c.shape[-1] != sensor.bins or (held and c.shape != held[-1].shape):
            want = f"{held[-1].shape}, as the frames before it" if held else f"(h, w, {sensor.bins}) photon counts"
            raise ValueError(f"{name}: frame {i} has shape {c.shape}, expected {want}")
        if not np.all(np.isfinite(c)) or np.any(c < 0):
            raise ValueError(f"{name}: frame {i} has negative or non-finite counts")
        held.append(c)
        if i == t + r:
            yield window(first)
            t += 1
            if len(held) > 2 * r:
                held.popleft()
                first += 1
    while held and t <= first + len(held) - 1:  # the last r frames: the sequence ends before their windows do
        yield window(first)
        t += 1


def iter_ambient_only(counts: Iterable, sensor: Sensor = Sensor(), *, alpha: float = 1e-3,
                      pixels: int = 3, frames: int = 9, pools: tuple = ()) -> Iterator[np.ndarray]:
    """`jaxsr.sensor.ambient_only` over a stream of histogram frames, frame by frame: (h, w) bool per frame, True
    where the photons of the `pixels` x `pixels` pixels and `frames` frames around a pixel (and, with `pools`,
    those of the flagged pixels around it) pass for ambient light alone at false-alarm rate `alpha` (no return
    to be seen). The same as `ambient_only` of the whole sequence, holding only `frames` frames at a time (frame
    t comes once frame t + frames // 2 has been read). Counts as `iter_network_inputs` checks them."""
    check_ambient_settings("iter_ambient_only", alpha, pixels, frames, pools)  # before the first frame is read
    for window in _iter_windows(counts, sensor, frames, "iter_ambient_only"):
        yield np.asarray(_ambient_centre(jnp.asarray(window), alpha, sensor, pixels, frames, tuple(pools)))


def iter_quiet(counts: Iterable, sensor: Sensor = Sensor(), *, alpha: float = 1e-3,
               frames: int = 9) -> Iterator[QuietFrame]:
    """Where the photons say no return may be output, frame by frame (`QuietFrame`): `quiet`, where the pixel's own
    histograms over `frames` frames and those of the quiet pixels pooled around it (`QUIET_POOLS`) pass for ambient
    light alone at `alpha`, in a region of two pixels or more that reaches the frame's edge or is larger than a hole
    (`jaxsr.sensor.quiet_pixels` of the whole sequence, holding `frames` frames at a time); `holes`, the quiet
    pixels that returns enclose (`jaxsr.sensor.hole_pixels`); `black`, those of them whose photons fall short of
    the ambient light around them at `alpha` (`jaxsr.sensor.black_holes`). The photons' part of `jaxsr upscale`'s
    no-return decision (`--keep-returns`)."""
    check_ambient_settings("iter_quiet", alpha, 1, frames, QUIET_POOLS)
    for window in _iter_windows(counts, sensor, frames, "iter_quiet"):
        quiet, holes, black = _quiet_centre(jnp.asarray(window), alpha, sensor, frames)
        yield QuietFrame(np.asarray(quiet), np.asarray(holes), np.asarray(black))


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


def super_resolve_histograms(model: Model, counts, sensor: Sensor = Sensor(), *, units: str = "normalised",
                             intensity=None,
                             batch_size: int | None = None, conv3d_impl: str = "auto",
                             tile: int | None = DEFAULT_TILE, precision: str = DEFAULT_PRECISION,
                             form: str = DEFAULT_FORM, ambient_alpha: float | None = None,
                             keep_returns: float | None = None) -> np.ndarray:
    """Super-resolve photon histograms: (T, h, w, K) counts -> (T, h r, w r) depth in `units` (NumPy, float32):
    "normalised" (default; the network's scale, the sensor's depth scale `sensor.depth`) or "m" (radial metres,
    inf = no return).

    A model that reads depth (the DUF network, iSeeBetter) gets the centre-of-mass depth of each frame
    (`jaxsr.centre_of_mass` with `sensor`, K = `sensor.bins` over the sensor's gate, put on its depth scale:
    `jaxsr.nn.network_inputs`), and the photons behind it if its config lists more `inputs` (`jaxsr.nn.network_inputs`),
    `super_resolve`d, streaming (see `iter_super_resolve`; `batch_size`, `conv3d_impl`, `tile` and `precision`
    as there, `form` as in `super_resolve`). A model that reads histograms (HistNet) gets the counts themselves
    with `intensity` (T, h r, w r), the HR intensity in [0, 1] it is guided by (required for it, refused
    otherwise), frame by frame in batches of `batch_size`. Any h, w >= `MIN_LR_SIDE`; histograms over another
    gate: `jaxsr.Sensor(gate=jaxsr.Gate(bins, bin_width, start))`.
    ambient_alpha: also output no return (1.0) wherever the photons around an LR pixel pass for ambient light
    alone at this false-alarm rate (`jaxsr.sensor.ambient_only`: 3 x 3 pixels, 9 frames; default None: off). It
    empties the insides of sky and absorbing regions that a model shows as depth, and drops returns too faint to
    stand out even summed: worth it from about 3 signal photons per pixel at SNR 1 and above, not at SNR 0.1
    (experiments/results/no_return_evidence.md).
    keep_returns: for a model with a no-return head, a false-alarm rate: its no return is kept only where the
    photons pass for ambient light alone at it (`iter_quiet`: each LR pixel's own over 9 frames, the quiet pixels'
    pooled around it, no hole that returns enclose), elsewhere the network's depth (`overrule_no_return`; `jaxsr upscale
    --keep-returns`), and the black holes' depth filled from around them (`fill_holes`); default None: the head decides.
    Not with ambient_alpha."""
    refuse_tracing((counts, intensity), "super_resolve_histograms",
                   "jaxsr.apply_histograms(model, counts, sensor)")
    _require_model(model, "super_resolve_histograms")
    precision = check_precision(model, precision, "super_resolve_histograms")
    if not isinstance(sensor, Sensor):
        raise TypeError(f"super_resolve_histograms: sensor is a jaxsr.Sensor (e.g. Sensor(gate=Gate(32, 0.5))), got "
                        f"{type(sensor).__name__}")
    if counts is None or isinstance(counts, (str, bytes)):
        raise TypeError(f"super_resolve_histograms: expected photon counts (T, h, w, {sensor.bins}), got "
                        f"{type(counts).__name__}")
    if np.iscomplexobj(counts):
        raise ValueError("super_resolve_histograms: the counts hold complex values; expected real photon counts")
    counts = require_numbers("super_resolve_histograms", "the counts", counts)
    if counts.ndim != 4 or counts.shape[0] < 1 or min(counts.shape[1:3]) < MIN_LR_SIDE:
        raise ValueError(f"super_resolve_histograms: expected counts (T, h, w, {sensor.bins}) with T >= 1 and h, w >= "
                         f"{MIN_LR_SIDE}, got shape {counts.shape}")
    check_units("super_resolve_histograms", units, sensor, depth_input=False)
    model = in_form(model, form, "super_resolve_histograms")
    if ambient_alpha is not None:  # refused before any work
        check_false_alarm_rate("super_resolve_histograms: ambient_alpha", ambient_alpha)
    check_keep_returns(keep_returns, ambient_alpha, model.has_no_return_head, "super_resolve_histograms: ")
    r = model.architecture.scale(model.config)
    if model.reads_histograms:
        out = _histograms_through_model(model, counts, intensity, sensor, batch_size or DEFAULT_BATCH_SIZE)
        out = out if ambient_alpha is None else _no_return_where_ambient(out, counts, sensor, ambient_alpha)
        return _in_units(out, units, sensor)
    if intensity is not None:
        raise ValueError(f"super_resolve_histograms: a {model.kind} model reads depth, not intensity; "
                         "pass intensity only to a model that reads histograms (HistNet)")
    out = np.empty((counts.shape[0], counts.shape[1] * r, counts.shape[2] * r), np.float32)
    if batch_size is None:  # the frames' count is known here, not in the stream of centre-of-mass frames
        batch_size = default_batch_size(counts, model.sequence_form)
    frames = iter_network_inputs(counts, sensor, model.channels)
    options = dict(batch_size=batch_size, conv3d_impl=conv3d_impl, tile=tile, precision=precision)
    if keep_returns is None:
        stream = iter_super_resolve(model, frames, **options)
    else:  # the no return kept where the photons agree; the holes that returns enclose filled from around them
        flags, holes = itertools.tee(iter_quiet(counts, sensor, alpha=keep_returns))
        kept = iter_returns_kept(model, frames, (q.quiet for q in flags), **options)
        stream = (filled_where_holes(hr, q.black, sensor.depth) for hr, q in zip(kept, holes, strict=True))
    for t, hr in enumerate(stream):
        out[t] = hr
    out = out if ambient_alpha is None else _no_return_where_ambient(out, counts, sensor, ambient_alpha)
    return _in_units(out, units, sensor)


def _in_units(out, units: str, sensor: Sensor) -> np.ndarray:
    if units == "normalised":
        return out
    for t in range(out.shape[0]):  # frame by frame: one frame's temporaries at a time
        out[t] = np.asarray(network_to_units(out[t], units, sensor))
    return out


def no_return_where(hr, flags):
    """HR frames (T, H, W) or one (H, W), normalised, with 1.0 (no return) where LR `flags` ((T, h, w) or (h, w),
    H = r h) say so. Booleans (`jaxsr.sensor.ambient_only`; integers too) paint each LR pixel's r x r HR pixels;
    floating shares of no return in [0, 1] (`jaxsr.sensor.no_return_shares`) are interpolated bilinearly between the
    LR pixels' centres and mark the HR pixels where they reach one half, so that an edge falls inside its block."""
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
    where `quiet` ((h, w) bool per frame, such as `iter_quiet`'s `QuietFrame.quiet`: the photons pass for ambient
    light alone) says so, elsewhere the network's depth (`overrule_no_return` at the model's threshold): the
    keep_returns decision of `super_resolve_histograms` and `jaxsr upscale`, streamed, before `fill_holes`."""
    raw = iter_super_resolve(model, frames, raw=True, **options)
    threshold = model.config.no_return_logit
    return (overrule_no_return(hr, q, threshold) for hr, q in zip(raw, quiet, strict=True))


def overrule_no_return(raw, quiet, threshold: float) -> np.ndarray:
    """A no-return head's decision, kept only where the photons agree: HR (..., H, W) normalised depth from `raw`
    (..., H, W, 2) [depth, logit] (`iter_super_resolve(raw=True)`), 1.0 (no return) where the logit is above
    `threshold` AND the pixel's LR block is `quiet` (..., h, w) bool: its photons pass for ambient light alone
    (`iter_quiet`, as `jaxsr upscale` decides). A head trained where ambient light is common
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


def _no_return_where_ambient(out, counts, sensor: Sensor, alpha: float) -> np.ndarray:
    for t, flags in enumerate(iter_ambient_only(counts, sensor, alpha=alpha)):
        out[t] = no_return_where(out[t], flags)
    return out


@functools.partial(jax.jit, static_argnames=("sensor",))
def _histogram_chunk(model: Model, counts, intensity, sensor):
    return model.architecture.apply(model.params, model.state, (counts, intensity), model.config, sensor=sensor)


def _histograms_through_model(model: Model, counts, intensity, sensor: Sensor, batch_size: int) -> np.ndarray:
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

