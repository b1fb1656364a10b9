"""Training data: the sources that feed the train step, and the fixed validation set.

A data source is a pure function `make_batch(key) -> (windows (B, 2tr+1, h, w), gt (B, h*r, w*r))`: LR
normalised-depth windows (centre frame at index tr) and the HR normalised depth of their centre frames, both
in [0, 1] (1 = no return). It is traced inside the jitted train step, so the examples are simulated on the
device and never stored. A source may carry a `description` attribute (a string) that the training card
records. The sources:

- `scene_batches`: random procedural clips (`jaxsr.scenes.training_clip`), the default;
- `sequence_batches`: windows drawn from HR depth/intensity sequences held in memory (e.g. AirSim recordings);
- `scene_clips` and `sequence_clips`: the same, as whole clips of L frames with the ground truth of every frame,
  `make_batch(key) -> (clips (B, L, h, w), gt (B, L, h*r, w*r))`, for the sequence form of the network;
- `regime_batches` and `regime_clips`: random procedural clips under a `jaxsr.config.PhotonRegime` (photons
  0.5-1000, SNR 0.05-20, IRF width, dark counts, hot and dead pixels, no-return regions, all drawn per clip).

Both draw a frame SNR and a mean signal log-uniformly per example, calibrate the sensor over the whole clip,
simulate photon histograms (`simulate_histograms`) and extract centre-of-mass depth; with a `patch`, the photons
are drawn for a random LR patch only (the distribution of a `random_crop` of the whole clip's, for less work).
`validation_set` builds the fixed validation windows from the named validation sequences.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

import json

from ..config import PAPER_REGIME, PhotonRegime, Sensor, TrainConfig
from ..sensor.effects import dark_counts, dead_pixels, hot_pixels, no_return_regions, thin_returns, with_irf_sigma
from ..nn.inputs import network_inputs
from ..sensor.poisson import sample_poisson
from ..scenes import test_sequences, training_clip
from ..sensor.forward import calibrate, calibrated_rates, normalise_depth, simulate_histograms
from ..temporal import windows as temporal_windows

__all__ = [
    "draw_batches",
    "log_uniform",
    "run_keys",
    "random_crop",
    "regime_batches",
    "regime_clips",
    "regime_draws",
    "regime_parameters",
    "scene_batches",
    "scene_clips",
    "sequence_batches",
    "sequence_clips",
    "validation_set",
]

_SCENES = "jaxsr.scenes.training_clip -> simulate_histograms -> centre_of_mass"  # the default data, described
_SENSOR = Sensor()  # the default sensor


def run_keys(seed: int):
    """The keys `fit` derives from `TrainConfig.seed`: (initial weights, training data, validation noise); scripts
    that reproduce a run's start (e.g. its validation frames or a grown network's added blocks) use these."""
    root = jax.random.key(seed)
    return tuple(jax.random.fold_in(root, i) for i in range(3))


def draw_batches(make_batch, key, steps):
    """The batches of train steps `steps` (int array (n,)) of a run drawing its data with `key`, in one jitted,
    vmapped call: what `make_batch(fold_in(key, s))` gives inside the train step of step s (as `fit` draws them),
    stacked: (inputs (n, B, ...), gt (n, B, ...)). For a train step fed batches drawn ahead of it
    (`make_train_step` with make_batch None): the data path then runs as one call per n steps, apart from the
    network's."""
    return _draw_batches(make_batch, key, jnp.asarray(steps, jnp.int32))


@functools.partial(jax.jit, static_argnums=0)
def _draw_batches(make_batch, key, steps):
    return jax.vmap(lambda s: make_batch(jax.random.fold_in(key, s)))(steps)


def log_uniform(key, lo: float, hi: float, shape=()):
    """Samples log-uniform in [lo, hi] (lo == hi gives the constant)."""
    u = jax.random.uniform(key, shape)
    return jnp.exp(jnp.log(lo) + u * (jnp.log(hi) - jnp.log(lo)))


def random_crop(key, windows, gt, patch: tuple[int, int] | None, scale: int):
    """A random LR crop of one example: windows (T, h, w) -> (T, ph, pw) and gt `(..., h*r, w*r)` ->
    `(..., ph*r, pw*r)` (one frame or several), aligned (LR pixel (y, x) covers HR pixels `r*y .. r*y + r - 1`).
    `patch` None returns the inputs."""
    if patch is None:
        return windows, gt
    t, h, w = windows.shape
    ph, pw = patch
    y0, x0 = _crop_origin(key, (h, w), patch, "random_crop")
    windows = jax.lax.dynamic_slice(windows, (0, y0, x0), (t, ph, pw))
    lead = gt.shape[:-2]
    gt = jax.lax.dynamic_slice(gt, (0,) * len(lead) + (y0 * scale, x0 * scale), (*lead, ph * scale, pw * scale))
    return windows, gt


def _crop_origin(key, shape: tuple[int, int], patch: tuple[int, int], who: str):
    """The top-left LR pixel (y0, x0) of a uniformly random `patch` (rows, cols) inside an LR frame `shape`."""
    (ph, pw), (h, w) = patch, shape
    if ph > h or pw > w:
        raise ValueError(f"{who}: patch {tuple(patch)} is larger than the LR frame {(h, w)}")
    ky, kx = jax.random.split(key)
    return jax.random.randint(ky, (), 0, h - ph + 1), jax.random.randint(kx, (), 0, w - pw + 1)


def _simulate_clip(key, depth, intensity, train_cfg: TrainConfig, sensor: Sensor, inputs=("depth",)):
    """(T, H, W) HR radial depth + intensity -> (LR clip (T, h, w) (or (T, h, w, C) for more `inputs`), GT of
    every frame (T, H, W)), cropped."""
    k_snr, k_sig, k_noise, k_crop = jax.random.split(key, 4)
    snr = log_uniform(k_snr, *train_cfg.snr_range)
    mean_signal = log_uniform(k_sig, *train_cfg.mean_signal_range)
    gt = normalise_depth(depth, sensor)
    if train_cfg.patch is None:
        # Calibration over the whole clip: the laser and the sun do not change from frame to frame.
        counts = simulate_histograms(k_noise, depth, intensity, sensor, snr=snr, mean_signal=mean_signal)
        return network_inputs(counts, sensor, inputs), gt
    # The same calibration over the whole clip, but photons drawn for the kept patch only: each LR pixel's
    # histogram depends on its own HR block alone, so the crop's counts have the same distribution as the
    # crop of the whole clip's, at a quarter of the cost with the cpu preset's patch (16 x 32 of 32 x 64).
    alpha, beta = calibrate(depth, intensity, sensor, snr=snr, mean_signal=mean_signal)
    (ph, pw), r, t = train_cfg.patch, sensor.scale, depth.shape[0]
    y0, x0 = _crop_origin(k_crop, (depth.shape[1] // r, depth.shape[2] // r), train_cfg.patch, "random_crop")
    hr_window = functools.partial(jax.lax.dynamic_slice, start_indices=(0, y0 * r, x0 * r),
                                  slice_sizes=(t, ph * r, pw * r))
    rates = calibrated_rates(hr_window(depth), hr_window(intensity), alpha, beta, sensor)
    clip = network_inputs(sample_poisson(k_noise, rates), sensor, inputs)
    return clip, hr_window(gt)


def _centre_frames(make_clips, tr: int):
    """A window source from a clip source of 2tr+1 frames: the GT of the centre frame only (keyword arguments
    passed through to the clip source)."""
    def make_batch(key, **kw):
        windows, gt = make_clips(key, **kw)
        return windows, gt[:, tr]

    return make_batch


def scene_batches(tr: int, train_cfg: TrainConfig, *, sensor: Sensor = Sensor(), inputs=("depth",)):
    """The default data source: `make_batch(key)` rendering `batch_size` random scenes.

    Per example: `jaxsr.scenes.training_clip` (2tr+1 frames, motion log-uniform in `motion_range`) -> SNR and
    mean signal log-uniform in the config's ranges -> `simulate_histograms` -> `centre_of_mass` -> the
    LR window; GT = `normalise_depth` of the centre frame; then an optional random crop (`patch`).
    `inputs`: what the network reads (`ModelConfig.inputs`; more than depth adds a channel axis).
    Returns make_batch: key -> (windows (B, 2tr+1, h, w), gt `(B, h*r, w*r)`).
    """
    make_batch = _centre_frames(scene_clips(2 * tr + 1, train_cfg, sensor=sensor, inputs=inputs), tr)
    make_batch.description = _SCENES
    return make_batch


def scene_clips(frames: int, train_cfg: TrainConfig, *, sensor: Sensor = _SENSOR, inputs=("depth",)):
    """Rendered training clips for the sequence form: `make_batch(key)` with `batch_size` random scenes of
    `frames` frames each, simulated as in `scene_batches` (one SNR, mean signal and crop per clip).

    Returns make_batch: key -> (clips (B, frames, h, w) LR normalised depth, gt `(B, frames, h*r, w*r)`).
    """
    def example(key):
        k_scene, k_rest = jax.random.split(key)
        depth, intensity = training_clip(k_scene, frames, sensor=sensor, shift_range=train_cfg.motion_range)
        return _simulate_clip(k_rest, depth, intensity, train_cfg, sensor, inputs)

    def make_batch(key):
        return jax.vmap(example)(jax.random.split(key, train_cfg.batch_size))

    make_batch.description = _SCENES
    return make_batch


def regime_parameters(key, regime: PhotonRegime = PhotonRegime()):
    """One clip's draw from `regime` (see `PhotonRegime`): a dict of scalars `mean_signal` (photons per LR pixel
    with a return), `snr`, `irf_sigma` (bins), `dark` (photons per bin), `hot_fraction`, `hot_level` (extra
    photons of a hot pixel over all bins, times `mean_signal`), `dead_fraction`, `no_return_fraction`, `sky`
    (the weight of the sky band), `thin_lines` (thin returns across the no-return regions) and `static` (bool: a
    static scene, every frame the centre frame). An effect not
    drawn for the clip has fraction, rate or count 0; a clip of the paper's regime (`regime.paper_prob`) has the
    paper's signal, SNR and IRF and no effects. jit/vmap-able."""
    k = iter(jax.random.split(key, 14))

    def chance(p):
        return jax.random.uniform(next(k)) < p

    def uniform(lo, hi):
        return jax.random.uniform(next(k), minval=lo, maxval=hi)

    lo, hi = (jnp.log(v) for v in regime.irf_sigma_range)
    tail = jnp.exp(lo + (hi - lo) * jax.random.uniform(next(k)) ** regime.irf_power)
    mean_signal = log_uniform(next(k), *regime.signal_range)
    wide = dict(
        mean_signal=mean_signal,
        snr=log_uniform(next(k), *regime.snr_range),
        irf_sigma=jnp.where(chance(regime.irf_paper_prob), regime.irf_paper, tail),
        dark=jnp.where(chance(regime.dark_prob), log_uniform(next(k), *regime.dark_range), 0.0),
        hot_fraction=jnp.where(chance(regime.hot_prob), uniform(0.0, regime.hot_fraction_max), 0.0),
        hot_level=log_uniform(next(k), *regime.hot_level_range),
        dead_fraction=jnp.where(chance(regime.dead_prob), uniform(0.0, regime.dead_fraction_max), 0.0),
        no_return_fraction=jnp.where(chance(regime.no_return_prob), uniform(*regime.no_return_fraction), 0.0),
        sky=uniform(0.0, 1.0),
    )
    # drawn from keys of their own (as the paper's regime below), so that thin_prob = 0 leaves every draw as it was
    k_thin, k_lines = jax.random.split(jax.random.fold_in(key, 15))
    lines = jax.random.randint(k_lines, (), 1, regime.thin_lines_max + 1)
    wide["thin_lines"] = jnp.where((jax.random.uniform(k_thin) < regime.thin_prob)
                                   & (wide["no_return_fraction"] > 0), lines, 0)
    wide["static"] = jax.random.uniform(jax.random.fold_in(key, 16)) < regime.static_prob  # a key of its own too
    # the paper's regime, drawn from keys of its own so that paper_prob = 0 leaves every other draw as it was
    k_paper, k_sig, k_snr = jax.random.split(jax.random.fold_in(key, 14), 3)
    paper = dict(wide, mean_signal=log_uniform(k_sig, *PAPER_REGIME.signal_range),
                 snr=log_uniform(k_snr, *PAPER_REGIME.snr_range), irf_sigma=jnp.asarray(regime.irf_paper, jnp.float32),
                 dark=0.0, hot_fraction=0.0, dead_fraction=0.0, no_return_fraction=0.0, thin_lines=0,
                 static=jnp.asarray(False))
    is_paper = jax.random.uniform(k_paper) < regime.paper_prob
    return {name: jnp.where(is_paper, paper[name], wide[name]) for name in wide}


def _regime_description(regime: PhotonRegime, inputs=("depth",)):
    return (f"jaxsr.scenes.training_clip(motion={regime.motion!r}) -> PhotonRegime "
            f"{json.dumps(regime.to_dict(), sort_keys=True)} -> no_return_regions, thin_returns -> calibrated_rates "
            "(per-clip IRF) -> dark_counts, hot_pixels, dead_pixels -> sample_poisson -> "
            + ("centre_of_mass" if tuple(inputs) == ("depth",) else f"network_inputs{tuple(inputs)}"))


def regime_clips(frames: int, train_cfg: TrainConfig, regime: PhotonRegime = PhotonRegime(), *,
                 sensor: Sensor = _SENSOR, inputs=("depth",)):
    """Training clips spanning real sensors: `make_batch(key)` with `batch_size` random scenes of `frames` frames,
    every parameter of `regime` drawn per clip (`regime_parameters`).

    Per clip: `jaxsr.scenes.training_clip` (motion log-uniform in `train_cfg.motion_range`, `regime.motion`; its
    centre frame in every frame for a static clip) -> `no_return_regions` on the HR depth, crossed by `thin_returns`
    -> calibration over the whole clip to the drawn SNR and photon level with the drawn IRF width (`with_irf_sigma`)
    -> rates of the kept crop (`train_cfg.patch`) -> `dark_counts`, `hot_pixels`, `dead_pixels` (one mask per clip) ->
    Poisson draw -> `centre_of_mass` with `sensor` (the nominal IRF's window, as a recording is read at inference).
    GT = `normalise_depth` of the depth with its no-return regions: 1.0 there. `train_cfg.snr_range` and
    `mean_signal_range` are not used. `inputs`: what the network reads (`jaxsr.nn.inputs.network_inputs`; more than
    depth adds a last axis of channels).
    Returns make_batch: (key, snr=None) -> (clips (B, frames, h, w) LR normalised depth, gt
    `(B, frames, h*r, w*r)`), with `description` (the regime as JSON) and `regime` (`regime.to_dict()`). `snr`, a
    scalar that may be traced, replaces every clip's drawn frame SNR (the other draws unchanged): one compiled
    source serves a grid of SNRs (`regime_validation`).
    """
    r, bins = sensor.scale, sensor.bins

    def example(key, snr):
        k_scene, k_par, k_sky, k_hot, k_dead, k_noise, k_crop = _regime_example_keys(key)
        depth, intensity = training_clip(k_scene, frames, sensor=sensor, shift_range=train_cfg.motion_range,
                                         motion=regime.motion)
        p = regime_parameters(k_par, regime)
        if regime.static_prob > 0:  # a static scene: the centre frame in every frame, only the photons differ
            depth, intensity = (jnp.where(p["static"], jnp.broadcast_to(x[frames // 2], x.shape), x)
                                for x in (depth, intensity))
        if snr is not None:  # rounded as log_uniform rounds lo == hi: the draws of a regime held at that SNR
            p = dict(p, snr=jnp.exp(jnp.log(jnp.asarray(snr, jnp.float32))))
        depth = _regime_no_return(k_sky, depth, p, regime)
        gt = normalise_depth(depth, sensor)
        clip_sensor = with_irf_sigma(sensor, p["irf_sigma"])
        alpha, beta = calibrate(depth, intensity, clip_sensor, snr=p["snr"], mean_signal=p["mean_signal"])
        if train_cfg.patch is not None:
            (ph, pw), t = train_cfg.patch, depth.shape[0]
            y0, x0 = _crop_origin(k_crop, (depth.shape[1] // r, depth.shape[2] // r), train_cfg.patch,
                                  "regime_clips")
            hr_window = functools.partial(jax.lax.dynamic_slice, start_indices=(0, y0 * r, x0 * r),
                                          slice_sizes=(t, ph * r, pw * r))
            depth, intensity, gt = hr_window(depth), hr_window(intensity), hr_window(gt)
        rates = calibrated_rates(depth, intensity, alpha, beta, clip_sensor)
        rates = dark_counts(rates, rate_per_bin=p["dark"])
        rates = hot_pixels(k_hot, rates, fraction=p["hot_fraction"], rate=p["hot_level"] * p["mean_signal"] / bins)
        rates = dead_pixels(k_dead, rates, fraction=p["dead_fraction"])
        return network_inputs(sample_poisson(k_noise, rates), sensor, inputs), gt

    def make_batch(key, snr=None):
        return jax.vmap(functools.partial(example, snr=snr))(jax.random.split(key, train_cfg.batch_size))

    make_batch.description = _regime_description(regime, inputs)
    make_batch.regime = regime.to_dict()
    return make_batch


def _regime_no_return(key, depth, p: dict, regime: PhotonRegime):
    """A clip's HR depth (..., H, W) with its drawn no-return regions (`no_return_regions` at `p`'s fraction and
    sky weight) crossed by its drawn thin returns (`thin_returns`, `p["thin_lines"]` of them, the scene's depth
    on them): `regime_clips`' sky, from `regime_parameters`' draw `p`. jit/vmap-able."""
    holed = no_return_regions(key, depth, fraction=p["no_return_fraction"], sky=p["sky"], blob_size=regime.blob_size)
    if regime.thin_prob == 0:  # no line is ever drawn: spare every training step the lines' distance maps
        return holed
    thin = thin_returns(jax.random.fold_in(key, 1), jnp.shape(depth)[-2:], lines=p["thin_lines"],
                        width_range=regime.thin_width_range, max_lines=regime.thin_lines_max)
    return jnp.where(thin, depth, holed)


def _regime_example_keys(key):
    """One regime clip's keys: (scene, parameters, sky, hot, dead, noise, crop)."""
    return jax.random.split(key, 7)


def regime_draws(key, batch_size: int, regime: PhotonRegime = PhotonRegime()) -> dict:
    """The parameters each clip of a `regime_clips` or `regime_batches` batch of `batch_size` was drawn with:
    `make_batch(key)`'s clip i has `regime_parameters` entry [i] of `regime_draws(key, batch_size, regime)` (the
    same keys), a dict of (batch_size,) arrays (mean_signal, snr, ...). For grouping drawn clips by their
    photon level or SNR (`jaxsr.training.no_return_set`). jit/vmap-able."""
    def one(k):
        return regime_parameters(_regime_example_keys(k)[1], regime)

    return jax.vmap(one)(jax.random.split(key, batch_size))


def regime_batches(tr: int, train_cfg: TrainConfig, regime: PhotonRegime = PhotonRegime(), *,
                   sensor: Sensor = Sensor(), inputs=("depth",)):
    """`regime_clips` as windows: `make_batch(key) -> (windows (B, 2tr+1, h, w), gt (B, h*r, w*r))`, the ground
    truth of the centre frame (like `scene_batches`, with the photon regimes of `regime`). Carries `description`
    and `regime` for the training card."""
    clips = regime_clips(2 * tr + 1, train_cfg, regime, sensor=sensor, inputs=inputs)
    make_batch = _centre_frames(clips, tr)
    make_batch.description, make_batch.regime = clips.description, clips.regime
    return make_batch


def sequence_batches(depth, intensity, tr: int, train_cfg: TrainConfig, *, sensor: Sensor = Sensor()):
    """A data source drawing windows from HR sequences held in memory (e.g. AirSim recordings read from files).

    depth: (N, T, H, W) or (T, H, W) radial metres (inf/NaN/beyond d_max = no return); intensity: the same
    shape in [0, 1]; (H, W) = sensor.hr_shape and T >= 2tr+1. Per example: a random sequence and start
    frame, then the same simulation as `scene_batches`. Returns make_batch: key -> (windows, gt).
    """
    clips = _sequence_clips(depth, intensity, 2 * tr + 1, train_cfg, sensor, "sequence_batches", "the window 2*tr+1")
    make_batch = _centre_frames(clips, tr)
    make_batch.description = clips.description
    return make_batch


def sequence_clips(depth, intensity, frames: int, train_cfg: TrainConfig, *, sensor: Sensor = _SENSOR):
    """Training clips of `frames` frames drawn from HR sequences held in memory, for the sequence form.

    depth, intensity: as for `sequence_batches`, with T >= frames. Per example: a random sequence and start
    frame, then the same simulation as `scene_clips`. Returns make_batch: key -> (clips (B, frames, h, w),
    gt `(B, frames, h*r, w*r)`).
    """
    return _sequence_clips(depth, intensity, frames, train_cfg, sensor, "sequence_clips", "the clip")


def _sequence_clips(depth, intensity, frames: int, train_cfg: TrainConfig, sensor: Sensor, who: str,
                    what: str):
    """`sequence_clips`, with the caller's name and what `frames` is for its error messages."""
    depth = jnp.asarray(depth, jnp.float32)
    intensity = jnp.asarray(intensity, jnp.float32)
    if depth.ndim == 3:
        depth, intensity = depth[None], intensity[None]
    if depth.ndim != 4 or depth.shape != intensity.shape or depth.shape[-2:] != tuple(sensor.hr_shape):
        raise ValueError(
            f"{who}: expected depth and intensity of equal shape (N, T, {sensor.hr_shape[0]}, "
            f"{sensor.hr_shape[1]}), got {depth.shape} and {intensity.shape}"
        )
    n, t = depth.shape[:2]
    if t < frames:
        raise ValueError(f"{who}: sequences have {t} frames, fewer than {what} = {frames}")

    def example(key):
        k_seq, k_start, k_rest = jax.random.split(key, 3)
        i = jax.random.randint(k_seq, (), 0, n)
        s = jax.random.randint(k_start, (), 0, t - frames + 1)
        d = jax.lax.dynamic_slice(depth[i], (s, 0, 0), (frames, *depth.shape[2:]))
        a = jax.lax.dynamic_slice(intensity[i], (s, 0, 0), (frames, *depth.shape[2:]))
        return _simulate_clip(k_rest, d, a, train_cfg, sensor)

    def make_batch(key):
        return jax.vmap(example)(jax.random.split(key, train_cfg.batch_size))

    make_batch.description = f"{n} HR sequence(s) of {t} frames -> simulate_histograms -> centre_of_mass"
    return make_batch


def _field(seq, name):
    return seq[name] if isinstance(seq, dict) else getattr(seq, name)


def validation_set(key, tr: int, train_cfg: TrainConfig, *, sensor: Sensor = Sensor(), sequences=None,
                   inputs=("depth",)):
    """Fixed validation windows: the first `val_frames` frames of each named sequence at its own SNR.

    sequences: {name: seq with fields depth, intensity (T, H, W) and snr}; default
    `jaxsr.scenes.test_sequences(n_frames=train_cfg.val_frames)` restricted to `train_cfg.val_sequences`.
    `inputs`: what the network reads (`ModelConfig.inputs`; more than depth adds a last axis of channels).
    Returns {"windows": (N, 2tr+1, h, w), "gt": (N, H, W), "lr": (N, h, w) centre frames, "names": [...],
    "lengths": [frames of each sequence, in order]} (the sequence form validates on "lr" sequence by sequence).
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
        lr = network_inputs(counts, sensor, inputs)
        windows.append(temporal_windows(lr, tr))
        gts.append(normalise_depth(depth, sensor))
        lrs.append(lr)
    return {"windows": jnp.concatenate(windows), "gt": jnp.concatenate(gts), "lr": jnp.concatenate(lrs), "names": names,
            "lengths": [int(lr.shape[0]) for lr in lrs]}
