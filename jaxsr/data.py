"""Training data: the sources that feed the train step, and the fixed validation set.

A data source is a pure function `make_batch(key) -> (windows (B, 2tr+1, h, w), gt (B, h*r, w*r))`: LR
normalised-depth windows (centre frame at index tr) and the HR normalised depth of their centre frames, both
in [0, 1] (1 = no return). It is traced inside the jitted train step, so the examples are simulated on the
device and never stored. A source may carry a `description` attribute (a string) that the training card
records. The sources:

- `scene_batches`: random procedural clips (`jaxsr.scenes.training_clip`), the default;
- `sequence_batches`: windows drawn from HR depth/intensity sequences held in memory (e.g. AirSim recordings).

Both draw a frame SNR and a mean signal log-uniformly per example, simulate photon histograms over the whole
clip (`simulate_histograms`), extract centre-of-mass depth and optionally crop a random LR patch
(`random_crop`). `validation_set` builds the fixed validation windows from the named validation sequences.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .config import SensorConfig, TrainConfig
from .peaks import centre_of_mass
from .scenes import test_sequences, training_clip
from .sensor import normalise_depth, simulate_histograms
from .temporal import windows as temporal_windows

__all__ = ["log_uniform", "random_crop", "scene_batches", "sequence_batches", "validation_set"]


def log_uniform(key, lo: float, hi: float, shape=()):
    """Samples log-uniform in [lo, hi] (lo == hi gives the constant)."""
    u = jax.random.uniform(key, shape)
    return jnp.exp(jnp.log(lo) + u * (jnp.log(hi) - jnp.log(lo)))


def random_crop(key, windows, gt, patch: tuple[int, int] | None, scale: int):
    """A random LR crop of one example: windows (T, h, w) -> (T, ph, pw) and gt (h*r, w*r) -> (ph*r, pw*r),
    aligned (LR pixel (y, x) covers HR pixels r*y .. r*y + r - 1). `patch` None returns the inputs."""
    if patch is None:
        return windows, gt
    ph, pw = patch
    t, h, w = windows.shape
    if ph > h or pw > w:
        raise ValueError(f"random_crop: patch {patch} is larger than the LR frame {(h, w)}")
    ky, kx = jax.random.split(key)
    y0 = jax.random.randint(ky, (), 0, h - ph + 1)
    x0 = jax.random.randint(kx, (), 0, w - pw + 1)
    windows = jax.lax.dynamic_slice(windows, (0, y0, x0), (t, ph, pw))
    gt = jax.lax.dynamic_slice(gt, (y0 * scale, x0 * scale), (ph * scale, pw * scale))
    return windows, gt


def _simulate_example(key, depth, intensity, tr: int, train_cfg: TrainConfig, sensor: SensorConfig):
    """(2tr+1, H, W) HR radial depth + intensity -> (LR window (2tr+1, h, w), GT of the centre (H, W))."""
    k_snr, k_sig, k_noise, k_crop = jax.random.split(key, 4)
    snr = log_uniform(k_snr, *train_cfg.snr_range)
    mean_signal = log_uniform(k_sig, *train_cfg.mean_signal_range)
    # Calibration over the whole clip: the laser and the sun do not change from frame to frame.
    counts = simulate_histograms(k_noise, depth, intensity, sensor, snr=snr, mean_signal=mean_signal)
    window = centre_of_mass(counts, sensor)
    gt = normalise_depth(depth[tr], sensor)
    return random_crop(k_crop, window, gt, train_cfg.patch, sensor.scale)


def scene_batches(tr: int, train_cfg: TrainConfig, *, sensor: SensorConfig = SensorConfig()):
    """The default data source: `make_batch(key)` rendering `batch_size` random scenes.

    Per example: `jaxsr.scenes.training_clip` (2tr+1 frames, motion log-uniform in `motion_range`) -> SNR and
    mean signal log-uniform in the config's ranges -> `simulate_histograms` -> `centre_of_mass` -> the
    LR window; GT = `normalise_depth` of the centre frame; then an optional random crop (`patch`).
    Returns make_batch: key -> (windows (B, 2tr+1, h, w), gt (B, h*r, w*r)).
    """
    def example(key):
        k_scene, k_rest = jax.random.split(key)
        depth, intensity = training_clip(k_scene, 2 * tr + 1, sensor=sensor, shift_range=train_cfg.motion_range)
        return _simulate_example(k_rest, depth, intensity, tr, train_cfg, sensor)

    def make_batch(key):
        return jax.vmap(example)(jax.random.split(key, train_cfg.batch_size))

    make_batch.description = "jaxsr.scenes.training_clip -> simulate_histograms -> centre_of_mass"
    return make_batch


def sequence_batches(depth, intensity, tr: int, train_cfg: TrainConfig, *, sensor: SensorConfig = SensorConfig()):
    """A data source drawing windows from HR sequences held in memory (e.g. AirSim recordings read from files).

    depth: (N, T, H, W) or (T, H, W) radial metres (inf/NaN/beyond d_max = no return); intensity: the same
    shape in [0, 1]; (H, W) = sensor.hr_shape and T >= 2tr+1. Per example: a random sequence and start
    frame, then the same simulation as `scene_batches`. Returns make_batch: key -> (windows, gt).
    """
    depth = jnp.asarray(depth, jnp.float32)
    intensity = jnp.asarray(intensity, jnp.float32)
    if depth.ndim == 3:
        depth, intensity = depth[None], intensity[None]
    if depth.ndim != 4 or depth.shape != intensity.shape or depth.shape[-2:] != tuple(sensor.hr_shape):
        raise ValueError(
            f"sequence_batches: expected depth and intensity of equal shape (N, T, {sensor.hr_shape[0]}, "
            f"{sensor.hr_shape[1]}), got {depth.shape} and {intensity.shape}"
        )
    n, t = depth.shape[:2]
    frames = 2 * tr + 1
    if t < frames:
        raise ValueError(f"sequence_batches: sequences have {t} frames, fewer than the window 2*tr+1 = {frames}")

    def example(key):
        k_seq, k_start, k_rest = jax.random.split(key, 3)
        i = jax.random.randint(k_seq, (), 0, n)
        s = jax.random.randint(k_start, (), 0, t - frames + 1)
        d = jax.lax.dynamic_slice(depth[i], (s, 0, 0), (frames, *depth.shape[2:]))
        a = jax.lax.dynamic_slice(intensity[i], (s, 0, 0), (frames, *depth.shape[2:]))
        return _simulate_example(k_rest, d, a, tr, train_cfg, sensor)

    def make_batch(key):
        return jax.vmap(example)(jax.random.split(key, train_cfg.batch_size))

    make_batch.description = f"{n} HR sequence(s) of {t} frames -> simulate_histograms -> centre_of_mass"
    return make_batch


def _field(seq, name):
    return seq[name] if isinstance(seq, dict) else getattr(seq, name)


def validation_set(key, tr: int, train_cfg: TrainConfig, *, sensor: SensorConfig = SensorConfig(), sequences=None):
    """Fixed validation windows: the first `val_frames` frames of each named sequence at its own SNR.

    sequences: {name: seq with fields depth, intensity (T, H, W) and snr}; default
    `jaxsr.scenes.test_sequences(n_frames=train_cfg.val_frames)` restricted to `train_cfg.val_sequences`.
    Returns {"windows": (N, 2tr+1, h, w), "gt": (N, H, W), "lr": (N, h, w) centre frames, "names": [...]}.
    """
    if sequences is None:
        sequences = test_sequences(n_frames=train_cfg.val_frames, names=train_cfg.val_sequences or None, sensor=sensor)
    names = list(train_cfg.val_sequences) or sorted(sequences)
    windows, gts, lrs = [], [], []
    for i, name in enumerate(names):
        seq = sequences[name]
        depth = jnp.asarray(_field(seq, "depth"))[: train_cfg.val_frames]
        intensity = jnp.asarray(_field(seq, "intensity"))[: train_cfg.val_frames]
        counts = simulate_histograms(
            jax.random.fold_in(key, i), depth, intensity, sensor,
            snr=float(_field(seq, "snr")), mean_signal=train_cfg.val_mean_signal,
        )
        lr = centre_of_mass(counts, sensor)
        windows.append(temporal_windows(lr, tr))
        gts.append(normalise_depth(depth, sensor))
        lrs.append(lr)
    return {"windows": jnp.concatenate(windows), "gt": jnp.concatenate(gts), "lr": jnp.concatenate(lrs), "names": names}
