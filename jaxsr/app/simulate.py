"""A simulated SPAD recording in one call, as `jaxsr simulate` makes it: render a procedural scene
(`jaxsr.scenes.sequence`) or read an AirSim recording (`read_airsim`), simulate photon histograms
(`jaxsr.sensor.simulate_histograms`), extract the centre-of-mass depth, score the bicubic baseline against the
ground truth and write the files and previews (`simulate_recording`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from ..baselines.interpolation import bicubic
from ..checks import require_memory
from ..config import DEFAULT_MEAN_SIGNAL, Sensor
from ..eval.metrics import psnr, ssim
from ..scenes import KINDS, sequence
from ..sensor.forward import normalise_depth, require_scalar_levels, simulate_histograms
from ..sensor.peaks import centre_of_mass
from ..io.files import atomic_folder, check_output_folder, refuse_link
from ..io.formats import read_airsim, write_histograms, write_sequence
from ..io.previews import write_comparison, write_gray_preview, write_preview

__all__ = ["SIMULATION_OUTPUTS", "CAMERAS", "Simulation", "simulate_recording"]

# the files `simulate_recording` writes into its folder
SIMULATION_OUTPUTS = ("histograms.npz", "com_depth.npy", "gt_depth.npy", "preview_gt.png", "preview_com.png",
                      "preview_intensity.png", "preview_strip.png")
CAMERAS = ("static", "moving", "random")


@dataclasses.dataclass(frozen=True)
class Simulation:
    """What `simulate_recording` made. out: the folder written (None when nothing was written); counts:
    (T, h, w, bins) photon histograms; com: (T, h, w) centre-of-mass depth, normalised [0, 1]; depth: (T, H, W)
    ground-truth radial metres (inf = no return); intensity: (T, H, W) reflectivity [0, 1]; metadata: the source
    (kind, seed, camera or input), fps, snr, mean_signal and frames, as stored in histograms.npz;
    bicubic_psnr_db, bicubic_ssim: the bicubic upsampling of `com` against the ground truth, averaged over
    frames (the baseline a network has to beat)."""

    out: Path | None
    counts: np.ndarray
    com: np.ndarray
    depth: np.ndarray
    intensity: np.ndarray
    metadata: dict
    bicubic_psnr_db: float
    bicubic_ssim: float

    def summary(self) -> dict:
        """The JSON summary `jaxsr simulate` prints: the metadata, the bicubic scores, out and counts_shape."""
        return dict(self.metadata, bicubic_psnr_db=self.bicubic_psnr_db, bicubic_ssim=self.bicubic_ssim,
                    out=None if self.out is None else str(self.out), counts_shape=list(self.counts.shape))


def _check_out(path, overwrite):
    """The output folder, checked (nothing is created yet): refuse (FileExistsError) a file, or a folder that
    already holds any of `SIMULATION_OUTPUTS` unless `overwrite`; a symbolic link and a place this process cannot
    write into in any case."""
    out = Path(path)
    refuse_link(out, "-o/--output")
    if out.exists() and not out.is_dir():
        raise FileExistsError(f"{out} is a file; -o/--output is a folder")
    clash = [n for n in SIMULATION_OUTPUTS if (out / n).exists()]
    if clash and not overwrite:
        raise FileExistsError(f"{out} already holds {', '.join(clash)}; pass --force to overwrite")
    check_output_folder(out)
    return out


def _check_memory(frames: int, max_memory) -> None:
    """Refuse (ValueError) a number of frames beyond the memory budget (`jaxsr.checks.require_memory`):
    rendering, the photon draw and the outputs hold the whole sequence, about 15 MB per frame (measured: 0.8 GB
    for 10 frames, 1.8 GB for 80)."""
    require_memory(0.7e9 + 15e6 * frames, f"simulating {frames} frames", max_memory,
                   remedy="simulate the recording in parts (--seed)")


def _airsim_frames(folder) -> int:
    """The frames an AirSim recording lists (the rows of airsim_rec.txt after its header; 0 when there is none:
    `read_airsim` says what is missing)."""
    rec = Path(folder) / "airsim_rec.txt"
    if not rec.is_file():
        return 0
    with open(rec, "rb") as f:
        return max(0, sum(1 for line in f if line.strip()) - 1)


def _check_options(kind, frames, fps, snr, mean_signal, camera, seed):
    if kind not in KINDS:
        raise ValueError(f"kind (--kind) is one of {', '.join(KINDS)}, got {kind!r}")
    if camera not in CAMERAS:
        raise ValueError(f"camera (--camera) is one of {', '.join(CAMERAS)}, got {camera!r}")
    if int(frames) != frames or frames < 1:
        raise ValueError(f"frames (--frames): expected an integer >= 1, got {frames!r}")
    require_scalar_levels("simulate_recording", snr, 0.0 if mean_signal is None else mean_signal)
    for name, value in (("fps", fps), ("snr", snr), ("mean_signal", mean_signal)):
        if value is not None and not (np.isfinite(value) and value > 0):
            raise ValueError(f"{name} (--{name.replace('_', '-')}): expected a finite number > 0, got {value!r}")
    if int(seed) != seed or not 0 <= seed < 2**32:
        raise ValueError(f"seed (--seed): expected an integer from 0 to {2**32 - 1}, got {seed!r}")


def _scene(input, kind, frames, fps, camera, seed, sensor):
    """(depth (T, H, W) radial m, intensity (T, H, W), fps, source metadata) from an AirSim folder or a scene."""
    if input is not None:
        rec = read_airsim(input, sensor=sensor)
        depth, intensity = rec["depth"], rec["intensity"]
        if depth.shape[1:] != sensor.hr_shape:
            raise ValueError(f"{input}: frames are {depth.shape[1:]}, the sensor expects {sensor.hr_shape}")
        return depth, intensity, rec["fps"], dict(input=str(input))
    depth, intensity = jax.jit(
        lambda k: sequence(k, frames, fps, kind=kind, sensor=sensor, camera=camera)
    )(jax.random.key(seed))
    return depth, intensity, fps, dict(kind=kind, seed=seed, camera=camera)


def simulate_recording(out, *, kind: str = "street", input=None, frames: int = 20, fps: float = 25.0,
                       snr: float = 1.3, mean_signal: float | None = None, camera: str = "static", seed: int = 0,
                       overwrite: bool = False, max_memory=None, report=None) -> Simulation:
    """Simulate a SPAD recording and write it: `jaxsr simulate -o OUT` in one call.

    Renders `frames` frames of a procedural scene of `kind` ("street", "road", "courtyard" or "walkers", --kind)
    at `fps` frames/s with a `camera` ("static", "moving" or "random"), or reads an AirSim recording folder
    (`input`, AIRSIM_DIR: airsim_rec.txt + images; then kind, frames, fps and camera are not used), on the paper's
    sensor (`Sensor()`); simulates photon histograms at a mean frame signal-to-background ratio `snr` with
    `mean_signal` signal photons per LR pixel (default `DEFAULT_MEAN_SIGNAL`), random seed `seed` (the scene
    draws from key(seed), the photons from key(seed + 1)); extracts the centre-of-mass depth.

    out: a folder (created if missing) that receives histograms.npz (counts, ground-truth depth, sensor and the
    metadata), com_depth.npy ((T, h, w) normalised depth), gt_depth.npy ((T, H, W) radial metres) and PNG
    previews of the first frame (ground truth, centre of mass, intensity, and a centre of mass | bicubic | ground
    truth strip), written into a hidden temporary folder and moved in when all are written; None writes nothing.
    overwrite (--force): replace those files in `out`. max_memory (--max-memory): the memory the command may take,
    bytes or a size such as "16GB" (default a share of this machine's RAM, `jaxsr.checks.memory_budget`), checked
    against an estimate from the frames (rendered or listed by the AirSim recording) before any work. report:
    called with a line for people at each long step (rendering, photons, writing; `jaxsr simulate` prints them).
    Options are keyword-only.

    Returns a `Simulation` (the arrays, the metadata and the bicubic baseline's PSNR / SSIM; `summary()` is the
    command's JSON). Raises FileExistsError (out is a file, or holds the outputs without overwrite), ValueError
    (a bad option, frames beyond this machine's memory, AirSim frames of another size) or FileNotFoundError, with
    the messages `jaxsr simulate` prints; nothing is written then.
    """
    sensor = Sensor()
    _check_options(kind, frames, fps, snr, mean_signal, camera, seed)
    out = None if out is None else _check_out(out, overwrite)
    n = int(frames) if input is None else _airsim_frames(input)
    _check_memory(n, max_memory)
    say = report or (lambda line: None)
    say(f"rendering {n} frames of {'the AirSim recording' if input is not None else f'a {kind} scene'}")
    depth, intensity, fps, source = _scene(input, kind, int(frames), fps, camera, int(seed), sensor)
    say(f"simulating photons at SNR {snr:g} and the centre of mass")
    mean_signal = DEFAULT_MEAN_SIGNAL if mean_signal is None else mean_signal
    counts = simulate_histograms(jax.random.key(int(seed) + 1), jnp.asarray(depth), jnp.asarray(intensity), sensor,
                                 snr=snr, mean_signal=mean_signal)
    counts, depth, intensity = np.asarray(counts), np.asarray(depth), np.asarray(intensity)
    com = np.asarray(centre_of_mass(counts, sensor))
    meta = dict(source, fps=float(fps), snr=snr, mean_signal=mean_signal, frames=int(depth.shape[0]))
    # The baseline a network has to beat: bicubic upsampling of the centre-of-mass depth.
    gt = np.asarray(normalise_depth(jnp.asarray(depth), sensor))
    up = np.asarray(bicubic(com, scale=sensor.scale))
    if out is not None:
        say(f"writing {out}")
        with atomic_folder(out) as tmp:
            write_histograms(tmp / "histograms.npz", counts, depth=depth, sensor=sensor, **meta)
            write_sequence(tmp / "com_depth.npy", com)
            write_sequence(tmp / "gt_depth.npy", depth)
            write_preview(tmp / "preview_gt.png", depth[0], d_max=float(sensor.d_max))
            write_preview(tmp / "preview_com.png", com[0], d_max=float(sensor.d_max), normalised=True)
            write_gray_preview(tmp / "preview_intensity.png", intensity[0])
            write_comparison(tmp / "preview_strip.png", com[0], np.clip(up[0], 0, 1), gt=gt[0],
                             labels=("centre of mass", "bicubic", "ground truth"))
    return Simulation(out, counts, com, depth, intensity, meta,
                      bicubic_psnr_db=round(float(np.mean(psnr(up, gt))), 2),
                      bicubic_ssim=round(float(np.mean(ssim(up, gt))), 3))
