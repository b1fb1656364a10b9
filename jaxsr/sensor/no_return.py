"""Where a scene has no return, placed to within an LR block: the share of each LR pixel without a return.

`ambient_only` flags an LR pixel when the photons of its 3 x 3 neighbourhood over 9 frames pass for ambient light
alone. That empties the insides of sky and absorbing regions, but a band one LR pixel wide inside every region
(and every region narrower than three pixels) stays depth, and a decision per LR pixel paints whole blocks while
the regions' edges run through them. `no_return_shares` starts from the test's flags and

1. grows the regions through neighbouring pixels whose own histogram (summed over the frames) passes for ambient
   light alone;
2. gives each pixel bordering a region a share of no return, 1 - its photon excess / the median excess of the
   returns around it (half the excess: half the block sees a surface);

both only where the pixel's photons can tell: where a return of half its neighbours' excess would have stood out
of the pixel's own ambient light (`DETECTABLE_AT`). Elsewhere, at a few photons against bright ambient light, the
3 x 3 test alone decides. Interpolated to HR and cut at one half (`jaxsr.inference.no_return_where`), the shares
place an edge inside its block.

On the project's test scenes with regions of no return (SNR 1.3, 8 frames each; experiments/results/
no_return_edges.md) the share of the no-return pixels output as depth goes from 30 / 45 / 55 / 61 % (the test
alone) to 22 / 25 / 9 / 10 % at 3 / 14 / 100 / 1000 signal photons per pixel, while the returns dropped go from
1.6 / 0.2 / 0.0 / 0.0 % to 2.9 / 0.9 / 0.8 / 0.6 % (the decision alone; with the paper's TR4 and its own noise draws
3.7 % and 1.2 % at 3 and 14 photons, the test 2.5 % and 0.3 %); TR4's PSNR with it is within 0.15 dB of the test's
in 10 of 11 regimes (1-1000 photons at SNR 0.1 and 1.3, and the paper's), 0.52 lower at 14 photons and SNR 0.1
(photon_regimes_shares.md). On a real recording with a lot of outline against dark sky (tower, in
experiments/results/real_photons_ambient.md) it marks 1.7-5.9 % of the building as no return, at the outline, and
costs TR4 6.1-12.8 dB against the test alone at 4-16 photons: `jaxsr upscale --ambient-alpha` applies the test,
not this. The rules' constants were chosen on the simulated scenes. Beyond about 1e28 photons per bin
each histogram is scaled down on its own (to keep sums finite), and the border shares, still finite, are no
longer to be trusted.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from ..config import Sensor
from .peaks import (
    _check_counts,
    _usable,
    ambient_only,
    capped_for_sum,
    check_ambient_settings,
    default_window,
    return_significance,
    window_sums,
)

__all__ = ["no_return_shares", "share_of_window"]

# A pixel joins a region where its own summed histogram's p-value is above this (passes for ambient alone) ...
JOIN_ABOVE = 1e-2
# ... and its excess counts as a return's, a reference for its neighbours, where the p-value is at most this.
RETURN_AT = 1e-3
# The side of the square, in LR pixels, of the returns a pixel's excess is read against.
REFERENCE_SIDE = 5
# A pixel may join or take a share only where a return of half the reference excess, over its own ambient level,
# would be significant at this p-value.
DETECTABLE_AT = 1e-4


def _square(x, side: int, fill):
    """(side * side, h, w): the values of the side x side square around each pixel, `fill` beyond the frame."""
    p = side // 2
    padded = jnp.pad(x, p, constant_values=fill)
    h, w = x.shape
    return jnp.stack([padded[dy:dy + h, dx:dx + w] for dy in range(side) for dx in range(side)])


def _square_median(values, side: int = REFERENCE_SIDE):
    """(h, w) median of the finite `values` in each side x side square; NaN where there is none."""
    return jnp.nanmedian(_square(values, side, jnp.nan), axis=0)


def _next_to(region):
    """(h, w) True outside `region` where one of the 8 neighbours is in it."""
    return jnp.any(_square(region, 3, False), axis=0) & ~region


def _grow(seeds, through):
    """The seeds and every `through` pixel connected to them by a path of `through` pixels (8-neighbours)."""
    def step(carry):
        region, _ = carry
        wider = region | (jnp.any(_square(region, 3, False), axis=0) & through)
        return wider, jnp.any(wider != region)

    return jax.lax.while_loop(lambda c: c[1], step, (seeds, jnp.array(True)))[0]


def _excess(n, sensor: Sensor):
    """(excess, ambient per bin) of (h, w, K) histograms: the photons of the window of the centre of mass's width
    around the largest bin minus the window's share of the photons outside it (no median: a median of bins is 0
    at a few photons), and the photons outside it per bin."""
    k = jnp.arange(sensor.bins)
    window = jnp.abs(k - jnp.argmax(n, axis=-1)[..., None]) <= default_window(sensor)
    inside = jnp.sum(jnp.where(window, n, 0.0), axis=-1)
    width = jnp.sum(window, axis=-1)
    ambient = (jnp.sum(n, axis=-1) - inside) / jnp.maximum(sensor.bins - width, 1)
    return jnp.maximum(inside - width * ambient, 0.0), ambient


def share_of_window(summed, sensor: Sensor = Sensor(), *, alpha=1e-3, pixels: int = 3):
    """The share of no return of each LR pixel of one frame, from its histograms summed over the frames of its
    window: (h, w, K) -> (h, w) float32 in [0, 1]. 1 where `ambient_only`'s `pixels` x `pixels` test of the sum
    flags the pixel or the region grows into it, a share at the regions' borders, 0 elsewhere (see the module).
    Counts as `ambient_only` takes them (finite, >= 0; traced, a histogram that is not adds no photons). jit-able
    with `pixels` static; no gradient."""
    check_ambient_settings("share_of_window", alpha, pixels, 1)
    n, _ = _usable(jax.lax.stop_gradient(_check_counts("share_of_window", summed, sensor)))
    if n.ndim != 3:
        raise ValueError(f"share_of_window: expected (h, w, {sensor.bins}) histograms of one frame summed over its "
                         f"window, got shape {n.shape}")
    n = capped_for_sum(n, pixels * pixels)
    flags = ambient_only(n[None], sensor, alpha=alpha, pixels=pixels, frames=1)[0]
    log_p = return_significance(n, sensor)
    excess, ambient_per_bin = _excess(n, sensor)
    significant = log_p <= jnp.log(RETURN_AT)
    # the guard: would half the neighbours' return have stood out of this pixel's ambient light?
    reference = jnp.nan_to_num(_square_median(jnp.where(significant, excess, jnp.nan)), nan=0.0)
    half_return = jnp.broadcast_to(ambient_per_bin[..., None], n.shape).at[..., sensor.bins // 2].add(0.5 * reference)
    can_tell = return_significance(half_return, sensor) <= jnp.log(DETECTABLE_AT)
    joins = (log_p > jnp.log(JOIN_ABOVE)) & can_tell
    # no region starts outside the test: a dim surface beside a bright one would (seeds of that kind cost TR4
    # 2.4 dB at 3 photons per pixel on the test scenes in a run that was not kept; docs/results/photon-regimes.md)
    region = _grow(flags, joins)
    # the share of return at the borders: the excess against the returns' around it, outside the region
    beside = _square_median(jnp.where(significant & ~region, excess, jnp.nan))
    # none around: its own excess (a share of 0, or 1 for no excess; the guard has no reference there either, so
    # such a pixel takes no share)
    beside = jnp.where(jnp.isnan(beside), excess, beside)
    share = 1.0 - jnp.clip(excess / jnp.maximum(beside, jnp.finfo(jnp.float32).tiny), 0.0, 1.0)
    border = _next_to(region) & can_tell
    return jnp.where(region, 1.0, jnp.where(border, share, 0.0)).astype(jnp.float32)


@functools.partial(jax.jit, static_argnames=("sensor", "pixels", "frames"))
def _shares(counts, alpha, sensor, pixels, frames):
    summed = window_sums(capped_for_sum(counts, pixels * pixels * frames), frames)  # over frames only
    return jax.vmap(lambda s: share_of_window(s, sensor, alpha=alpha, pixels=pixels))(summed)


def no_return_shares(counts, sensor: Sensor = Sensor(), *, alpha=1e-3, pixels: int = 3,
                     frames: int = 9):
    """The share of each LR pixel without a return, from a video's histograms: (T, h, w, K) counts -> (T, h, w)
    float32 in [0, 1], each frame's from its histograms summed over the `frames` frames centred on it (cut at the
    ends of the sequence). `ambient_only`'s flags (at false-alarm rate `alpha`, `pixels` x `pixels` x `frames`)
    are 1; the regions grow and their borders get shares where the photons can tell (see the module). Give them
    to `jaxsr.inference.no_return_where` to mark HR frames. Counts finite and >= 0 (eagerly checked; traced, a
    histogram that is not adds nothing). jit-able with `pixels`, `frames` static; no gradient."""
    check_ambient_settings("no_return_shares", alpha, pixels, frames)
    if jnp.ndim(counts) != 4:
        raise ValueError(f"no_return_shares: counts must be (T, h, w, {sensor.bins}) histograms of consecutive "
                         f"frames, got shape {jnp.shape(counts)}")
    n, _ = _usable(jax.lax.stop_gradient(_check_counts("no_return_shares", counts, sensor)))
    return _shares(n, alpha, sensor, pixels, frames)
