"""Real photons with a reference: real single-photon recordings (two in ../shared/realdata, one more held out)
made into low-resolution
photon videos at 1-16 photons per LR pixel and frame, upscaled x4 by bicubic, TV, the bundled TR0 and TR4 (and
any `--model`), and scored against the depth of all the recording's photons at full resolution.

    python experiments/studies/real_photons.py                              # the benchmark (~2 min on 2 cores)
    python experiments/studies/real_photons.py --model TR0-photons=tr0-photons --model TR4-photons=tr4-photons
    python experiments/studies/real_photons.py --levels 2 --frames 3 --tv-frames 1   # a quick look
    python experiments/studies/real_photons.py --model TR4-photons+2=tr4-photons --no-return-logit TR4-photons+2=2
    python experiments/studies/real_photons.py --model K=tr4-photons --no-return-logit K=2 --keep-returns K=0.001

Data (`--data`, one or more folders, default ../shared/realdata beside the repository; never copied into the project;
each recording read from the first folder that holds it, those no folder holds skipped with a line:
docs/own-sensor.md, "Real recordings", says where each file comes from): tower.mat (160 x 160 pixels, photon
arrival times in ps, gate mm..MM = 200 ns, 3.7 photons per pixel) and two_layer.mat (100 x 100, arrival times in
the system's time bins of unknown width, 51 photons per pixel), read with `jaxsr.read_time_tags`; held out
(`experiments/studies/heldout.py prepare` copies it from its repository, _heldout_data.REAL): face.mat (340 x 340, a
mannequin face raster-scanned, time bins of unknown width, 8.3 photons per pixel). Considered and left out: the
K11 building 21 km away (Li et al., 21km_K11_night.mat): with 1.24 signal photons per pixel its all-photon
reference is only about 17.5 dB from itself (two halves of its photons, `reference_noise`), too noisy to score
against.

The photon video: the photons of each 4 x 4 block of pixels make one LR pixel (160 x 160 -> 40 x 40, 100 x 100
-> 25 x 25). A seeded random permutation of all the recording's photons is cut into consecutive runs of
L x (LR pixels) photons, one run per frame (`split_photons`): the frames are disjoint (each photon in one frame
at most), every frame holds a mean of exactly L photons per LR pixel, and each is what an acquisition L / (the
recording's photons per LR pixel) as long would have caught (thinning a Poisson process leaves a Poisson
process), so bright pixels get more photons than dark ones, as in a real shorter exposure. Up to `--frames` (9 =
TR4's window) frames per level, fewer where the photons run out (tower: 59 per LR pixel, so 7 frames at 8
photons and 3 at 16); TR4's windows are edge-replicated at the ends (`jaxsr.super_resolve`). Each frame's LR
pixels are histogrammed into 16 bins over the recording's gate and read by the centre of mass
(`jaxsr.histogram_time_tags`, `jaxsr.sensor.gate_depth`, as experiments/paper/real_data.py does), then put on the
network's scale (`jaxsr.sensor.to_network_depth`): tower, 0 at the gate start and 1.0 = 35 m further, the
trained span; two_layer, the gate filled onto [0, 1] (its time unit is unknown, so its depth is relative).

The reference: the depth of each full-resolution pixel from ALL the recording's photons (its histogram over the
same gate, centre of mass), kept where the peak is significant (`gate_depth` with z = REF_Z: peak bin >=
median + 3 sqrt(max(median, 1)), i.e. >= 3 photons in one bin on a dark background), the pixel holds at least
REF_MIN_PHOTONS photons and no second return rivals the peak (`competing_return`: two_layer's pixels that see
both surfaces about equally, whose centre of mass jumps between them from one draw of photons to the next); other
pixels are excluded from every score. Its own noise is measured by splitting the photons into two random halves
and comparing the two halves' depths (`reference_noise`).

Scores per recording, level and method, on the reference's valid pixels and averaged over the frames: PSNR
(normalised depth, output clipped to [0, 1], peak 1, `jaxsr.psnr` on the valid pixels), MAE (metres for tower,
bins of the gate for both) with a no-return output counted at its distance, and the share of valid pixels the
method outputs as no return (normalised >= _photon_benchmark.NO_RETURN_AT); and the other side of that decision,
the share of the pixels where all the photons hold no return (`reference_sky`: tower's sky) that the method
outputs as depth. The goal: TR4 >= bicubic + 3 dB at
every level (paired over frames; frames are disjoint photon sets, so the interval resamples them one by one).

Writes experiments/results/real_photons.md (or --out), a .json of the raw numbers and a .png (reference | LR |
each method at `--picture-level` photons, one row per recording) beside it.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import jax
import numpy as np

import jaxsr
from jaxsr.inference import filled_where_holes, iter_network_inputs, iter_super_resolve, lr_blocks, no_return_where
from jaxsr.inference.confidence import (EVIDENCE_FRAMES, coefficients_for, confidence_frame, iter_count_windows,
                                        no_return_by_probability)
from jaxsr.app import DEPTH_ENSEMBLE, Reading, photon_levels
from jaxsr.app.job import ensemble_depth
from jaxsr.app.recordings import gate_frames
from jaxsr.sensor import black_hole_pixels
from jaxsr.sensor.timetags import TimeTags
from _photon_benchmark import (NO_RETURN_AT, TV_TR, decision_of, load_models, no_return_decision,  # studies/
                               returns_kept)

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # experiments/: the shared harness
from harness.reports import hand_written_tail, header, markdown_table, save_figure, write_atomic  # noqa: E402
from harness.scoring import format_interval  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
DEFAULT_DATA = ROOT.parent / "shared" / "realdata"
RESULTS = ROOT / "experiments" / "results"
FACTOR = 4  # HR pixels per LR pixel along each axis (the models' x4)
BINS = 16  # histogram bins over the gate, as the trained sensor
LEVELS = (1.0, 2.0, 4.0, 8.0, 16.0)  # photons per LR pixel and frame (mean over the frame's LR pixels)
MAX_FRAMES = 9  # frames per level at most: TR4's window of 2 x 4 + 1
REF_Z = 3.0  # the reference's peak significance (`centre_of_mass`'s z)
REF_MIN_PHOTONS = 3  # photons a reference pixel needs at least
REF_SKY_ALPHA = 1e-3  # false-alarm rate of the all-photon test that finds no return (`reference_sky`)
REF_SKY_SHARE = 0.1  # ... and the most photons a no-return block may hold, as a share of a typical return's
REF_EDGE_SKY_PHOTONS = 1  # the most of all the photons a 3 x 3 full-resolution patch of sky beside a surface holds
GOAL_DB = 3.0  # TR4 - bicubic at every level, at least
PICTURE_LEVEL = 2.0
# The results file's commentary is written by hand after a run; a re-run regenerates everything above it.
HAND_WRITTEN = "## Reading"


@dataclasses.dataclass(frozen=True)
class Source:
    """A recording to read: its file, cell array, time unit in seconds (a nominal 1 ps where unknown), depth span
    of the network's [0, 1] (None: the trained 35 m; "gate": the gate's length) and whether its metres mean
    anything (False where the time unit is unknown)."""

    name: str
    file: str
    variable: str
    time_unit_s: float
    span: float | str | None
    metric: bool


SOURCES = (
    Source("tower", "tower.mat", "data_processed", 1e-12, None, True),
    # the system's time bins, width not given by the source: a nominal 1 ps, the depth relative to the gate
    Source("two_layer", "two_layer.mat", "photon_times", 1e-12, "gate", False),
    # held out (experiments/studies/_heldout_data.py, REAL): a raster-scanned mannequin face in the system's time
    # bins (width not given)
    Source("face", "face.mat", "Ts", 1e-12, "gate", False),
)


@dataclasses.dataclass(frozen=True)
class Recording:
    """One recording's photons at full resolution (one frame), the gate they are histogrammed over (16 bins over
    the arrival times of all its photons) and the network's depth scale."""

    source: Source
    tags: TimeTags
    gate: jaxsr.Gate
    scale: jaxsr.DepthScale

    @property
    def name(self) -> str:
        return self.source.name


@dataclasses.dataclass(frozen=True)
class PhotonFrames:
    """Histogrammed frames: counts (T, h, w, K), their centre-of-mass network depth (T, h, w) (1.0 = no return)
    and the gate and scale they were made with."""

    counts: np.ndarray
    depth: np.ndarray
    gate: jaxsr.Gate
    scale: jaxsr.DepthScale


# ------------------------------------------------------------------------------------------------ photons

def found_sources(folders, sources=SOURCES) -> list:
    """[(source, the first of `folders` holding its file, or None)] for each of `sources`."""
    return [(s, next((Path(f) for f in folders if (Path(f) / s.file).is_file()), None)) for s in sources]


def crop_tags(tags: TimeTags, y0: int, x0: int, h: int, w: int) -> TimeTags:
    """The photons of pixels [y0, y0 + h) x [x0, x0 + w), on a grid of that size."""
    y, x = np.divmod(tags.pixel, tags.shape[1])
    keep = (y >= y0) & (y < y0 + h) & (x >= x0) & (x < x0 + w)
    return dataclasses.replace(tags, pixel=(y[keep] - y0) * w + x[keep] - x0, frame=tags.frame[keep],
                               time=tags.time[keep], shape=(h, w))


def read_recording(data, source: Source, *, crop=None) -> Recording:
    """A recording from the folder `data`; crop: (y0, x0, size) in full-resolution pixels, or None. The gate
    covers the arrival times of all the file's photons (`jaxsr.sensor.gate_of_tags`), crop or not: for tower that
    is its mm..MM (5.18-5.38 us, 776.5-806.4 m), for two_layer its bins 3000-7000."""
    tags = jaxsr.read_time_tags(Path(data) / source.file, variable=source.variable, time_unit_s=source.time_unit_s)
    gate = jaxsr.sensor.gate_of_tags(tags, bins=BINS)
    if crop is not None:
        y0, x0, size = crop
        tags = crop_tags(tags, y0, x0, size, size)
    h, w = tags.shape
    if h % FACTOR or w % FACTOR:
        raise ValueError(f"{source.name}: {h} x {w} pixels do not split into {FACTOR} x {FACTOR} blocks")
    scale = jaxsr.DepthScale.for_gate(gate, gate.length if source.span == "gate" else source.span)
    return Recording(source, tags, gate, scale)


def bin_pixels(tags: TimeTags, factor: int = FACTOR) -> TimeTags:
    """The photons of each factor x factor block of pixels as one LR pixel: (h, w) -> (h / factor, w / factor)."""
    h, w = tags.shape
    y, x = np.divmod(tags.pixel, w)
    lw = w // factor
    return dataclasses.replace(tags, pixel=(y // factor) * lw + x // factor, shape=(h // factor, lw))


def split_photons(n_photons: int, per_frame: int, *, max_frames: int, seed) -> np.ndarray:
    """Each photon's frame (-1: in none): a seeded random permutation of the n photons cut into consecutive runs
    of `per_frame`, as many runs as there are photons for, `max_frames` at most. The frames are disjoint and each
    holds exactly `per_frame` photons, a uniform random share of the whole: thinning."""
    if per_frame < 1 or max_frames < 0:
        raise ValueError(f"split_photons: per_frame must be >= 1 and max_frames >= 0, got {per_frame}, {max_frames}")
    frames = min(max_frames, n_photons // per_frame)
    label = np.full(n_photons, -1, np.int64)
    order = np.random.default_rng(seed).permutation(n_photons)
    label[order[:frames * per_frame]] = np.repeat(np.arange(frames), per_frame)
    return label


def photon_video(lr: TimeTags, level: float, *, max_frames: int = MAX_FRAMES, seed=0) -> TimeTags | None:
    """LR photons (one frame, `bin_pixels`) -> frames of `level` photons per LR pixel on average (`split_photons`);
    None where the recording has fewer than one frame's photons."""
    h, w = lr.shape
    per_frame = max(1, round(level * h * w))
    label = split_photons(lr.time.size, per_frame, max_frames=max_frames, seed=seed)
    keep = label >= 0
    if not keep.any():
        return None
    return dataclasses.replace(lr, pixel=lr.pixel[keep], frame=label[keep], time=lr.time[keep],
                               frames=int(label.max()) + 1)


def histogram_frames(tags: TimeTags, gate, scale, *, z: float = 0.0) -> tuple[PhotonFrames, np.ndarray]:
    """Histograms over `gate` and their centre-of-mass network depth (as experiments/paper/real_data.py's
    `tags_depth`); z: the centre of mass's peak significance. Returns (frames, valid (T, h, w))."""
    counts = jaxsr.histogram_time_tags(tags, gate)
    depth, valid = _network_depth(counts, gate, scale, z)
    return PhotonFrames(counts, np.asarray(depth, np.float32), gate, scale), np.asarray(valid)


@jax.jit
def _network_depth(counts, gate, scale, z):
    """Centre-of-mass network depth of histograms over `gate` and its validity (compiled once per shape)."""
    metres, valid = jaxsr.sensor.gate_depth(counts, gate, z=z, return_mask=True)
    return jaxsr.sensor.to_network_depth(metres, scale), valid


def confidence_decided(model, frames: PhotonFrames, guard: float | tuple | None = None) -> np.ndarray:
    """A model with a no-return head on the frames, no return where the confidence's P(return) (its logit and each
    pixel's photons over 9 frames, `jaxsr.inference.confidence`) is below one half and, with a `guard` rate, the
    LR pixel's own photons over 9 frames, and those of the quiet pixels pooled around it (`QUIET_POOLS`), pass for
    ambient light alone at it, outside the holes that returns enclose (`jaxsr upscale`'s default: 0.001, `iter_quiet`);
    ("pooled-sky", rate): and the pixels beside the sky left to P(return) (`jaxsr.sensor.beside_sky`)."""
    raw = np.stack(list(iter_super_resolve(model, iter(model_input(model, frames)), raw=True)))
    coeffs = coefficients_for(None, True)
    sensor = jaxsr.Sensor(gate=jaxsr.Gate.spanning(35.0, frames.gate.bins))
    per_unit = float(frames.scale.span) / float(frames.gate.bin_width)
    out = []
    for r, window in zip(raw, iter_count_windows(iter(np.asarray(frames.counts)), EVIDENCE_FRAMES)):
        p, _ = confidence_frame(window, r[..., 0], coeffs, sensor, head_logit=r[..., 1], bins_per_unit=per_unit)
        out.append(no_return_by_probability(r[..., 0], p, model.config.no_return_logit))
    out = np.stack(out)
    if guard is not None:
        quiet = no_return_decision(frames.counts, sensor, guard if isinstance(guard, tuple) else ("pooled", guard))
        out = np.where(lr_blocks(np.asarray(quiet), FACTOR), out, raw[..., 0])
    return out


def with_ensemble(output: np.ndarray, frames: PhotonFrames, levels, apply: bool = True) -> np.ndarray:
    """`output` with its returns' depth averaged with the paper's TR4's where the frames' photon levels (`levels`,
    `photon_levels` of their first frames) reach `DEPTH_ENSEMBLE`'s, as `jaxsr upscale`'s default gives them; else
    (or not `apply`) itself."""
    if not (apply and DEPTH_ENSEMBLE.applies(levels.signal, levels.snr)):
        return output
    model = jaxsr.load_model(DEPTH_ENSEMBLE.model)
    other = np.asarray(jaxsr.super_resolve(model, model_input(model, frames), form="model"))
    return np.stack([ensemble_depth(o, d) for o, d in zip(output, other)])


def with_holes_filled(output: np.ndarray, frames: PhotonFrames, guard: float | tuple | None) -> np.ndarray:
    """`output` with the black holes (`jaxsr.sensor.black_hole_pixels` at the `guard`'s rate: quiet regions that
    returns enclose, or lone quiet pixels, whose photons fall short of the ambient light around them) filled from
    the depth around them (`jaxsr.inference.fill_holes`), as `jaxsr upscale`'s default decision ends; itself
    without a guard."""
    if guard is None:
        return output
    alpha = guard[1] if isinstance(guard, tuple) else guard
    sensor = jaxsr.Sensor(gate=jaxsr.Gate.spanning(35.0, frames.gate.bins))
    holes = np.asarray(black_hole_pixels(frames.counts, sensor, alpha=alpha))
    return np.stack([filled_where_holes(o, f, frames.scale) for o, f in zip(output, holes)])


def upscaled(frames: PhotonFrames, model: str = "default") -> np.ndarray:
    """What a user gets: `jaxsr.upscale` of the frames' histograms with their gate given, `model` (a bundled name;
    default the library's choice) and every other option the library's default (the depth span it fits, the
    no-return decision, and for the default model the ensemble and the holes), in metres, put on the frames'
    normalised scale (no return: 1.0) to be scored as the other methods are."""
    g = frames.gate
    read = Reading(kind="histograms", bins=g.bins, bin_width=float(g.bin_width), gate_start=float(g.start), units="m")
    metres = np.asarray(jaxsr.upscale(np.asarray(frames.counts), None, model=model, read=read).depth)
    normalised = (metres - float(frames.scale.offset)) / float(frames.scale.span)
    return np.where(np.isfinite(metres), normalised, 1.0).astype(np.float32)


def confidence_settings(given, beside_sky=()) -> dict:
    """{NAME: guard} of --confidence NAME[=ALPHA] values: None without ALPHA, the rate, or ("pooled-sky", rate) for
    a NAME of --beside-sky (which needs a rate)."""
    settings = {n: (float(a) if a else None) for n, _, a in (c.partition("=") for c in given)}
    for name in beside_sky:
        if settings.get(name) is None:
            raise SystemExit(f"--beside-sky {name}: give --confidence {name}=ALPHA first (the guard it widens)")
        settings[name] = ("pooled-sky", settings[name])
    return settings


def model_input(model, frames: PhotonFrames) -> np.ndarray:
    """What `model` reads, built from the frames: the centre-of-mass depth (T, h, w) for a depth-only network;
    for one reading photons too, (T, h, w, C) channels of `jaxsr.nn.network_inputs` over the same gate, the
    depth converted to the network's scale as `jaxsr upscale` converts it."""
    inputs = tuple(getattr(model.config, "inputs", ("depth",)))
    if inputs == ("depth",):
        return frames.depth
    channels = iter_network_inputs(frames.counts, jaxsr.Sensor(gate=jaxsr.Gate.spanning(35.0, frames.gate.bins)), inputs)
    return np.stack(list(gate_frames(channels, frames.gate, frames.scale)))


# ------------------------------------------------------------------------------------------------ the reference

def competing_return(counts, *, z: float = REF_Z, window: int = 1) -> np.ndarray:
    """(...) True where a histogram (..., K) holds a second return that rivals its peak: the highest bin n2
    outside the peak's +-window bins (the centre of mass's window) is itself significant over the median
    background b (n2 >= b + z sqrt(max(b, 1)), as `centre_of_mass` tests the peak) and the peak n1 does not beat
    it by z Poisson standard deviations (n1 - n2 < z sqrt(n1 + n2)). Which of two such returns is the highest
    flips from one draw of photons to the next (two_layer's two surfaces), so their depth is no reference."""
    counts = np.asarray(counts, np.float64)
    k = np.arange(counts.shape[-1])
    n1 = counts.max(-1)
    n2 = np.where(np.abs(k - counts.argmax(-1)[..., None]) > window, counts, 0.0).max(-1)
    b = np.median(counts, -1)
    return (n2 >= b + z * np.sqrt(np.maximum(b, 1.0))) & (n1 - n2 < z * np.sqrt(n1 + n2))


def reference_depth(rec: Recording) -> tuple[np.ndarray, np.ndarray]:
    """(depth (H, W) network depth of all the photons, valid (H, W)): the centre of mass with peak significance
    REF_Z, at least REF_MIN_PHOTONS photons in the pixel and no competing second return (`competing_return`)."""
    frames, valid = histogram_frames(rec.tags, rec.gate, rec.scale, z=REF_Z)
    counts = frames.counts[0]
    return frames.depth[0], valid[0] & (counts.sum(-1) >= REF_MIN_PHOTONS) & ~competing_return(counts)


def lr_all_photons(rec: Recording) -> tuple[np.ndarray, np.ndarray]:
    """(counts (h, w, K), log p (h, w)): each LR block's histogram of all the recording's photons and its
    `jaxsr.sensor.return_significance`."""
    frames, _ = histogram_frames(bin_pixels(rec.tags), rec.gate, rec.scale)
    counts = np.asarray(frames.counts, np.float32).sum(0)
    return counts, np.asarray(jaxsr.sensor.return_significance(counts, jaxsr.Sensor(gate=jaxsr.Gate.spanning(35.0, BINS))))


def reference_sky(all_photons) -> np.ndarray:
    """(H, W) True where all the recording's photons (`lr_all_photons`) show no return: the pixel's LR block (the photon video's
    4 x 4) and its 8 neighbours hold no significant return (log p above log REF_SKY_ALPHA: ambient light alone
    explains them) and at most REF_SKY_SHARE of the photons of the median block that holds one, so that a return
    a tenth as bright as the scene's typical one would have been seen. A surface darker than that counts as sky
    too: the photons cannot tell them apart. The neighbours keep mixed blocks at a surface's edge out."""
    from scipy import ndimage

    counts, log_p = all_photons
    photons, found = counts.sum(-1), log_p <= np.log(REF_SKY_ALPHA)
    typical = float(np.median(photons[found])) if found.any() else np.inf
    empty = ~found & (photons <= REF_SKY_SHARE * typical)
    return lr_blocks(ndimage.minimum_filter(empty.astype(np.uint8), size=3, mode="nearest"), FACTOR)


def edge_sky(photons, sky) -> np.ndarray:
    """(H, W) True for the sky beside the surfaces that `reference_sky` (`sky`), one decision per LR block and
    its neighbours, leaves out: pixels outside `sky` whose 3 x 3 neighbourhood holds at most REF_EDGE_SKY_PHOTONS
    of all the recording's photons (`photons`, (H, W) per full-resolution pixel; none beyond the frame). Where the
    surfaces hold many photons per pixel and the sky hardly any (tower: 17 per valid pixel, 0.2 per pixel of
    `sky`), nine pixels of a surface are all but never that empty and 44 % of the sky's pixels are: a sample of the
    sky in the LR blocks that a surface's edge crosses, where a decision made per block shows it as depth and PSNR
    on the valid pixels does not count it. A surface darker than that counts as sky, as in `reference_sky`."""
    from scipy import ndimage

    near = ndimage.convolve(np.asarray(photons, np.int64), np.ones((3, 3), np.int64), mode="constant")  # 3 x 3 sums
    return (near <= REF_EDGE_SKY_PHOTONS) & ~np.asarray(sky, bool)


@dataclasses.dataclass(frozen=True)
class References:
    """What a recording's methods are scored against: `depth` and `valid` (`reference_depth`), `sky`
    (`reference_sky`, less the valid pixels), `edge` (`empty_edges`), `near` (`near_gaps`), `beside` (`edge_sky`),
    `photons` (H, W) of all the recording's photons per pixel and `all_photons` (`lr_all_photons`)."""

    depth: np.ndarray
    valid: np.ndarray
    sky: np.ndarray
    edge: np.ndarray
    near: np.ndarray
    beside: np.ndarray
    photons: np.ndarray
    all_photons: tuple

    def sky_beside_text(self) -> str:
        """How `edge_sky` reads on this recording: photons per valid and per sky pixel, and the share of the
        block-level sky that passes the same test (the sample it takes of the sky)."""
        as_beside = edge_sky(self.photons, np.zeros_like(self.sky))
        if not self.sky.any():
            return f"{self.photons[self.valid].mean():.1f} photons per valid pixel, no block-level sky"
        return (f"{self.photons[self.valid].mean():.1f} photons per valid pixel, {self.photons[self.sky].mean():.2f} "
                f"per pixel of the block-level sky, of which {as_beside[self.sky].mean():.0%} passes the same test")


def references(rec: Recording) -> References:
    """The `References` of a recording (all its photons read once)."""
    depth, valid = reference_depth(rec)
    all_photons = lr_all_photons(rec)  # once: the sky, the edges and the SNR read it
    sky = reference_sky(all_photons) & ~valid
    photons = np.bincount(rec.tags.pixel, minlength=valid.size).reshape(valid.shape)
    return References(depth, valid, sky, empty_edges(all_photons), near_gaps(valid), edge_sky(photons, sky), photons,
                      all_photons)


def recording_snr(all_photons) -> float:
    """The recording's frame SNR from all its photons in LR blocks (`lr_all_photons`; `jaxsr.sensor.frame_snr`:
    signal / ambient photons over the blocks with a return; a second surface in a block counts as ambient, so
    two_layer reads low)."""
    return jaxsr.sensor.frame_snr(all_photons[0], jaxsr.Sensor(gate=jaxsr.Gate.spanning(35.0, BINS)))


def reference_noise(rec: Recording, valid, *, seed=0) -> dict:
    """The reference's own noise: the photons split into two random halves, each half's depth (centre of mass,
    any peak), compared on the reference's valid pixels where both halves give a return.

    The two halves' errors are independent, so their difference has twice a half's error variance; with the
    variance going as 1 / photons, the all-photon reference has half a half's: its RMS error is about the
    halves' RMS difference / 2, i.e. its PSNR about the halves' PSNR + 6.0 dB (and its MAE about theirs / 2)."""
    label = split_photons(rec.tags.time.size, rec.tags.time.size // 2, max_frames=2, seed=seed)
    keep = label >= 0
    tags = dataclasses.replace(rec.tags, pixel=rec.tags.pixel[keep], frame=label[keep], time=rec.tags.time[keep],
                               frames=2)
    frames, ok = histogram_frames(tags, rec.gate, rec.scale)
    both = valid & ok[0] & ok[1]
    diff = (frames.depth[0] - frames.depth[1])[both]
    mse = float(np.mean(diff ** 2)) if diff.size else float("nan")
    mae = float(np.mean(np.abs(diff))) if diff.size else float("nan")
    psnr = -10.0 * np.log10(max(mse, 1e-12))
    return {"pixels": int(valid.sum()), "both_return": float(both.sum() / max(valid.sum(), 1)),
            "psnr_halves": psnr, "mae_halves": mae, "rmse_halves": float(np.sqrt(mse)),
            "psnr_reference": psnr + 20 * np.log10(2.0), "mae_reference": mae / 2, "rmse_reference": np.sqrt(mse) / 2,
            "exact_share": float(np.mean(diff == 0)) if diff.size else float("nan")}


# ------------------------------------------------------------------------------------------------ methods, scores

def tv_frames_of(total: int, n: int | None) -> np.ndarray:
    """The frames TV runs on: n of `total` spread evenly (first included), all for None."""
    if n is None or n >= total:
        return np.arange(total)
    return np.unique(np.linspace(0, total - 1, max(n, 1)).round().astype(int))


def tv_output(lr, frames) -> np.ndarray:
    """TV (`jaxsr.tv_super_resolve`, tr TV_TR, defaults) on `frames` of lr, each with its edge-replicated window."""
    out = []
    for t in frames:
        window = lr[np.clip(t + np.arange(-TV_TR, TV_TR + 1), 0, len(lr) - 1)]
        out.append(np.asarray(jaxsr.tv_super_resolve(window, scale=FACTOR, tr=TV_TR))[TV_TR])
    return np.stack(out)


def masked_scores(sr, ref, valid, sky=None, edge=None, near=None, sky_beside=None) -> dict:
    """Per-frame scores of sr (T, H, W) against the reference on its valid pixels: psnr (dB, `jaxsr.psnr` of
    the valid pixels, output clipped to [0, 1]), mae (normalised; x scale.span for metres, x span / bin width for
    bins), no_return (share of valid pixels output as no return), and of those dropped, the share at an edge
    (`edge`, `empty_edges`: next to an LR block without a return; NaN where none is dropped); on the
    reference's no-return pixels (`sky`, `reference_sky`), sky_as_depth (share output as depth; NaN without such
    pixels), and the same on the sky beside the surfaces (`sky_beside`, `edge_sky`): edge_sky_as_depth; and
    psnr_near / psnr_away, the PSNR of the valid pixels in `near` (`near_gaps`) and of the others (NaN where there
    are none). Each (T,)."""
    out = np.clip(np.asarray(sr, np.float32), 0, 1)
    pred = out[:, valid]  # (T, n)
    gt = np.broadcast_to(ref[valid], pred.shape)
    psnr = np.asarray(jaxsr.psnr(pred[:, None, :], gt[:, None, :]))
    nan = np.full(len(out), np.nan)

    def psnr_of(where):  # of the valid pixels `where` selects; NaN where it selects none
        return np.asarray(jaxsr.psnr(pred[:, None, where], gt[:, None, where])) if where.any() else nan

    near_v = np.zeros(pred.shape[1], bool) if near is None else near[valid]

    def as_depth(where):  # share of the pixels `where` selects output as depth; NaN where it selects none
        return (out[:, where] < NO_RETURN_AT).mean(-1) if where is not None and where.any() else nan

    dropped = pred >= NO_RETURN_AT
    at_edge = nan
    if edge is not None:
        with np.errstate(invalid="ignore", divide="ignore"):
            at_edge = (dropped & edge[valid]).sum(-1) / dropped.sum(-1)
    return {"psnr": psnr, "mae": np.abs(pred - gt).mean(-1), "no_return": dropped.mean(-1),
            "dropped_at_edge": at_edge, "sky_as_depth": as_depth(sky), "edge_sky_as_depth": as_depth(sky_beside),
            "psnr_near": psnr_of(near_v),
            "psnr_away": psnr_of(~near_v) if near is not None else nan}


def near_gaps(valid) -> np.ndarray:
    """(H, W) True for valid pixels whose LR block or one of its 8 neighbours holds a pixel without a reference
    depth (sky, two rival returns, too few photons): where the LR photons mix what the reference scores with what
    it cannot, so that an output must place an edge inside a block (two_layer's two surfaces meet there)."""
    from scipy import ndimage

    h, w = valid.shape[0] // FACTOR, valid.shape[1] // FACTOR
    gap = (~valid).reshape(h, FACTOR, w, FACTOR).any(axis=(1, 3))
    return lr_blocks(ndimage.maximum_filter(gap.astype(np.uint8), size=3, mode="nearest"), FACTOR) & valid


def empty_edges(all_photons) -> np.ndarray:
    """(H, W) True for pixels whose LR block or one of its 8 neighbours holds no significant return in all the
    recording's photons (`lr_all_photons`): the surfaces' edges against sky or nothing."""
    from scipy import ndimage

    log_p = all_photons[1]
    return lr_blocks(ndimage.maximum_filter((log_p > np.log(REF_SKY_ALPHA)).astype(np.uint8), size=3,
                                     mode="nearest"), FACTOR)


def evaluate(recordings, models: dict, *, levels=LEVELS, max_frames: int = MAX_FRAMES, tv_frames: int | None = None,
             tv: bool = True, seed: int = 0, picture_level: float = PICTURE_LEVEL, ambient=None, confidence=None,
             ensemble=(), upscale=None, log=print) -> dict:
    """Score nearest, bicubic, TV and `models` ({label: Model}) on each recording's photon video at every level
    against its all-photon reference. tv_frames: frames per level TV runs on (None: all). ambient: {label:
    alpha} for models whose output is also no return where `jaxsr.sensor.ambient_only` flags a pixel of the
    photon video at that false-alarm rate (as `jaxsr upscale --ambient-alpha`), {label: ("shares", alpha)}
    where `jaxsr.sensor.no_return_shares` say so, or {label: ("keep", alpha)} for `_photon_benchmark.returns_kept`;
    confidence: {label: guard} for models with a no-return head whose no return is where the confidence's P(return)
    is below one half (`confidence_decided`; guard: None, or the photons' test's rate, as `jaxsr upscale` decides by
    default at 0.001, the black holes then filled from around them: `with_holes_filled`); ensemble: labels whose
    returns' depth is averaged with the paper's TR4's where the frames' photon levels reach
    `jaxsr.app.DEPTH_ENSEMBLE`'s (`with_ensemble`, as `jaxsr upscale`'s default); upscale:
    {label: model} of methods that are `jaxsr.upscale` itself with that model ("default": the library's choice)
    and the library's defaults (`upscaled`). Returns
    {name: {"reference", "noise", "levels": [{"level", "frames", "photons_ref", "scores": {method: {psnr, mae,
    no_return: (T,)}}, "tv_frames"}], "picture": {panel: (H, W)}}}."""
    results = {}
    for i, rec in enumerate(recordings):
        started = time.time()
        refs = references(rec)
        ref, valid, sky, edge, near, sky_beside = refs.depth, refs.valid, refs.sky, refs.edge, refs.near, refs.beside
        noise = reference_noise(rec, valid, seed=seed)
        lr_tags = bin_pixels(rec.tags)
        h, w = lr_tags.shape
        # LR pixels whose block holds a valid reference pixel: where the scores are taken
        covered = valid.reshape(h, FACTOR, w, FACTOR).any(axis=(1, 3))
        out = {"reference": ref, "valid": valid, "sky": sky, "sky_beside": sky_beside,
               "sky_beside_text": refs.sky_beside_text(), "edge_share": float(edge[valid].mean()),
               "near_share": float(near[valid].mean()),
               "snr": recording_snr(refs.all_photons), "noise": noise, "levels": [], "picture": None,
               "photons_per_lr_pixel": lr_tags.time.size / (h * w), "lr_shape": (h, w)}
        log(f"{rec.name}: {rec.tags.time.size} photons, {h} x {w} LR, {int(valid.sum())} valid reference pixels "
            f"({valid.mean():.1%}); reference noise: halves {noise['psnr_halves']:.2f} dB")
        for k, level in enumerate(levels):
            t0 = time.time()
            video = photon_video(lr_tags, level, max_frames=max_frames, seed=(seed, i, k))
            if video is None:
                log(f"  {level:g} photons: fewer photons than one frame needs, skipped")
                continue
            frames, _ = histogram_frames(video, rec.gate, rec.scale)
            lr = frames.depth
            measured = photon_levels(iter(np.asarray(frames.counts)), frames.gate.bins)  # what the default decides on
            outputs = {"nearest": np.kron(lr, np.ones((1, FACTOR, FACTOR), np.float32)),
                       "bicubic": np.asarray(jaxsr.bicubic(lr, scale=FACTOR))}
            tv_idx = tv_frames_of(len(lr), tv_frames) if tv else np.zeros(0, int)
            if tv:
                outputs["TV"] = tv_output(lr, tv_idx)
            for label, name in (upscale or {}).items():
                outputs[label] = upscaled(frames, name)
            for label, model in models.items():
                if label in (confidence or {}):
                    guard = confidence[label]
                    decided = with_ensemble(confidence_decided(model, frames, guard), frames, measured,
                                            label in ensemble)
                    outputs[label] = with_holes_filled(decided, frames, guard)
                    continue
                if decision_of((ambient or {}).get(label, ("", 0.0)))[0] == "keep":
                    quiet = no_return_decision(frames.counts, jaxsr.Sensor(gate=jaxsr.Gate.spanning(35.0, frames.gate.bins)),
                                               ambient[label])
                    outputs[label] = returns_kept(model, model_input(model, frames), np.arange(len(lr)), quiet)
                    continue
                outputs[label] = jaxsr.super_resolve(model, model_input(model, frames), form="model")
                if label in (ambient or {}):
                    flags = no_return_decision(frames.counts, jaxsr.Sensor(gate=jaxsr.Gate.spanning(35.0, frames.gate.bins)),
                                               ambient[label])
                    outputs[label] = no_return_where(outputs[label], np.asarray(flags))
            scores = {m: masked_scores(sr, ref, valid, sky, edge, near, sky_beside) for m, sr in outputs.items()}
            photons_ref = float(frames.counts.sum(-1)[:, covered].mean()) if covered.any() else float("nan")
            out["levels"].append({"level": float(level), "frames": len(lr), "photons_ref": photons_ref,
                                  "signal": measured.signal, "snr": measured.snr, "scores": scores,
                                  "tv_frames": tv_idx})
            if out["picture"] is None or level == picture_level:
                t = int(tv_idx[0]) if len(tv_idx) else 0
                out["picture"] = {"level": float(level), "frame": t, "LR": lr[t],
                                  **{m: sr[list(tv_idx).index(t)] if m == "TV" else sr[t]
                                     for m, sr in outputs.items() if m != "nearest"}}
            log(f"  {level:g} photons, {len(lr)} frames: "
                + ", ".join(f"{m} {v['psnr'].mean():.2f} dB" for m, v in scores.items())
                + f" ({time.time() - t0:.0f} s)")
        results[rec.name] = out
        log(f"  {rec.name} done in {time.time() - started:.0f} s")
    return results


# ------------------------------------------------------------------------------------------------ the report

def goal(entry, *, model: str = "TR4", seed: int = 0) -> dict | None:
    """TR4 - bicubic PSNR at one level, paired over the frames (disjoint photons: resampled one by one)."""
    s = entry["scores"]
    if model not in s:
        return None
    a, b = s[model]["psnr"], s["bicubic"]["psnr"]
    diff = float(np.mean(a - b))
    iv = jaxsr.paired_interval(jax.random.key(seed), a, b, block=1) if len(a) > 1 else None
    return {"diff": diff, "met": diff >= GOAL_DB, "short": max(0.0, GOAL_DB - diff),
            "cell": format_interval(iv) if iv is not None else f"{diff:+.2f}",
            **({} if iv is None else {"low": float(iv.low), "high": float(iv.high)})}


def _mae_unit(rec: Recording) -> tuple[str, float]:
    """The unit MAE is reported in and normalised depth's size in it: metres where the gate is known, else bins."""
    span = float(rec.scale.span)
    return ("m", span) if rec.source.metric else ("bins", span / float(rec.gate.bin_width))


def recording_text(rec: Recording, r) -> str:
    """A recording's paragraph: its photons, gate and scale, the reference and the reference's own noise."""
    n = r["noise"]
    unit, k = _mae_unit(rec)
    gate = (f"gate {float(rec.gate.start):.2f}-{float(rec.gate.end):.2f} m ({float(rec.gate.length):.2f} m in {BINS} "
            f"bins of {float(rec.gate.bin_width):.3f} m), network 0 at the gate start and 1.0 "
            f"{float(rec.scale.span):g} m further" if rec.source.metric else
            f"time unit unknown: {BINS} bins over the photons' span, filled onto the network's [0, 1] (relative "
            "depth, no metres; MAE in bins of the gate)")
    return (f"## {rec.name}\n\n"
            f"{rec.tags.shape[0]} x {rec.tags.shape[1]} pixels, {rec.tags.time.size} photons "
            f"({r['photons_per_lr_pixel']:.1f} per LR pixel of {r['lr_shape'][0]} x {r['lr_shape'][1]}); {gate}. "
            f"Reference: {n['pixels']} valid pixels ({r['valid'].mean():.1%}), {int(r['sky'].sum())} without a "
            f"return ({r['sky'].mean():.1%}). Frame SNR of all the photons (`recording_snr`, "
            f"`jaxsr.sensor.frame_snr`: signal / ambient photons over the LR blocks with a return): {r['snr']:.3g}.\n\n"
            f"Reference noise: the photons split into two random halves, each half's depth compared on the valid "
            f"pixels where both give a return ({n['both_return']:.1%} of them): PSNR between the halves "
            f"{n['psnr_halves']:.2f} dB, MAE {n['mae_halves'] * k:.3f} {unit}, the same depth in "
            f"{n['exact_share']:.1%} of them. The halves' errors are independent, so their difference carries twice "
            "a half's error variance, and the all-photon reference (twice a half's photons) about half of it if the "
            "variance goes as 1 / photons: the reference's own error is about the halves' RMS difference / 2, "
            f"**{n['psnr_reference']:.1f} dB PSNR** (the halves' + 6.0 dB), MAE about {n['mae_reference'] * k:.3f} "
            f"{unit}. A method scoring near that is limited by the reference.\n")


def tables(results, recordings) -> str:
    text = []
    for rec in recordings:
        r = results[rec.name]
        methods = list(r["levels"][0]["scores"]) if r["levels"] else []
        text.append(recording_text(rec, r))
        if not methods:
            text.append("No level had the photons for a frame.\n")
            continue
        rows = [[f"{e['level']:g}", str(e["frames"]), f"{e['photons_ref']:.1f}", f"{e['signal']:.1f} / {e['snr']:.3g}"]
                + [f"{e['scores'][m]['psnr'].mean():.2f}" for m in methods] for e in r["levels"]]
        tv_subset = any(len(e["tv_frames"]) < e["frames"] for e in r["levels"] if "TV" in e["scores"])
        text.append("### PSNR (dB) against the reference, mean over frames" + (" (TV: on its frames only)" if tv_subset
                                                                               else "") + "\n\n"
                    + markdown_table(["photons", "frames", "photons / LR pixel on the reference",
                                      "measured signal / SNR (`jaxsr.app.photon_levels`)", *methods], rows))
        rows = [[f"{e['level']:g}"] + [f"{_finite_mean(e['scores'][m]['psnr_near'])} / "
                                       f"{_finite_mean(e['scores'][m]['psnr_away'])}" for m in methods]
                for e in r["levels"]]
        text.append("### PSNR (dB) next to the reference's gaps / away from them\n\n"
                    f"Next (`near_gaps`): valid pixels whose LR block or one of its 8 neighbours holds a pixel "
                    f"without a reference depth (sky, two rival returns, too few photons), "
                    f"{100 * r['near_share']:.1f} % of the valid pixels: there an output must place an edge inside "
                    "an LR block.\n\n" + markdown_table(["photons", *methods], rows))
        unit, k = _mae_unit(rec)
        rows = [[f"{e['level']:g}"] + [f"{e['scores'][m]['mae'].mean() * k:.3f}" for m in methods]
                for e in r["levels"]]
        text.append(f"### MAE ({unit}; a no-return output counts at its distance)\n\n"
                    + markdown_table(["photons", *methods], rows))
        rows = _level_rows(r, methods, lambda s: f"{100 * s['no_return'].mean():.1f}")
        text.append(f"### % of the reference's valid pixels output as no return (>= {NO_RETURN_AT:g})\n\n"
                    + markdown_table(["photons", *methods], rows))
        rows = _level_rows(r, methods, lambda s: _percent(s["dropped_at_edge"]))
        text.append("### Of those, % at an edge\n\n"
                    f"Edges (`empty_edges`): pixels next to an LR block without a significant return in all the "
                    f"photons, {100 * r['edge_share']:.1f} % of the valid pixels; \"-\" where none is dropped.\n\n"
                    + markdown_table(["photons", *methods], rows))
        for mask, key, title, note in (
                ("sky", "sky_as_depth", f"% of the reference's no-return pixels output as depth (< {NO_RETURN_AT:g})",
                 "where all the photons show no return (`reference_sky`: the LR block and its 8 neighbours hold no "
                 f"significant return at a false-alarm rate of {REF_SKY_ALPHA:g} and at most {REF_SKY_SHARE:g} of a "
                 "typical return's photons; a surface darker than that would count as sky too). The two tables above "
                 "and this one are the two sides of a model's no-return decision."),
                ("sky_beside", "edge_sky_as_depth", "% of the sky beside the surfaces output as depth",
                 "that the table above leaves out (`edge_sky`: outside its sky, and their 3 x 3 full-resolution "
                 f"neighbourhood holds at most {REF_EDGE_SKY_PHOTONS} of all the photons): the sky in and beside the "
                 "LR blocks a surface's edge crosses, which PSNR on the valid pixels does not count. Here "
                 f"{r['sky_beside_text']}.")):
            if r[mask].any():
                rows = _level_rows(r, methods, lambda s, key=key: f"{100 * s[key].mean():.1f}")
                text.append(f"### {title}\n\n{int(r[mask].sum())} pixels ({r[mask].mean():.1%}) {note}\n\n"
                            + markdown_table(["photons", *methods], rows))
    return "\n".join(text)


def _level_rows(r, methods, cell) -> list:
    """A table's rows: each level of a recording's results `r`, then `cell(scores)` of each method."""
    return [[f"{e['level']:g}"] + [cell(e["scores"][m]) for m in methods] for e in r["levels"]]


def _finite_mean(values, fmt: str = ".2f", scale: float = 1.0) -> str:
    """The mean of the finite values (times `scale`), "-" where none is (no pixel of that kind)."""
    values = np.asarray(values, float)
    values = values[np.isfinite(values)]
    return "-" if not values.size else f"{scale * values.mean():{fmt}}"


def _percent(shares) -> str:
    """The mean of the finite shares in per cent, "-" where none is."""
    return _finite_mean(shares, ".0f", 100.0)


def goal_table(results) -> tuple[str, bool]:
    """The goal for the bundled TR4 (whether it is met at every level: the second value) and, beside it, for
    every other TR4 scored (labels starting with "TR4", such as a photon model)."""
    entries = [(name, e) for name, r in results.items() for e in r["levels"]]
    models = [m for m in (entries[0][1]["scores"] if entries else {}) if m.startswith("TR4")]
    if "TR4" not in models:
        return "", False
    rows, met = [], {m: True for m in models}
    for name, e in entries:
        cells = []
        for m in models:
            g = goal(e, model=m)
            met[m] &= g["met"]
            cells.append(f"{g['cell']} " + ("yes" if g["met"] else f"NO, {g['short']:.2f} dB short"))
        rows.append([name, f"{e['level']:g}", str(e["frames"]), *cells])
    others = "".join(f" {m}: {'yes' if met[m] else 'NO'}." for m in models if m != "TR4")
    return (f"## Goal: TR4 >= bicubic + {GOAL_DB:g} dB at every level\n\n"
            f"Model - bicubic PSNR (dB), mean over the frames [95 % bootstrap interval, frames resampled one by one: "
            f"each holds its own photons]; met by the mean. **Met at every level by the bundled TR4: "
            f"{'yes' if met['TR4'] else 'NO'}.**{others}\n\n"
            + markdown_table(["recording", "photons", "frames", *(f"{m} - bicubic" for m in models)], rows)), met["TR4"]


def picture(results, recordings, path) -> None:
    """One row per recording: reference | LR | each method (its picture level and frame), one colour scale per
    row from the reference's valid depth, no return (and invalid reference pixels) black."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [(rec, results[rec.name]) for rec in recordings if results[rec.name]["picture"] is not None]
    if not rows:
        return
    panels = max(len(r["picture"]) - 1 for _, r in rows)  # reference + the picture's frames - "level", "frame"
    fig, axes = plt.subplots(len(rows), panels, figsize=(2.6 * panels, 2.8 * len(rows)), squeeze=False)
    cmap = matplotlib.colormaps["turbo"].with_extremes(bad="black")
    for ax_row, (rec, r) in zip(axes, rows):
        pic = r["picture"]
        ref = np.where(r["valid"], r["reference"], 1.0)
        lo, hi = np.quantile(r["reference"][r["valid"]], [0.01, 0.99])
        lo, hi = lo - 0.15 * (hi - lo), hi + 0.15 * (hi - lo)  # off turbo's dark ends
        items = [("reference (all photons)", ref)] + [(k, v) for k, v in pic.items() if k not in ("level", "frame")]
        for ax, (title, img) in zip(ax_row, items):
            img = np.clip(img, 0, 1)
            ax.imshow(np.ma.masked_greater_equal(img, NO_RETURN_AT), cmap=cmap, vmin=lo, vmax=hi,
                      interpolation="nearest")
            ax.set_title(f"{rec.name}: {title}" if title.startswith("reference") else
                         f"{title}, {pic['level']:g} ph" if title == "LR" else title, fontsize=9)
        for ax in ax_row:
            ax.axis("off")
    save_figure(fig, path, dpi=80)


def raw(results, info, settings) -> dict:
    def level(e):
        return {"level": e["level"], "frames": e["frames"], "photons_ref": e["photons_ref"],
                **{k: e[k] if np.isfinite(e[k]) else None for k in ("signal", "snr")},  # NaN, inf: none seen
                "tv_frames": np.asarray(e["tv_frames"]).tolist(),
                "scores": {m: {k: [None if np.isnan(x) else x for x in np.round(np.asarray(v, float), 5).tolist()]
                               for k, v in s.items()}
                           for m, s in e["scores"].items()},
                "goal": {k: v for k, v in (goal(e) or {}).items() if k != "cell"}}
    return {"models": info, "settings": settings,
            "recordings": {name: {"noise": r["noise"], "valid_pixels": int(r["valid"].sum()),
                                  "no_return_pixels": int(r["sky"].sum()),
                                  "sky_beside_pixels": int(r["sky_beside"].sum()), "snr": r["snr"],
                                  "edge_share": r["edge_share"], "near_share": r["near_share"],
                                  "photons_per_lr_pixel": r["photons_per_lr_pixel"],
                                  "levels": [level(e) for e in r["levels"]]} for name, r in results.items()}}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", nargs="+", action="extend",
                        default=[str(DEFAULT_DATA)] if DEFAULT_DATA.is_dir() else None,
                        help="folders holding the recordings of SOURCES (tower.mat, two_layer.mat; face.mat, which "
                             "`experiments/studies/heldout.py prepare` writes into its real/ folder), searched after "
                             "../shared/realdata beside the repository, where it exists")
    parser.add_argument("--levels", type=float, nargs="+", default=list(LEVELS),
                        help="photons per LR pixel and frame (default 1 2 4 8 16)")
    parser.add_argument("--frames", type=int, default=MAX_FRAMES,
                        help=f"disjoint frames per level at most (default {MAX_FRAMES}, TR4's window)")
    parser.add_argument("--tv-frames", type=int, default=None, help="frames per level TV runs on (default all)")
    parser.add_argument("--no-tv", action="store_true", help="leave TV out")
    parser.add_argument("--model", action="append", default=[], metavar="NAME=PATH",
                        help="an extra model file to score (skipped with a line when absent); repeatable")
    parser.add_argument("--no-return-logit", action="append", default=[], metavar="NAME=LOGIT",
                        help="run --model NAME (one with a no-return head) at this decision threshold; repeatable")
    parser.add_argument("--ambient-alpha", action="append", default=[], metavar="NAME=ALPHA",
                        help="run --model NAME also marking no return where the photons around a pixel pass for "
                        "ambient light alone at this false-alarm rate (jaxsr.sensor.ambient_only); repeatable")
    parser.add_argument("--no-return-shares", action="append", default=[], metavar="NAME=ALPHA",
                        help="run --model NAME also marking no return where jaxsr.sensor.no_return_shares (the "
                        "ambient-only test grown to the regions' edges, at this false-alarm rate) say so; repeatable")
    parser.add_argument("--keep-returns", action="append", default=[], metavar="NAME=ALPHA",
                        help="run --model NAME (one with a no-return head) outputting depth wherever the LR block's "
                        "own photons over 9 frames show a return at this false-alarm rate, whatever the head says "
                        "(_photon_benchmark.returns_kept); repeatable")
    parser.add_argument("--confidence", action="append", default=[], metavar="NAME[=ALPHA]",
                        help="run --model NAME (one with a no-return head) with no return where the confidence's "
                        "P(return) is below one half and, with ALPHA, the pixel's own photons over 9 frames and those "
                        "of the quiet pixels pooled around it pass for ambient light alone at that rate, outside the "
                        "holes that returns enclose, and beside the sky P(return) alone (jaxsr upscale's default: "
                        "0.001, jaxsr.sensor.quiet_pixels); repeatable")
    parser.add_argument("--beside-sky", action="append", default=[], metavar="NAME",
                        help="a --confidence NAME=ALPHA whose guard also leaves the LR pixels beside a quiet region "
                        "larger than a hole to P(return) (jaxsr.sensor.beside_sky; not the default); repeatable")
    parser.add_argument("--ensemble", action="append", default=[], metavar="NAME",
                        help="a --confidence NAME whose returns' depth is averaged with the paper's TR4's where the "
                        "photon levels reach jaxsr.app.DEPTH_ENSEMBLE's (jaxsr upscale's default); repeatable")
    parser.add_argument("--upscale", action="append", default=[], metavar="NAME[=MODEL]",
                        help="score jaxsr.upscale itself on the histograms, their gate given, MODEL (a bundled name; "
                        "default the library's choice) and every other option the library's default (what a user "
                        "gets: the depth span it fits, the decision, the ensemble, the holes), as NAME; repeatable")
    parser.add_argument("--picture-level", type=float, default=PICTURE_LEVEL,
                        help="photons of the pictured frame (default 2)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the photon permutations")
    parser.add_argument("--out", default=str(RESULTS / "real_photons.md"),
                        help="the results file (a .json and a .png beside it)")
    args = parser.parse_args(argv)
    if args.data is None:
        raise SystemExit(f"no recordings: {DEFAULT_DATA} does not exist; give the folder with --data")
    started = time.time()
    models, info, ambient = load_models(args.model, args.no_return_logit, args.ambient_alpha,
                                       args.no_return_shares, args.keep_returns)
    upscale = {k: m or "default" for k, _, m in (u.partition("=") for u in args.upscale)}
    unknown = set(args.ensemble) - set(confidence_settings(args.confidence))
    if unknown:
        raise SystemExit(f"--ensemble {', '.join(sorted(unknown))}: give --confidence NAME first (the decision whose "
                         "returns' depth is averaged)")
    recordings = []
    for source, folder in found_sources(args.data):
        if folder is None:
            print(f"skipping {source.name}: no --data folder holds {source.file}")
        else:
            recordings.append(read_recording(folder, source))
    if not recordings:
        raise SystemExit(f"no recordings: none of {', '.join(s.file for s in SOURCES)} in {', '.join(args.data)}")
    results = evaluate(recordings, models, levels=args.levels, max_frames=args.frames, tv_frames=args.tv_frames,
                       tv=not args.no_tv, seed=args.seed, picture_level=args.picture_level, ambient=ambient,
                       confidence=confidence_settings(args.confidence, args.beside_sky), ensemble=set(args.ensemble),
                       upscale=upscale)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    goals, all_met = goal_table(results)
    png = out.with_suffix(".png")
    picture(results, recordings, png)
    text = (header("Real photons against an all-photon reference", started)
            + f"{len(recordings)} real single-photon recordings ({', '.join(r.name for r in recordings)}) made into LR photon videos and upscaled x4; each method's output "
            "is scored against the depth from all the recording's photons at full resolution. How the video and "
            "the reference are made: the docstring of experiments/studies/real_photons.py. In short: 4 x 4 pixels "
            "-> one LR pixel; a seeded random permutation of all photons cut into disjoint frames of L photons per LR "
            f"pixel on average (up to {args.frames} frames, fewer where the photons run out); {BINS}-bin histograms "
            "over the gate, centre of mass. Reference: each full-resolution pixel's centre of mass of all its "
            f"photons, valid where the peak is significant (z = {REF_Z:g}), the pixel has >= {REF_MIN_PHOTONS} "
            f"photons and no second return rivals the peak (a second bin outside the peak's window significant at z = "
            f"{REF_Z:g} that the peak does not beat by {REF_Z:g} Poisson standard deviations); scores on the valid "
            "pixels only. PSNR on normalised depth (peak 1, output clipped to [0, 1]); "
            f"no return: normalised output >= {NO_RETURN_AT:g}. "
            + (f"TV (`tv_super_resolve`, tr {TV_TR}, its defaults) on "
               + ("every frame" if args.tv_frames is None else f"{args.tv_frames} frames per level") + ". "
               if not args.no_tv else "TV not run. ")
            + f"Photon permutations seeded {args.seed}. Models: " + "; ".join(f"{k}: {v}" for k, v in info.items())
            + "".join(f"; {k}: jaxsr.upscale with the gate given, model {m} and the library's defaults"
                      for k, m in upscale.items())
            + ". The recordings are third-party and not part of the project (docs/own-sensor.md, 'Real recordings', "
            "says where to get them).\n\n"
            + goals + "\n" + tables(results, recordings)
            + f"\n## Pictures\n\n![frames]({png.name}) Reference | LR | each method at {args.picture_level:g} photons "
            "per LR pixel (the first frame), one colour scale per row (the reference's 1-99 % depth, widened by 15 % "
            "each side), no return "
            "and the reference's invalid pixels black.\n"
            + hand_written_tail(out, HAND_WRITTEN))
    settings = {"levels": args.levels, "max_frames": args.frames, "tv_frames": args.tv_frames, "tv": not args.no_tv,
                "seed": args.seed, "bins": BINS, "factor": FACTOR, "ref_z": REF_Z, "ref_min_photons": REF_MIN_PHOTONS,
                "ref_sky_alpha": REF_SKY_ALPHA, "ref_sky_share": REF_SKY_SHARE, "no_return_at": NO_RETURN_AT,
                "goal_db": GOAL_DB}
    write_atomic(out, text)
    write_atomic(out.with_suffix(".json"), json.dumps(raw(results, info, settings), indent=1) + "\n")
    print(goals)
    print(f"goal met at every level: {'yes' if all_met else 'NO'}")
    print(f"wrote {out}, {out.with_suffix('.json')} and {png}")


if __name__ == "__main__":
    main()
