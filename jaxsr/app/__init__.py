"""The application: super-resolve a recording in one call, as `jaxsr upscale` does, and simulate one, as
`jaxsr simulate` does. It sits between the command (`jaxsr.cli`) and the engine (`jaxsr.inference`, which runs
networks over frames, windows and streams): reading recordings and their photons, choosing the model, estimating
the memory, writing arrays, frames, previews, videos and point clouds.

What `upscale` is asked to do comes as four checked specifications (`jaxsr.app.specs`): `Reading` (what is
read), `ModelChoice` (which model, how it runs), `PhotonRules` (the photon tests beside the network) and `Writing`
(what is written beside the output). The work comes in two halves for scripts that want them apart:
`prepare_upscale` (a checked `UpscaleJob` whose `iter_frames()` streams the result) and `write_upscaled`.

Frames stream from the input through the model to the output, so a long recording needs memory for a batch, not
for the whole sequence. Histograms and photon time tags are read over a gate and put on the network's scale with
the gate's start as its 0 m and `Reading.span` metres (default the depth the first frames' returns reach,
`jaxsr.sensor.data_span`) as its 1.0; where that takes the models outside what they were trained on, the job's
warnings say so. Outputs never replace an existing file
or write into a non-empty folder unless `Writing.overwrite`.
"""

from __future__ import annotations

from typing import Callable

from ..checks import memory_budget
from .job import UpscaleJob, prepare_upscale
from .memory import upscale_memory
from .models import DEFAULT_MODELS, DEPTH_ENSEMBLE, DepthEnsemble
from .outputs import Outputs, check_outputs
from .photons import (AUTO_AMBIENT_ALPHA, AUTO_AMBIENT_MIN_FRAMES, AUTO_AMBIENT_MIN_SIGNAL_SNR, AUTO_AMBIENT_MIN_SNR,
                      AUTO_KEEP_RETURNS, FEW_PHOTONS, HEAD_FRAMES, PhotonLevels, auto_ambient_alpha, photon_levels)
from .recordings import DEPTH_UNITS, Recording, open_recording, to_metres, to_units
from .simulate import SIMULATION_OUTPUTS, Simulation, simulate_recording
from .specs import FRAME_FORMATS, KINDS, ModelChoice, PhotonRules, Reading, Writing
from .writing import UpscaleResult, write_upscaled

__all__ = ["Reading", "ModelChoice", "PhotonRules", "Writing", "upscale", "prepare_upscale", "write_upscaled",
           "UpscaleJob", "UpscaleResult", "Outputs", "check_outputs", "upscale_memory", "DEFAULT_MODELS",
           "DEPTH_ENSEMBLE", "DepthEnsemble",
           "AUTO_AMBIENT_ALPHA", "AUTO_AMBIENT_MIN_FRAMES", "AUTO_AMBIENT_MIN_SIGNAL_SNR", "AUTO_AMBIENT_MIN_SNR",
           "AUTO_KEEP_RETURNS", "FEW_PHOTONS", "HEAD_FRAMES", "PhotonLevels", "auto_ambient_alpha", "photon_levels",
           "DEPTH_UNITS", "FRAME_FORMATS", "KINDS", "Recording", "open_recording", "to_metres", "to_units",
           "SIMULATION_OUTPUTS", "Simulation", "simulate_recording"]


def upscale(input, output, *, model="default", read: Reading = Reading(), photons: PhotonRules = PhotonRules(),
            write: Writing = Writing(), batch_size: int | None = None, max_memory=None, progress: bool = False,
            report: Callable[[str], None] | None = None) -> UpscaleResult:
    """Super-resolve a recording x4 with a trained model and write it: `jaxsr upscale INPUT OUTPUT` in one call.

    input: a path (.npy / .npz array of depth (T, h, w) or photon counts (T, h, w, bins); a folder or glob
    pattern of EXR, PFM, TIFF or 16-bit PNG depth frames; photon time tags with `Reading(kind="timetags")`: a
    MATLAB v4-v7 .mat cell array of per-pixel arrival times, or an .npz table 'pixel', 'time', 'shape'), or a
    `Recording`, a NumPy array or `jaxsr.sensor.TimeTags`. output: .npy / .npz, a folder of frames, or None (the
    result is returned in `UpscaleResult.depth`, (T, H, W) float32, in the input's units).

    model: a `ModelChoice`, or what its `model` takes: "default" (the bundled model that fits the input,
    `DEFAULT_MODELS`: tr4 for depth, tr4-ambient for histograms and time tags), a bundled name (tr0..tr4,
    paper-tr0..paper-tr4, tr4-ambient, ...), "auto" (the TR `jaxsr.inference.choose_tr` picks from the motion of
    the first 64 frames), a checkpoint path or a `jaxsr.Model`. read (`Reading`): the input's kind, the gate of
    histograms and time tags, the depth span, units. photons (`PhotonRules`): the ambient-only test and the keep
    rule (histograms and time tags). write (`Writing`): the frame files' format, a preview, a video with a
    reference, point clouds, overwrite. batch_size: frames per compiled call. max_memory: the memory the command
    may take, bytes or a size such as "16GB" (default: a share of this machine's RAM,
    `jaxsr.checks.memory_budget`); an .npz input's array, time tags' histograms and the work (`upscale_memory`)
    are estimated before they allocate and refused beyond it. progress: a progress bar. report: called with each
    line of `UpscaleResult.notes` as soon as it is known; `jaxsr upscale` prints them.

    Everything is checked before the model runs, in order: the specifications, the output, preview, video and
    point clouds' paths (and that the reference reads), the model, the input and every frame, the memory. Returns
    an `UpscaleResult` (`summary()` is the command's JSON). Raises FileNotFoundError (missing input, model,
    reference or output folder), FileExistsError (an output, preview, video or point clouds' file exists, or their
    folder holds files, without overwrite), IsADirectoryError, NotADirectoryError or ValueError (bad options or input),
    with the messages `jaxsr upscale` prints, TypeError (an input or model of another type, None among them), or
    `jaxsr.io.WriteError` (the disk refused a write: full, over quota, ...); nothing is left written then.
    """
    memory_budget(max_memory)  # a bad size is refused before anything is read
    outputs = check_outputs(output, write, input=input)
    job = prepare_upscale(input, model=model, read=read, photons=photons, max_memory=max_memory, outputs=outputs)
    return write_upscaled(job, outputs, batch_size=batch_size, progress=progress, max_memory=max_memory,
                          report=report)
