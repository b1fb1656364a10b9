"""SPAD direct time-of-flight forward model: HR radial depth + intensity -> LR photon histograms.

Implements docs/sensor-model.md, sections 1-2. Every function is pure and jit/vmap/grad compatible; the sensor
config is a pytree whose physical numbers are leaves. Eager calls validate shapes and values and raise a
`ValueError` that says what was expected. Traced (under `jax.jit`, `vmap` or `grad`) only the shapes can be
checked, and the values have these meanings instead (a bad pixel is read as a valid one and turns no other
pixel NaN; a bad scalar turns everything NaN):

- depth: NaN, inf, negative and outside the sensor's gate mean "no return" (signal weight 0), eager or traced alike;
- intensity: a non-finite value is a black pixel (rho = 0: no signal, ambient floor only) and a finite one
  outside [0, 1] is clipped to it, for that pixel alone (eagerly both are a `ValueError`);
- scalars: `snr` not finite and > 0, `mean_signal` not finite and >= 0, or a sensor leaf out of its domain
  (the gate's bin width, the depth span, the pulse's sigma, `r_min` finite and > 0, `ambient_floor` finite and
  >= 0) make every rate and count
  NaN, and `calibrate` return (NaN, NaN).

Conventions: depth is radial range in metres along each pixel's ray; NaN, inf, negative and beyond-the-gate
depths mean "no return". Intensity is a reflectivity proxy in [0, 1].
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..checks import is_concrete, require_hr_pair
from ..config import DEFAULT_MEAN_SIGNAL, Sensor
from .poisson import PATHWISE_ESTIMATORS, poisson_pathwise, sample_poisson


def planar_to_radial(z, sensor: Sensor = Sensor()):
    """Convert a planar z-buffer (AirSim "DepthPlanar") to radial range along each pixel's ray.

    r = z * sqrt(1 + ((u - cx)/f)^2 + ((v - cy)/f)^2), pixel centres u = col + 0.5, v = row + 0.5,
    (cx, cy) the frame centre and f = `sensor.focal_px`.

    Args:
      z: (..., H, W) planar depth in metres, (H, W) = `sensor.hr_shape`.
    Returns:
      (..., H, W) radial depth in metres (non-finite values pass through).
    """
    z = jnp.asarray(z)
    if z.ndim < 2 or z.shape[-2:] != tuple(sensor.hr_shape):
        raise ValueError(f"planar_to_radial: expected (..., {sensor.hr_shape[0]}, {sensor.hr_shape[1]}), got {z.shape}")
    return z * ray_norm(sensor)


def pixel_rays(sensor: Sensor = Sensor(), *, tilt=0.0):
    """Ray directions of the HR pixel centres (col + 0.5, row + 0.5) in the camera frame (x right, y up, z
    forward), scaled so that their z component is 1.

    tilt: a downward view as a vertical lens shift (radians, small): each ray's y is reduced by `tilt`.
    Returns (dx (W,), dy (H,), norm (H, W)): D = (dx[col], dy[row], 1) and norm = |D|, so a planar depth z is
    the radial depth z * norm.
    """
    h, w = sensor.hr_shape
    f = sensor.focal_px
    dx = (jnp.arange(w, dtype=jnp.float32) + 0.5 - w / 2) / f
    dy = -(jnp.arange(h, dtype=jnp.float32) + 0.5 - h / 2) / f - tilt
    norm = jnp.sqrt(1.0 + dx[None, :] ** 2 + dy[:, None] ** 2)
    return dx, dy, norm


def ray_norm(sensor: Sensor = Sensor()):
    """(H, W) length of the ray direction (x, y, 1) through each HR pixel centre: radial = planar * norm."""
    return pixel_rays(sensor)[2]


def has_return(depth, sensor: Sensor = Sensor()):
    """Boolean mask of pixels that return signal: finite, non-negative and within the range gate
    [gate.start, gate.end]."""
    depth = jnp.asarray(depth)
    return jnp.isfinite(depth) & (depth >= 0) & (depth >= sensor.gate.start) & (depth <= sensor.gate.end)


def normalise_depth(depth, sensor: Sensor = Sensor()):
    """Radial metres -> normalised depth clip((r - offset) / span, 0, 1) on the sensor's depth scale
    (`sensor.depth`; by default r / 35 m), with "no return" (outside the gate, `has_return`) mapped to 1.0.

    The normalisation is global (a fixed scale), never per frame, so that video does not flicker.

    Args:
      depth: (...) radial depth in metres.
    Returns:
      (...) float normalised depth in [0, 1].
    """
    depth = jnp.asarray(depth, dtype=jnp.result_type(float))
    scale, ret = sensor.depth, has_return(depth, sensor)
    safe = jnp.where(ret, depth, scale.offset)  # a finite stand-in: gradients through `where` stay finite
    return jnp.where(ret, jnp.clip((safe - scale.offset) / scale.span, 0.0, 1.0), 1.0)


def denormalise_depth(norm, sensor: Sensor = Sensor()):
    """Normalised depth -> radial metres offset + norm * span on the sensor's depth scale (`sensor.depth`; by
    default norm * 35 m), with "no return" mapped to +inf.

    The one threshold: no return is normalised 1.0 and above (docs/sensor-model.md: 1.0 is the no-return code, and
    r > d_max lies past the range gate), and anything below 1.0 is a return, however close to 1 (0.999 ->
    34.965 m at d_max = 35 m). Network outputs are not clipped, but no margin below 1.0 would separate "far"
    from "nothing": training targets put a wall at 34.9 m at 0.997 and the sky at exactly 1.0, so a margin
    would turn real far returns into sky. Below 0 is clipped to 0 m. NaN is no return, as in
    `normalise_depth` and `jaxsr.io.formats.read_depth`. The inverse of `normalise_depth` for depths in the gate
    and below offset + span; offset + span itself normalises to 1.0 and so comes back as no return.

    Args:
      norm: (...) normalised depth, nominally [0, 1].
    Returns:
      (...) float radial depth in metres, in [offset, offset + span) or +inf.
    """
    norm = jnp.asarray(norm, dtype=jnp.result_type(float))
    no_return = jnp.isnan(norm) | (norm >= 1.0)
    return jnp.where(no_return, jnp.inf, sensor.depth.offset + jnp.clip(norm, 0.0, 1.0) * sensor.depth.span)


def irf_bin_weights(tau, sensor: Sensor = Sensor()):
    """Fraction of a return at `tau` (bins) that falls into each of the K bins.

    h_k(tau) = Phi((k+1-tau)/sigma) - Phi((k-tau)/sigma): a Gaussian IRF integrated over each bin,
    truncated at the gate (what falls outside [0, K) is lost).

    Args:
      tau: (...) return time in bin units.
    Returns:
      (..., K) weights, each in [0, 1], summing to at most 1.
    """
    edges = jnp.arange(sensor.bins + 1, dtype=jnp.result_type(float))
    # Phi via erf: K+1 evaluations per pixel, not 2K, and erf is cheaper than ndtr on XLA:CPU.
    cdf = 0.5 + 0.5 * jax.lax.erf((edges - tau[..., None]) / (sensor.irf_sigma * jnp.sqrt(2.0)))
    return cdf[..., 1:] - cdf[..., :-1]


def gate_fraction(tau, sensor: Sensor = Sensor()):
    """Fraction of a return at `tau` (bins) that falls inside the gate [0, K): the sum over k of
    `irf_bin_weights`, Phi((K - tau)/sigma) - Phi(-tau/sigma). About 1/2 for a return at 0 m or at d_max.

    Args:
      tau: (...) return time in bin units.
    Returns:
      (...) fraction in [0, 1].
    """
    scale = sensor.irf_sigma * jnp.sqrt(2.0)
    return 0.5 * (jax.lax.erf((sensor.bins - tau) / scale) - jax.lax.erf(-tau / scale))


def _sum_over_blocks(f, scale: int, *hr_arrays):
    """sum_{i in block} f(arrays at sub-pixel i): LR-pixel sums of a per-HR-pixel quantity.

    Slicing the (..., H, W) inputs at each of the scale^2 sub-pixel offsets *before* evaluating `f` lets
    XLA fuse each term and accumulate; reshaping f's (..., H, W, K) output into blocks and reducing was 9x
    slower on XLA:CPU.
    """
    total = 0.0
    for dy in range(scale):
        for dx in range(scale):
            total = total + f(*(x[..., dy::scale, dx::scale] for x in hr_arrays))
    return total


def _reflectivity(intensity):
    """rho: intensity clipped to [0, 1], non-finite -> 0 (the traced rule; eager calls refuse both).

    `where`, not `jnp.clip`: the gradient stays 1 at exactly 0 and 1 (clip's is 1/2 there) and is 0 at a
    non-finite pixel."""
    rho = jnp.where(jnp.isfinite(intensity), intensity, 0.0)
    return jnp.where(rho < 0, 0.0, jnp.where(rho > 1, 1.0, rho))


def _photon_terms(depth, intensity, sensor: Sensor):
    """Per-LR-pixel un-calibrated sums: (signal histogram shape, sum s_i inside the gate, sum a_i).

    s_i = rho_i / max(r_i, r_min)^2 for pixels with a return (else 0); a_i = rho_i + a0, with rho_i the
    intensity clipped to [0, 1] and 0 where it is not finite (a no-op on checked input). The gated sum,
    sum s_i * `gate_fraction`(tau_i), is the histogram's signal summed over its bins, in closed form: the signal
    the paper's SNR counts (the IRF's tails beyond 0 m and d_max never reach the bins).
    Returns shapes (..., h, w, K), (..., h, w), (..., h, w).
    """
    depth = jnp.asarray(depth, dtype=jnp.result_type(float))
    intensity = _reflectivity(jnp.asarray(intensity, dtype=depth.dtype))
    ret = has_return(depth, sensor)
    # Keep a finite stand-in where there is no return, so gradients through `where` stay finite.
    gate = sensor.gate
    r = jnp.where(ret, depth, gate.end)
    s = jnp.where(ret, intensity / jnp.maximum(r, sensor.r_min) ** 2, 0.0)
    a = intensity + sensor.ambient_floor
    tau = gate.bins * (r - gate.start) / gate.length  # bins from the gate's start

    def signal(s_i, tau_i):
        return s_i[..., None] * irf_bin_weights(tau_i, sensor)

    def gated(s_i, tau_i):
        return s_i * gate_fraction(tau_i, sensor)

    def identity(x):
        return x

    return (
        _sum_over_blocks(signal, sensor.scale, s, tau),
        _sum_over_blocks(gated, sensor.scale, s, tau),
        _sum_over_blocks(identity, sensor.scale, a),
    )


def _physical_scalars(sensor: Sensor, snr, mean_signal):
    """name -> (value, must be > 0 rather than >= 0, what it is): every scalar the rates depend on."""
    return {
        "snr": (snr, True, " (signal / background photons)"),
        "mean_signal": (mean_signal, False, " photons per LR pixel"),
        "Sensor.gate.bin_width": (sensor.gate.bin_width, True, " m"),
        "Sensor.depth.span": (sensor.depth.span, True, " m"),
        "Sensor.pulse.sigma": (sensor.irf_sigma, True, " bins"),
        "Sensor.r_min": (sensor.r_min, True, " m"),
        "Sensor.ambient_floor": (sensor.ambient_floor, False, ""),
    }


def _in_domain(x, strict, xp):
    return xp.isfinite(x) & ((x > 0) if strict else (x >= 0))


def levels_valid(sensor: Sensor, snr, mean_signal):
    """Whether every physical scalar of `sensor`, `snr` and `mean_signal` lies in its domain (finite, positive
    where it must be), as a traced value to select on (e.g. NaN for a score under jit or vmap), not a check.

    Returns a boolean scalar."""
    ok = True
    for value, strict, _ in _physical_scalars(sensor, snr, mean_signal).values():
        ok = ok & jnp.all(_in_domain(jnp.asarray(value), strict, jnp))
    return ok


def _calibrate_from_sums(s_sum, a_sum, sensor: Sensor, *, snr, mean_signal):
    """alpha, beta from per-LR-pixel sums over everything passed (docs/sensor-model.md, "Calibration"): s_sum the
    signal inside the gate (`_photon_terms`), a_sum the ambient. Both NaN when a physical scalar is out of its
    domain (which only a traced call can reach)."""
    has_signal = s_sum > 0
    n_valid = jnp.sum(has_signal)
    denom = jnp.maximum(n_valid, 1)
    mean_s = jnp.sum(s_sum) / denom
    # Double `where`: a block with no ambient (a0 = 0, black) must not put inf * 0 = NaN into the gradients.
    ratio = jnp.where(has_signal, s_sum / jnp.where(has_signal, a_sum, 1.0), 0.0)
    mean_ratio = jnp.sum(ratio) / denom
    any_signal = n_valid > 0
    alpha = jnp.where(any_signal, mean_signal / jnp.where(any_signal, mean_s, 1.0), 0.0)
    beta_signal = alpha * mean_ratio / snr
    # All sky: put mean_signal / snr background photons on the mean pixel (none at all if the scene is
    # black and a0 = 0, where any beta gives zero rates).
    mean_a = jnp.mean(a_sum)
    beta_sky = jnp.where(mean_a > 0, mean_signal / (snr * jnp.where(mean_a > 0, mean_a, 1.0)), 0.0)
    beta = jnp.where(any_signal, beta_signal, beta_sky)
    # Invalid levels: NaN everywhere downstream, never counts that look plausible.
    valid = levels_valid(sensor, snr, mean_signal)
    return jnp.where(valid, alpha, jnp.nan), jnp.where(valid, beta, jnp.nan)


def require_scalar_levels(name, snr, mean_signal=0.0):
    """Refuse an `snr` or `mean_signal` that is not one number (an array would broadcast into the bins' axis): a
    ValueError in `name`'s words. Shapes are known under a trace too, so this holds under jit and vmap."""
    for label, value in (("snr", snr), ("mean_signal", mean_signal)):
        if np.shape(value) != ():
            raise ValueError(f"{name}: {label} must be a scalar (one number for the whole sequence), got an array "
                             f"of shape {np.shape(value)}; for several values, jax.vmap over them")


def check_photon_args(name, depth, intensity, sensor, snr, mean_signal):
    """Shapes always; values where concrete (eager). Traced values follow the rules in the module docstring."""
    depth, intensity = require_hr_pair(name, depth, intensity, sensor)
    # Value checks use NumPy so that they never create tracers inside a jit.
    if is_concrete(intensity):
        values = np.asarray(intensity)
        lo, hi = (float(values.min()), float(values.max())) if values.size else (0.0, 0.0)
        if not (0.0 <= lo and hi <= 1.0):  # also catches NaN, whose comparisons are False
            raise ValueError(f"{name}: intensity must be finite and in [0, 1], got values in [{lo}, {hi}] (under "
                             "jit a non-finite intensity is taken as 0 and one outside [0, 1] is clipped)")
    require_scalar_levels(name, snr, mean_signal)
    for label, (value, strict, unit) in _physical_scalars(sensor, snr, mean_signal).items():
        if is_concrete(value) and not np.all(_in_domain(np.asarray(value), strict, np)):
            raise ValueError(f"{name}: {label} must be finite and {'>' if strict else '>='} 0{unit}, got {value} "
                             "(under jit the result would be all NaN)")
    return depth, intensity


def calibrate(depth, intensity, sensor: Sensor = Sensor(), *, snr, mean_signal=DEFAULT_MEAN_SIGNAL):
    """Laser (alpha) and ambient (beta) scale factors that hit a target frame SNR and signal level.

    Computed once over everything passed (a whole sequence: laser and sun do not change frame to frame).
    Over the LR pixels V with a return: mean signal photons = `mean_signal` and mean per-pixel
    signal / background photons = `snr`, both counting the photons inside the gate's K bins (a return near 0 m or
    d_max loses part of its IRF outside them). All sky: alpha = 0 and the background matches `mean_signal / snr`.

    Args:
      depth: (..., H, W) radial metres; (H, W) = `sensor.hr_shape`.
      intensity: (..., H, W) in [0, 1].
      snr: target frame SNR (finite, > 0).
      mean_signal: target mean signal photons per LR pixel with a return (finite, >= 0).
    Returns:
      (alpha, beta) scalars: photons per unit of s = rho / r^2, and per unit of a = rho + a0. Values out of
      their domain raise `ValueError` eagerly; traced, they give the rules of the module docstring
      (invalid scalars: (NaN, NaN)).
    """
    depth, intensity = check_photon_args("calibrate", depth, intensity, sensor, snr, mean_signal)
    _, s_sum, a_sum = _photon_terms(depth, intensity, sensor)
    return _calibrate_from_sums(s_sum, a_sum, sensor, snr=snr, mean_signal=mean_signal)


def expected_histograms(
    depth, intensity, sensor: Sensor = Sensor(), *, snr, mean_signal=DEFAULT_MEAN_SIGNAL
):
    """Expected photon counts per LR pixel and bin (the Poisson rates), calibrated to `snr`, `mean_signal`.

    lambda_p[k] = alpha * sum_{i in p} s_i h_k(tau_i) + (beta / K) * sum_{i in p} a_i,
    with HR pixels i summed over each scale x scale LR block before any noise. Differentiable in depth,
    intensity, snr, mean_signal and the sensor's physical parameters.

    Args:
      depth: (..., H, W) radial metres (NaN/inf/negative/beyond d_max = no return, eager or traced).
      intensity: (..., H, W) reflectivity proxy in [0, 1]; eagerly anything else is a `ValueError`, traced
        a non-finite value counts as 0 and a finite one is clipped to [0, 1], on its own pixel.
      snr: target frame SNR (finite, > 0). Calibration runs over all leading axes together.
      mean_signal: mean signal photons per LR pixel with a return (finite, >= 0; default `DEFAULT_MEAN_SIGNAL`).
    Returns:
      (..., H/scale, W/scale, K) non-negative rates (photons); all NaN if, traced, `snr`, `mean_signal` or a
      sensor leaf is out of its domain (eagerly a `ValueError`).
    """
    depth, intensity = check_photon_args("expected_histograms", depth, intensity, sensor, snr, mean_signal)
    signal_hist, s_sum, a_sum = _photon_terms(depth, intensity, sensor)
    alpha, beta = _calibrate_from_sums(s_sum, a_sum, sensor, snr=snr, mean_signal=mean_signal)
    return alpha * signal_hist + (beta / sensor.bins) * a_sum[..., None]


def calibrated_rates(depth, intensity, alpha, beta, sensor: Sensor = Sensor()):
    """The rates of `expected_histograms` with given scale factors, for any `(..., h*scale, w*scale)` HR window.

    alpha, beta: from `calibrate` over a whole clip; depth, intensity: a window of it aligned to the LR grid
    (no shape check against `sensor.hr_shape`, traced values follow `expected_histograms`' rules). Rates of a
    window equal that window of the whole clip's rates, so a training crop can be simulated alone.
    Returns (..., h, w, K) rates (photons).
    """
    signal_hist, _, a_sum = _photon_terms(depth, intensity, sensor)
    return alpha * signal_hist + (beta / sensor.bins) * a_sum[..., None]


def _require_key(name, key):
    """Refuse what is no `jax.random` key (None, a bare seed) with a TypeError that says how to make one, before
    JAX's words on invalid key data."""
    dtype = getattr(key, "dtype", None)
    if dtype is None or not (jax.dtypes.issubdtype(dtype, jax.dtypes.prng_key) or dtype == jnp.uint32):
        raise TypeError(f"{name}: key must be a jax.random key, e.g. jax.random.key(seed), got "
                        f"{type(key).__name__} {key!r:.40}")


def simulate_histograms(
    key,
    depth,
    intensity,
    sensor: Sensor = Sensor(),
    *,
    snr,
    mean_signal=DEFAULT_MEAN_SIGNAL,
    sampler: str = "fast",
    gradient: str | None = None,
):
    """Poisson photon counts drawn from `expected_histograms` (one draw per LR pixel and bin).

    Args:
      key: a `jax.random` key.
      depth: as in `expected_histograms`.
      intensity: as in `expected_histograms`.
      snr: as in `expected_histograms`.
      mean_signal: as in `expected_histograms`.
      sampler: "fast" (exact below 24 photons per bin, Cornish-Fisher above; see `jaxsr.sensor.poisson`) or
        "exact" (`jax.random.poisson`, about 4x slower on CPU).
      gradient: None (the default: a draw has no derivative, so gradients stop at the rates), "normal" or
        "straight-through": a surrogate derivative of the counts with respect to the rates
        (`jaxsr.sensor.poisson.poisson_pathwise`; "normal" is the normal approximation's pathwise derivative from
        3 photons per bin, straight through below). The counts drawn are the same whatever `gradient` is.
    Returns:
      (..., H/scale, W/scale, K) counts, integers stored as floats so they feed the centre of mass directly;
      all NaN where the rates are (traced, invalid scalars: see `expected_histograms`). With `gradient`,
      differentiable (by that surrogate) in everything `expected_histograms` is.
    """
    if gradient is not None and gradient not in PATHWISE_ESTIMATORS:
        raise ValueError(
            f"simulate_histograms: gradient must be None or one of {PATHWISE_ESTIMATORS}, got {gradient!r}"
        )
    _require_key("simulate_histograms", key)
    require_hr_pair("simulate_histograms", depth, intensity, sensor)  # messages in the caller's name
    require_scalar_levels("simulate_histograms", snr, mean_signal)
    rates = expected_histograms(depth, intensity, sensor, snr=snr, mean_signal=mean_signal)
    counts = sample_poisson(key, jax.lax.stop_gradient(rates), method=sampler)
    return counts if gradient is None else poisson_pathwise(counts, rates, estimator=gradient)
