"""jaxsr: video super-resolution of single-photon (SPAD) lidar depth, in pure functional JAX.

The pipeline's stages are subpackages: `jaxsr.sensor` (histograms from depth, depth from histograms),
`jaxsr.scenes` (procedural depth video), `jaxsr.nn` (the network), `jaxsr.baselines`, `jaxsr.training`,
`jaxsr.inference`, `jaxsr.io` and `jaxsr.eval`; `jaxsr.app` is the application of the command (`upscale`,
`simulate_recording`). The names a user's script needs are here at the top level
(`__all__`); everything else is imported from its subpackage.
"""

__version__ = "0.2.0"

# before any module below can start JAX's CPU backend: XLA reads its flags then (see runtime.limit_cpu_fusions)
from .runtime import guard_cpu_fusions as _guard_cpu_fusions

_guard_cpu_fusions()

import importlib as _importlib
import warnings as _warnings

from . import app, baselines, eval, inference, io, nn, scenes, sensor, spad, training
from .app import simulate_recording, upscale
from .baselines import bicubic, lanczos, tv_super_resolve
from .config import PRESETS, ModelConfig, TrainConfig
from .spad import DepthScale, Gate, Optics, Pulse, Sensor
from .eval import paired_interval, psnr, ssim, ssim_global, temporal_coherence
from .inference import (
    Stream,
    apply_histograms,
    apply_sequence,
    choose_tr,
    iter_super_resolve,
    pipeline_metric,
    super_resolve,
    super_resolve_histograms,
)
from .io import (
    load_model,
    read_depth,
    read_histograms,
    read_metadata,
    read_sequence,
    save_model,
    write_depth,
    write_histograms,
    write_preview,
    write_sequence,
)
from .nn import Model, apply_model, apply_model_sequence, init_model
from .sensor import (
    TimeTags,
    calibrate,
    centre_of_mass,
    denormalise_depth,
    expected_histograms,
    histogram_time_tags,
    maximum_likelihood_depth,
    normalise_depth,
    read_time_tags,
    simulate_histograms,
)
from .temporal import windows
from .training import evaluate, fit

SensorConfig = spad.SensorConfig  # deprecated (a DeprecationWarning when called): jaxsr.Sensor

__all__ = [
    # the pipeline's stages
    "sensor", "scenes", "nn", "baselines", "training", "inference", "io", "eval", "app",
    # configuration
    "Sensor", "Gate", "Optics", "Pulse", "DepthScale", "ModelConfig", "TrainConfig", "PRESETS",
    # sensor: depth -> photons -> depth
    "expected_histograms", "simulate_histograms", "calibrate", "normalise_depth", "denormalise_depth",
    "centre_of_mass", "maximum_likelihood_depth", "TimeTags", "read_time_tags", "histogram_time_tags",
    # the network and its files
    "Model", "init_model", "apply_model", "apply_model_sequence", "load_model", "save_model", "read_metadata",
    # super-resolution of recordings
    "super_resolve", "super_resolve_histograms", "iter_super_resolve", "Stream", "choose_tr", "windows",
    "pipeline_metric", "upscale", "apply_sequence", "apply_histograms",
    # training
    "fit", "evaluate",
    # baselines
    "bicubic", "lanczos", "tv_super_resolve",
    # files
    "read_depth", "write_depth", "read_sequence", "write_sequence", "read_histograms", "write_histograms",
    "write_preview", "simulate_recording",
    # scores
    "psnr", "ssim", "ssim_global", "temporal_coherence", "paired_interval",
]

# Names that were top-level before 0.2 and now live in a subpackage: they still work here, with a warning, for one
# release.
_MOVED = {
    "jaxsr.config": ["DEFAULT_MEAN_SIGNAL"],
    "jaxsr.runtime": ["compiler_options", "enable_compilation_cache", "limit_cpu_fusions", "use_cpu_cores"],
    "jaxsr.temporal": ["change_frame_rate"],
    "jaxsr.scenes": ["Scene", "render", "in_view_lr_shift", "mean_lr_shift", "sample_scene", "sequence",
                     "test_sequences", "training_clip"],
    "jaxsr.sensor": ["planar_to_radial", "poisson_pathwise", "sample_poisson", "gate_depth", "gate_warnings",
                     "to_network_depth", "from_network_depth", "gate_of_tags", "histogram_photons",
                     "time_tags_from_cells"],
    "jaxsr.nn": ["apply_model_train", "apply_model_sequence_train", "count_params", "grow_tr", "stream_init",
                 "stream_step"],
    "jaxsr.baselines": ["optical_flow", "warp", "HistNetConfig", "apply_histnet", "apply_histnet_features",
                        "histnet_features", "init_histnet", "second_peak_depth", "RBPNConfig", "apply_discriminator",
                        "apply_rbpn", "discriminator_loss", "generator_loss", "init_discriminator", "init_rbpn",
                        "rbpn_flows", "tv_loss"],
    "jaxsr.training": ["BaselineModel", "fit_baseline", "histogram_batches", "load_baseline", "save_baseline",
                       "super_resolve_baseline", "init_adam_pair", "make_histnet_train_step",
                       "make_iseebetter_train_step", "make_rbpn_train_step", "adam_init", "adam_update",
                       "step_decay", "make_train_step"],
    "jaxsr.inference": ["estimate_motion"],
    "jaxsr.io": ["read_airsim", "write_comparison"],
    "jaxsr.eval": ["TemporalCoherence", "huber_loss", "Interval", "ratio_interval"],
}
_MOVED_FROM = {name: module for module, names in _MOVED.items() for name in names}


def __getattr__(name):
    module = _MOVED_FROM.get(name)
    if module is None:
        raise AttributeError(f"module 'jaxsr' has no attribute {name!r}")
    _warnings.warn(f"jaxsr.{name} moved to {module}.{name}; the top-level name goes in the next release",
                   DeprecationWarning, stacklevel=2)
    return getattr(_importlib.import_module(module), name)


def __dir__():
    return sorted(__all__)
