"""The memory `jaxsr upscale` needs, estimated from a job's sizes before anything runs (`upscale_memory`), and
the refusal of a job beyond the budget (`check_memory`), with what would need less.

The constants were measured on XLA:CPU as peak resident sizes (2 cores); measured peaks were 0.6-0.9x of the
estimate for frames of 32 x 64 to 2048 x 2048 LR pixels and batches of 1-8.
"""

from __future__ import annotations

import numpy as np

from ..checks import require_memory
from ..inference import DEFAULT_TILE, default_batch_size

from .photons import AMBIENT_FRAMES

__all__ = ["BASE_BYTES", "HISTOGRAM_CHUNK", "HISTOGRAM_COPIES", "NETWORK_BYTES_TR4", "upscale_memory",
           "result_memory", "batch_size_of", "check_memory", "check_result_memory"]

HISTOGRAM_CHUNK = 16  # histogram frames turned into the network's input per compiled call (`iter_network_inputs`)
BASE_BYTES = 0.5e9  # JAX, a model and the interpreter before any frame (0.36-0.49 GB)
HISTOGRAM_COPIES = 6  # copies each float32 frame of counts makes on its way to the network (16 of 2000 bins: 1.6 GB)
NETWORK_BYTES_TR4 = 25e3  # a network's features per LR pixel where its architecture does not say (the DUF TR4's)


def _feature_bytes(model, batch_size: int) -> float:
    count = model.architecture.feature_bytes
    return NETWORK_BYTES_TR4 if count is None else count(model.config, batch_size)


def upscale_memory(job, *, batch_size: int, in_memory: bool, looks: bool = False) -> float:
    """Bytes `write_upscaled` is estimated to need at its peak, from the sizes of `job` (an `UpscaleJob`, from
    `prepare_upscale`, which imports this module) alone (nothing is run):
    `BASE_BYTES`; the input where it is held whole (an .npz's array, time tags' histograms; an .npy is
    memory-mapped); histogram frames on their way to the network (`HISTOGRAM_CHUNK` x `HISTOGRAM_COPIES`); the
    network on one tile (at most `DEFAULT_TILE` LR pixels a side) per frame of the batch; with a photon rule,
    three copies of the `AMBIENT_FRAMES` histogram frames its test holds; the HR frames of two batches (the one
    computed and the one drained; twice over with the keep rule or the confidence: depth and logit) and of a frame
    converted; with the confidence, its window of `AMBIENT_FRAMES` histogram frames and a frame's features; with
    a second network (`UpscaleJob.ensemble_model`), its histogram frames, tile, input and output batches too; and
    the whole result when it is held (`in_memory`: an .npz output or none; with the confidence three times: depth,
    confidence and depth_std) or drawn (`looks`: the video's panels or a point cloud per frame)."""
    rec, model = job.recording, job.model
    h, w = (int(v) for v in rec.shape[:2])
    hr = 4.0 * job.hr_shape[0] * job.hr_shape[1]
    need = BASE_BYTES + _held_input_bytes(rec)
    if rec.kind == "histograms":
        need += HISTOGRAM_COPIES * HISTOGRAM_CHUNK * 4.0 * h * w * int(rec.shape[-1])
    keep = job.keep_returns is not None
    if job.ambient_alpha is not None or keep:  # the frames held, their stack and the padded sums of `ambient_only`
        need += 3 * AMBIENT_FRAMES * 4.0 * h * w * int(rec.shape[-1])
    tile = min(h, DEFAULT_TILE) * min(w, DEFAULT_TILE)
    for net in (model,) if job.ensemble_model is None else (model, job.ensemble_model):
        radius = net.architecture.input_radius(net.config)
        need += (batch_size * tile * _feature_bytes(net, batch_size)
                 + 3 * (batch_size + 2 * radius) * 4.0 * h * w * len(net.channels))
    if job.ensemble_model is not None:  # its own histogram stream and HR batches
        need += HISTOGRAM_COPIES * HISTOGRAM_CHUNK * 4.0 * h * w * int(rec.shape[-1]) + (2 * batch_size + 1) * hr
    raw = keep or job.has_confidence
    need += (2 * batch_size + 1) * hr * (2 if raw else 1)  # raw: depth and logit
    if job.has_confidence:  # the confidence's window of histograms and its frame's features
        need += 2 * AMBIENT_FRAMES * 4.0 * h * w * int(rec.shape[-1]) + 16 * hr
    results = 3 if job.has_confidence else 1  # depth, confidence and depth_std held
    need += (results * job.frames * hr if in_memory else 0) + (6 * hr if looks else 0)
    return need


def batch_size_of(job, batch_size: int | None) -> int:
    """Frames per compiled call: `batch_size` (default as `jaxsr.inference.iter_super_resolve`'s) but no more
    than the recording's frames (a larger batch would be padded with copies of the last frame)."""
    if batch_size is not None and (isinstance(batch_size, bool) or int(batch_size) != batch_size
                                   or int(batch_size) < 1):
        raise ValueError(f"batch_size (--batch-size): expected an integer >= 1, got {batch_size!r}")
    size = (default_batch_size(range(job.frames), job.model.sequence_form) if batch_size is None
            else int(batch_size))
    return min(size, job.frames)


def check_memory(job, *, batch_size: int, in_memory: bool, looks: bool, max_memory) -> None:
    """Refuse a job whose `upscale_memory` exceeds the budget (`jaxsr.checks.require_memory`), naming its sizes and
    what would need less."""
    need = upscale_memory(job, batch_size=batch_size, in_memory=in_memory, looks=looks)
    ways = ([f"a smaller --batch-size (now {batch_size})"] if batch_size > 1 else []) + (
        ["an .npy or folder OUTPUT (written frame by frame, not held)"] if in_memory and job.frames > 1 else []) + (
        ["--ambient-alpha off (its test sums 9 frames)"] if job.ambient_alpha is not None else [])
    frame = " x ".join(map(str, job.recording.shape))
    what = (f"upscaling {job.frames} frame{'s' if job.frames > 1 else ''} of {frame} to {job.hr_shape[0]} x "
            f"{job.hr_shape[1]}")
    require_memory(need, what, max_memory, remedy="give " + " or ".join(ways) if ways else "")


def _held_input_bytes(rec) -> int:
    """The input's bytes where it is held whole (an .npz's array, time tags' histograms; not a memory-mapped .npy
    or image frames)."""
    return 0 if rec.array is None or isinstance(rec.array, np.memmap) else int(rec.array.nbytes)


def result_memory(recording, scale: int, *, in_memory: bool, looks: bool) -> float:
    """The least `upscale_memory` can be for `recording` upscaled `scale` times, from its sizes alone (no frame read,
    no model built): `BASE_BYTES`, the input where held whole, the HR frames of a batch of one (computed, drained
    and converted), and the whole result where it is held (`in_memory`) or the pictures' frames (`looks`)."""
    h, w = (int(v) for v in recording.shape[:2])
    hr = 4.0 * h * w * scale * scale
    return BASE_BYTES + _held_input_bytes(recording) + 3 * hr + (
        recording.frames * hr if in_memory else 0) + (6 * hr if looks else 0)


def check_result_memory(recording, scale: int, *, in_memory: bool, looks: bool, max_memory) -> None:
    """Refuse a recording whose `result_memory` exceeds the budget (`jaxsr.checks.require_memory`) before any of its
    frames is read: a recording too long to hold its result is refused from its sizes, not after a pass over it."""
    need = result_memory(recording, scale, in_memory=in_memory, looks=looks)
    frame = " x ".join(map(str, recording.shape))
    what = (f"upscaling {recording.frames} frame{'s' if recording.frames > 1 else ''} of {frame} to "
            f"{recording.shape[0] * scale} x {recording.shape[1] * scale}")
    require_memory(need, what, max_memory, remedy="give an .npy or folder OUTPUT (written frame by frame, not held)"
                   if in_memory and recording.frames > 1 else "", at_least=True)
