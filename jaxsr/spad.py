"""The SPAD sensor, described once: `Sensor`, composed of its time gate (`Gate`), its optics (`Optics`), its pulse
(`Pulse`) and the depth scale the network reads (`DepthScale`).

The same object is built from Python (`Sensor(gate=Gate.spanning(35.0, bins=32))`), from a sensor's TOML file
(`jaxsr.training.read_sensor`) and from the command's flags (`jaxsr.app.Reading.sensor`),
and it is what the simulator (`jaxsr.simulate_histograms`), the readers (`jaxsr.centre_of_mass`,
`jaxsr.nn.network_inputs`), the super-resolution functions (`jaxsr.super_resolve_histograms`,
`jaxsr.apply_histograms`, metres in and out with `units="m"`), the command and fine-tuning take.

Each part is a frozen dataclass registered as a pytree: the fields that set array shapes (bins, frame size,
scale) are static, the physical numbers (bin width, gate start, field of view, pulse width, depth offset and
span, r_min, ambient floor) are leaves, so a sweep can `jax.jit`, `jax.vmap` or `jax.grad` over them.
"""

from __future__ import annotations

import dataclasses
import numbers
import warnings

import jax
import jax.numpy as jnp

__all__ = ["Sensor", "Gate", "Optics", "Pulse", "DepthScale", "SensorConfig", "TRAINED_RANGE_M",
           "METRES_PER_SECOND", "MIN_LR_SIDE"]

# Smallest LR frame side the network is run on: below 4 pixels every output pixel lies in the border the network
# pads, and a (T, h, w) array with such a side is more likely another layout (frames last, histograms) than frames.
MIN_LR_SIDE = 4
# Metres of radial range per second of round-trip time: r = c t / 2.
METRES_PER_SECOND = 299_792_458.0 / 2
# The range the bundled models were trained on: radial 0 .. 35 m as normalised depth 0 .. 1 (docs/sensor-model.md).
TRAINED_RANGE_M = 35.0


def _concrete_float(value, bad) -> bool:
    """bad(float(value)) for a number given as such (Python, NumPy); False for a JAX array, traced or not (checked
    by the caller's maths instead): a gradient or a `jax.tree.map` rebuilds the parts with any values."""
    if isinstance(value, jax.Array):
        return False
    try:
        return bool(bad(float(value)))
    except ValueError:  # a string: not a number at all
        return True
    except (TypeError, jax.errors.ConcretizationTypeError):
        return False


def _positive_metres(v) -> bool:
    return not (v > 0 and v < float("inf"))


@dataclasses.dataclass(frozen=True)
class Gate:
    """The time grid of a photon histogram: `bins` (K, static) bins of `bin_width` metres of radial range each,
    the first starting at `start` metres (bin k covers start + [k, k + 1) * bin_width). Times convert to range
    as r = c t / 2 (`Gate.from_time`). The paper's sensor is Gate(16, 35 / 16, 0.0), the default."""

    bins: int = dataclasses.field(default=16, metadata=dict(static=True))
    bin_width: float = TRAINED_RANGE_M / 16
    start: float = 0.0

    def __post_init__(self):
        if (isinstance(self.bins, bool) or not isinstance(self.bins, numbers.Real) or int(self.bins) != self.bins
                or self.bins < 2):
            raise ValueError(f"Gate: bins must be an integer >= 2, got {self.bins!r}")
        object.__setattr__(self, "bins", int(self.bins))  # a NumPy integer hashes and prints as the int it is
        if _concrete_float(self.bin_width, _positive_metres):
            raise ValueError(f"Gate: bin_width must be a finite number of metres > 0, got {self.bin_width}")
        if _concrete_float(self.start, lambda v: not (abs(v) < float("inf"))):
            raise ValueError(f"Gate: start must be a finite number of metres, got {self.start}")

    @classmethod
    def spanning(cls, length: float, bins: int = 16, start: float = 0.0) -> "Gate":
        """`bins` bins over `length` metres from `start`: Gate(bins, length / bins, start)."""
        return cls(bins, length / bins, start)

    @classmethod
    def from_time(cls, bins: int, bin_width_s: float, start_s: float = 0.0) -> "Gate":
        """A gate given in round-trip time: `bins` bins of `bin_width_s` seconds from `start_s` seconds.
        Returns a Gate in metres (r = c t / 2)."""
        return cls(bins, bin_width_s * METRES_PER_SECOND, start_s * METRES_PER_SECOND)

    @classmethod
    def of_sensor(cls, sensor: "Sensor") -> "Gate":
        """The gate of a sensor (`sensor.gate`)."""
        return sensor.gate

    @property
    def length(self):
        """Metres of range the gate covers: bins * bin_width."""
        return self.bins * self.bin_width

    @property
    def end(self):
        """Metres at which the gate closes: start + length."""
        return self.start + self.length


@dataclasses.dataclass(frozen=True)
class DepthScale:
    """How radial metres map to the network's normalised depth: n = (r - offset) / span, so `offset` metres is
    the network's 0 and `offset + span` its 1.0 (no return). The bundled models were trained with offset 0 and
    span `TRAINED_RANGE_M` (35 m); a span far from that shows them depth steps of another size than they learned.
    `DepthScale.for_gate(gate)` puts the network's 0 at the gate's start and keeps the trained 35 m span."""

    offset: float = 0.0
    span: float = TRAINED_RANGE_M

    def __post_init__(self):
        if _concrete_float(self.span, _positive_metres):
            raise ValueError(f"DepthScale: span must be a finite number of metres > 0, got {self.span}")
        if _concrete_float(self.offset, lambda v: not (abs(v) < float("inf"))):
            raise ValueError(f"DepthScale: offset must be a finite number of metres, got {self.offset}")

    @classmethod
    def for_gate(cls, gate: Gate, span: float | None = None) -> "DepthScale":
        """The gate's start as the network's 0 m, and `span` metres (default the trained 35 m) as its 1.0."""
        return cls(gate.start, TRAINED_RANGE_M if span is None else span)


@dataclasses.dataclass(frozen=True)
class Optics:
    """The sensor's pixels and field of view: `lr_shape` (rows, cols of SPAD pixels, static), `scale` (static: HR
    pixels per SPAD pixel along each axis, the super-resolution factor and the simulator's render of each pixel)
    and `fov_deg` (horizontal field of view in degrees; square pixels, the optical axis through the frame's
    centre)."""

    lr_shape: tuple[int, int] = dataclasses.field(default=(32, 64), metadata=dict(static=True))
    scale: int = dataclasses.field(default=4, metadata=dict(static=True))
    fov_deg: float = 30.0

    def __post_init__(self):
        shape = tuple(self.lr_shape) if isinstance(self.lr_shape, (tuple, list)) else None
        if (shape is None or len(shape) != 2
                or not all(isinstance(v, numbers.Integral) and not isinstance(v, bool) and v >= 1 for v in shape)):
            raise ValueError(f"Optics: lr_shape must be (rows, cols) of SPAD pixels, two integers >= 1, got "
                             f"{self.lr_shape!r}")
        object.__setattr__(self, "lr_shape", tuple(int(v) for v in shape))  # a list (from JSON) hashes as a tuple
        if isinstance(self.scale, bool) or not isinstance(self.scale, numbers.Integral) or self.scale < 1:
            raise ValueError(f"Optics: scale must be an integer >= 1 (HR pixels per SPAD pixel), got {self.scale!r}")
        object.__setattr__(self, "scale", int(self.scale))
        if _concrete_float(self.fov_deg, lambda v: not 0 < v < 180):
            raise ValueError(f"Optics: fov_deg must be a horizontal field of view in (0, 180) degrees, got "
                             f"{self.fov_deg}")

    @classmethod
    def of_hr(cls, hr_shape, scale: int = 4, fov_deg: float = 30.0) -> "Optics":
        """The optics of an HR frame `hr_shape` rendered at `scale` HR pixels per SPAD pixel; ValueError unless
        both sides divide by `scale`."""
        h, w = (int(v) for v in hr_shape)
        if isinstance(scale, bool) or not isinstance(scale, numbers.Integral) or scale < 1 or h % scale or w % scale:
            raise ValueError(f"Optics: HR shape {tuple(hr_shape)} must be divisible by scale {scale}")
        return cls((h // scale, w // scale), scale, fov_deg)

    @property
    def hr_shape(self) -> tuple[int, int]:
        """(rows, cols) of the HR frame: lr_shape x scale."""
        return (self.lr_shape[0] * self.scale, self.lr_shape[1] * self.scale)

    @property
    def focal_px(self):
        """Focal length in HR pixels: (W/2) / tan(fov/2), square pixels."""
        return (self.hr_shape[1] / 2) / jnp.tan(jnp.deg2rad(self.fov_deg) / 2)


@dataclasses.dataclass(frozen=True)
class Pulse:
    """The sensor's instrument response (laser pulse and timing jitter) as the Gaussian the forward model bins:
    `sigma` in histogram bins. It also sets the centre of mass's window (1 bin up to sigma 0.5, else 2).
    `jaxsr.training.fit_irf(counts)["sigma_bins"]` is the sigma of the Gaussian fitted to a measured IRF."""

    sigma: float = 0.4

    def __post_init__(self):
        if _concrete_float(self.sigma, lambda v: not (v > 0 and v < float("inf"))):
            raise ValueError(f"Pulse: sigma must be a finite width in bins > 0, got {self.sigma}")


def _part(name: str, value, cls):
    if not isinstance(value, cls):
        raise TypeError(f"Sensor: {name} is a jaxsr.{cls.__name__}, got {type(value).__name__}")


@dataclasses.dataclass(frozen=True)
class Sensor:
    """A SPAD direct time-of-flight sensor (docs/sensor-model.md): its histogram `gate` (`Gate`: bins, bin width,
    start), `optics` (`Optics`: SPAD pixels, super-resolution scale, field of view), `pulse` (`Pulse`: the IRF's
    Gaussian width in bins), `depth` (`DepthScale`: which metres the network reads as 0 and 1; default
    `DepthScale.for_gate(gate)`, the gate's start as 0 and the trained 35 m span), and the forward model's
    `r_min` (m, the floor of the inverse-square law) and `ambient_floor` (a0, ambient added to every pixel's
    reflectivity: dark targets, dark counts). The default is the paper's sensor: 32 x 64 pixels, 16 bins over
    0-35 m, 30 degrees, a pulse of 0.4 bins.

    The flat names of the parts read through: `bins`, `bin_width`, `d_max` (the gate's end, m), `lr_shape`,
    `hr_shape`, `scale`, `fov_deg`, `focal_px`, `irf_sigma`."""

    gate: Gate = Gate()
    optics: Optics = Optics()
    pulse: Pulse = Pulse()
    depth: DepthScale | None = None
    r_min: float = 0.5
    ambient_floor: float = 0.05

    def __post_init__(self):
        for name, cls in (("gate", Gate), ("optics", Optics), ("pulse", Pulse)):
            _part(name, getattr(self, name), cls)
        if self.depth is None:
            object.__setattr__(self, "depth", DepthScale.for_gate(self.gate))
        _part("depth", self.depth, DepthScale)
        if _concrete_float(self.r_min, _positive_metres):
            raise ValueError(f"Sensor: r_min must be a finite number of metres > 0, got {self.r_min}")
        if _concrete_float(self.ambient_floor, lambda v: not (v >= 0 and v < float("inf"))):
            raise ValueError(f"Sensor: ambient_floor must be a finite number >= 0, got {self.ambient_floor}")

    def replace(self, **changes) -> "Sensor":
        """A copy with parts replaced: the part names (gate, optics, pulse, depth, r_min, ambient_floor) or the
        leaves `irf_sigma` (the pulse's sigma) and `fov_deg`, traced values allowed."""
        flat = {"irf_sigma": ("pulse", "sigma"), "fov_deg": ("optics", "fov_deg")}
        for name in [n for n in changes if n in flat]:
            part, field = flat[name]
            base = changes.get(part, getattr(self, part))
            changes[part] = dataclasses.replace(base, **{field: changes.pop(name)})
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        """The sensor as JSON-ready values: {"gate": {...}, "optics": {...}, "pulse": {...}, "depth": {...},
        "r_min", "ambient_floor"}, numbers as Python floats and ints (`Sensor.from_dict` reads it back)."""
        def plain(v):
            if isinstance(v, dict):
                return {k: plain(x) for k, x in v.items()}
            if isinstance(v, (tuple, list)):
                return [plain(x) for x in v]
            return v if isinstance(v, int) else float(v)

        return plain(dataclasses.asdict(self))

    @classmethod
    def from_dict(cls, d: dict) -> "Sensor":
        """`to_dict`'s output -> the Sensor."""
        parts = {"gate": Gate, "optics": Optics, "pulse": Pulse, "depth": DepthScale}
        unknown = set(d) - set(parts) - {"r_min", "ambient_floor"}
        if unknown:
            raise ValueError(f"Sensor.from_dict: unknown keys {sorted(unknown)}; expected {sorted(parts)}, r_min, "
                             "ambient_floor")
        return cls(**{k: parts[k](**v) if k in parts else v for k, v in d.items()})

    # the parts' names, read through
    bins = property(lambda self: self.gate.bins, doc="Histogram bins K (static).")
    bin_width = property(lambda self: self.gate.bin_width, doc="Metres of radial range per histogram bin.")
    d_max = property(lambda self: self.gate.end, doc="Metres at which the gate closes (start + bins x width).")
    lr_shape = property(lambda self: self.optics.lr_shape, doc="(rows, cols) of the SPAD (LR) frame.")
    hr_shape = property(lambda self: self.optics.hr_shape, doc="(rows, cols) of the HR frame.")
    scale = property(lambda self: self.optics.scale, doc="HR pixels per SPAD pixel along each axis.")
    fov_deg = property(lambda self: self.optics.fov_deg, doc="Horizontal field of view, degrees.")
    focal_px = property(lambda self: self.optics.focal_px, doc="Focal length in HR pixels.")
    irf_sigma = property(lambda self: self.pulse.sigma, doc="The pulse's Gaussian width, bins.")


def _register(cls, data_fields: list[str], meta_fields: list[str]) -> None:
    """Register `cls` as a pytree: `data_fields` leaves (or subtrees), `meta_fields` static. Unflattening sets the
    fields without `__post_init__`: a gradient, a `jax.tree.map` or a filter spec (equinox, optimistix) rebuilds
    the parts with values that are no metres at all (negative, booleans, None), which only a user's call checks."""
    def flatten_with_keys(x):
        return [(jax.tree_util.GetAttrKey(n), getattr(x, n)) for n in data_fields], tuple(getattr(x, n)
                                                                                          for n in meta_fields)

    def flatten(x):
        return [getattr(x, n) for n in data_fields], tuple(getattr(x, n) for n in meta_fields)

    def unflatten(meta, data):
        obj = object.__new__(cls)
        for name, value in (*zip(meta_fields, meta), *zip(data_fields, data)):
            object.__setattr__(obj, name, value)
        return obj

    jax.tree_util.register_pytree_with_keys(cls, flatten_with_keys, unflatten, flatten)


_register(Gate, ["bin_width", "start"], ["bins"])
_register(DepthScale, ["offset", "span"], [])
_register(Optics, ["fov_deg"], ["lr_shape", "scale"])
_register(Pulse, ["sigma"], [])
_register(Sensor, ["gate", "optics", "pulse", "depth", "r_min", "ambient_floor"], [])


def SensorConfig(*args, **kwargs) -> Sensor:
    """Deprecated (jaxsr 0.2's flat sensor), with its fields (hr_shape, scale, bins, d_max, fov_deg, irf_sigma,
    r_min, ambient_floor), positional or keyword. Returns the `Sensor` of `bins` bins over [0, d_max) m read as the
    network's [0, 1], an HR frame `hr_shape` at `scale`, `fov_deg`, a pulse of `irf_sigma` bins. Use `Sensor`."""
    return _flat_sensor(*args, **kwargs)


def _flat_sensor(hr_shape=(128, 256), scale: int = 4, bins: int = 16, d_max: float = TRAINED_RANGE_M,
                 fov_deg: float = 30.0, irf_sigma: float = 0.4, r_min: float = 0.5,
                 ambient_floor: float = 0.05) -> Sensor:
    warnings.warn("jaxsr.SensorConfig is deprecated: use jaxsr.Sensor(gate=Gate.spanning(d_max, bins), "
                  "optics=Optics.of_hr(hr_shape, scale, fov_deg), pulse=Pulse(irf_sigma), "
                  "depth=DepthScale(0, d_max)); SensorConfig goes in the next release", DeprecationWarning,
                  stacklevel=3)
    if isinstance(bins, bool) or not isinstance(bins, numbers.Integral) or bins < 2:
        raise ValueError(f"SensorConfig: bins must be >= 2, got {bins}")
    return Sensor(gate=Gate.spanning(d_max, bins), optics=Optics.of_hr(hr_shape, scale, fov_deg),
                  pulse=Pulse(irf_sigma), depth=DepthScale(0.0, d_max), r_min=r_min, ambient_floor=ambient_floor)

