"""What `jaxsr upscale` is asked to do, as four frozen specifications, each checked once where it is built:

- `Reading`: what is read (the input's kind, the histogram gate, the depth span, time tags' units, depth units);
- `ModelChoice`: which model, in which temporal form and precision, at which no-return threshold;
- `PhotonRules`: the photon tests that decide no return beside the network (histograms and time tags);
- `Writing`: what is written beside the output (frame files, a preview, a video, point clouds) and whether an
  existing file may be replaced.

The command builds them from its flags, a script from keywords (`Reading(bins=32, bin_width="250ps")`). A
specification refuses a value it cannot use when it is built (ValueError or TypeError, naming the option and its
flag); what depends on the recording or the model (a gate option given for depth frames, a rate for a model
without a no-return head) is checked once they are known, by `prepare_upscale`.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import os

import numpy as np

from ..checks import one_positive_number
from ..config import PRECISIONS, TRAINED_RANGE_M, DepthScale, Gate, Sensor
from ..inference import DEFAULT_FORM, DEFAULT_PRECISION, FORMS
from ..nn.model import Model
from ..io.pointcloud import points_camera
from ..sensor.camera import AXES, DEPTH_KINDS, Intrinsics, as_intrinsics
from ..sensor.peaks import check_false_alarm_rate
from ..sensor.quantities import parse_span, parse_time_unit, range_metres
from ..training.sensor_file import read_sensor
from .recordings import DEPTH_UNITS

__all__ = ["AUTO", "KINDS", "FRAME_FORMATS", "Reading", "ModelChoice", "PhotonRules", "Writing", "is_auto"]

AUTO = "auto"
KINDS = ("depth", "histograms", "timetags")  # what an input holds (-k/--kind)
FRAME_FORMATS = ("exr", "pfm", "tif", "png")  # frame files of a folder OUTPUT
DEFAULT_BINS = 16
DEFAULT_CMAP = "turbo"  # the colour map of previews, videos and point clouds
# the ranges a gate's bin and the network's [0, 1] may span, metres: a SPAD's bins are picoseconds to microseconds
# (0.1 mm to 1 km), and float32 depth on spans beyond these holds nothing the models can mean
BIN_WIDTH_RANGE_M = (1e-4, 1e3)
SPAN_RANGE_M = (1e-3, 1e6)
# frames per second of a video: beyond these, players show nothing of it (ffmpeg refuses far below)
MIN_FPS, MAX_FPS = 0.1, 1000.0


def is_auto(setting) -> bool:
    """True for the string "auto" (a setting the recording decides)."""
    return isinstance(setting, str) and setting == AUTO


def _positive(value, what: str, parse, unit: str):
    """None, a string parsed by `parse` (a quantity with its unit), or a finite number > 0 in `unit`."""
    if value is None:
        return None
    if isinstance(value, str):
        try:
            return parse(value)
        except ValueError as e:
            raise ValueError(f"{what}: {e}") from None
    return one_positive_number(value, what, f"one value > 0 in {unit}")


def _flag(value) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"expected True or False, got {value!r}")
    return bool(value)


def check_fps(fps, what: str) -> float:
    """A video's frames per second: a number from `MIN_FPS` to `MAX_FPS`."""
    expected = f"frames per second from {MIN_FPS:g} to {MAX_FPS:g}"
    fps = one_positive_number(fps, what, expected)
    if not MIN_FPS <= fps <= MAX_FPS:
        raise ValueError(f"{what}: expected {expected}, got {fps:g}")
    return fps


@dataclasses.dataclass(frozen=True)
class Reading:
    """What is read. kind (-k/--kind): "depth", "histograms" or "timetags" (None: depth or histograms from the
    data; time tags must be named). bins, bin_width, gate_start (histograms and time tags): the gate, `bins`
    (default: the histograms' own, then spanning 35 m unless bin_width says; 16 for time tags) bins of bin_width
    from gate_start, metres or strings with a unit ("12.5ns", "2.19m"; a time
    converts as r = c t / 2); default 35 m / 16 from 0 (time tags: the photons' span). span: metres of range from
    the gate's start mapped onto the network's [0, 1] (default None: the depth the first frames' returns reach,
    `jaxsr.sensor.data_span`), or "gate" (the gate's length).
    time_unit (--time-unit, time tags): seconds per time unit or a string such as "1ps"; variable: the .mat cell
    array to read; drop_outside: ignore photons outside the gate (default: refuse them). clip_negative
    (histograms): clip negative counts at 0, as background-subtracted data need, and say how many. units
    (--units): of depth input and array output, one of `DEPTH_UNITS` (None: guessed, see
    `jaxsr.app.recordings.guess_units`; histograms give metres). sensor (--sensor): the sensor instead of the
    gate's options, a `jaxsr.Sensor` or its TOML file (`jaxsr.training.read_sensor`: its gate, depth scale and pulse).
    `sensor_for` is the `jaxsr.Sensor` the histograms are read with.

    Built checked: bin_width and gate_start are held in metres, span in metres or "gate", time_unit in seconds."""

    kind: str | None = None
    bins: int | None = None
    bin_width: float | str | None = None
    gate_start: float | str | None = None
    span: float | str | None = None
    time_unit: float | str | None = None
    variable: str | None = None
    drop_outside: bool = False
    clip_negative: bool = False
    units: str | None = None
    sensor: str | os.PathLike | Sensor | None = None

    def __post_init__(self):
        if self.kind is not None and self.kind not in KINDS:
            raise ValueError(f"kind (--kind) is one of {', '.join(KINDS)}, got {self.kind!r}")
        if self.bins is not None and (isinstance(self.bins, bool) or not isinstance(self.bins, numbers.Integral)
                                      or self.bins < 2):
            raise ValueError(f"bins (--bins): expected an integer >= 2, got {self.bins!r}")
        set_ = lambda name, value: object.__setattr__(self, name, value)  # noqa: E731 (frozen: normalised once)
        set_("bin_width", range_metres(self.bin_width, "bin_width"))
        set_("gate_start", range_metres(self.gate_start, "gate_start"))
        if self.bin_width is not None and not self.bin_width > 0:
            raise ValueError(f"bin_width (--bin-width): expected a width > 0, got {self.bin_width:g} m")
        if self.gate_start is not None and self.gate_start < 0:  # before the laser pulse: depth would be negative
            raise ValueError(f"gate_start (--gate-start): expected a range >= 0 from the laser pulse, got "
                             f"{self.gate_start:g} m")
        if self.span != "gate":
            set_("span", _positive(self.span, "span", parse_span, "metres or 'gate'"))
        for name, value, (lo, hi) in (("bin_width", self.bin_width, BIN_WIDTH_RANGE_M),
                                      ("span", None if self.span == "gate" else self.span, SPAN_RANGE_M)):
            if value is not None and not lo <= value <= hi:  # beyond what float32 depth and the models can mean
                raise ValueError(f"{name} (--{name.replace('_', '-')}): expected {lo:g} to {hi:g} m, got {value:g} m")
        set_("time_unit", _positive(self.time_unit, "time_unit", parse_time_unit, "seconds"))
        if self.variable is not None and not isinstance(self.variable, str):
            raise TypeError(f"variable (--variable): expected the name of a .mat cell array, got {self.variable!r}")
        for name in ("drop_outside", "clip_negative"):
            try:
                set_(name, _flag(getattr(self, name)))
            except TypeError as e:
                raise TypeError(f"{name}: {e}") from None
        if self.sensor is not None:
            if self.gate_options:
                raise ValueError("--sensor gives the gate and the depth scale: --bins, --bin-width, --gate-start and "
                                 "--span do not go beside it")
            if isinstance(self.sensor, (str, os.PathLike)):
                set_("sensor", read_sensor(self.sensor))
            elif not isinstance(self.sensor, Sensor):
                raise TypeError(f"sensor (--sensor): expected a jaxsr.Sensor or its TOML file, got "
                                f"{type(self.sensor).__name__}")
        if self.units is not None and self.units not in DEPTH_UNITS:
            raise ValueError(f"units is one of {', '.join(map(repr, DEPTH_UNITS))}, got {self.units!r}")
        tag_only = self.tag_options
        if tag_only and self.kind in ("depth", "histograms"):
            raise ValueError(f"{', '.join(tag_only)} applies to time tags only (--kind timetags)")
        if self.kind == "depth":
            self.refuse_for_depth()
        if self.clip_negative and self.kind == "timetags":
            raise ValueError("--clip-negative applies to histograms only (counts of time tags are never negative)")

    @property
    def tag_options(self) -> tuple[str, ...]:
        """The flags given that only time tags take."""
        return tuple(flag for flag, value in (("--time-unit", self.time_unit), ("--variable", self.variable),
                                              ("--drop-outside", self.drop_outside or None)) if value is not None)

    @property
    def gate_options(self) -> bool:
        """True when any of the gate's options (bins, bin_width, gate_start, span) is given."""
        return any(v is not None for v in (self.bins, self.bin_width, self.gate_start, self.span))

    @property
    def n_bins(self) -> int:
        """The gate's bins: `bins`, default 16."""
        return DEFAULT_BINS if self.bins is None else int(self.bins)

    def sensor_for(self, bins: int | None = None) -> Sensor:
        """The sensor histograms are read with: `sensor`, or the gate's options (the flags' route): `bins`
        (default the histograms' own, `bins` here, else 16) bins of bin_width (default: 35 m over the histograms'
        own bins, 35 / 16 m beside --bins) from gate_start (default 0), the network's 0 at the gate's start and
        its 1.0 `span` metres on (default the trained 35 m here; the histogram job fits it to the data, see
        `sensor_of_gate`; "gate": the gate's end). Raises ValueError where the histograms' bins differ from the
        sensor's."""
        if self.sensor is not None:
            if bins is not None and int(bins) != self.sensor.bins:
                raise ValueError(f"the histograms have {int(bins)} bins and the sensor (--sensor) {self.sensor.bins}")
            return self.sensor
        n = int(bins) if self.bins is None and bins is not None else self.n_bins
        width = self.bin_width
        if width is None:  # bins read from the data span the trained range, as the bundled sensor's 16 do
            width = Gate().bin_width if self.bins is not None else TRAINED_RANGE_M / n
        return self.sensor_of_gate(Gate(n, width, 0.0 if self.gate_start is None else self.gate_start))

    def sensor_of_gate(self, gate: Gate, fitted_span: float | None = None) -> Sensor:
        """The sensor of a gate (given, or found from time tags) with the depth scale `span` says, or `sensor`.
        Where `span` is None the scale spans `fitted_span` metres (the histogram job's `jaxsr.sensor.data_span`),
        or the trained 35 m without it."""
        if self.sensor is not None:
            return self.sensor
        span = gate.length if self.span == "gate" else fitted_span if self.span is None else self.span
        return Sensor(gate=gate, depth=DepthScale.for_gate(gate, span))

    def refuse_for_depth(self) -> None:
        """Raise ValueError for an option that depth frames cannot take (they hold no photons)."""
        if self.sensor is not None:
            raise ValueError("--sensor applies to histograms and time tags only (depth frames hold no photons)")
        if self.gate_options or self.drop_outside:
            raise ValueError("--bins, --bin-width, --gate-start and --span apply to histograms and time tags only")
        if self.clip_negative:
            raise ValueError("--clip-negative applies to histograms only (negative depth is no return)")


@dataclasses.dataclass(frozen=True)
class ModelChoice:
    """Which model, and how it runs. model (--model): "default" (the bundled model that fits the input:
    `jaxsr.app.models.DEFAULT_MODELS`), "auto" (the TR that `jaxsr.inference.choose_tr` picks from the measured
    motion, within `min_fps`), a bundled name (tr0..tr4, tr4-ambient, paper-tr4, ...), a checkpoint path, or a
    loaded `jaxsr.Model`. form (--form): the temporal form, one of `jaxsr.inference.FORMS` ("auto": the model's own
    form, or the sequence form where its card records the two forms measured equivalent). precision
    (--precision): one of `jaxsr.config.PRECISIONS`. no_return_logit (--no-return-logit): for a model with a
    no-return head, the logit above which a pixel is output as no return (None: the model's own). min_fps
    (--min-fps): with "auto" only, the slowest acceptable frames/s."""

    model: str | os.PathLike | Model = "default"
    form: str = DEFAULT_FORM
    precision: str = DEFAULT_PRECISION
    no_return_logit: float | None = None
    min_fps: float | None = None

    def __post_init__(self):
        if not isinstance(self.model, (str, os.PathLike, Model)):
            raise TypeError(f"model: expected 'default', 'tr0'..'tr4', 'auto', a checkpoint path or a loaded "
                            f"jaxsr.Model, got {type(self.model).__name__} {self.model!r:.60}")
        if not isinstance(self.precision, str) or self.precision not in PRECISIONS:
            raise ValueError(f"precision (--precision) is one of {', '.join(map(repr, PRECISIONS))}, got "
                             f"{self.precision!r}")
        if not isinstance(self.form, str) or self.form not in FORMS:
            raise ValueError(f"form (--form) is one of {', '.join(map(repr, FORMS))}, got {self.form!r}")
        logit = self.no_return_logit
        if logit is not None and (isinstance(logit, bool) or not isinstance(logit, numbers.Real)
                                  or not math.isfinite(float(logit))):
            raise ValueError(f"no_return_logit (--no-return-logit): expected a finite number (a logit), got {logit!r}")
        if self.min_fps is not None:
            if not self.is_auto:
                raise ValueError("--min-fps applies to --model auto only (a fixed model runs at its own speed)")
            object.__setattr__(self, "min_fps", one_positive_number(self.min_fps, "min_fps (--min-fps)",
                                                                    "frames per second > 0"))

    @property
    def is_auto(self) -> bool:
        """True for "auto" (the TR chosen from the recording's motion)."""
        return isinstance(self.model, str) and self.model == AUTO

    @property
    def is_default(self) -> bool:
        """True for "default" (the bundled model that fits the input's kind)."""
        return isinstance(self.model, str) and self.model == "default"


@dataclasses.dataclass(frozen=True)
class PhotonRules:
    """The photon tests that decide no return beside the network (histograms and time tags only).

    ambient_alpha (--ambient-alpha): also output no return wherever the photons of 3 x 3 pixels and 9 frames
    around a pixel pass for ambient light alone at this false-alarm rate (`jaxsr.sensor.ambient_only`); "auto"
    (default): on where the recording's photon levels say it holds (`jaxsr.app.photons.auto_ambient_alpha`), else
    off; None: off. keep_returns (--keep-returns): for a model with a no-return head, output no return only where
    the head says so AND the pixel's own photons over 9 frames, and those of the quiet pixels pooled around it
    (`jaxsr.sensor.QUIET_POOLS`), pass for ambient light alone at this rate; "auto" (default):
    `jaxsr.app.photons.AUTO_KEEP_RETURNS` for a model with a head, unless an ambient rate decides instead; None:
    the head decides alone. The two rates are two decisions on the same pixels: give one."""

    ambient_alpha: float | str | None = AUTO
    keep_returns: float | str | None = AUTO

    def __post_init__(self):
        for name, flag in (("ambient_alpha", "--ambient-alpha"), ("keep_returns", "--keep-returns")):
            value = getattr(self, name)
            if isinstance(value, str) and value != AUTO:
                raise ValueError(f"{name} ({flag}) is 'auto', None (off) or a false-alarm rate such as 0.001, "
                                 f"got {value!r}")
            if value is not None and not is_auto(value):
                check_false_alarm_rate(f"{name} ({flag})", value)
        if self.rates_given == 2:
            raise ValueError("keep_returns (--keep-returns) and ambient_alpha (--ambient-alpha) are two decisions "
                             "on no return: give one (ambient_alpha None, --ambient-alpha off)")

    @property
    def rates_given(self) -> int:
        """How many of the two are set to a rate (neither "auto" nor None)."""
        return sum(v is not None and not is_auto(v) for v in (self.ambient_alpha, self.keep_returns))


@dataclasses.dataclass(frozen=True)
class Writing:
    """What is written beside the output, and how. frame_format (--frame-format): the frame files of a folder
    OUTPUT, one of `FRAME_FORMATS` (None: "exr"; refused for any other output). preview (--preview): an input |
    output .png strip of the middle frame. video (--video): an .mp4 or .gif of every frame, input | output |
    reference, at fps (--fps; default the recording's where its file says, else 25); reference (--reference): HR
    depth (T, H, W) to show beside them, a path in INPUT's depth formats, a NumPy array or a
    `jaxsr.app.recordings.Recording`, in metres or normalised. points (--points): PLY point clouds, a folder of one
    per frame or one .ply file for the whole sequence (each point with its frame index), coloured by depth
    (points_colour "depth") or not (None). Their camera (`jaxsr.io.pointcloud`), one of: fov_deg (--fov), a
    horizontal field of view in degrees or (horizontal, vertical) (None: the sensor model's 30, square pixels);
    intrinsics (--intrinsics), fx, fy, cx, cy in HR pixels; lr_intrinsics (--lr-intrinsics), the same for the LR
    sensor, scaled to HR by the recording's scale (`Intrinsics.scaled`). points_depth (--points-depth): the depth
    is "radial" range (None: the sensor's) or "planar" z; points_axes (--points-axes): "opencv" (None: x right, y
    down, z forward) or "opengl" (x right, y up, z backward). vmin, vmax (--vmin, --vmax): the colour scale of
    previews, videos and point clouds in metres (None: the recording's depth range, read from its first frames);
    cmap (--cmap): a matplotlib colour map (None: `DEFAULT_CMAP`); vmin, vmax and cmap are refused without a picture
    to colour. overwrite (--force): replace an existing output, preview, video or point clouds."""

    frame_format: str | None = None
    preview: str | os.PathLike | None = None
    video: str | os.PathLike | None = None
    fps: float | None = None
    reference: object = None
    points: str | os.PathLike | None = None
    fov_deg: float | None = None
    points_colour: str | None = "depth"
    overwrite: bool = False
    vmin: float | None = None
    vmax: float | None = None
    cmap: str | None = None
    intrinsics: object = None
    lr_intrinsics: object = None
    points_depth: str | None = None
    points_axes: str | None = None

    def __post_init__(self):
        if self.frame_format is not None and self.frame_format not in FRAME_FORMATS:
            raise ValueError(f"frame_format (--frame-format) is one of {', '.join(FRAME_FORMATS)}, got "
                             f"{self.frame_format!r}")
        if self.video is None:
            for name, value in (("--fps", self.fps), ("--reference", self.reference)):
                if value is not None:
                    raise ValueError(f"{name} applies to --video only")
        if self.fps is not None:
            object.__setattr__(self, "fps", check_fps(self.fps, "fps (--fps)"))
        self._check_points()
        if self.points_colour not in ("depth", None):
            raise ValueError(f"points_colour: 'depth' or None, got {self.points_colour!r}")
        for name in ("vmin", "vmax"):
            value = getattr(self, name)
            if value is not None and (isinstance(value, bool) or not isinstance(value, numbers.Real)
                                      or not math.isfinite(float(value))):
                raise ValueError(f"{name} (--{name}): expected finite metres, got {value!r}")
        if self.vmin is not None and self.vmax is not None and not self.vmin < self.vmax:
            raise ValueError(f"vmin (--vmin) must be below vmax (--vmax), got {self.vmin:g} and {self.vmax:g}")
        import matplotlib  # late: the colour maps are only needed where pictures are drawn

        if self.cmap is not None and self.cmap not in matplotlib.colormaps:
            raise ValueError(f"cmap (--cmap): expected a matplotlib colour map such as 'turbo' or 'viridis', got "
                             f"{self.cmap!r}")
        if self.preview is None and self.video is None and self.points is None:  # no picture to colour
            given = [flag for flag, v in (("--vmin", self.vmin), ("--vmax", self.vmax), ("--cmap", self.cmap))
                     if v is not None]
            if given:
                raise ValueError(f"{', '.join(given)} appl{'ies' if len(given) == 1 else 'y'} to --preview, --video "
                                 "and --points only (the colour scale of pictures)")
        if self.cmap is None:
            object.__setattr__(self, "cmap", DEFAULT_CMAP)
        try:
            object.__setattr__(self, "overwrite", _flag(self.overwrite))
        except TypeError as e:
            raise TypeError(f"overwrite: {e}") from None

    def _check_points(self):
        camera = (("--fov", self.fov_deg), ("--intrinsics", self.intrinsics), ("--lr-intrinsics", self.lr_intrinsics))
        given = [flag for flag, value in (*camera, ("--points-depth", self.points_depth),
                                          ("--points-axes", self.points_axes)) if value is not None]
        if self.points is None and given:
            raise ValueError(f"{given[0]} applies to --points only")
        ways = [flag for flag, value in camera if value is not None]
        if len(ways) > 1:
            raise ValueError(f"the point clouds' camera is given one way, by --fov, --intrinsics or --lr-intrinsics: "
                             f"got {' and '.join(ways)}")
        if self.fov_deg is not None:
            pair = self.fov_deg if isinstance(self.fov_deg, (tuple, list)) else (self.fov_deg,)
            if len(pair) not in (1, 2) or not all(isinstance(a, numbers.Real) and not isinstance(a, bool)
                                                  and 0 < a < 180 for a in pair):
                raise ValueError(f"fov_deg (--fov): expected a horizontal field of view in (0, 180) degrees, or "
                                 f"(horizontal, vertical), got {self.fov_deg!r}")
            object.__setattr__(self, "fov_deg", float(pair[0]) if len(pair) == 1 else tuple(map(float, pair)))
        for name in ("intrinsics", "lr_intrinsics"):
            if getattr(self, name) is not None:
                flag = "--" + name.replace("_", "-")
                object.__setattr__(self, name, as_intrinsics(getattr(self, name), f"{name} ({flag})"))
        for name, allowed in (("points_depth", DEPTH_KINDS), ("points_axes", AXES)):
            value = getattr(self, name)
            if value is not None and value not in allowed:
                raise ValueError(f"{name} (--{name.replace('_', '-')}): expected one of {', '.join(allowed)}, got "
                                 f"{value!r}")

    def points_camera(self, hr_shape, scale) -> Intrinsics:
        """The point clouds' camera on (H, W) HR frames of a recording upscaled `scale` times: the intrinsics given
        (lr_intrinsics scaled to HR) or those of the fields of view. Returns `jaxsr.sensor.Intrinsics`."""
        if self.lr_intrinsics is not None:
            return self.lr_intrinsics.scaled(scale)
        return points_camera(hr_shape, fov_deg=self.fov_deg, intrinsics=self.intrinsics)

    @property
    def looks(self) -> bool:
        """True when every frame is drawn too (a video or point clouds)."""
        return self.video is not None or self.points is not None
