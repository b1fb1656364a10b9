"""Depth videos for people to watch: side-by-side panels (input | output | reference) of a depth sequence, one
video frame per depth frame, written as MP4 (H.264) or animated GIF.

Every panel shares one colour scale, from `d_min` to `d_max` metres (the sensor's true range: for a gated
recording, the gate's start to its start plus the span), drawn as a colour bar in metres under the panels; no
return (inf, NaN, beyond `d_max`) is black, named in a legend beside the bar, as in `jaxsr.io.previews`; each
frame shows its number. An LR input panel (h, w) is nearest-neighbour upscaled to the HR size (H, W).

Frames are streamed to an ffmpeg process (the binary bundled with imageio-ffmpeg) through a pipe, one at a time,
so memory stays bounded on long recordings. The file is written atomically (`jaxsr.io.files.atomic_path`): an
interrupted or failed video leaves nothing, and an existing file is replaced only with `overwrite=True`.
"""

from __future__ import annotations

import contextlib
import errno
import math
import shutil
import warnings
from pathlib import Path

import numpy as np

from .files import WriteError, atomic_path, check_new_file, refuse_link
from .previews import NO_RETURN_RGB, _colourise, _to_png, render

__all__ = ["VIDEO_FORMATS", "DepthVideoWriter", "write_depth_video", "check_video"]

VIDEO_FORMATS = (".mp4", ".gif")
DEFAULT_FPS = 25.0

_BACKGROUND = (1.0, 1.0, 1.0)
_FULL_BYTES = 2**20  # free space below which a failed write is the disk's being full
_MARGIN, _GAP, _TITLE, _BAR, _BAR_BAND = 8, 4, 20, 10, 34  # pixels
_FONT = 8  # points at 100 dpi
_DIGIT_W = 7  # pixels per character of the frame number (monospace)


def check_video(spec, *, force: bool, output=None) -> Path:
    """A video path (.mp4 or .gif): refuses another suffix, an existing file unless `force`, a folder, a missing
    folder or one this process cannot write into, a symbolic link, and the OUTPUT path itself. Writes nothing.
    Returns the path."""
    path = Path(spec)
    if path.suffix.lower() not in VIDEO_FORMATS:
        raise ValueError(f"{path}: the video is an {' or '.join(VIDEO_FORMATS)} file")
    if output is not None and path.resolve() == Path(output).resolve():
        raise ValueError(f"{path}: the video and OUTPUT are the same file")
    refuse_link(path, "the video")
    check_new_file(path, force=force, what="the video")
    return path


def _render(width, height, draw):
    """An RGB float image (height, width, 3) drawn by `draw(fig)` on the video's background."""
    return render(width, height, draw, facecolor=_BACKGROUND)


class DepthVideoWriter:
    """Write a side-by-side depth video frame by frame (a context manager; `write_depth_video` in one call).

    Args:
      path: .mp4 (H.264, yuv420p: plays in browsers and most players) or .gif (a palette per frame, loops).
      shape: (H, W) of an HR panel; an (h, w) panel of an integer downscale is nearest-neighbour upscaled.
      labels: one title per panel, e.g. ("input", "output", "reference").
      fps: frames per second of the video (default 25).
      d_min, d_max: metres at the two ends of the colour scale (the true range: gate start to start + span).
      frames: the number of frames, shown as "frame t / T" (None: "frame t").
      cmap: a matplotlib colour map name (default turbo). zoom: integer magnification of the panels (default:
        enough for legible labels on small frames). overwrite: replace an existing file.

    Use: `with DepthVideoWriter(path, (H, W), labels=...) as video: video.write(lr, sr, gt)`, one call per depth
    frame with one (H, W) or (h, w) frame in metres per panel (inf or NaN: no return). The file appears when the
    block ends without an exception. `frames_written` counts the frames.
    """

    def __init__(self, path, shape, *, labels, fps: float = DEFAULT_FPS, d_min: float = 0.0, d_max: float = 35.0,
                 frames: int | None = None, cmap: str = "turbo", zoom: int | None = None, overwrite: bool = False):
        self.path = Path(path)
        if self.path.suffix.lower() not in VIDEO_FORMATS:
            raise ValueError(f"{self.path}: the video is an {' or '.join(VIDEO_FORMATS)} file")
        fps = float(fps)
        if not (math.isfinite(fps) and fps > 0):
            raise ValueError(f"fps: expected frames per second > 0, got {fps}")
        d_min, d_max = float(d_min), float(d_max)
        if not (math.isfinite(d_min) and math.isfinite(d_max) and d_max > d_min):
            raise ValueError(f"the colour scale needs finite metres d_min < d_max, got {d_min}, {d_max}")
        self.shape = tuple(int(s) for s in shape)
        if len(self.shape) != 2 or min(self.shape) < 1:
            raise ValueError(f"shape: expected an (H, W) panel size, got {shape}")
        self.labels = tuple(str(s) for s in labels)
        if not self.labels:
            raise ValueError("labels: a video needs at least one panel")
        self.fps, self.d_min, self.d_max, self.cmap = fps, d_min, d_max, cmap
        self.total = None if frames is None else int(frames)
        self.overwrite = overwrite
        n = len(self.labels)
        h, w = self.shape
        self.zoom = int(zoom) if zoom is not None else max(1, min(8, math.ceil(96 / h), math.ceil(480 / (n * w))))
        if self.zoom < 1:
            raise ValueError(f"zoom: expected an integer >= 1, got {zoom}")
        ph, pw = h * self.zoom, w * self.zoom
        width = 2 * _MARGIN + n * pw + (n - 1) * _GAP
        height = _TITLE + ph + _BAR_BAND
        # H.264 in yuv420p wants even sides, and ffmpeg's writer 16-pixel blocks: pad with background
        self.size = (-(-width // 16) * 16, -(-height // 16) * 16)
        self._panel_xy = [(_MARGIN + i * (pw + _GAP), _TITLE) for i in range(n)]
        # the frame number, right-aligned above the last panel: "t/T", or up to 6 digits when T is unknown
        self._chars = 2 * len(str(self.total)) + 1 if self.total is not None else 6
        self._digits_x = width - _MARGIN - self._chars * _DIGIT_W
        self._chrome = self._draw_chrome(width, height)
        self._glyphs = None
        self._writer = None
        self._atomic = None
        self.frames_written = 0

    # -- the picture around the panels, drawn once

    def _draw_chrome(self, width, height):
        import matplotlib
        from matplotlib.patches import Rectangle
        from matplotlib.ticker import FuncFormatter, MaxNLocator

        W, H = self.size
        ph = self.shape[0] * self.zoom

        def draw(fig):
            for (x, y), label in zip(self._panel_xy, self.labels):
                fig.text((x + 1) / W, 1 - (y - 4) / H, label, fontsize=_FONT, ha="left", va="bottom")
            fig.text((self._digits_x - 3) / W, 1 - (_TITLE - 4) / H, "frame", fontsize=_FONT, ha="right",
                     va="bottom")
            legend_w = 80
            bar_x, bar_y = _MARGIN + 16, _TITLE + ph + 4  # room for the first tick's label
            bar_w = max(40, width - 2 * _MARGIN - 16 - legend_w)
            ax = fig.add_axes((bar_x / W, 1 - (bar_y + _BAR) / H, bar_w / W, _BAR / H))
            ax.imshow(np.linspace(0, 1, 256)[None], aspect="auto", cmap=matplotlib.colormaps[self.cmap],
                      extent=(self.d_min, self.d_max, 0, 1))
            ax.set_yticks([])
            ax.xaxis.set_major_locator(MaxNLocator(nbins=max(3, bar_w // 80)))
            ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g} m"))
            ax.tick_params(axis="x", labelsize=_FONT - 1, length=2, pad=1)
            sx = bar_x + bar_w + 10
            fig.patches.append(Rectangle((sx / W, 1 - (bar_y + _BAR) / H), _BAR / W, _BAR / H,
                                         transform=fig.transFigure, facecolor=NO_RETURN_RGB, edgecolor="0.5",
                                         linewidth=0.5))
            fig.text((sx + _BAR + 4) / W, 1 - (bar_y + _BAR / 2) / H, "no return", fontsize=_FONT - 1,
                     ha="left", va="center")

        return _render(W, H, draw)

    def _frame_text(self, text):
        """`text` (digits, '/', ' ') as an image, glyph by glyph (each drawn once, then reused)."""
        gw, gh = _DIGIT_W, _TITLE - 4
        if self._glyphs is None:
            self._glyphs = {}
            for ch in "0123456789/ ":
                self._glyphs[ch] = _render(gw, gh, lambda fig, ch=ch: fig.text(
                    0.5, 0.0, ch, fontsize=_FONT, family="DejaVu Sans Mono", ha="center", va="bottom"))
        return np.concatenate([self._glyphs[c] for c in text], axis=1)

    # -- writing

    def __enter__(self):
        import imageio_ffmpeg

        self._atomic = atomic_path(self.path, overwrite=self.overwrite)
        tmp = self._atomic.__enter__()
        try:
            if self.path.suffix.lower() == ".gif":
                # a palette per frame (streams: no pass over the whole video), looping forever
                params = dict(codec="gif", pix_fmt_out="pal8", quality=None, macro_block_size=1,
                              output_params=["-vf", "split[a][b];[a]palettegen=stats_mode=single[p];"
                                             "[b][p]paletteuse=new=1:dither=none", "-loop", "0", "-f", "gif"])
            else:
                params = dict(codec="libx264", pix_fmt_out="yuv420p", quality=6, macro_block_size=16,
                              output_params=["-movflags", "+faststart", "-f", "mp4"])
            self._writer = imageio_ffmpeg.write_frames(str(tmp), self.size, fps=self.fps, ffmpeg_log_level="quiet",
                                                       **params)
            with warnings.catch_warnings():  # fork + exec of ffmpeg at once: JAX's threads are never touched
                warnings.filterwarnings("ignore", message=r"os\.fork\(\) was called", category=RuntimeWarning)
                self._writer.send(None)
        except BaseException as e:
            self._atomic.__exit__(type(e), e, e.__traceback__)
            raise
        return self

    def finish(self) -> None:
        """Let ffmpeg finish the file (called by the end of the `with` block; call it earlier to know that the
        video is complete before other files are committed). Raises ValueError if no frame was written, OSError
        if ffmpeg failed."""
        writer, self._writer = self._writer, None
        if writer is not None:
            try:
                writer.close()  # ffmpeg finishes the file (and ends, on an error too)
            except (OSError, RuntimeError) as e:
                raise self._ffmpeg_failed(e) from None
            if self.frames_written == 0:
                raise ValueError(f"{self.path}: no frames to write")

    def _abandon(self) -> None:
        """Stop ffmpeg without finishing the file (its temporary is removed by the atomic block): no wait for it, and
        no word of its own (imageio-ffmpeg's "No frames have been written" would stand beside Ctrl-C's)."""
        writer, self._writer = self._writer, None
        if writer is not None:
            with contextlib.suppress(BaseException):
                writer.throw(KeyboardInterrupt)  # imageio-ffmpeg kills ffmpeg on an interrupt, and says nothing

    def _ffmpeg_failed(self, error) -> WriteError:
        """ffmpeg's failure (a closed pipe, its multi-line stderr naming the hidden temporary) as one `WriteError`
        naming the video: "no space left on device while writing v.gif" where the disk is full."""
        if shutil.disk_usage(self.path.parent).free < _FULL_BYTES:
            return WriteError(errno.ENOSPC, self.path, "no space left on device")
        first = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        return WriteError(errno.EIO, self.path, f"ffmpeg failed ({first[:200]})")

    def __exit__(self, exc_type, exc, tb):
        if exc_type is not None:  # the block failed or was interrupted: that is what to report, not the video
            self._abandon()
            return self._atomic.__exit__(exc_type, exc, tb)
        try:
            self.finish()
        except BaseException as e:
            if exc_type is None:
                exc_type, exc, tb = type(e), e, e.__traceback__
            self._atomic.__exit__(exc_type, exc, tb)
            raise
        return self._atomic.__exit__(exc_type, exc, tb)

    def frame(self, *panels) -> np.ndarray:
        """The (height, width, 3) uint8 video frame of one depth frame: one (H, W) or (h, w) array in metres per
        panel."""
        if len(panels) != len(self.labels):
            raise ValueError(f"{self.path}: {len(panels)} panels given, the video has {len(self.labels)} "
                             f"({', '.join(self.labels)})")
        canvas = self._chrome.copy()
        H, W = self.shape
        for (x, y), panel in zip(self._panel_xy, panels):
            d = np.asarray(panel, np.float32)
            if d.ndim != 2 or H % d.shape[0] or W % d.shape[1]:
                raise ValueError(f"{self.path}: a panel of shape {d.shape} is no integer downscale of {self.shape}")
            z = self.zoom
            rgb = _colourise(d, self.d_min, self.d_max, self.cmap)
            rgb = np.repeat(np.repeat(rgb, H // d.shape[0] * z, 0), W // d.shape[1] * z, 1)
            canvas[y : y + rgb.shape[0], x : x + rgb.shape[1]] = rgb
        t = self.frames_written + 1
        text = f"{t}/{self.total}" if self.total is not None else f"{t}"
        label = self._frame_text(f"{text[-self._chars:]:>{self._chars}}")
        x0 = self._digits_x
        canvas[2 : 2 + label.shape[0], x0 : x0 + label.shape[1]] = label
        return _to_png(canvas)

    def write(self, *panels) -> None:
        """Append one video frame: one depth frame per panel, in metres (see `frame`)."""
        if self._writer is None:
            raise RuntimeError("DepthVideoWriter.write outside its `with` block")
        try:
            self._writer.send(np.ascontiguousarray(self.frame(*panels)))
        except (OSError, RuntimeError) as e:  # ffmpeg ended: a full disk, most often
            writer, self._writer = self._writer, None
            with contextlib.suppress(OSError, RuntimeError):
                writer.close()
            raise self._ffmpeg_failed(e) from None
        self.frames_written += 1


def write_depth_video(path, lr, sr, gt=None, *, fps: float = DEFAULT_FPS, d_min: float = 0.0, d_max: float = 35.0,
                      labels=("input", "output", "reference"), frames: int | None = None, cmap: str = "turbo",
                      zoom: int | None = None, overwrite: bool = False) -> int:
    """Write an input | output (| reference) depth video, one video frame per depth frame (see `DepthVideoWriter`).

    Args:
      path: .mp4 or .gif.
      lr: (T, h, w) input frames in metres, or any iterable of (h, w) frames (nearest-neighbour upscaled).
      sr: (T, H, W) output frames in metres, or an iterable of them.
      gt: (T, H, W) reference frames in metres, an iterable of them, or None (two panels).
      labels: one title per panel (the first two without `gt`).
      frames: T, shown on each frame (default len(sr) where it has one).

    fps, d_min, d_max, cmap, zoom and overwrite are `DepthVideoWriter`'s.

    Returns the number of frames written. Frames are read from the iterables one at a time (memory for a frame).
    Raises ValueError if the streams differ in length.
    """
    streams = [lr, sr] if gt is None else [lr, sr, gt]
    labels = tuple(labels)[: len(streams)]
    if frames is None and hasattr(sr, "__len__"):
        frames = len(sr)
    iters = [iter(s) for s in streams]
    first = [next(it, None) for it in iters]
    if any(f is None for f in first):
        raise ValueError(f"{path}: no frames to write")
    shape = np.shape(first[1])
    done = object()
    with DepthVideoWriter(path, shape, labels=labels, fps=fps, d_min=d_min, d_max=d_max, frames=frames, cmap=cmap,
                          zoom=zoom, overwrite=overwrite) as video:
        video.write(*first)
        while True:
            nxt = [next(it, done) for it in iters]
            if all(f is done for f in nxt):
                break
            if any(f is done for f in nxt):
                raise ValueError(f"{path}: the input, output and reference streams differ in length")
            video.write(*nxt)
    return video.frames_written
