"""A sensor described in a TOML file, for fine-tuning a model to it (`jaxsr finetune --sensor FILE`).

    [sensor]
    bins = 16                      # histogram bins K
    bin_width_ps = 12500           # or bin_width_ns, bin_width_m (radial metres; r = c t / 2)
    gate_start_ps = 5180000        # optional (default 0): or gate_start_ns, gate_start_m
    lr_rows = 160                  # the SPAD frame, LR pixels
    lr_cols = 160
    fov_deg = 30.0                 # optional: horizontal field of view the training scenes are rendered with
    irf_sigma_bins = 0.4           # the pulse: a Gaussian's sigma in bins, or
    # irf_file = "irf.csv"         # a measured IRF (one column of counts), its Gaussian width fitted
    # irf_sample_width_ps = 250    # with irf_file: its sample spacing (default: one sample per bin)

    [photons]
    signal_range = [2.0, 7.0]      # mean signal photons per LR pixel with a return, drawn log-uniformly
    snr_range = [8.0, 32.0]        # frame SNR (signal / ambient photons), drawn log-uniformly
    no_return_prob = 0.5           # optional: the other fields of `jaxsr.config.PhotonRegime`

`read_sensor_file(path)` returns the sensor (`jaxsr.Sensor`: the one description that `jaxsr upscale --sensor`,
the library's functions and fine-tuning take), the photon regime (`PhotonRegime`) and a dict of what was read and
derived (the file's text, the gate, the IRF fit, warnings, the `jaxsr upscale` gate
options); every key is checked, and an unknown key or a bad value is refused (ValueError) naming the file, the
key and what was expected. Pure functions otherwise: `parse_sensor_file(text)` does the same on a string.
`training_sensor(sensor)` is the sensor as fine-tuning simulates it (the gate moved to the procedural scenes' range,
a window of a large frame).

The network's sensor model has a Gaussian pulse: a measured IRF is summarised by the sigma of the Gaussian
fitted to it (`fit_irf`, integrated over each sample as the simulation integrates it over each bin); the fit's
relative RMS residual says how far from Gaussian the measurement is (a warning above `IRF_RESIDUAL_WARN`).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..config import (METRES_PER_SECOND, MIN_LR_SIDE, DepthScale, Gate, Optics, PhotonRegime, Pulse,
                      REGIME_LIMITS, Sensor)
from ..sensor.gates import require_float32_depth
from ..sensor.quantities import TIME_UNITS

try:  # Python 3.11+
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10 with the `tomli` backport
    import tomli as tomllib

__all__ = ["read_sensor_file", "parse_sensor_file", "training_sensor", "fit_irf", "read_irf_file", "card_entry",
           "sensor_differences",
           "IRF_RESIDUAL_WARN", "MAX_RENDER_SIDE", "PAPER_PITCH_DEG"]

SCALE = 4  # the bundled models' upsampling factor, and so the fine-tune's
# The paper's sensor: 30 deg over 64 LR columns. The training scenes are rendered at this angular pitch unless
# the file gives fov_deg, so that their structures have the sizes in pixels the bundled models learned.
PAPER_PITCH_DEG = 30.0 / 64
# Training renders at most this many LR pixels a side (a centred window of a larger sensor's field, at its pitch):
# the network trains on crops of 16 x 32 LR pixels anyway, and rendering costs grow with the frame.
MAX_RENDER_SIDE = 256
# Relative RMS residual of the IRF fit above which the file is said to be non-Gaussian (for photon counts, only
# when the residuals also exceed 3x the Poisson noise: a reduced chi-square above 3).
IRF_RESIDUAL_WARN = 0.05
# Metres of range the procedural training scenes span: 1 % of their depths lie below 3.6 m, 99 % below 46 m (64
# rendered clips), median 13.6 m; a gate shorter or longer than these bounds sees little of them (most lie beyond
# it), or squeezes them into its first bins: said in a warning.
SCENE_DEPTH_M = (3.6, 46.0)
GATE_WARN_M = (10.0, 200.0)
# a bin's range, metres: beyond it the gate is not a SPAD's (0.67 ps to 6.7 us a bin), and float32 training on such
# a gate computes NaN or nothing
BIN_WIDTH_RANGE_M = (1e-4, 1e3)

_LENGTH = {"m": 1.0, **{unit: TIME_UNITS[unit] * METRES_PER_SECOND for unit in ("ns", "ps")}}  # r = c t / 2


# --- checks of single values: each returns the value or raises ValueError(what was expected) -------------------

class _Bad(ValueError):
    """A value that is not what a key expects; the message is what was expected."""


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _number(v, lo=None, hi=None, *, lo_open=True, what="a number"):
    if not _is_number(v) or not math.isfinite(v):
        raise _Bad(f"expected {what}")
    if lo is not None and (v <= lo if lo_open else v < lo) or hi is not None and v > hi:
        raise _Bad(f"expected {what}")
    return float(v)


def _positive(v):
    return _number(v, 0.0, what="a finite number > 0")


def _probability(v):
    return _number(v, 0.0, 1.0, lo_open=False, what="a probability from 0 to 1")


def _integer(lo, hi=None):
    def check(v):
        want = f"an integer >= {lo}" if hi is None else f"an integer from {lo} to {hi}"
        if not isinstance(v, int) or isinstance(v, bool) or v < lo or (hi is not None and v > hi):
            raise _Bad(f"expected {want}")
        return v
    return check


def _pair(lo=0.0, hi=None, strict=True):
    def check(v):
        bound = f"{lo:g} {'<' if strict else '<='} lo <= hi" + ("" if hi is None else f" <= {hi:g}")
        want = f"[lo, hi], two finite numbers with {bound}"
        if not (isinstance(v, list) and len(v) == 2 and all(_is_number(x) and math.isfinite(x) for x in v)):
            raise _Bad(f"expected {want}")
        a, b = (float(x) for x in v)
        if not ((a > lo if strict else a >= lo) and a <= b and (hi is None or b <= hi)):
            raise _Bad(f"expected {want}")
        return (a, b)
    return check


def _string(v):
    if not isinstance(v, str) or not v.strip():
        raise _Bad("expected a non-empty string")
    return v


def _choice(*options):
    def check(v):
        if v not in options:
            raise _Bad(f"expected one of {', '.join(repr(o) for o in options)}")
        return v
    return check


_SENSOR_KEYS = {
    "bins": _integer(2, 4096),
    "bin_width_m": _positive, "bin_width_ns": _positive, "bin_width_ps": _positive,
    "gate_start_m": lambda v: _number(v, 0.0, lo_open=False, what="a finite number >= 0"),
    "gate_start_ns": lambda v: _number(v, 0.0, lo_open=False, what="a finite number >= 0"),
    "gate_start_ps": lambda v: _number(v, 0.0, lo_open=False, what="a finite number >= 0"),
    "lr_rows": _integer(MIN_LR_SIDE, 65536), "lr_cols": _integer(MIN_LR_SIDE, 65536),
    "fov_deg": lambda v: _number(v, 0.0, 170.0, what="degrees, a number > 0 and <= 170"),
    "irf_sigma_bins": lambda v: _number(v, 0.0, 1000.0, what="bins, a number > 0 and <= 1000"),
    "irf_file": _string,
    "irf_sample_width_m": _positive, "irf_sample_width_ns": _positive, "irf_sample_width_ps": _positive,
}
# [photons]: the fields of PhotonRegime a sensor file may set (the IRF comes from [sensor])
_PHOTON_KEYS = {
    "signal_range": _pair(*REGIME_LIMITS["signal_range"], strict=False),
    "snr_range": _pair(*REGIME_LIMITS["snr_range"], strict=False),
    "dark_prob": _probability, "dark_range": _pair(),
    "hot_prob": _probability, "hot_fraction_max": _probability, "hot_level_range": _pair(),
    "dead_prob": _probability, "dead_fraction_max": _probability,
    "no_return_prob": _probability, "no_return_fraction": _pair(0.0, 1.0, strict=False),
    "blob_size": _integer(1, 4096),
    "thin_prob": _probability, "thin_lines_max": _integer(1, 64), "thin_width_range": _pair(),
    "motion": _choice("seen", "drawn"), "static_prob": _probability,
    "paper_prob": _probability,
}
_TOP_KEYS = {"description": _string}
_REQUIRED = {"sensor": ("bins", "lr_rows", "lr_cols"), "photons": ("signal_range", "snr_range")}


def _one_of(where: str, table: dict, names: tuple, *, required: bool):
    """The one key of `names` present in `table` (None if none and not required); ValueError for two or none."""
    given = [n for n in names if n in table]
    if len(given) > 1:
        raise ValueError(f"{where} gives {' and '.join(given)}; expected one of {', '.join(names)}")
    if not given and required:
        raise ValueError(f"{where} needs one of {', '.join(names)}")
    return given[0] if given else None


def _metres(table: dict, stem: str, where: str, *, required: bool):
    """A length given as stem_m, stem_ns or stem_ps (times converted as r = c t / 2) -> metres, or None."""
    key = _one_of(where, table, tuple(f"{stem}_{u}" for u in _LENGTH), required=required)
    return (None, None) if key is None else (table[key] * _LENGTH[key.rsplit("_", 1)[1]], key)


def _checked_table(source: str, name: str, table, keys: dict) -> dict:
    if not isinstance(table, dict):
        raise ValueError(f"{source}: {name} must be a table ([{name}]), got {type(table).__name__}")
    out = {}
    for key, value in table.items():
        if key not in keys:
            raise ValueError(f"{source}: [{name}] unknown key {key!r}; expected one of {', '.join(keys)}")
        try:
            out[key] = keys[key](value)
        except _Bad as e:
            raise ValueError(f"{source}: [{name}] {key}: {e}, got {value!r}") from None
    for key in _REQUIRED[name]:
        if key not in out:
            raise ValueError(f"{source}: [{name}] needs {key} ({_EXPECTED[key]})")
    return out


_EXPECTED = {"bins": "histogram bins, an integer >= 2", "lr_rows": "LR pixels, an integer >= 4",
             "lr_cols": "LR pixels, an integer >= 4",
             "signal_range": "[lo, hi] mean signal photons per LR pixel with a return",
             "snr_range": "[lo, hi] frame signal-to-background ratios"}


# --- the IRF --------------------------------------------------------------------------------------------------

def read_irf_file(path) -> np.ndarray:
    """A measured IRF: counts (or any non-negative-on-the-whole weights) per sample, evenly spaced, from an .npy
    array of one axis (or one row or column) or a text file (.txt, .csv, .dat, ...) of one column or one row of
    numbers separated by commas, semicolons, tabs or spaces; lines that are not numbers (a header, # comments) are
    skipped. Returns a float64 1-D array; ValueError for another shape, non-finite values or fewer than 4 samples."""
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(f"irf_file: {path} is a folder; expected a file of the IRF (one column of counts, "
                                "or an .npy array)")
    if not path.is_file():
        raise FileNotFoundError(f"irf_file: no such file: {path}")
    if path.suffix.lower() == ".npy":
        try:
            values = np.load(path, allow_pickle=False)
        except (ValueError, OSError) as e:
            raise ValueError(f"irf_file {path}: not a readable .npy array ({e})") from None
        if values.ndim == 2 and 1 in values.shape:
            values = values.ravel()
        if values.ndim != 1 or values.dtype.kind not in "iuf":
            raise ValueError(f"irf_file {path}: expected one axis of numbers (counts per sample), got an array of "
                             f"shape {values.shape} and dtype {values.dtype}")
    else:
        try:
            text = path.read_text(encoding="utf-8-sig", errors="strict")  # a spreadsheet's byte-order mark too
        except UnicodeDecodeError:
            raise ValueError(f"irf_file {path}: not a text file; expected one column of numbers (or an .npy "
                             "array)") from None
        rows = []
        for line in text.splitlines():
            fields = line.split("#", 1)[0].replace(",", " ").replace(";", " ").split()
            if not fields:
                continue
            try:
                rows.append([float(f) for f in fields])
            except ValueError:
                if rows:  # text after the numbers began: not a header
                    raise ValueError(f"irf_file {path}: expected numbers, got the line {line.strip()!r}") from None
        widths = {len(r) for r in rows}
        if len(rows) == 1:
            values = np.asarray(rows[0])
        elif widths == {1}:
            values = np.asarray([r[0] for r in rows])
        else:
            raise ValueError(f"irf_file {path}: expected one column (or one row) of counts per sample, got "
                             f"{len(rows)} rows of {sorted(widths)} numbers; give the counts column alone")
    values = np.asarray(values, np.float64)
    if values.size < 4 or not np.all(np.isfinite(values)):
        raise ValueError(f"irf_file {path}: expected at least 4 finite numbers, got {values.size} values"
                         + ("" if np.all(np.isfinite(values)) else " with NaN or inf"))
    return values


def _binned_gaussian(x, centre, sigma):
    """The mass of a unit Gaussian (centre, sigma) in each sample [x, x + 1)."""
    from scipy.special import ndtr  # late: scipy comes with scikit-image

    return ndtr((x + 1.0 - centre) / sigma) - ndtr((x - centre) / sigma)


def fit_irf(values, *, sample_width_bins: float = 1.0) -> dict:
    """The Gaussian width of a measured IRF (counts per sample, `sample_width_bins` histogram bins apart).

    Fits background + amplitude x (a Gaussian integrated over each sample) by least squares, as the sensor model
    integrates its Gaussian pulse over each bin. Returns {"sigma_bins", "sigma_samples", "centre_samples",
    "background", "amplitude", "residual" (RMS of the residuals / the fitted pulse's peak), "reduced_chi2" (for
    photon counts, whole numbers >= 0: the squared residuals over the Poisson variance, about 1 when the pulse is
    Gaussian and only counting noise is left; None for other values), "samples"}.
    ValueError for an IRF without a peak above its background."""
    from scipy.optimize import least_squares  # late: scipy comes with scikit-image

    y = np.asarray(values, np.float64).ravel()
    n = y.size
    if n < 4 or not np.all(np.isfinite(y)):
        raise ValueError(f"fit_irf: expected at least 4 finite values, got {n}")
    if not (math.isfinite(sample_width_bins) and sample_width_bins > 0):
        raise ValueError(f"fit_irf: sample_width_bins must be a finite number > 0, got {sample_width_bins}")
    x = np.arange(n, dtype=np.float64)
    median = float(np.median(y))
    if median - y.min() > y.max() - median:  # a dip below the background, not a pulse above it
        raise ValueError(f"fit_irf: the IRF dips {median - y.min():.4g} below its median {median:.4g} and rises only "
                         f"{y.max() - median:.4g} above it: expected a pulse of counts above a background (inverted "
                         "or background-subtracted with the wrong sign?)")
    b0 = float(np.percentile(y, 10))
    excess = np.clip(y - b0, 0.0, None)
    if not excess.max() > 0:
        raise ValueError("fit_irf: the IRF has no peak above its background (a flat or empty measurement)")
    k = int(np.argmax(y))
    above = np.flatnonzero(excess >= excess.max() / 2)
    s0 = max(0.3, (above.max() - above.min() + 1) / 2.355)
    scale = float(excess.max())

    def residuals(p):
        centre, log_sigma, amplitude, background = p
        return (background + amplitude * _binned_gaussian(x, centre, math.exp(log_sigma)) - y) / scale

    start = [k + 0.5, math.log(s0), float(excess.sum()), b0]
    lower = [-0.5 * n, math.log(1e-3), 0.0, -np.inf]
    upper = [1.5 * n, math.log(10.0 * n), np.inf, np.inf]
    fit = least_squares(residuals, start, bounds=(lower, upper), x_scale="jac")
    centre, log_sigma, amplitude, background = (float(v) for v in fit.x)
    sigma = math.exp(log_sigma)
    peak = amplitude * float(_binned_gaussian(x, centre, sigma).max())
    if not peak > 0:
        raise ValueError("fit_irf: no Gaussian pulse fits the IRF (its fitted amplitude is 0)")
    res = fit.fun * scale
    rms = float(np.sqrt(np.mean(res ** 2)))
    counts = bool(np.all(y >= 0) and np.all(y == np.round(y)))
    # photon counts: the residuals Poisson noise alone leaves have a reduced chi-square of about 1
    chi2 = float(np.sum(res ** 2 / np.maximum(y + res, 1.0)) / max(n - 4, 1)) if counts else None
    return {"sigma_bins": sigma * sample_width_bins, "sigma_samples": sigma, "centre_samples": centre,
            "background": background, "amplitude": amplitude, "residual": rms / peak, "reduced_chi2": chi2,
            "samples": n}


# --- the file -------------------------------------------------------------------------------------------------

def _render_window(rows: int, cols: int, fov_deg: float) -> tuple[tuple[int, int], float]:
    """(LR rows, cols) the training scenes are rendered at and their horizontal field of view: the sensor's frame,
    or a centred window of at most MAX_RENDER_SIDE pixels a side at the same angular pitch."""
    r, c = min(rows, MAX_RENDER_SIDE), min(cols, MAX_RENDER_SIDE)
    if c == cols:
        return (r, c), fov_deg
    return (r, c), math.degrees(2 * math.atan(math.tan(math.radians(fov_deg) / 2) * c / cols))


def _quantity(metres: float, key: str) -> str:
    """A gate quantity for `jaxsr upscale` in the unit family of the file's `key`: metres (2m) for a key in m,
    else nanoseconds of round trip (12.5ns)."""
    return f"{metres:.10g}m" if key.endswith("_m") else f"{metres / _LENGTH['ns']:.10g}ns"


def parse_sensor_file(text: str, *, source: str = "sensor file", base_dir=".",
                      photons: bool = True) -> tuple[Sensor, PhotonRegime | None, dict]:
    """`read_sensor_file` on the TOML `text` (named `source` in messages; an irf_file is read relative to
    `base_dir`). Returns (Sensor, PhotonRegime, info); ValueError for an unknown key or a bad value. photons=False:
    the [photons] table is optional (the regime None without it), as reading a recording needs only [sensor]."""
    try:
        doc = tomllib.loads(text)
    except RecursionError:  # tables or arrays nested thousands deep
        raise ValueError(f"{source}: not valid TOML for a sensor file (nested too deeply to read)") from None
    except tomllib.TOMLDecodeError as e:
        raise ValueError(f"{source}: not valid TOML: {e}") from None
    for key in doc:
        if key not in ("sensor", "photons") and key not in _TOP_KEYS:
            what = f"table [{key}]" if isinstance(doc[key], dict) else f"key {key!r}"
            raise ValueError(f"{source}: unknown {what}; expected the tables [sensor] and [photons] (and an optional "
                             "description)")
    top = {}
    for key, check in _TOP_KEYS.items():
        if key in doc:
            try:
                top[key] = check(doc[key])
            except _Bad as e:
                raise ValueError(f"{source}: {key}: {e}, got {doc[key]!r}") from None
    for name in ("sensor", "photons") if photons else ("sensor",):
        if name not in doc:
            raise ValueError(f"{source}: needs a [{name}] table")
    s = _checked_table(source, "sensor", doc["sensor"], _SENSOR_KEYS)
    p = _checked_table(source, "photons", doc["photons"], _PHOTON_KEYS) if "photons" in doc else None
    where = f"{source}: [sensor]"
    bins, rows, cols = s["bins"], s["lr_rows"], s["lr_cols"]
    bin_width, bin_width_key = _metres(s, "bin_width", where, required=True)
    gate_start, gate_start_key = _metres(s, "gate_start", where, required=False)
    gate_start = 0.0 if gate_start is None else gate_start
    if not BIN_WIDTH_RANGE_M[0] <= bin_width <= BIN_WIDTH_RANGE_M[1]:  # float32 training turns such gates into NaN
        lo, hi = BIN_WIDTH_RANGE_M
        raise ValueError(f"{where} {bin_width_key}: a bin of {bin_width:.3g} m; expected {lo * 1e3:g} mm to "
                         f"{hi / 1e3:g} km of range per bin ({lo / METRES_PER_SECOND * 1e12:.2g} ps to "
                         f"{hi / METRES_PER_SECOND * 1e6:.2g} us)")
    span = bins * bin_width
    require_float32_depth(gate_start + span, bin_width, f"{where} the gate")
    warnings = []

    # the pulse: a sigma in bins, or the Gaussian fitted to a measured IRF
    irf_key = _one_of(where, s, ("irf_sigma_bins", "irf_file"), required=True)
    sample_key = _one_of(where, s, tuple(f"irf_sample_width_{u}" for u in _LENGTH), required=False)
    if irf_key == "irf_sigma_bins":
        if sample_key is not None:
            raise ValueError(f"{where} {sample_key} applies to irf_file only (irf_sigma_bins is in bins already)")
        sigma = s["irf_sigma_bins"]
        irf = {"sigma_bins": sigma, "source": "irf_sigma_bins"}
    else:
        irf_path = Path(base_dir) / s["irf_file"]
        sample_bins = 1.0 if sample_key is None else s[sample_key] * _LENGTH[sample_key.rsplit("_", 1)[1]] / bin_width
        try:
            measured = read_irf_file(irf_path)
            fit = fit_irf(measured, sample_width_bins=sample_bins)
        except ValueError as e:
            raise ValueError(f"{where} irf_file: {e}") from None
        sigma = fit["sigma_bins"]
        irf = {"sigma_bins": sigma, "source": "irf_file", "file": str(irf_path), "sample_width_bins": sample_bins,
               "fit": fit}
        if fit["residual"] > IRF_RESIDUAL_WARN and (fit["reduced_chi2"] is None or fit["reduced_chi2"] > 3.0):
            warnings.append(f"the measured IRF is not Gaussian: the fitted Gaussian (sigma {sigma:.3g} bins) leaves "
                            f"a relative RMS residual of {fit['residual']:.1%} (tails, afterpulses or several peaks); "
                            "the network's sensor model has a Gaussian pulse, so it trains at the fitted width")
        if not 0 < fit["centre_samples"] < measured.size:
            warnings.append("the measured IRF's fitted peak lies outside the file's samples; check the file")
    if not 1e-3 <= sigma <= bins:
        raise ValueError(f"{where} the pulse's sigma is {sigma:.3g} bins; expected 0.001 to {bins} bins (the gate)")
    if sigma > 3.0:
        warnings.append(f"the pulse's sigma ({sigma:.3g} bins) is wider than any the bundled models met (0.3-3 bins)")

    fov_deg = s.get("fov_deg", min(90.0, PAPER_PITCH_DEG * cols))
    (render_rows, render_cols), fov = _render_window(rows, cols, fov_deg)
    if (render_rows, render_cols) != (rows, cols):
        warnings.append(f"training renders a centred window of {render_rows} x {render_cols} LR pixels of the "
                        f"{rows} x {cols} field, at its angular pitch (the network trains on crops anyway)")
    if not GATE_WARN_M[0] <= span <= GATE_WARN_M[1]:
        warnings.append(f"the gate spans {span:.3g} m; the training scenes (procedural streets) have depths of "
                        f"about {SCENE_DEPTH_M[0]:g}-{SCENE_DEPTH_M[1]:g} m, so "
                        + ("most of them lie beyond the gate (no return)" if span < GATE_WARN_M[0] else
                           "they fill only the first bins of the gate"))
    # the network's 0 .. 1 spans the gate (the `--span gate` of `jaxsr upscale`)
    sensor = Sensor(gate=Gate(bins, bin_width, gate_start), optics=Optics((rows, cols), SCALE, fov_deg),
                    pulse=Pulse(sigma), depth=DepthScale(gate_start, span))
    regime = None
    if p is not None:
        regime_fields = dict(p)
        regime_fields.update(irf_sigma_range=(sigma, sigma), irf_paper=sigma, irf_paper_prob=1.0)
        try:
            regime = PhotonRegime(**regime_fields)
        except ValueError as e:
            raise ValueError(f"{source}: [photons] {e}") from None
    gate = {"bins": bins, "bin_width_m": bin_width, "start_m": gate_start, "span_m": span}
    # the gate flags in the units the file gave (a time as ns, a range as m; the start as the width when unset)
    options = (f"--bins {bins} --bin-width {_quantity(bin_width, bin_width_key)} "
               f"--gate-start {_quantity(gate_start, gate_start_key or bin_width_key)} --span gate")
    info = {
        "source": source,
        "text": text,
        **top,
        "sensor": {key: list(v) if isinstance(v, tuple) else v for key, v in s.items()},
        "photons": {key: list(v) if isinstance(v, tuple) else v for key, v in (p or {}).items()},
        "lr_shape": [rows, cols],
        "render_lr_shape": [render_rows, render_cols],
        "fov_deg": fov,
        "gate": gate,
        "irf": irf,
        "upscale_options": options,
        "warnings": warnings,
    }
    return sensor, regime, info


def read_sensor(path) -> Sensor:
    """The `jaxsr.Sensor` of a TOML file's [sensor] table (`read_sensor_file` reads its [photons] too)."""
    return read_sensor_file(path, photons=False)[0]


def read_sensor_file(path, *, photons: bool = True) -> tuple[Sensor, PhotonRegime | None, dict]:
    """A sensor's TOML file (see the module docstring) -> (Sensor, PhotonRegime, info).

    Sensor: the gate (bins, bin width, start), the optics (lr_rows x lr_cols SPAD pixels, the bundled models'
    scale 4, fov_deg: default the paper's pitch, 30 deg per 64 columns, at most 90 deg), the pulse
    (irf_sigma_bins, or the Gaussian fitted to irf_file) and the depth scale of the gate (the network's 0 at the
    gate's start, its 1.0 at the gate's end); `training_sensor` of it is what fine-tuning simulates.
    PhotonRegime (None when photons=False and the file has no [photons]): [photons] over `PhotonRegime`'s defaults,
    every clip with the
    sensor's pulse (irf_sigma_bins, or the Gaussian fitted to irf_file). info: "text" (the file as read),
    "sensor" and "photons" (the keys as given), "gate" (bins, bin_width_m, start_m, span_m), "irf" (sigma_bins,
    its source and the fit), "lr_shape", "render_lr_shape", "fov_deg", "upscale_options" (the `jaxsr upscale`
    gate flags that put the sensor's histograms or time tags on the fine-tuned model's scale) and "warnings"
    (sentences on what the training cannot match). Raises FileNotFoundError, or ValueError naming the key and
    what was expected."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"--sensor: no such file: {path}" if not path.exists() else
                                f"--sensor: {path} is not a file; expected a sensor's TOML file")
    try:
        text = path.read_text(encoding="utf-8-sig")  # the byte-order mark some editors (Notepad) begin a file with
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a text file; expected a sensor's TOML file") from None
    sensor, regime, info = parse_sensor_file(text, source=str(path), base_dir=path.parent, photons=photons)
    return sensor, regime, dict(info, path=str(path))


def training_sensor(sensor: Sensor) -> Sensor:
    """The sensor as fine-tuning simulates it: its frame, or a centred window of at most `MAX_RENDER_SIDE` SPAD
    pixels a side at its angular pitch (the network trains on crops anyway); its bins and bin width over a gate
    moved to start at 0 m, so that the procedural scenes (about 3.6-46 m) fill it, with the network's 0 .. 1 over
    the gate as the sensor reads it; r_min the gate's start (the inverse-square law flat across the gate seen from
    its start, as it nearly is across a gate far from the sensor); its pulse."""
    (rows, cols), fov = _render_window(*sensor.lr_shape, float(sensor.fov_deg))
    gate = sensor.gate
    return Sensor(gate=Gate(gate.bins, gate.bin_width, 0.0), optics=Optics((rows, cols), sensor.scale, fov),
                  pulse=sensor.pulse, depth=DepthScale(0.0, gate.length),
                  r_min=max(Sensor.r_min, float(gate.start)), ambient_floor=sensor.ambient_floor)


def card_entry(info: dict) -> dict:
    """What a fine-tuned model's training card records of its sensor file (beside the regime, the card's
    "regime"): the file's path and text, the keys as read, the gate, the IRF (and its fit), the rendered frame,
    the warnings and the `jaxsr upscale` gate flags."""
    keep = ("path", "text", "description", "sensor", "photons", "gate", "irf", "lr_shape", "render_lr_shape",
            "fov_deg", "upscale_options", "warnings")
    return {k: info[k] for k in keep if k in info}


def sensor_differences(card: dict, entry: dict, regime: PhotonRegime) -> list[str]:
    """What differs, in what training simulates, between the sensor a training card records (its "sensor_file"
    and "regime") and a sensor file just read (`card_entry` of its info, and its regime): the gate, the frame,
    the field of view, the pulse's sigma and the photon regime, not the file's path, comments or layout."""
    saved = card.get("sensor_file", {})
    differ = [k for k in ("gate", "lr_shape", "render_lr_shape", "fov_deg") if _plain(saved.get(k)) != _plain(entry[k])]
    if _plain(saved.get("irf", {}).get("sigma_bins")) != _plain(entry["irf"]["sigma_bins"]):
        differ.append("pulse sigma")
    # a field the card predates (added to PhotonRegime since) had its default then: a run begun before it resumes
    if _plain({**PhotonRegime().to_dict(), **card.get("regime", {})}) != _plain(regime.to_dict()):
        differ.append("photon regime")
    return differ


def _plain(v):
    """JSON-like values compared as JSON would store them (tuples as lists, floats as floats)."""
    if isinstance(v, dict):
        return {k: _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if _is_number(v):
        return float(v)
    return v
