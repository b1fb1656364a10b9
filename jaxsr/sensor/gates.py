"""Histograms over any time gate: centre-of-mass depth in metres on the gate's grid, and the explicit scale that
turns metres into the network's normalised depth and back.

The paper's sensor has 16 bins over [0, 35 m) and the network reads depth / 35 m. A real sensor has its own
number of bins, bin width and gate start (`jaxsr.Gate`); `gate_depth` measures range on that grid, and a
`jaxsr.DepthScale` (offset, span) says which metres become the network's 0 and 1: by default `data_span`, the depth
the recording's returns reach. `gate_warnings` says where a scale takes the models outside what they were trained
on.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ..config import DepthScale, Gate, Sensor
from .peaks import centre_of_mass

__all__ = ["gate_depth", "to_network_depth", "from_network_depth", "gate_to_network", "gate_warnings",
           "require_float32_depth", "data_span", "SPAN_PERCENTILE",
           "SPAN_MARGIN", "SPAN_MIN_BINS"]

# The depth span the data shows (`data_span`): its returns' SPAN_PERCENTILE-th percentile from the gate start, times
# SPAN_MARGIN, at least SPAN_MIN_BINS bins (a bin no coarser than the trained 1/16 of the span: the paper's 16 bins
# keep their 35 m) and at most the gate.
# On simulated gates of 3 to 300 m it had the lowest median depth error of the spans measured; the gate's length
# came to 1.9x it and the trained 35 m to 13x (experiments/results/span_choice.md)
SPAN_PERCENTILE = 99.0
SPAN_MARGIN = 1.1
SPAN_MIN_BINS = 16


def gate_depth(counts, gate: Gate = Gate(), *, window: int = 1, z: float = 0.0, return_mask: bool = False):
    """Centre-of-mass range of photon histograms over `gate`, in metres.

    The centre of mass of docs/sensor-model.md, section 3 (median background, +-`window` bins around the first maximum,
    bin-centre convention) gives tau in bins; the range is gate.start + tau * gate.bin_width. With the default
    gate this is `centre_of_mass(counts) * 35 m`.

    Args:
      counts: (..., K) photon counts, K = gate.bins, finite and >= 0 (as `jaxsr.centre_of_mass`).
      window: half-width of the centre-of-mass window in bins (1 suits an IRF of sigma <= 0.5 bins, 2 wider).
      z: peak-significance threshold (see `jaxsr.centre_of_mass`).
      return_mask: also return the validity mask.
    Returns:
      (...) radial range in metres, +inf where there is no usable return; with `return_mask`, (range, valid).
    """
    norm, valid = centre_of_mass(counts, Sensor(gate=gate), window=window, z=z, return_mask=True)
    depth = jnp.where(valid, gate.start + norm * gate.length, jnp.inf)
    return (depth, valid) if return_mask else depth


def to_network_depth(depth, scale: DepthScale = DepthScale()):
    """Radial metres -> the network's normalised depth (r - offset) / span, clipped to [0, 1].

    No return (NaN, +-inf, or beyond offset + span) is 1.0; a return nearer than `offset` is 0 (the nearest
    the network knows). With the default scale this equals `jaxsr.normalise_depth` for depths >= 0.

    Args:
      depth: (...) radial range in metres.
    Returns:
      (...) float normalised depth in [0, 1].
    """
    depth = jnp.asarray(depth, dtype=jnp.result_type(float))
    norm = (depth - scale.offset) / scale.span
    return jnp.where(jnp.isfinite(norm) & (norm <= 1.0), jnp.clip(norm, 0.0, 1.0), 1.0)


def from_network_depth(norm, scale: DepthScale = DepthScale()):
    """The network's normalised depth -> radial metres offset + n * span; 1.0 and above (and NaN) is no return,
    +inf (the one threshold of `jaxsr.denormalise_depth`), below 0 is clipped to `offset`.

    Args:
      norm: (...) normalised depth (network output, unclipped).
    Returns:
      (...) float radial range in metres, in [offset, offset + span) or +inf.
    """
    norm = jnp.asarray(norm, dtype=jnp.result_type(float))
    no_return = jnp.isnan(norm) | (norm >= 1.0)
    return jnp.where(no_return, jnp.inf, scale.offset + jnp.clip(norm, 0.0, 1.0) * scale.span)


def gate_to_network(norm, sensor: Sensor = Sensor()):
    """Depth normalised to the sensor's gate (tau / K, as `jaxsr.centre_of_mass` gives it; 1.0 = no return) ->
    the network's normalised depth on the sensor's depth scale: the range gate.start + n * gate.length, then
    `to_network_depth` (beyond offset + span: no return; before offset: 0). The identity (to the bit) when the
    depth scale is the gate's own, as for the paper's sensor. jit-, vmap- and grad-compatible.

    Args:
      norm: (...) gate-normalised depth.
    Returns:
      (...) normalised depth on `sensor.depth`, in [0, 1].
    """
    gate, scale = sensor.gate, sensor.depth
    norm = jnp.asarray(norm)
    # n' = a + n b: a = 0 and b = 1 exactly for the paper's sensor, so its depth passes unchanged
    a = (gate.start - scale.offset) / scale.span
    b = gate.length / scale.span
    out = a + norm * b
    return jnp.where((norm >= 1.0) | ~(out <= 1.0), 1.0, jnp.clip(out, 0.0, 1.0)).astype(norm.dtype)


def require_float32_depth(far_m: float, bin_width_m: float, where: str = "the gate") -> None:
    """Raise ValueError where float32 metres (the output's, and the training's) step by more than a bin at `far_m`,
    the far end of the depth scale: the depth within the gate could not be written (a start of 10^10 m steps by
    1 km, and every pixel would read as the gate's start)."""
    with np.errstate(over="ignore"):
        step = float(np.spacing(np.float32(far_m)))  # NaN beyond float32 (inf)
    if not step <= bin_width_m:
        where_float32 = ("beyond float32 metres (the output's)" if np.isnan(step) else
                         f"where float32 metres (the output's) step by {step:.3g} m, more than a bin "
                         f"({bin_width_m:.3g} m)")
        raise ValueError(f"{where} ends {far_m:.4g} m away, {where_float32}: no depth within it could be written; "
                         "give the gate start as 0 (depth from the gate's start) and add the start back in float64")


def data_span(depth, gate: Gate) -> float:
    """The depth span the data shows: metres from the gate's start to its returns' SPAN_PERCENTILE-th percentile,
    times SPAN_MARGIN, at least SPAN_MIN_BINS bins and at most the gate's length (the gate's length where no return
    is seen). A scene put on the network's [0, 1] by it fills that range as the trained scenes filled 35 m.

    Args:
      depth: (...) radial metres of the returns seen (`gate_depth` of a recording's first frames; inf, NaN for no
        return).
    Returns:
      The span in metres."""
    depth = np.asarray(depth, np.float64)
    returns = depth[np.isfinite(depth)] - float(gate.start)
    length = float(gate.length)
    if returns.size == 0:
        return length
    reach = float(np.percentile(returns, SPAN_PERCENTILE)) * SPAN_MARGIN
    return float(min(length, max(reach, SPAN_MIN_BINS * float(gate.bin_width))))


def gate_warnings(gate: Gate, scale: DepthScale, *, returns=None,
                  refit: str = "leave --span out to fit it") -> list[str]:
    """What the bundled models never saw in this gate and scale, as sentences (empty for the paper's sensor).

    Raises ValueError if the gate lies wholly outside [offset, offset + span): every return would read as no
    return or as 0 m. With `returns` (radial metres of the returns a recording's first frames show, inf for no
    return), warns where 1 % of them or more lie outside the span (they read as no return, or 0 m) and where the
    span is 2x or more the one `data_span` fits to them (the network sees their depth steps that much smaller than
    it learned: on simulated gates of 3 to 15 m the trained 35 m measured 2.7 to 13x the median depth error of the
    fitted span, experiments/results/span_choice.md); without `returns`, where part of the gate lies outside the
    span. Warns when a bin is over 2x wider than the trained 1/16 of the span
    (coarser depth). `refit`: how the user fits the span to the data, said after the warnings on it (the command's
    --span by default)."""
    start, end = float(gate.start), float(gate.end)
    lo, hi = float(scale.offset), float(scale.offset + scale.span)
    if end <= lo or start >= hi:
        raise ValueError(f"the gate [{start:g}, {end:g}) m lies outside the depth scale's [{lo:g}, {hi:g}) m: every "
                         "return would be read as 0 m or no return; put the scale's offset at the gate start")
    require_float32_depth(hi, float(gate.bin_width))
    out = []
    seen = None if returns is None else np.asarray(returns, np.float64)
    seen = None if seen is None else seen[np.isfinite(seen)]
    if seen is None or seen.size == 0:
        if seen is None and (end > hi or start < lo):
            out.append(f"the gate [{start:g}, {end:g}) m extends past the depth scale's [{lo:g}, {hi:g}) m: returns "
                       "outside it read as no return (beyond) or 0 m (before)")
    else:
        outside = float(np.mean((seen >= hi) | (seen < lo)))
        if outside >= 0.01:
            out.append(f"{100 * outside:.3g} % of the returns in the first frames lie outside the depth scale's "
                       f"[{lo:g}, {hi:g}) m: they read as no return (beyond) or 0 m (before); {refit}, or give a "
                       "longer one")
        fitted = data_span(seen, Gate(gate.bins, gate.bin_width, lo))
        if float(scale.span) >= 2.0 * fitted:
            out.append(f"the returns in the first frames fit a depth span of {fitted:.3g} m, and the span is "
                       f"{float(scale.span):g} m: the network sees their depth steps "
                       f"{float(scale.span) / fitted:.3g}x smaller than it learned (in simulation 2.7 to 13x the "
                       f"depth error of the fitted span); {refit}")
    coarse = float(gate.bin_width) / float(scale.span) * 16
    if coarse > 2.0:
        out.append(f"bins of {float(gate.bin_width):g} m are {coarse:.3g}x the trained 1/16 of the depth span: "
                   "coarser depth than the models saw")
    return out
