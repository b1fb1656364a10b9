"""Frozen configuration dataclasses shared by every stage of the pipeline: the network (`ModelConfig`) and its
training (`TrainConfig`, `PhotonRegime`, `PRESETS`). The sensor is described once in `jaxsr.spad` (`Sensor`,
its names importable from here too).
"""

from __future__ import annotations

import dataclasses
import math
import numbers

import jax

__all__ = ["DEFAULT_MEAN_SIGNAL", "TRAIN_MEAN_SIGNAL_RANGE", "TEMPORAL_FORMS", "PRECISIONS", "MODEL_INPUTS",
           "MODEL_LIMITS", "check_int_field", "ModelConfig", "DEFAULT_CLIP_OUTPUTS", "TrainConfig", "PhotonRegime",
           "PAPER_REGIME", "PRESETS",
           # the sensor's description lives in jaxsr.spad; its names stay importable from here
           "METRES_PER_SECOND", "MIN_LR_SIDE", "TRAINED_RANGE_M", "DepthScale", "Gate", "Optics", "Pulse", "Sensor",
           "SensorConfig"]

from .spad import (METRES_PER_SECOND, MIN_LR_SIDE, TRAINED_RANGE_M, DepthScale, Gate, Optics, Pulse, Sensor,
                   SensorConfig)

# Mean signal photons per LR pixel with a return (docs/sensor-model.md, section 2). The paper does not give it; this is
# the level at which bicubic upsampling of centre-of-mass depth on our three test scenes comes closest to the
# paper's bicubic row (RMS 1.2 dB; experiments/results/calibration.md).
DEFAULT_MEAN_SIGNAL = 14.0
# Training draws the photon level log-uniformly around it (half to double), so models meet brighter and
# darker scenes than the calibrated one.
TRAIN_MEAN_SIGNAL_RANGE = (DEFAULT_MEAN_SIGNAL / 2, DEFAULT_MEAN_SIGNAL * 2)


# The network's temporal forms (`ModelConfig.temporal`).
TEMPORAL_FORMS = ("window", "sequence")


# How the network's convolutions take their products (`jaxsr.nn.layers.conv3d`, `TrainConfig.precision`):
# "default" (the backend's own: float32 on CPU, TF32 for float32 operands on NVIDIA GPUs since Ampere), "float32"
# (full float32 products on every backend, the dynamic filter's sum included) or "bfloat16" (the convolutions'
# operands rounded to bfloat16 in the forward pass and both gradients, their sums float32: the fast path of GPUs'
# matrix units and of CPUs with AVX512-BF16). Weights, inputs, outputs and everything between the convolutions stay
# float32.
PRECISIONS = ("default", "float32", "bfloat16")

# What a network may read per LR pixel (`ModelConfig.inputs`): the centre-of-mass depth, always first (the dynamic
# filters upsample it), then optionally the photons behind it (`jaxsr.sensor.peak_evidence`, log-encoded by
# `jaxsr.nn.inputs`): "signal" (photons in the peak above the background), "background" (ambient photons, the
# median bin x K) and "ambient" (ambient photons from the mean of the bins outside the peak,
# `jaxsr.sensor.ambient_photons`, which unlike the median does not read 0 at a few photons per pixel).
MODEL_INPUTS = ("depth", "signal", "background", "ambient")
# Bounds of `ModelConfig` far beyond the paper's network (TR 0-4, x4 or x8, widths up to 512), so that no
# config (one read from a checkpoint above all) builds an absurd network: 3 + tr blocks of up to `width` channels.
# The baselines' configs (`jaxsr.baselines.HistNetConfig`, `RBPNConfig`) are bounded by the same table: "width" bounds
# every channel count, "tr" the temporal radius of an RBPN window (frames <= 2 tr + 1), "blocks" RBPN's residual
# blocks per module and the discriminator's convolutions, "flow_levels" and "flow_iterations" its optical flow's
# pyramid and Gauss-Newton steps, "bins" HistNet's first-peak half-width (in histogram bins).
MODEL_LIMITS = {"tr": 64, "scale": 16, "filter_size": 15, "same_blocks": 16, "width": 4096, "blocks": 64,
                "flow_levels": 8, "flow_iterations": 256, "bins": 4096}


def check_int_field(who: str, name: str, value, lo: int, hi: int, unit: str = "") -> None:
    """Raise ValueError unless `value` is an integer (not a bool) in lo..hi: a config field read from a file,
    bounded so that no config builds an absurd network (`MODEL_LIMITS`)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or not lo <= value <= hi:
        raise ValueError(f"{who}: {name} must be an integer {lo}..{hi}{unit}, got {value!r}")


@dataclasses.dataclass(frozen=True)
class ModelConfig:
    """The 3+TR-block dynamic-upsampling-filter network (docs/network.md). All fields are static.

    `tr` is the temporal radius: the network sees `2*tr+1` LR frames and has 3 + tr blocks. `scale` is the
    upsampling factor r (4, or 8 as in the paper's supplement). `base` (stem channels, 64), `growth` (channels
    added per block, 32), `head` (256), `filter_hidden` (512) and `filter_size` (5: 5x5 dynamic filters) are
    the paper's widths. `same_blocks` is the number of temporally padded blocks (3). BN uses the Keras
    defaults `bn_momentum` 0.99, `bn_eps` 1e-3. `filter_padding` is how the 5x5 neighbourhood of a border LR
    pixel is completed: "edge" (replicate; the default, a deviation from DUF's zero padding, because a zero
    means "depth 0", the nearest possible return) or "zero" (DUF). The config describes what the network
    computes and goes into checkpoints; how it runs (`conv3d_impl`) is an argument of `apply_model`.
    `temporal` is the form the network was trained in (docs/network.md): "window" (the paper: each
    output from its own window of `2*tr+1` frames, the first `same_blocks` blocks temporally padded) or
    "sequence" (every block temporally valid, run once over a whole edge-padded sequence: output t from frames
    t-R .. t+R, R = `input_radius` = same_blocks + tr). Both forms have the same parameters.
    `inputs` is what the network reads per LR pixel (`MODEL_INPUTS`): ("depth",) for the paper's networks
    (inputs (..., H, W)); with photon channels, ("depth", "signal", "background") say, inputs carry a last
    axis of that many channels, built from histograms by `jaxsr.nn.inputs.network_inputs`. `no_return_head`
    adds an output: per HR pixel the logit that it has no return, trained against the ground truth's 1.0;
    where it is above `no_return_logit` (0.0, p = 0.5, unless calibrated: `jaxsr.training.calibrate_no_return`)
    the output is 1.0 (no return), elsewhere the upsampled depth. `no_return_logit` is a decision threshold, not a
    weight: the training loss reads the raw logit, and a model without the head ignores it.
    """

    tr: int = 0
    scale: int = 4
    base: int = 64
    growth: int = 32
    head: int = 256
    filter_hidden: int = 512
    filter_size: int = 5
    same_blocks: int = 3
    bn_momentum: float = 0.99
    bn_eps: float = 1e-3
    filter_padding: str = "edge"
    temporal: str = "window"
    inputs: tuple = ("depth",)
    no_return_head: bool = False
    no_return_logit: float = 0.0

    def __post_init__(self):
        # upper limits too: a config read from a file builds its templates block by block, and a tr of 10^5
        # (a damaged or hostile checkpoint) would take minutes and gigabytes before any shape is checked
        check_int_field("ModelConfig", "tr", self.tr, 0, MODEL_LIMITS["tr"])
        check_int_field("ModelConfig", "scale", self.scale, 1, MODEL_LIMITS["scale"])
        check_int_field("ModelConfig", "filter_size", self.filter_size, 1, MODEL_LIMITS["filter_size"])
        if self.filter_size % 2 == 0:
            raise ValueError(f"ModelConfig: filter_size must be odd and 1..{MODEL_LIMITS['filter_size']}, got "
                             f"{self.filter_size}")
        check_int_field("ModelConfig", "same_blocks", self.same_blocks, 0, MODEL_LIMITS["same_blocks"])
        for name in ("base", "growth", "head", "filter_hidden"):
            check_int_field("ModelConfig", name, getattr(self, name), 1, MODEL_LIMITS["width"], " channels")
        # batch norm divides by sqrt(var + eps) and blends its averages by the momentum: an eps <= 0 or a momentum
        # outside [0, 1) makes a network that computes NaN or forgets nothing it saw
        for name, lo, hi, closed in (("bn_eps", 0.0, 1.0, False), ("bn_momentum", 0.0, 1.0, True)):
            value = getattr(self, name)
            ok = (not isinstance(value, bool) and isinstance(value, numbers.Real) and math.isfinite(float(value))
                  and (lo <= float(value) if closed else lo < float(value)) and float(value) < hi)
            if not ok:
                raise ValueError(f"ModelConfig: {name} must be a number in {'[' if closed else '('}{lo:g}, {hi:g}), "
                                 f"got {value!r}")
        if self.filter_padding not in ("edge", "zero"):
            raise ValueError(f"ModelConfig: filter_padding must be 'edge' or 'zero', got {self.filter_padding!r}")
        if self.temporal not in TEMPORAL_FORMS:
            raise ValueError(f"ModelConfig: temporal must be one of {TEMPORAL_FORMS}, got {self.temporal!r}")
        inputs = tuple(self.inputs) if isinstance(self.inputs, (list, tuple)) else None
        if (not inputs or inputs[0] != "depth" or len(set(inputs)) != len(inputs)
                or not set(inputs) <= set(MODEL_INPUTS)):
            raise ValueError(f"ModelConfig: inputs must be 'depth' followed by distinct names of {MODEL_INPUTS}, got "
                             f"{self.inputs!r}")
        object.__setattr__(self, "inputs", inputs)  # a list (from JSON) hashes as the tuple it means
        if not isinstance(self.no_return_head, bool):
            raise ValueError(f"ModelConfig: no_return_head must be True or False, got {self.no_return_head!r}")
        logit = self.no_return_logit
        if isinstance(logit, bool) or not isinstance(logit, numbers.Real) or not abs(float(logit)) < float("inf"):
            raise ValueError(f"ModelConfig: no_return_logit must be a finite number (a logit), got {logit!r}")
        object.__setattr__(self, "no_return_logit", float(logit))  # 0 from JSON hashes and prints as 0.0

    @property
    def channels(self) -> int:
        """Input channels per LR pixel, len(inputs)."""
        return len(self.inputs)

    @property
    def frames(self) -> int:
        """Input window length `2*tr + 1`."""
        return 2 * self.tr + 1

    @property
    def input_radius(self) -> int:
        """R: output frame t depends on input frames t-R .. t+R; tr (window form) or same_blocks + tr (sequence
        form, also the stream's latency in frames)."""
        return self.tr if self.temporal == "window" else self.same_blocks + self.tr

    @property
    def features(self) -> int:
        """Channels entering the head: base + growth * (same_blocks + tr)."""
        return self.base + self.growth * (self.same_blocks + self.tr)


jax.tree_util.register_dataclass(
    ModelConfig, data_fields=[], meta_fields=[f.name for f in dataclasses.fields(ModelConfig)]
)


# Outputs per training clip of the sequence form when `TrainConfig.clip_frames` is None (L = 2R + this). The TR4
# train step (batch 2, 16 x 32 LR patches, 2 busy CPU cores) trained 2.2 output frames/s at 1 output per clip
# (the windowed step: 2.3), 4.3 at 8 (L = 22) and 4.1 at 16 (L = 30): longer clips stop paying at about 8
# (benchmarks/bench_train.py::test_train_step_sequence_tr4).
DEFAULT_CLIP_OUTPUTS = 8


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Everything that affects a training run's result (docs/training.md); it goes into the checkpoint.

    Optimisation: Huber loss with `huber_delta` (a model with a no-return head adds `no_return_weight` x the
    mean binary cross-entropy of its no-return logits against the ground truth's 1.0); hand-written Adam (`lr`, `adam_b1`, `adam_b2`, `adam_eps`,
    Keras's epsilon placement and default 1e-7); step decay of the rate by `lr_decay` every `decay_epochs`
    epochs, exactly at epoch boundaries. `batch_size` examples per step, `examples_per_epoch` examples per
    epoch (steps per epoch = examples_per_epoch // batch_size), at most `epochs` epochs, early stopping after
    `patience` epochs without a lower validation loss (the best weights are kept).
    Data: frame SNR log-uniform in `snr_range`; mean signal photons per LR pixel log-uniform in
    `mean_signal_range` (half to double the calibrated `DEFAULT_MEAN_SIGNAL` by default); mean scene motion
    log-uniform in `motion_range` LR pixels per frame (`jaxsr.scenes.training_clip`). `patch` = (rows, cols) of a
    random LR crop to train on (None: whole frames; the network is fully convolutional, crops only cut compute).
    Validation: the first `val_frames` frames of each sequence in `val_sequences` of
    `jaxsr.scenes.test_sequences` (by default three static-camera validation sequences, a street, a road and a
    courtyard like the test scenes but distinct from them), at each sequence's own SNR, with `val_mean_signal`.
    `seed` fixes everything random (data, initial weights, validation noise).
    `clip_frames`: LR frames per training clip of a sequence-form model (`ModelConfig(temporal="sequence")`),
    at least 2R + 1 (R = 3 + tr); the loss covers the clip's L - 2R frames whose inputs all lie inside it. None:
    2R + `DEFAULT_CLIP_OUTPUTS`. Window-form training ignores it.
    `precision`: how the network's convolutions multiply in training (`PRECISIONS`; "default": the backend's).
    """

    batch_size: int = 4
    examples_per_epoch: int = 15500
    epochs: int = 100
    patience: int = 5
    lr: float = 1e-3
    lr_decay: float = 0.1
    decay_epochs: int = 10
    huber_delta: float = 0.01
    no_return_weight: float = 0.01
    adam_b1: float = 0.9
    adam_b2: float = 0.999
    adam_eps: float = 1e-7
    snr_range: tuple[float, float] = (0.5, 8.0)
    mean_signal_range: tuple[float, float] = TRAIN_MEAN_SIGNAL_RANGE
    motion_range: tuple[float, float] = (0.2, 5.0)
    patch: tuple[int, int] | None = None
    val_frames: int = 500
    # val1_street and val3_courtyard before 2026-11-24 (their moving cameras leave the scene within 500 frames)
    val_sequences: tuple[str, ...] = ("val4_street", "val2_road", "val5_courtyard")
    val_mean_signal: float = DEFAULT_MEAN_SIGNAL
    seed: int = 0
    clip_frames: int | None = None
    precision: str = "default"

    def __post_init__(self):
        if self.batch_size < 1 or self.examples_per_epoch < self.batch_size:
            raise ValueError(
                f"TrainConfig: need batch_size >= 1 and examples_per_epoch >= batch_size, got "
                f"{self.batch_size} and {self.examples_per_epoch}"
            )
        if self.epochs < 1 or self.patience < 1 or self.decay_epochs < 1:
            raise ValueError("TrainConfig: epochs, patience and decay_epochs must be >= 1")
        if not self.no_return_weight >= 0:
            raise ValueError(f"TrainConfig: no_return_weight must be >= 0, got {self.no_return_weight}")
        if not (0 < self.snr_range[0] <= self.snr_range[1]):
            raise ValueError(f"TrainConfig: snr_range must be 0 < lo <= hi, got {self.snr_range}")
        if not (0 < self.mean_signal_range[0] <= self.mean_signal_range[1]):
            raise ValueError(f"TrainConfig: mean_signal_range must be 0 < lo <= hi, got {self.mean_signal_range}")
        if self.precision not in PRECISIONS:
            raise ValueError(f"TrainConfig: precision must be one of {', '.join(map(repr, PRECISIONS))}, "
                             f"got {self.precision!r}")

    def clip_length(self, model: ModelConfig) -> int:
        """L, the frames per training clip of `model` in the sequence form (`clip_frames` or its default);
        raises ValueError if it is shorter than 2R + 1."""
        r = model.same_blocks + model.tr
        frames = 2 * r + DEFAULT_CLIP_OUTPUTS if self.clip_frames is None else self.clip_frames
        if frames < 2 * r + 1:
            raise ValueError(f"TrainConfig: clip_frames must be at least 2R + 1 = {2 * r + 1} for tr={model.tr} "
                             f"(R = {r}), got {frames}")
        return frames

    @property
    def steps_per_epoch(self) -> int:
        """Optimiser steps per epoch."""
        return self.examples_per_epoch // self.batch_size


# the bounds of `PhotonRegime`'s photon levels: mean signal photons per LR pixel, frame SNR
REGIME_LIMITS = {"signal_range": (1e-3, 1e6), "snr_range": (1e-3, 1e4)}


def _check_range(who, name, pair, lo=0.0, strict=True, hi=None):
    a, b = (float(v) for v in pair)
    if not ((a > lo if strict else a >= lo) and a <= b and (hi is None or b <= hi) and b < float("inf")):
        bound = f"{lo:g} {'<' if strict else '<='} lo <= hi" + ("" if hi is None else f" <= {hi:g}")
        raise ValueError(f"{who}: {name} must be finite with {bound}, got {tuple(pair)}")


@dataclasses.dataclass(frozen=True)
class PhotonRegime:
    """The photon regimes a training clip is drawn from, every parameter per clip (docs/training.md, "Photon
    regimes"; `jaxsr.training.regime_batches`). JSON-ready (`to_dict`) for the model card.

    - `signal_range`: mean signal photons per LR pixel with a return, log-uniform (0.5-1000);
    - `snr_range`: frame SNR (signal / ambient photons), log-uniform (0.05-20);
    - IRF width in bins: with probability `irf_paper_prob` the paper's `irf_paper` (0.4), else
      exp(log lo + (log hi - log lo) u^`irf_power`) for u uniform in [0, 1] over `irf_sigma_range` (0.3-3): power
      1 is log-uniform, 2 puts the median at 0.53 bins with a long tail (16 % above 1.5 bins);
    - dark counts: with probability `dark_prob`, a flat `jaxsr.sensor.dark_counts` rate per bin log-uniform in
      `dark_range` photons;
    - hot pixels: with probability `hot_prob`, a fraction uniform in [0, `hot_fraction_max`] of the LR pixels,
      each with `hot_level_range` (log-uniform) times the clip's mean signal as extra photons spread evenly
      over the bins;
    - dead pixels: with probability `dead_prob`, a fraction uniform in [0, `dead_fraction_max`];
    - no return (sky, absorbing surfaces): with probability `no_return_prob`, a fraction uniform in
      `no_return_fraction` of the HR pixels (`jaxsr.sensor.no_return_regions`, sky weight uniform in [0, 1],
      blobs of `blob_size` HR pixels), on top of the scene's own sky;
    - thin returns across them: with probability `thin_prob` (of the clips with drawn no-return regions), 1 to
      `thin_lines_max` lines (uniform) of width log-uniform in `thin_width_range` HR pixels keep the scene's
      depth (`jaxsr.sensor.thin_returns`: poles, cables, a lattice tower's beams against the sky; one mask for
      the clip's frames, as the regions');
    - `motion`: `jaxsr.scenes.training_clip`'s motion mode ("seen": every clip's motion shows in its depth);
    - static scenes: with probability `static_prob`, every frame of the clip shows its centre frame, so that only
      the photons differ from frame to frame (a static scene seen from a still sensor, as a photon video made of
      one recording is: the network otherwise sees motion in every clip; never in clips of the paper's regime);
    - `paper_prob`: the share of clips drawn from the paper's regime instead (`PAPER_REGIME`'s signal and SNR
      ranges, the IRF `irf_paper`, no dark counts, hot or dead pixels and no added no-return regions),
      so that a model of the wide regime keeps the paper's accuracy there.
    """

    signal_range: tuple[float, float] = (0.5, 1000.0)
    snr_range: tuple[float, float] = (0.05, 20.0)
    irf_sigma_range: tuple[float, float] = (0.3, 3.0)
    irf_power: float = 2.0
    irf_paper: float = 0.4
    irf_paper_prob: float = 0.25
    dark_prob: float = 0.5
    dark_range: tuple[float, float] = (1e-3, 0.3)
    hot_prob: float = 0.3
    hot_fraction_max: float = 0.01
    hot_level_range: tuple[float, float] = (0.1, 10.0)
    dead_prob: float = 0.3
    dead_fraction_max: float = 0.01
    no_return_prob: float = 0.5
    no_return_fraction: tuple[float, float] = (0.05, 0.6)
    blob_size: int = 16
    thin_prob: float = 0.0
    thin_lines_max: int = 8
    thin_width_range: tuple[float, float] = (1.0, 8.0)
    motion: str = "seen"
    static_prob: float = 0.0
    paper_prob: float = 0.0

    def __post_init__(self):
        who = "PhotonRegime"
        for name in ("irf_sigma_range", "dark_range", "hot_level_range", "thin_width_range"):
            _check_range(who, name, getattr(self, name))
        # the photon levels a clip is simulated at: 1e300 photons or an SNR of 1e-300 (a sensor file's typo) would
        # only surface as NaN steps after the set-up; the SNR bounds are the simulator's tested 1e-3..1e4, the
        # signal's a million photons per pixel and frame, beyond any SPAD's
        for name, (lo, hi) in REGIME_LIMITS.items():
            _check_range(who, name, getattr(self, name), lo=lo, strict=False, hi=hi)
        _check_range(who, "no_return_fraction", self.no_return_fraction, strict=False, hi=1.0)
        for name in ("irf_paper_prob", "dark_prob", "hot_prob", "hot_fraction_max", "dead_prob",
                     "dead_fraction_max", "no_return_prob", "thin_prob", "static_prob", "paper_prob"):
            v = float(getattr(self, name))
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"{who}: {name} must be in [0, 1], got {v}")
        if not (0 < float(self.irf_paper) < float("inf")) or not (0 < float(self.irf_power) < float("inf")):
            raise ValueError(f"{who}: irf_paper and irf_power must be finite and > 0, got {self.irf_paper}, "
                             f"{self.irf_power}")
        if int(self.blob_size) != self.blob_size or self.blob_size < 1:
            raise ValueError(f"{who}: blob_size must be an integer >= 1, got {self.blob_size}")
        if int(self.thin_lines_max) != self.thin_lines_max or self.thin_lines_max < 1:
            raise ValueError(f"{who}: thin_lines_max must be an integer >= 1, got {self.thin_lines_max}")
        if self.motion not in ("drawn", "seen"):
            raise ValueError(f"{who}: motion must be 'drawn' or 'seen', got {self.motion!r}")

    def to_dict(self) -> dict:
        """The regime as JSON-ready values (tuples as lists), for the model card."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(self).items()}


# The ranges `scene_batches` draws (photons 7-28, SNR 0.5-8, IRF 0.4, no effects) as a regime, for ablations of the
# new effects; `regime_batches` with it draws from the same ranges, not the same clips.
PAPER_REGIME = PhotonRegime(signal_range=TRAIN_MEAN_SIGNAL_RANGE, snr_range=(0.5, 8.0), irf_paper_prob=1.0,
                            dark_prob=0.0, hot_prob=0.0, dead_prob=0.0, no_return_prob=0.0, motion="drawn")


# Training presets. `paper`: the paper's schedule (15500 examples/epoch, batch 4, 100 epochs, patience 5,
# validation on 3 x 500 frames). `cpu`: sized so that TR0-TR4 all train in about 45 min on 2 CPU cores.
# Measured on 2 shared XLA:CPU cores (benchmarks/bench_train.py, 16 x 32 LR patches, sensor simulation
# included, rendering not): TR0 0.22 s/step (18 examples/s), TR4 2.2 s/step (1.9 examples/s); TR0-TR4 together
# about 5.5 s per step each, so 5 epochs x 64 steps = 320 steps per TR is about 30 min plus rendering,
# validation (3 x 8 full frames per epoch) and compilation. The decay (epoch 4) and the patience (3) are
# scaled down with the epochs.
PRESETS = {
    "paper": TrainConfig(),
    "cpu": TrainConfig(
        examples_per_epoch=256,
        epochs=5,
        patience=3,
        decay_epochs=4,
        patch=(16, 32),
        val_frames=8,
    ),
    # The bundled weights (jaxsr/weights): what 2 CPU cores afford in about 90 minutes for TR0-TR4 together,
    # the same number of steps for every TR (5 x 256 = 1280 steps, 5120 examples), the rate cut for the last
    # epoch.
    "bundle": TrainConfig(
        examples_per_epoch=1024,
        epochs=5,
        patience=3,
        decay_epochs=4,
        patch=(16, 32),
        val_frames=16,
    ),
    # The long CPU campaign (experiments/paper/campaign.py): 8x the bundle's steps (20 x 512 = 10240, 40960 examples),
    # the rate cut once, half way, and validation on 3 x 64 frames so that model selection sees enough frames
    # to rank checkpoints (3 x 16 picked ones 1.5-4 dB worse on the test scenes).
    "long": TrainConfig(
        examples_per_epoch=2048,
        epochs=20,
        patience=6,
        decay_epochs=10,
        patch=(16, 32),
        val_frames=64,
    ),
}
