"""Pictures of depth for people to look at: colour-mapped PNG previews, labelled comparison strips and grayscale
previews of intensity. Drawn with matplotlib's colour maps and Agg renderer, written with `jaxsr.io.formats.write_image`
(atomic; no existing file is replaced unless `overwrite=True`). No return is black in every picture, distinct
from every colour of the map. File formats for data (depth, histograms, sequences) are in `jaxsr.io.formats`.
"""

from __future__ import annotations

import numpy as np

from ..config import DepthScale, Gate, Sensor
from .formats import write_image
from ..sensor.forward import denormalise_depth
from ..sensor.gates import from_network_depth

__all__ = ["write_comparison", "write_gray_preview", "write_preview"]


NO_RETURN_RGB = (0.0, 0.0, 0.0)  # no return, in every picture and video: black


def _colourise(depth, d_min, d_max, cmap):
    """(H, W) metres -> (H, W, 3) float32 RGB in [0, 1], d_min at the map's first colour and d_max at its last;
    no return (inf, NaN, > d_max) black."""
    import matplotlib

    depth = np.asarray(depth, np.float32)
    norm = np.clip((np.where(np.isfinite(depth), depth, np.inf) - d_min) / (d_max - d_min), 0.0, 1.0)
    rgb = matplotlib.colormaps[cmap](norm)[..., :3]
    no_return = ~np.isfinite(depth) | (depth > d_max)
    rgb[no_return] = NO_RETURN_RGB
    return rgb.astype(np.float32)


def _to_metres(frame, d_min, d_max):
    """(H, W) normalised [0, 1] -> metres d_min + n (d_max - d_min), inf for no return
    (`jaxsr.sensor.gates.from_network_depth`; with d_min 0, `jaxsr.sensor.forward.denormalise_depth`)."""
    if d_min == 0:
        sensor = Sensor(gate=Gate.spanning(d_max), depth=DepthScale(0.0, d_max))
        return np.asarray(denormalise_depth(frame, sensor), np.float32)
    return np.asarray(from_network_depth(frame, DepthScale(d_min, d_max - d_min)), np.float32)


def _metres_or_normalised(frame, d_min, d_max):
    """Accept normalised depth in [0, 1] (1 = no return) or metres; return metres with inf for no return.
    A frame whose finite values all lie within [0, 1] is taken as normalised (no lidar scene lies within a metre)."""
    frame = np.asarray(frame, np.float32)
    if np.nanmax(np.where(np.isfinite(frame), frame, 0.0), initial=0.0) <= 1.0:
        return _to_metres(frame, d_min, d_max)
    return frame


def _check_range(d_min, d_max):
    if not (np.isfinite(d_min) and np.isfinite(d_max) and d_max > d_min):
        raise ValueError(f"the colour scale needs finite metres d_min < d_max, got {d_min}, {d_max}")


def _to_png(rgb):
    """(H, W, 3) float RGB in [0, 1] -> uint8, rounded."""
    return (rgb * 255 + 0.5).astype(np.uint8)


def write_preview(path, depth, *, d_max=35.0, d_min=0.0, cmap="turbo", normalised=False, overwrite=False):
    """Write a colour-mapped PNG of a depth frame (H, W) in metres (or normalised [0, 1] with normalised=True,
    0 meaning d_min and 1 no return); the colours span d_min to d_max metres (the sensor's true range: for a
    gated recording, the gate's start to start + span); no return (inf, NaN, > d_max) is black.

    Args: path (.png), depth (H, W). Returns None (an RGB PNG of shape (H, W, 3)).
    """
    depth = np.asarray(depth, np.float32)
    if depth.ndim != 2:
        raise ValueError(f"writing {path}: expected a depth frame (H, W), got {depth.shape}")
    _check_range(d_min, d_max)
    if normalised:
        depth = _to_metres(depth, d_min, d_max)
    write_image(path, _to_png(_colourise(depth, d_min, d_max, cmap)), overwrite=overwrite)


def render(width: int, height: int, draw, facecolor=(1.0, 1.0, 1.0)):
    """An RGB float image (height, width, 3) drawn by `draw(fig)` with matplotlib's Agg renderer."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width / 100, height / 100), dpi=100, facecolor=facecolor)
    canvas = FigureCanvasAgg(fig)
    draw(fig)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].astype(np.float32) / 255.0


COLOUR_BAR_HEIGHT = 34  # pixels of a preview's colour bar, its tick labels included


def colour_bar(width: int, d_min: float, d_max: float, cmap: str = "turbo") -> np.ndarray:
    """(COLOUR_BAR_HEIGHT, width, 3) float RGB: the colour scale from d_min to d_max metres with ticks in metres,
    and a black swatch for no return, on white."""
    import matplotlib
    from matplotlib.ticker import FuncFormatter, MaxNLocator

    def draw(fig):
        legend = 70
        ax = fig.add_axes((16 / width, 0.55, max(0.1, (width - legend - 26) / width), 0.4))  # room for "0 m"
        ax.imshow(np.linspace(0, 1, 256)[None], aspect="auto", cmap=matplotlib.colormaps[cmap],
                  extent=(d_min, d_max, 0, 1))
        ax.set_yticks([])
        ax.xaxis.set_major_locator(MaxNLocator(nbins=max(3, width // 90)))
        ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g} m"))
        ax.tick_params(axis="x", labelsize=7, length=2, pad=1)
        swatch = fig.add_axes(((width - legend + 2) / width, 0.55, 10 / width, 0.4))
        swatch.set_facecolor((0.0, 0.0, 0.0))
        swatch.set_xticks([])
        swatch.set_yticks([])
        fig.text((width - legend + 15) / width, 0.75, "no return", fontsize=7, va="center")

    return render(width, COLOUR_BAR_HEIGHT, draw)


def _label(rgb, text):
    """Draw `text` in the top-left corner with matplotlib's Agg renderer (white on a dark box)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    h, w = rgb.shape[:2]
    fig = Figure(figsize=(w / 100, h / 100), dpi=100)
    canvas = FigureCanvasAgg(fig)
    ax = fig.add_axes((0, 0, 1, 1))
    ax.imshow(rgb, interpolation="nearest")
    ax.axis("off")
    ax.text(3, 3, text, color="white", fontsize=7, va="top", ha="left",
            bbox=dict(facecolor="black", alpha=0.6, pad=1, linewidth=0))
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].astype(np.float32) / 255.0


def write_comparison(path, lr, sr, *, gt=None, d_max=35.0, d_min=0.0, cmap="turbo", labels=("LR", "SR", "GT"),
                     overwrite=False):
    """Write an LR | SR | GT strip (LR | SR without `gt`) as PNG. lr (h, w) is nearest-upsampled to the HR size
    of sr and gt (H, W). Frames in metres or normalised [0, 1] (0 = d_min, 1 = no return); one colour scale from
    d_min to d_max metres (the sensor's true range, the gate's start included) for every panel; no return is black.

    Args: path (.png), lr (h, w), sr (H, W), gt (H, W) or None. Returns None (a PNG of shape
    (H + COLOUR_BAR_HEIGHT, n W + 2 (n - 1), 3) for n panels: the colour scale in metres under them).
    """
    _check_range(d_min, d_max)
    frames = [_metres_or_normalised(a, d_min, d_max) for a in ((lr, sr) if gt is None else (lr, sr, gt))]
    lr, hr = frames[0], frames[1:]
    if hr[0].ndim != 2 or any(a.shape != hr[0].shape for a in hr):
        raise ValueError(f"writing {path}: SR and GT must be equal (H, W) frames, got {[a.shape for a in hr]}")
    shape = hr[0].shape
    fy, fx = shape[0] // lr.shape[0], shape[1] // lr.shape[1]
    if lr.ndim != 2 or lr.shape[0] * fy != shape[0] or lr.shape[1] * fx != shape[1]:
        raise ValueError(f"writing {path}: LR {lr.shape} is not an integer downscale of {shape}")
    lr_up = np.repeat(np.repeat(lr, fy, 0), fx, 1)
    panels = [_colourise(a, d_min, d_max, cmap) for a in [lr_up, *hr]]
    if labels:
        panels = [_label(p, t) for p, t in zip(panels, labels)]
    gap = np.ones((shape[0], 2, 3), np.float32)
    strip = np.concatenate([x for p in panels for x in (gap, p)][1:], axis=1)
    strip = np.concatenate([strip, colour_bar(strip.shape[1], d_min, d_max, cmap)], axis=0)
    write_image(path, _to_png(strip), overwrite=overwrite)


def write_gray_preview(path, image, *, overwrite=False):
    """Write an 8-bit grayscale PNG of an image (H, W) with values in [0, 1] (clipped), e.g. the intensity.

    Args: path (.png), image (H, W). Returns None.
    """
    image = np.asarray(image, np.float32)
    if image.ndim != 2:
        raise ValueError(f"writing {path}: expected a grayscale image (H, W), got {image.shape}")
    write_image(path, _to_png(np.clip(image, 0, 1)), overwrite=overwrite)
