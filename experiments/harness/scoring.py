"""Scoring models on the fixed test clips, as the experiments (experiments/) do: the test scenes simulated at their
SNR (`test_clips`), the frame-rate study's walkers scene (`walkers_clip`, `walkers_at`), per-frame PSNR and SSIM
(`frame_metrics`, `scene_metrics`: PSNR, the paper's Eq. 2 SSIM and the windowed SSIM; `frame_scores`, `scene_scores`:
PSNR and the windowed SSIM), paired intervals of score differences (`interval`), frames/s (`model_fps`), and
the models scored (bundled, trained, or from a folder: `load_tr`, `get_model`).

Importing this module exposes the host's CPU cores as JAX devices (`jaxsr.runtime.use_cpu_cores`), as `jaxsr
upscale` and `jaxsr train` do: import it before any JAX operation, or the device count stays as it is.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from pathlib import Path
from types import SimpleNamespace
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

import jaxsr
from jaxsr import scenes
from jaxsr.config import DEFAULT_MEAN_SIGNAL, MODEL_INPUTS, PRESETS, ModelConfig, Optics, Sensor, TrainConfig
from jaxsr.inference import in_form, super_resolve, super_resolve_histograms
from jaxsr.io.checkpoint import resolve_model_path
from jaxsr.runtime import compiler_options
from jaxsr.sensor.forward import require_scalar_levels
from jaxsr.scenes import TEST_SEQUENCES, mean_lr_shift, render_sequence, test_scene
from jaxsr.training.data import sequence_batches
from jaxsr.training import resume_config

# The host's cores as CPU devices, before any JAX operation: training and `super_resolve` split batches over
# them, as `jaxsr upscale` and `jaxsr train` do.
N_DEVICES = jaxsr.runtime.use_cpu_cores()
FPS_NOTE = f"default batch: one frame on each of {N_DEVICES} CPU cores as JAX devices"

TEST_SCENES = ("scene1_street", "scene2_road", "scene3_courtyard")
SCENE_LABELS = {"scene1_street": "Scene 1", "scene2_road": "Scene 2", "scene3_courtyard": "Scene 3"}
# The paper's Table 1 (x4, RTX 2070): PSNR, SSIM per scene and frames/s per TR.
PAPER_TABLE1 = {
    0: ((20.68, 0.877), (22.18, 0.895), (30.66, 0.889), 46.9),
    1: ((21.20, 0.890), (22.72, 0.910), (31.17, 0.901), 43.4),
    2: ((21.90, 0.903), (22.82, 0.912), (31.33, 0.905), 38.4),
    3: ((22.04, 0.907), (22.89, 0.915), (31.35, 0.906), 33.5),
    4: ((22.05, 0.909), (23.00, 0.916), (31.31, 0.906), 30.8),
}
PAPER_BICUBIC = ((15.82, 0.538), (17.60, 0.607), (26.80, 0.841), 185.0)


@dataclasses.dataclass
class Clip:
    """One simulated recording: LR centre-of-mass depth (T, h, w), photon counts (T, h, w, K), the normalised
    HR ground truth (T, H, W), its frame rate and SNR."""

    name: str
    lr: np.ndarray
    counts: np.ndarray
    gt: np.ndarray
    fps: float
    snr: float
    intensity: np.ndarray | None = None  # the HR intensity (T, H, W) in [0, 1], HistNet's guide image
    scored: np.ndarray | None = None  # the frames a test scores (`scored_frames`); None: every frame
    # the photons behind each LR depth, (T, h, w, C) encoded channels (`jaxsr.nn.network_inputs`), for networks
    # that read them; None when made without them. `channels` names them, in order.
    photons: np.ndarray | None = None
    channels: tuple[str, ...] = MODEL_INPUTS[1:]

    def network_input(self, inputs=("depth",)) -> np.ndarray:
        """What a network reading `inputs` (`ModelConfig.inputs`) gets: lr, or (T, h, w, C) channels."""
        inputs = tuple(inputs)
        if inputs == ("depth",):
            return self.lr
        if self.photons is None:
            raise ValueError(f"clip {self.name!r} was made without its photons; a model reading {inputs} needs them")
        if len(self.channels) != self.photons.shape[-1]:
            raise ValueError(f"clip {self.name!r}: its photons hold {self.photons.shape[-1]} channels but "
                             f"channels names {len(self.channels)}: {self.channels}")
        channel = {"depth": self.lr, **dict(zip(self.channels, np.moveaxis(self.photons, -1, 0)))}
        missing = [name for name in inputs if name not in channel]
        if missing:
            raise ValueError(f"clip {self.name!r} was made without the channels {missing}; a model reading {inputs} "
                             "needs them")
        return np.stack([channel[name] for name in inputs], axis=-1)

    def at(self, frames) -> Clip:
        """The clip of only these frames (indices; None: this clip), all of them scored."""
        if frames is None:
            return self
        intensity = None if self.intensity is None else self.intensity[frames]
        photons = None if self.photons is None else self.photons[frames]
        return dataclasses.replace(self, lr=self.lr[frames], counts=self.counts[frames], gt=self.gt[frames],
                                   intensity=intensity, scored=None, photons=photons)


@jax.jit
def _simulate(key, depth, intensity, sensor, snr, mean_signal):
    counts = jaxsr.simulate_histograms(key, depth, intensity, sensor, snr=snr, mean_signal=mean_signal)
    return counts, jaxsr.centre_of_mass(counts, sensor), jaxsr.normalise_depth(depth, sensor)


def simulate_clip(key, seq, *, sensor: Sensor = Sensor(), snr=None,
                  mean_signal: float = DEFAULT_MEAN_SIGNAL, name=None) -> Clip:
    """Histograms, centre of mass and normalised ground truth of a `TestSequence`-like record (depth,
    intensity, fps, snr), at its own SNR unless `snr` is given."""
    snr = seq.snr if snr is None else snr
    require_scalar_levels("simulate_clip", snr, mean_signal)
    counts, lr, gt = _simulate(key, jnp.asarray(seq.depth), jnp.asarray(seq.intensity), sensor,
                               jnp.float32(snr), jnp.float32(mean_signal))
    return Clip(name or seq.name, np.asarray(lr), np.asarray(counts), np.asarray(gt), float(seq.fps), float(snr),
                np.asarray(seq.intensity, np.float32))


# Frames of every test sequence (`jaxsr.scenes.test_sequences`)
SEQUENCE_FRAMES = 500


def scored_frames(n: int, total: int = SEQUENCE_FRAMES) -> np.ndarray:
    """`n` frame indices spread evenly over a sequence of `total` frames, each the middle of its share (every
    frame when n >= total). The test scenes change along their 500 frames, so a sequence's first frames do not
    score like the whole: bicubic on scene 1 gave 18.99 dB on its first 50 frames, 15.27 on its first 100 and
    17.04 on all 500."""
    n = min(int(n), total)
    if n < 1:
        raise ValueError(f"scored_frames: expected at least one frame, got {n}")
    return ((np.arange(n) + 0.5) * total / n).astype(int)


def test_clips(n_frames: int, *, seed: int = 0, sensor: Sensor = Sensor(), names=TEST_SCENES,
               spread: bool = False):
    """The test scenes simulated at their SNR (noise from `seed`): their first `n_frames` frames or, with
    `spread`, all `SEQUENCE_FRAMES` of them with `n_frames` spread over them to score (`Clip.scored`)."""
    seqs = scenes.test_sequences(n_frames=SEQUENCE_FRAMES if spread else n_frames, names=names, sensor=sensor)
    clips = {n: simulate_clip(jax.random.key(seed * 1000 + i), seqs[n], sensor=sensor) for i, n in enumerate(names)}
    if spread:
        for clip in clips.values():
            clip.scored = scored_frames(n_frames, len(clip.gt))
    return clips


# The frame rates of the frame-rate study (experiments/paper/fps_study.py, the paper's Table 2)
FRAME_RATES = (1.0, 2.5, 5.0, 10.0, 20.0, 25.0, 50.0, 100.0)
_render = jax.jit(render_sequence, static_argnames=("sensor",))


def walkers_clip(fps, n_frames, *, t0, seed, sensor, n_scored=None) -> tuple[Clip, float]:
    """The frame-rate study's scene at `fps` from time t0: the simulated clip (scoring `n_scored` frames spread
    over it; None: all) and the exact mean motion."""
    scene, _ = test_scene("walkers_100fps")
    snr = TEST_SEQUENCES["walkers_100fps"][3]
    times = t0 + jnp.arange(n_frames, dtype=jnp.float32) / fps
    depth, intensity = _render(scene, times, sensor=sensor)
    record = SimpleNamespace(name=f"walkers_{fps:g}fps", depth=depth, intensity=intensity, fps=fps, snr=snr)
    clip = simulate_clip(jax.random.key(seed * 1000 + int(fps * 10)), record, sensor=sensor)
    clip.scored = None if n_scored is None else scored_frames(n_scored, n_frames)
    return clip, float(mean_lr_shift(scene, fps, sensor=sensor, t=t0))


def walkers_at(fps: float, frames: int, *, seed: int = 0):
    """The static-camera walkers sequence sampled at about `fps` (every round(100 / fps)-th frame of the 100 FPS
    sequence), simulated with noise seed `seed`: (Clip, the sampled sequence)."""
    step = round(100 / fps)
    seq = scenes.test_sequence("walkers_100fps", n_frames=frames * step)
    seq = seq._replace(depth=seq.depth[::step], intensity=seq.intensity[::step], fps=100.0 / step)
    return simulate_clip(jax.random.key(seed), seq), seq


@functools.cache
def _apply_windows():
    return jax.jit(jaxsr.apply_model, static_argnames=("cfg", "precision"), compiler_options=compiler_options())


def frame_windows(lr, frames, tr: int) -> np.ndarray:
    """The windows of 2 tr + 1 frames around `frames` (indices) of `lr` (T, ...), edge-replicated at the sequence
    ends as `jaxsr.windows`: (len(frames), 2 tr + 1, ...)."""
    return np.asarray(lr)[np.clip(np.asarray(frames)[:, None] + np.arange(-tr, tr + 1), 0, len(lr) - 1)]


def super_resolve_frames(model, lr, frames=None, *, batch: int = 8, precision: str = "default",
                         form: str = "model") -> np.ndarray:
    """`jaxsr.super_resolve(model, lr, precision=precision, form=form)[frames]` (frames: indices, None = all) for
    normalised LR depth in [0, 1] (no NaN: test clips' centre of mass), computing only those frames' windows in
    the window form (the sequence form runs the whole sequence, as its outputs share work). form: as
    `super_resolve`'s, but "model" by default: the experiments score a model in the form its config names."""
    model = in_form(model, form, frames=len(lr))
    if frames is None or model.architecture.sequence_form(model.config):
        out = jaxsr.super_resolve(model, lr, precision=precision, form="model")
        return out if frames is None else out[frames]
    windows = frame_windows(lr, frames, model.config.tr)
    mesh = Mesh(np.asarray(jax.local_devices()), ("batch",))  # each batch split over the cores, as super_resolve does
    batch = -(-batch // mesh.size) * mesh.size
    params, state = jax.device_put((model.params, model.state), NamedSharding(mesh, P()))
    out = []
    for i in range(0, len(windows), batch):
        chunk = windows[i:i + batch]
        padded = np.concatenate([chunk, np.repeat(chunk[-1:], batch - len(chunk), 0)])  # one compiled shape
        split = jax.device_put(padded, NamedSharding(mesh, P("batch")))
        out.append(np.asarray(_apply_windows()(params, state, split, model.config, precision=precision))[:len(chunk)])
    return np.concatenate(out)


def scored_output(model, clip: Clip) -> tuple[np.ndarray, np.ndarray]:
    """The model's output on the clip's scored frames and their ground truth."""
    lr = clip.network_input(getattr(model.config, "inputs", ("depth",)))
    return super_resolve_frames(model, lr, clip.scored), clip.gt if clip.scored is None else clip.gt[clip.scored]


class Scores(NamedTuple):
    """A frame's scores (each (T,) per frame, or a float mean): PSNR (dB), SSIM as the paper's Eq. 2 (whole-frame
    means, variances and covariance, `jaxsr.ssim_global`) and the 11 x 11 Gaussian-window SSIM (`jaxsr.ssim`)."""

    psnr: np.ndarray | float
    ssim_eq2: np.ndarray | float
    ssim_window: np.ndarray | float

    def mean(self) -> Scores:
        """The means over frames, as floats."""
        return Scores(*(float(np.mean(v)) for v in self))


def scene_metrics(model, clips: dict) -> tuple[dict, np.ndarray]:
    """Mean `Scores` per scene of one model on the clips' scored frames, and its per-frame PSNR (scenes, frames),
    scenes in the clips' order."""
    means, frames = {}, []
    for name, clip in clips.items():
        scores = frame_metrics(*scored_output(model, clip))
        means[name] = scores.mean()
        frames.append(scores.psnr)
    return means, np.stack(frames)


def scene_scores(model, clips: dict) -> tuple[dict, np.ndarray]:
    """Mean PSNR and windowed SSIM per scene of one model on the clips' scored frames, and its per-frame PSNR
    (scenes, frames), scenes in the clips' order (`scene_metrics` also gives the paper's Eq. 2 SSIM)."""
    means, frames = scene_metrics(model, clips)
    return {name: (m.psnr, m.ssim_window) for name, m in means.items()}, frames


@jax.jit
def _frame_metrics(sr, gt):
    return jaxsr.psnr(sr, gt), jaxsr.ssim_global(sr, gt), jaxsr.ssim(sr, gt)


def frame_metrics(sr, gt, *, chunk: int = 50) -> Scores:
    """Per-frame `Scores`, each (T,), of sr against gt (T, H, W), both normalised; sr is clipped to [0, 1] as a
    user would display it."""
    parts = [_frame_metrics(jnp.clip(jnp.asarray(sr[i:i + chunk]), 0, 1), jnp.asarray(gt[i:i + chunk]))
             for i in range(0, len(gt), chunk)]
    return Scores(*(np.concatenate([np.asarray(part[k]) for part in parts]) for k in range(3)))


def frame_scores(sr, gt, *, chunk: int = 50) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame PSNR (dB) and windowed SSIM, each (T,), of sr against gt (T, H, W), as `frame_metrics`."""
    scores = frame_metrics(sr, gt, chunk=chunk)
    return scores.psnr, scores.ssim_window


# Frames per bootstrap block: consecutive frames of a video score alike (the scene changes slowly, the noise does
# not), so intervals resample runs of frames (jaxsr.paired_interval)
BLOCK = 10


def interval(a, b, seed: int = 0):
    """Mean score difference a - b (per-frame scores, (T,) or (scenes, T)) with its 95 % block-bootstrap
    interval."""
    return jaxsr.paired_interval(jax.random.key(seed), a, b, block=min(BLOCK, np.shape(a)[-1]))


def format_interval(iv) -> str:
    """'+0.13 [+0.05, +0.20]': an interval's mean and bounds, in dB."""
    return f"{float(iv.mean):+.2f} [{float(iv.low):+.2f}, {float(iv.high):+.2f}]"


def score(sr, gt, *, chunk: int = 50) -> tuple[float, float]:
    """Mean PSNR (dB) and windowed SSIM over frames (see `frame_scores`)."""
    p, s = frame_scores(sr, gt, chunk=chunk)
    return float(np.mean(p)), float(np.mean(s))


def frames_per_second(fn, n_frames: int, *, min_time: float = 3.0) -> float:
    """Frames/s of `fn()` (which processes n_frames frames and returns NumPy), after one warm-up call."""
    fn()
    done, start = 0, time.perf_counter()
    while True:
        fn()
        done += n_frames
        elapsed = time.perf_counter() - start
        if elapsed >= min_time:
            return done / elapsed


def model_fps(model, clip: Clip, *, batch_size=None, frames: int = 32, histograms: bool = True,
              min_time: float = 3.0, precision: str = "default", form: str = "model") -> float:
    """End-to-end frames/s of a model on this machine: histograms -> centre of mass -> network (or from the
    centre-of-mass frames with histograms=False). batch_size None: the default, one frame per device. precision,
    form: as `super_resolve`'s, form "model" by default (the form the model's config names)."""
    kw = {"batch_size": batch_size, "precision": precision, "form": form}
    if histograms:
        counts = clip.counts[:frames]
        fn = lambda: super_resolve_histograms(model, counts, **kw)  # noqa: E731
    else:
        lr = clip.lr[:frames]
        fn = lambda: super_resolve(model, lr, **kw)  # noqa: E731
    return frames_per_second(fn, frames, min_time=min_time)


@jax.jit
def _com_bicubic(counts, sensor):
    return jaxsr.bicubic(jaxsr.centre_of_mass(counts, sensor), scale=sensor.scale)


def bicubic_fps(clip: Clip, *, sensor: Sensor = Sensor(), frames: int = 32, min_time: float = 3.0):
    """End-to-end frames/s of the bicubic baseline: histograms -> centre of mass -> bicubic, `frames` at once."""
    counts = jnp.asarray(clip.counts[:frames])
    return frames_per_second(lambda: np.asarray(_com_bicubic(counts, sensor)), frames, min_time=min_time)


def quick_config() -> TrainConfig:
    """The `--quick` smoke run: 2 steps of 2 examples, validation on 2 frames."""
    return dataclasses.replace(PRESETS["cpu"], batch_size=2, examples_per_epoch=4, epochs=1, val_frames=2)


def get_model(tr: int, *, pretrained: bool, preset: str, runs: Path, scale: int = 4, quick: bool = False,
              progress: bool = True):
    """The bundled weights (`pretrained`), or a model trained with `preset` into runs/x{scale}/tr{tr}
    (resumed when interrupted; a finished run is loaded, not retrained). Returns (Model, card dict)."""
    if pretrained:
        if scale != 4:
            raise SystemExit("bundled weights are x4 only; train x8 models with --train")
        model = jaxsr.load_model(f"tr{tr}")
        return model, jaxsr.read_metadata(Path(jaxsr.__file__).parent / "weights" / f"tr{tr}.npz").get("card", {})
    sensor = Sensor(optics=Optics.of_hr(Sensor().hr_shape, scale))  # the paper's HR frame at this scale
    cfg = ModelConfig(tr=tr, scale=scale)
    out = runs / ("quick" if quick else preset) / f"x{scale}" / f"tr{tr}"
    make_batch = None
    train_cfg = PRESETS[preset]
    if quick:  # no scene rendering inside the step (its compilation alone takes a minute)
        train_cfg = quick_config()
        seq = scenes.test_sequence("val1_street", n_frames=2 * tr + 3, sensor=sensor)
        make_batch = sequence_batches(seq.depth, seq.intensity, tr, train_cfg, sensor=sensor)
    model, history = jaxsr.fit(cfg, resume_config(out, train_cfg), out=out, make_batch=make_batch, sensor=sensor,
                               resume=True, progress=progress)
    card = jaxsr.read_metadata(out / "last.npz").get("card", {})
    return model, card


def add_model_args(parser, *, trs) -> None:
    """--trs and --weights, shared by the scripts that score trained models (see `load_tr`)."""
    parser.add_argument("--trs", type=int, nargs="+", default=list(trs),
                        help=f"temporal radii (default {' '.join(map(str, trs))})")
    parser.add_argument("--weights", default=None,
                        help="folder of trained models, tr<N>.npz or tr<N>/best.npz (default: bundled weights)")


def load_tr(tr: int, weights=None):
    """TR`tr`'s model: the bundled weights (weights=None), or from a folder holding tr<N>.npz or
    tr<N>/best.npz (e.g. a run folder of experiments/sweep_tr.py such as runs/sweep_tr/cpu/x4)."""
    if weights is None:
        return jaxsr.load_model(f"tr{tr}")
    folder = Path(weights)
    for path in (folder / f"tr{tr}.npz", folder / f"tr{tr}" / "best.npz"):
        if path.is_file():
            return jaxsr.load_model(path)
    raise SystemExit(f"no TR{tr} weights in {folder} (expected tr{tr}.npz or tr{tr}/best.npz)")


def bundled(name: str) -> Path | None:
    """The file of the bundled weights `name` (e.g. "tr4-seq"), or None where they are not bundled."""
    try:
        return resolve_model_path(name)
    except FileNotFoundError:
        return None


def weights_source(weights) -> str:
    """Where a script's models came from (its --weights), for its results text."""
    return "the bundled weights (jaxsr/weights)" if weights is None else f"the weights in {weights}"
