"""Depth extraction from photon histograms: centre of mass, and a Poisson maximum-likelihood fit.

Implements docs/sensor-model.md, section 3. Both work per LR pixel on the last (bins) axis and accept any leading
axes. Depth is returned normalised (tau / K in [0, 1], bin-centre convention); pixels without a usable
return are 1.0 ("no return", the same value the ground truth uses for sky).

Counts must be finite and >= 0: eagerly anything else is a `ValueError`; traced (under `jax.jit`, `vmap` or
`grad`, where values cannot be checked) a histogram holding a non-finite or negative count is "no return"
(1.0, invalid) and no other pixel is affected. Counts are computed in at least float32, and the centre of
mass does not depend on the photon scale, so float16 histograms and counts up to float32's maximum work.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import jax.scipy.special
import numpy as np
import optimistix as optx

from ..checks import is_concrete, require_bins
from ..config import Sensor

NO_RETURN = 1.0


def _check_counts(name, counts, sensor):
    """Eagerly refuse non-finite or negative counts; return them as floats of at least 32 bits (float16 sums
    of a few thousand photons overflow)."""
    counts = require_bins(name, counts, sensor)
    if is_concrete(counts):
        values = np.asarray(counts)
        if values.size and not (np.all(np.isfinite(values)) and values.min() >= 0):
            raise ValueError(f"{name}: counts must be finite and >= 0 photons, got min {values.min()} (under jit "
                             "such a histogram is no return, 1.0)")
    return jnp.asarray(counts, dtype=jnp.promote_types(jnp.result_type(counts.dtype, float), jnp.float32))


def _usable(n):
    """(counts with unusable histograms zeroed, usable mask): a histogram with a non-finite or negative count
    is no return (the traced rule; eager calls have refused it)."""
    usable = jnp.all(jnp.isfinite(n) & (n >= 0), axis=-1)
    return jnp.where(usable[..., None], n, 0.0), usable


# `median_of_bins` ranks by comparisons up to this many bins, and sorts above: the comparisons take K^2 memory
# per histogram (16 frames of 32 x 64 pixels with 2000 bins asked XLA for 540 GB).
RANK_MEDIAN_MAX_BINS = 64


def median_of_bins(n):
    """Median over the last axis: for K <= `RANK_MEDIAN_MAX_BINS` without a sort, K^2 rank comparisons, which
    XLA fuses; above, `jnp.median` (a sort), whose memory grows as K.

    For K = 16 the comparisons are 10x faster than `jnp.median` on XLA:CPU and have the same value and
    gradient: the mean of the two middle order statistics for even K, the middle one for odd K.
    """
    k = n.shape[-1]
    if k > RANK_MEDIAN_MAX_BINS:
        return jnp.median(n, axis=-1)
    idx = jnp.arange(k)
    smaller = n[..., None, :] < n[..., :, None]
    tie_before = (n[..., None, :] == n[..., :, None]) & (idx[None, :] < idx[:, None])
    rank = jnp.sum(smaller | tie_before, axis=-1)  # a permutation of 0..K-1 in every histogram
    lower = jnp.sum(jnp.where(rank == (k - 1) // 2, n, 0.0), axis=-1)
    upper = jnp.sum(jnp.where(rank == k // 2, n, 0.0), axis=-1)
    return 0.5 * (lower + upper)


def default_window(sensor: Sensor):
    """Half-width w of the centre-of-mass window in bins: 1 if irf_sigma <= 0.5 bins, else 2."""
    return jnp.where(sensor.irf_sigma <= 0.5, 1, 2)


def centre_of_mass(counts, sensor: Sensor = Sensor(), *, window=None, z=0.0, return_mask=False):
    """Background-subtracted centre of mass around the histogram peak.

    b = median over bins (robust background per bin), k* = first argmax, window W = k* +- w clipped to
    the gate, x_k = max(n_k - b, 0) on W, tau = sum (k + 0.5) x_k / sum x_k. A pixel is invalid (-> 1.0) if
    sum x_k = 0 (zero photons, a flat histogram) or n[k*] < b + z sqrt(max(b, 1)). Differentiable in the
    counts (except at ties of the median and the argmax), with finite gradients everywhere, zero photons
    included.

    Args:
      counts: (..., K) photon counts, K = `sensor.bins`: finite and >= 0 (eagerly a `ValueError`; traced, a
        histogram with a non-finite or negative count is invalid).
      window: half-width w in bins (default: `default_window(sensor)`).
      z: peak-significance threshold in standard deviations of the background (0 keeps every peak).
      return_mask: also return the boolean validity mask.
    Returns:
      (...) normalised depth in [0, 1]; with `return_mask`, (depth, valid).
    """
    n, usable = _usable(_check_counts("centre_of_mass", counts, sensor))
    k = jnp.arange(sensor.bins)
    excess, background = _peak_excess(n, sensor, window)
    # Counts near float32's maximum would overflow the sums below: scale those by 2^-100, which is exact (a
    # power of two), so that nothing else changes, gradients included.
    huge = jnp.max(excess, axis=-1, keepdims=True) > 2.0**100
    excess = jnp.where(huge, excess * 2.0**-100, excess)
    mass = jnp.sum(excess, axis=-1)
    peak = jnp.max(n, axis=-1)
    valid = usable & (mass > 0) & (peak >= background + z * jnp.sqrt(jnp.maximum(background, 1.0)))
    tau = jnp.sum((k + 0.5) * excess, axis=-1) / jnp.where(valid, mass, 1.0)
    depth = jnp.where(valid, tau / sensor.bins, NO_RETURN)
    return (depth, valid) if return_mask else depth


def _window(sensor: Sensor, window):
    """The half-width in bins: `window` (eagerly checked) or the sensor's default."""
    if window is None:
        return default_window(sensor)
    if is_concrete(window):
        w = np.asarray(window)
        if w.shape != () or w.dtype.kind not in "iu" or int(w) < 0:
            raise ValueError(f"window: expected a half-width in bins, an integer >= 0 (or None for the sensor's "
                             f"default), got {window!r}")
    return window


def _peak_window(n, sensor: Sensor, window):
    """(..., K) bool: the bins within the half-width of the first argmax (clipped to the gate)."""
    return jnp.abs(jnp.arange(sensor.bins) - jnp.argmax(n, axis=-1)[..., None]) <= _window(sensor, window)


def _peak_excess(n, sensor: Sensor, window):
    """(counts above the median background in the window around the first argmax (..., K), the median (...))."""
    background = median_of_bins(n)
    in_window = _peak_window(n, sensor, window)
    return jnp.where(in_window, jnp.maximum(n - background[..., None], 0.0), 0.0), background



COM_STD_FLOOR = 0.01  # bins: a centre of mass's std below it (huge counts) reads as this


def centre_of_mass_std(counts, sensor: Sensor = Sensor()):
    """The standard deviation, in bins, of each histogram's centre of mass (`jaxsr.centre_of_mass`) under Poisson
    noise: (..., K) counts -> (...). The delta method on tau = sum (k + 0.5) x_k / sum x_k over the peak's window,
    each bin's variance its expected count (the excess x_k plus the median background b): var = sum (k + 0.5 -
    tau)^2 (x_k + b) / (sum x_k)^2. A histogram without excess (no photons, a flat one) gets the std of a depth
    uniform over the gate, K / sqrt(12). Counts as `centre_of_mass` takes them."""
    n, usable = _usable(_check_counts("centre_of_mass_std", counts, sensor))
    n = n * jnp.minimum(1.0, 2.0**60 / jnp.maximum(jnp.max(n, axis=-1, keepdims=True), 1.0))  # sums stay finite
    excess, background = _peak_excess(n, sensor, None)
    mass = jnp.sum(excess, axis=-1)
    k = jnp.arange(sensor.bins) + 0.5
    tau = jnp.sum(k * excess, axis=-1) / jnp.maximum(mass, 1e-30)
    in_window = excess > 0
    spread = jnp.where(in_window, (k - tau[..., None]) ** 2 * (excess + background[..., None]), 0.0)
    var = jnp.sum(spread, axis=-1) / jnp.maximum(mass, 1e-30) ** 2
    flat = sensor.bins / np.sqrt(12.0)
    std = jnp.where(usable & (mass > 0), jnp.sqrt(var), flat)
    return jnp.clip(std, COM_STD_FLOOR, flat)


def peak_evidence(counts, sensor: Sensor = Sensor(), *, window=None):
    """How much a histogram says about its return: (signal, background) in photons per pixel.

    signal = the counts above the median background in the centre of mass's window (the photons the depth
    is computed from); background = median per bin x K (the ambient and dark photons of the whole gate).
    Ambient light alone gives signal of the order of sqrt(background) (the largest fluctuation), a return
    gives about the photons it sent back: the two tell "no return" from "a surface in mid-gate", which the
    centre of mass alone cannot. Same rules for counts as `centre_of_mass` (an unusable histogram gives 0, 0).

    Returns two arrays of shape counts.shape[:-1], float32 (or wider).
    """
    n, usable = _usable(_check_counts("peak_evidence", counts, sensor))
    excess, background = _peak_excess(n, sensor, window)
    signal = jnp.sum(excess, axis=-1)
    return jnp.where(usable, signal, 0.0), jnp.where(usable, background * sensor.bins, 0.0)


def ambient_photons(counts, sensor: Sensor = Sensor(), *, window=None):
    """The ambient (and dark) photons of the whole gate, estimated from the mean of the bins outside the peak's
    window: photons outside x K / (bins outside).

    Unlike `peak_evidence`'s background (the median bin x K), it does not read 0 when most bins are empty: at a
    few photons per pixel the median is 0 whatever the ambient light (measured: 99.5 % of pixels at 3 signal
    photons and SNR 1.3, every pixel at SNR 45), while the mean outside the window reads the ambient level
    beside a return (within 4 % at 3 signal photons; the return lies inside the window but for a wide pulse's
    tails). In a pixel of ambient light alone the window sits on the largest fluctuation, so it reads low there
    (by 20-70 % below 0.5 photons per bin). A pixel's estimate is
    noisy at low counts; over a neighbourhood and 2 TR + 1 frames it tells SNR 1 from SNR 50. Same rules for
    counts as `centre_of_mass` (an unusable histogram, or a window that covers the gate, gives 0); finite for
    counts up to float32's maximum.

    Returns an array of shape counts.shape[:-1], float32 (or wider).
    """
    n, usable = _usable(_check_counts("ambient_photons", counts, sensor))
    in_window = _peak_window(n, sensor, window)
    outside = jnp.sum(~in_window, axis=-1)
    # the mean of the bins outside (<= the largest count, so finite), then x K within float range
    mean = jnp.sum(jnp.where(in_window, 0.0, n / jnp.maximum(outside, 1)[..., None]), axis=-1)
    photons = jnp.minimum(mean, jnp.finfo(mean.dtype).max / sensor.bins) * sensor.bins
    return jnp.where(usable & (outside > 0), photons, 0.0)


# `return_significance` takes the binomial tail from the incomplete beta function up to this many photons per
# histogram; above, float32's betainc is too coarse (ambient alone at 3e5 photons per bin read as a return in 7 %
# of pixels at a = 0.001), and the Chernoff bound takes over: looser, so the test only grows more careful.
EXACT_TAIL_MAX_PHOTONS = 1e5
# ... and histograms whose largest bin exceeds this are scaled down to it (sums would overflow float32); at such
# counts any departure from a flat histogram is decisive and a flat one is not, as before the scaling.
HUGE_BIN = 2.0**100


def return_significance(counts, sensor: Sensor = Sensor(), *, window=None):
    """How unlikely ambient light alone makes a histogram: log of a p-value (<= 0), low where it holds a return.

    Ambient and dark photons fall uniformly over the gate, so given a histogram's N photons, the photons in any
    fixed window of 2w + 1 bins are Binomial(N, (2w + 1) / K). The statistic is the largest window sum S (a
    scan over the K - 2w full windows), and the p-value is its Bonferroni bound, (K - 2w) P(Binomial >= S),
    at most 1; above `EXACT_TAIL_MAX_PHOTONS` the binomial tail is its Chernoff bound exp(-N KL(S/N || p)). It
    needs no estimate of the background: conditioning on N makes it hold at every ambient level, and a return
    smeared by motion or a wide pulse only weakens it. The counts must be photons, not rates or normalised
    histograms: the evidence grows with the photons (the same shape at 10x the photons is far more significant).
    Summing a pixel's histograms over frames before the call gathers evidence over time: 3 signal photons per
    frame against 2 ambient ones are found in about 6 % of single frames at a = 0.001 and in nearly every sum of
    nine.

    Args:
      counts: (..., K) photon counts, finite and >= 0 (as `centre_of_mass` takes them; traced, an unusable
        histogram gives 0: no evidence); a decision statistic, so no gradient flows through it.
      window: half-width w in bins (default: `default_window(sensor)`, the centre of mass's).
    Returns:
      (...) log p-value in [log(float32 tiny), 0] (about -87.3: evidence beyond float32 stays finite); a pixel
      holds a return at false-alarm rate a where it is <= log(a).
    """
    n, usable = _usable(_check_counts("return_significance", counts, sensor))
    n = jax.lax.stop_gradient(n)
    n = n * jnp.minimum(1.0, HUGE_BIN / jnp.maximum(jnp.max(n, axis=-1, keepdims=True), 1.0))
    w = _window(sensor, window)
    width = jnp.minimum(2 * w + 1, sensor.bins)
    total = jnp.sum(n, axis=-1)
    cumulative = jnp.concatenate([jnp.zeros_like(n[..., :1]), jnp.cumsum(n, axis=-1)], axis=-1)
    starts = jnp.arange(sensor.bins + 1)
    ends = jnp.minimum(starts + width, sensor.bins)
    full = starts + width <= sensor.bins  # windows that lie inside the gate
    sums = jnp.take(cumulative, ends, axis=-1) - cumulative
    scan = jnp.max(jnp.where(full, sums, 0.0), axis=-1)
    log_tail = _log_binomial_tail(scan, total, width / sensor.bins)
    log_p = jnp.log(sensor.bins - width + 1.0) + log_tail
    log_p = jnp.clip(log_p, jnp.log(jnp.finfo(jnp.float32).tiny), 0.0)
    return jnp.where(usable, log_p, 0.0)


# The smallest false-alarm rate `ambient_only` takes: `return_significance` stops at log(float32 tiny) (about
# 1e-37 with the scan's factor), so a smaller alpha would read every pixel as ambient light alone.
MIN_FALSE_ALARM_RATE = 1e-30


def check_false_alarm_rate(name: str, alpha) -> None:
    """Refuse a false-alarm rate that is not a number in [MIN_FALSE_ALARM_RATE, 1) (a traced one passes)."""
    if isinstance(alpha, jax.core.Tracer):
        return
    if isinstance(alpha, bool) or not isinstance(alpha, (int, float, np.integer, np.floating)) or not (
            MIN_FALSE_ALARM_RATE <= float(alpha) < 1.0):
        raise ValueError(f"{name} is a false-alarm rate in [{MIN_FALSE_ALARM_RATE:g}, 1), such as 0.001; got {alpha!r}")


# the pools of the default no-return decision (`ambient_only`): the flagged pixels in 3 x 3 and 5 x 5 around a pixel,
# the smallest that found the returns of dim indoor walls that single pixels miss (experiments/results/
# quiet_pools.md) at the least cost to the sky beside returns
QUIET_POOLS = (3, 5)
# the largest region of quiet LR pixels that returns enclose and that is given back to a return (`without_holes`;
# a black one takes the depth around it: `black_holes`, `jaxsr.inference.fill_holes`): the black screens and
# furniture of indoor rooms are given back (up to 64 scored as any size on the held-out rooms,
# experiments/results/quiet_pools.md), an opening of more than 8 x 8 LR pixels stays no return
HOLE_PIXELS = 64


def check_ambient_settings(name: str, alpha, pixels: int = 3, frames: int = 9, pools=()) -> None:
    """Refuse settings of `ambient_only` before any work: odd sides >= 1 (pools a tuple of them), a false-alarm
    rate in range."""
    if not isinstance(pools, tuple):
        raise ValueError(f"{name}: pools must be a tuple of odd sides in pixels such as (3, 5), got {pools!r}")
    sides = [("pixels", pixels), ("frames", frames)] + [("pools", k) for k in pools]
    for side, value in sides:
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1 or value % 2 == 0:
            raise ValueError(f"{name}: {side} must be an odd integer >= 1, got {value!r}")
    check_false_alarm_rate(f"{name}: alpha", alpha)


def capped_for_sum(counts, histograms: int):
    """Each (..., K) histogram scaled down where its largest bin exceeds HUGE_BIN / `histograms`, so that a sum of
    that many stays finite (pixel by pixel: one corrupt bin does not rescale the others)."""
    cap = HUGE_BIN / histograms
    return counts * jnp.minimum(1.0, cap / jnp.maximum(jnp.max(counts, axis=-1, keepdims=True), 1.0))


def window_sums(counts, frames: int, pixels: int = 1):
    """(T, h, w, K) histograms, each summed with its neighbours over the `frames` frames and `pixels` x `pixels`
    pixels centred on it (odd sides), cut at the edges of the frame and of the sequence, where fewer are summed:
    not replicated, since a repeated histogram's photons are not independent and repeats of one fluctuation would
    read as a return. Same shape; jit-able with `frames` and `pixels` static."""
    r, q = frames // 2, pixels // 2
    padded = jnp.pad(counts, ((r, r), (q, q), (q, q), (0, 0)))
    return jax.lax.reduce_window(padded, 0.0, jax.lax.add, (frames, pixels, pixels, 1), (1, 1, 1, 1), "VALID")


def ambient_only(counts, sensor: Sensor = Sensor(), *, alpha=1e-3, pixels: int = 3, frames: int = 9,
                 pools: tuple = (), window=None):
    """Where the photons around each pixel are consistent with ambient light alone: the no-return test of a video.

    One pixel's histogram in one frame holds too few photons to tell a faint return from ambient light (at 3
    signal photons against 2 ambient, `return_significance` finds about 6 % of returns at alpha = 0.001). This
    sums each pixel's histograms over the `pixels` x `pixels` pixels and `frames` frames centred on it (cut at
    the edges of the frame and of the sequence, where fewer are summed) and tests the sum: True where its
    `return_significance` p-value is above `alpha`, no return to be seen. Inside a region without a return (sky,
    an absorbing surface) the sum is ambient light alone and the test says so with probability about 1 - alpha or
    more at any light level (the p-value is a bound); a pixel whose neighbourhood holds returns is not flagged. It can flag true returns whose
    photons are too few to stand out even summed: added to tr4-photons' decision on the project's test scenes,
    the returns dropped inside their regions went from 0.6 to 1.0 % at 3 signal photons per pixel and SNR 1.3,
    to 4.5 % at 1 photon, and to 15-31 % at 1-3 photons and SNR 0.1 (experiments/results/no_return_evidence*.md).

    `pools` gathers the evidence of a dim surface that no single pixel holds: a pixel stays flagged only where,
    for each side k of `pools`, the summed histograms of the flagged pixels in the k x k pixels around it pass too
    (at alpha / len(pools) each). Only flagged pixels are pooled, so a bright return beside sky does not unflag
    the sky, while a dark wall of a room, whose pixels each show too few photons, shows its return in the pool
    (`QUIET_POOLS`, the default decision of `jaxsr.upscale`: docs/network.md, "The pools").

    Args:
      counts: (T, h, w, K) photon counts of consecutive frames, finite and >= 0 (traced, a histogram that is not
        adds nothing to its neighbours' sums and is flagged if they hold no return).
      alpha: the false-alarm rate of the test per pixel, in [`MIN_FALSE_ALARM_RATE`, 1): below it float32's
        p-values (floored near 1e-37) would flag every pixel.
      pixels, frames: the odd sides of the neighbourhood summed, in LR pixels and in frames (default 9: a TR4
        window).
      pools: odd sides in LR pixels of the flagged neighbourhoods tested after (default none).
      window: half-width in bins of the scan (default: `default_window(sensor)`).
    Returns:
      (T, h, w) bool. jit-able with `pixels`, `frames` and `pools` static; no gradient.
    """
    check_ambient_settings("ambient_only", alpha, pixels, frames, pools)
    if jnp.ndim(counts) != 4:
        raise ValueError(f"ambient_only: counts must be (T, h, w, {sensor.bins}) histograms of consecutive frames, "
                         f"got shape {jnp.shape(counts)}")
    # traced, an unusable histogram adds no photons to its neighbours' sums (eagerly it is refused)
    n, _ = _usable(jax.lax.stop_gradient(_check_counts("ambient_only", counts, sensor)))
    # each histogram capped so that sums of huge counts stay finite (pixel by pixel: one corrupt bin does not
    # rescale the others, and a stream of windows computes what the whole sequence does)
    n = capped_for_sum(n, summed_histograms(pixels, frames, pools))
    summed = window_sums(n, frames, pixels)
    quiet = return_significance(summed, sensor, window=window) > jnp.log(alpha)
    flagged = jnp.where(quiet[..., None], summed, 0.0) if pools else None
    for k in pools:  # the flagged pixels' photons pooled: a dim surface's return shows where no pixel's does
        pooled = window_sums(flagged, 1, k)
        quiet &= return_significance(pooled, sensor, window=window) > jnp.log(alpha / len(pools))
    return quiet


def without_holes(flags, max_pixels: int = HOLE_PIXELS):
    """No-return flags (..., h, w) bool, each kept only in a region (8-connected) of two LR pixels or more that
    reaches the frame's edge or holds more than `max_pixels` pixels. A flagged region that returns enclose on every
    side is more often a surface that sends back no photon (a black screen, a dark object, a real sensor's outlier
    pixels) than an opening onto nothing within the gate; it is given back to a return (`hole_pixels`), a black one
    taking the depth of the surfaces around it (`black_holes`, `jaxsr.inference.fill_holes`). Sky, and ground
    beyond the gate, reach the frame's edge and stay no return; an enclosed opening larger than `max_pixels` (a
    window onto the sky) does too. A lone flagged pixel is given back anywhere. Edges count as not flagged. jit-able
    with `max_pixels` static; no gradient."""
    def one(f):
        h, w = f.shape
        label, size = regions(f)
        on_edge = np.ones((h, w), bool)
        on_edge[1:-1, 1:-1] = False
        reaches_edge = jnp.zeros(h * w + 1, bool).at[label.ravel()].max((f & on_edge).ravel())
        n = size[label]
        return f & (n >= 2) & (reaches_edge[label] | (n > max_pixels))

    return _frame_by_frame("without_holes", flags, "max_pixels", max_pixels, 1, one)


def hole_pixels(flags, max_pixels: int = HOLE_PIXELS):
    """The flagged LR pixels (..., h, w) bool that `without_holes` gives back to a return: the quiet regions that
    returns enclose (up to `max_pixels`) and the lone quiet pixels; those of them that are black (`black_holes`)
    take the depth around them (`jaxsr.inference.fill_holes`), the others keep the network's. jit-able with
    `max_pixels` static; no gradient."""
    f = jnp.asarray(flags, bool)
    return f & ~without_holes(f, max_pixels)


def black_holes(summed, holes, sensor: Sensor = Sensor(), *, alpha=1e-3):
    """The holes whose surface sends back neither the laser's photons nor the ambient light: (..., h, w) bool.

    Ambient light reaches the sensor from a surface in proportion to its reflectivity, at any distance, while its
    return falls with the distance squared. A hole that returns enclose (`hole_pixels`) is either a far or dim
    surface that reflects the ambient light as its neighbours do but returns too few of the laser's photons to
    stand out, or a black one (a screen, dark furniture) that reflects neither. Only the second is the surface
    around it continued (`jaxsr.inference.fill_holes`); a far surface behind a nearer frame is not. Each
    8-connected region of `holes` is black where its photons N are fewer than the ambient light of the pixels
    around it predicts, at false-alarm rate `alpha`: P(Poisson(lambda) <= N) < alpha, lambda = the region's
    pixels times the mean of those pixels' ambient photons (`ambient_photons`). Without ambient light around (a
    dark scene) nothing is black: the test cannot tell.

    Args:
      summed: (..., h, w, K) each pixel's histograms summed over the frames of its window (`window_sums`).
      holes: (..., h, w) bool, the LR pixels `without_holes` gave back to a return.
    Returns:
      (..., h, w) bool, within `holes`. jit-able; no gradient.
    """
    check_false_alarm_rate("black_holes: alpha", alpha)
    n = jnp.asarray(summed, jnp.float32)
    f = jnp.asarray(holes, bool)
    if n.ndim < 3 or n.shape[:-1] != f.shape or n.shape[-1] != sensor.bins:
        raise ValueError(f"black_holes: summed must be (..., h, w, {sensor.bins}) histograms over holes' (..., h, w) "
                         f"pixels, got {n.shape} and {f.shape}")
    h, w = f.shape[-2:]
    none = h * w

    def one(counts, frame):
        label, size = regions(frame)
        photons = jnp.zeros(none + 1).at[label.ravel()].add(jnp.where(frame, counts.sum(-1), 0.0).ravel())
        # each pixel around a region (a return: the regions are whole 8-connected components) counted for the
        # region beside it (for the smallest label where it touches two)
        around = jnp.where(frame, none, _around(label, none, jax.lax.min)).ravel()
        ambient = jnp.zeros(none + 1).at[around].add(ambient_photons(counts, sensor).ravel())
        pixels_around = jnp.zeros(none + 1).at[around].add(1.0)
        expected = size * ambient / jnp.maximum(pixels_around, 1.0)
        fewer = jax.scipy.special.gammaincc(photons + 1.0, expected)  # P(Poisson(expected) <= photons)
        return frame & ((fewer < alpha) & (expected > 0))[label]

    return jax.vmap(one)(n.reshape(-1, h, w, sensor.bins), f.reshape(-1, h, w)).reshape(f.shape)


def _frame_by_frame(name: str, flags, size_name: str, size, least: int, one):
    """`one` mapped over the (h, w) frames of (..., h, w) `flags`, after checking them and `size` (an integer >=
    `least`, the caller's argument `size_name`)."""
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or size < least:
        raise ValueError(f"{name}: {size_name} must be an integer >= {least}, got {size!r}")
    f = jnp.asarray(flags, bool)
    if f.ndim < 2:
        raise ValueError(f"{name}: flags must be (..., h, w), got shape {f.shape}")
    h, w = f.shape[-2:]
    return jax.vmap(one)(f.reshape(-1, h, w)).reshape(f.shape)


def beside_sky(flags, min_pixels: int = HOLE_PIXELS):
    """No-return flags (..., h, w) bool, and the LR pixels beside a flagged region (8-connected) of more than
    `min_pixels` pixels: sky, or ground beyond the gate. Such a pixel holds a return (else it would be flagged) and
    its block may straddle the sky's edge; with these flags the network's P(return) says which of its HR pixels are
    sky, where the photons of the whole block keep all of them at depth. Not in the default decision: on the
    simulated test scenes it halves the sky shown as depth, on the real tower recording (where P(return) lies
    outside its fit) it drops the building's edge, 12 dB at 16 photons (experiments/results/real_photons_pools.md).
    jit-able with `min_pixels` static; no gradient."""
    def one(frame):
        label, size = regions(frame)
        sky = (frame & (size[label] > min_pixels)).astype(jnp.int32)
        return frame | (_around(sky, 0, jax.lax.max) > 0)

    return _frame_by_frame("beside_sky", flags, "min_pixels", min_pixels, 0, one)


def regions(f):
    """The 8-connected regions of an (h, w) bool mask: (label (h, w) int32, the smallest flat index of the
    region's pixels, h w where not set; size (h w + 1,) int32, the pixels of each label, size[h w] unused).
    Labels spread as minima over each 3 x 3 and jump along the labels they point at, until nothing changes
    (about log of a region's length in steps for compact regions). jit-able."""
    h, w = f.shape
    none = h * w
    start = jnp.where(f, jnp.arange(h * w, dtype=jnp.int32).reshape(h, w), none)

    def step(state):
        label, _ = state
        spread = _around(label, none, jax.lax.min)
        jumped = jnp.append(spread.ravel(), none)[spread]  # the label of the pixel a label points at: same region
        new = jnp.where(f, jnp.minimum(spread, jumped), none)
        return new, jnp.any(new != label)

    label, _ = jax.lax.while_loop(lambda state: state[1], step, (start, jnp.bool_(True)))
    size = jnp.zeros(none + 1, jnp.int32).at[label.ravel()].add(f.ravel().astype(jnp.int32))
    return label, size


def _around(x, outside, op):
    """`op` (jax.lax.min, max) over each (h, w) pixel's 3 x 3 neighbourhood, `outside` beyond the frame."""
    return jax.lax.reduce_window(x, jnp.asarray(outside, x.dtype), op, (3, 3), (1, 1), "SAME")


def quiet_pixels(counts, sensor: Sensor = Sensor(), *, alpha=1e-3, frames: int = 9):
    """The photons' part of the default no-return decision over a whole sequence: (T, h, w) bool, True where an
    LR pixel's block may be output as no return where the network says so: the pixel's own histograms over
    `frames` frames and those of the quiet pixels pooled around it (`QUIET_POOLS`) pass for ambient light alone at
    `alpha`, in a region of two pixels or more that reaches the frame's edge or holds more than `HOLE_PIXELS`
    (`without_holes`). `jaxsr.inference.iter_quiet` streams it. jit-able with `frames` static."""
    flags = ambient_only(counts, sensor, alpha=alpha, pixels=1, frames=frames, pools=QUIET_POOLS)
    return without_holes(flags)


def black_hole_pixels(counts, sensor: Sensor = Sensor(), *, alpha=1e-3, frames: int = 9, pools: tuple = QUIET_POOLS,
                      max_pixels: int = HOLE_PIXELS):
    """The black holes of the default no-return decision over a whole sequence: (T, h, w) bool, the LR pixels that
    `quiet_pixels` gives back to a return (`hole_pixels`) whose region's photons over `frames` frames fall short of
    the ambient light around it at `alpha` (`black_holes`), whose depth `jaxsr.inference.fill_holes` takes from the
    surfaces around them. `jaxsr.inference.iter_quiet` streams it (`QuietFrame.black`); `pools` and `max_pixels`
    (the largest hole) other than the default's are for measuring the decision. jit-able with `frames`, `pools` and
    `max_pixels` static."""
    flags = ambient_only(counts, sensor, alpha=alpha, pixels=1, frames=frames, pools=pools)
    n = capped_for_sum(jnp.asarray(counts, jnp.float32), summed_histograms(1, frames, pools))
    return black_holes(window_sums(n, frames), hole_pixels(flags, max_pixels), sensor, alpha=alpha)


def summed_histograms(pixels: int, frames: int, pools: tuple = ()) -> int:
    """The most histograms `ambient_only` adds into one test: what each is capped for (`capped_for_sum`)."""
    return pixels * pixels * frames * max(pools, default=1) ** 2


def frame_snr(counts, sensor: Sensor = Sensor(), *, false_alarm=1e-3):
    """The frame SNR a recording was made at, as `calibrate` defines it (mean signal / mean ambient photons per
    LR pixel with a return), estimated from its histograms: (T, h, w, K) or (h, w, K) counts, summed over the
    frames first. Over the pixels whose summed histogram holds a return (`return_significance` <= log
    `false_alarm`), ambient = the photons outside the scan's peak window, scaled to the whole gate, and signal =
    the rest; the window grows in proportion beyond 16 bins. Indicative, not exact: a scene that moves across the
    frames smears its peaks and reads lower (a street scene calibrated to SNR 100 read 38-56 over 8 frames); few
    photons (a few frames, few bins) read high, as ambient noise lifts the peak's window (SNR 10 at 20 signal
    photons read 15 from one frame of 16 bins, 35 from one of 8; SNR 0.1 reads 0.15-0.25); a second surface counts
    as ambient. Returns a Python float: NaN where no pixel holds a return, inf where no ambient photon is seen."""
    return _levels("frame_snr", counts, sensor, false_alarm)[0]


def signal_photons(counts, sensor: Sensor = Sensor(), *, false_alarm=1e-3):
    """The mean signal photons per LR pixel with a return and per frame a recording was made at (`calibrate`'s
    `mean_signal`), estimated as `frame_snr` estimates the SNR (the same pixels, signal = the photons beyond the
    ambient level, over the frames summed, divided by their number). Pixels whose returns are too faint to be
    found in the sum are left out, so few photons read high. Returns a Python float, NaN where no pixel holds a
    return."""
    return _levels("signal_photons", counts, sensor, false_alarm)[1]


def frame_levels(counts, sensor: Sensor = Sensor(), *, false_alarm=1e-3) -> tuple[float, float]:
    """(`frame_snr`, `signal_photons`) of the same counts from one significance scan (each alone scans again)."""
    return _levels("frame_levels", counts, sensor, false_alarm)


def _levels(name, counts, sensor, false_alarm) -> tuple[float, float]:
    signal, ambient, frames = _signal_and_ambient(name, counts, sensor, false_alarm)
    if signal.size == 0:
        return float("nan"), float("nan")
    snr = float(signal.mean() / ambient.mean()) if ambient.mean() > 0 else float("inf")
    return snr, float(signal.mean() / frames)


def _signal_and_ambient(name, counts, sensor, false_alarm):
    """Per pixel with a return in the frames' sum: (signal photons, ambient photons over the gate) and the number
    of frames summed (see `frame_snr`)."""
    n = np.asarray(counts)
    if n.ndim < 3 or n.shape[-1] != sensor.bins:
        raise ValueError(f"{name}: counts must be (T, h, w, {sensor.bins}) or (h, w, {sensor.bins}) histograms, "
                         f"got shape {n.shape}")
    n = n.reshape(-1, *n.shape[-3:])
    frames = n.shape[0]
    n = n.sum(axis=0, dtype=np.float64)
    found = np.asarray(return_significance(n.astype(np.float32), sensor)) <= np.log(false_alarm)
    if not found.any():
        return np.zeros(0), np.zeros(0), frames
    # the peak's window widened by a bin each side, for the pulse's tails and a little motion; wider in proportion
    # beyond 16 bins (finer bins of a gate hold the same pulse in more of them)
    width = (2 * int(np.asarray(default_window(sensor))) + 3) * max(1, sensor.bins // 16)
    width = min(width, sensor.bins - 1)
    windows = np.lib.stride_tricks.sliding_window_view(n[found], width, axis=-1).sum(axis=-1)
    peak = windows.max(axis=-1)
    total = n[found].sum(axis=-1)
    ambient = (total - peak) * sensor.bins / max(sensor.bins - width, 1)
    return np.maximum(total - ambient, 0.0), ambient, frames


def _log_binomial_tail(s, n, p):
    """log P(Binomial(n, p) >= s) for photon counts s <= n (0 where s < 1 or p >= 1): from the regularised
    incomplete beta I_p(s, n - s + 1) up to EXACT_TAIL_MAX_PHOTONS, its Chernoff bound -n KL(s/n || p) above."""
    s1 = jnp.maximum(s, 1.0)
    exact = jnp.log(jnp.maximum(jax.scipy.special.betainc(s1, jnp.maximum(n - s1 + 1.0, 1e-6), p),
                                jnp.finfo(jnp.float32).tiny))
    # KL(q || p) from d = q - p through log1p: its two first-order terms cancel, and in this form float32 keeps
    # their difference (d^2 / 2p(1 - p)) to about 1e-7 / d relative, where x log x terms would lose it.
    n1 = jnp.maximum(n, 1.0)
    p = jnp.minimum(p, 1.0 - 1e-6)
    # less the rounding of s and p n (a few float32 ulps): at 1e13 photons and more, H0's own spread of q falls
    # below it, and rounding alone would read as a return
    d = (s - p * n) / n1 - 8.0 * jnp.finfo(jnp.float32).eps * jnp.maximum(s / n1, p)
    q = jnp.clip(s / n1, 0.0, 1.0)
    rest = jnp.where(q < 1.0, (1.0 - q) * jnp.log1p(-jnp.minimum(d / (1.0 - p), 1.0 - 1e-7)), 0.0)
    kl = q * jnp.log1p(d / p) + rest
    chernoff = jnp.where(d > 0, -n * jnp.maximum(kl, 0.0), 0.0)
    tail = jnp.where(n <= EXACT_TAIL_MAX_PHOTONS, exact, chernoff)
    return jnp.where((s >= 1.0) & (p < 1.0 - 1e-6), tail, 0.0)


def _bin_model(theta, sensor):
    """Expected counts for one pixel, theta = (tau in bins, log signal, log background)."""
    tau, log_s, log_b = theta
    edges = jnp.arange(sensor.bins + 1, dtype=theta.dtype)
    cdf = 0.5 + 0.5 * jax.lax.erf((edges - tau) / (sensor.irf_sigma * jnp.sqrt(2.0)))
    return jnp.exp(log_s) * (cdf[1:] - cdf[:-1]) + jnp.exp(log_b) / sensor.bins


def _poisson_nll(theta, args):
    n, sensor = args
    lam = _bin_model(theta, sensor)
    return jnp.sum(lam - jax.scipy.special.xlogy(n, lam))  # 0 log 0 = 0 where erf saturates


def maximum_likelihood_depth(
    counts, sensor: Sensor = Sensor(), *, max_steps: int = 64, rtol=1e-5, atol=1e-5, return_mask=False
):
    """Per-pixel Poisson maximum-likelihood fit of (tau, signal, background) under the sensor's IRF.

    Minimises sum_k lambda_k - n_k log lambda_k with lambda_k = S h_k(tau) + B / K (the forward model of
    one LR pixel with a single surface) by BFGS (optimistix), vmapped over pixels and started from the
    centre of mass (tau), the counts above the median over all bins (S) and the median (B). Better than the centre
    of mass where photons are plentiful; no better in the photon-starved regime (experiments/results/extraction.md).

    Args:
      counts: (..., K) photon counts, as in `centre_of_mass` (eagerly checked; traced, a histogram with a
        non-finite or negative count is invalid and is fitted as an empty one).
      max_steps: BFGS iterations per pixel; rtol, atol: its tolerances.
      return_mask: also return (valid, converged) masks: a pixel is valid if the centre of mass was.
    Returns:
      (...) normalised depth in [0, 1] (invalid pixels 1.0); with `return_mask`, (depth, valid, converged).
    """
    n, _ = _usable(_check_counts("maximum_likelihood_depth", counts, sensor))
    com, valid = centre_of_mass(n, sensor, return_mask=True)
    batch_shape = n.shape[:-1]
    n_flat = n.reshape(-1, sensor.bins)
    background = median_of_bins(n_flat)
    signal = jnp.maximum(jnp.sum(n_flat, axis=-1) - background * sensor.bins, 1.0)
    theta0 = jnp.stack(
        [com.reshape(-1) * sensor.bins, jnp.log(signal), jnp.log(jnp.maximum(background * sensor.bins, 0.5))], -1
    )
    solver = optx.BFGS(rtol=rtol, atol=atol)

    def fit_one(theta, counts_1):
        sol = optx.minimise(_poisson_nll, solver, theta, args=(counts_1, sensor), max_steps=max_steps, throw=False)
        return sol.value[0], sol.result == optx.RESULTS.successful

    tau, converged = jax.vmap(fit_one)(theta0, n_flat)
    tau = jnp.where(jnp.isfinite(tau), tau, theta0[:, 0]).reshape(batch_shape)
    depth = jnp.where(valid, jnp.clip(tau / sensor.bins, 0.0, 1.0), NO_RETURN)
    converged = converged.reshape(batch_shape)
    return (depth, valid, converged) if return_mask else depth
