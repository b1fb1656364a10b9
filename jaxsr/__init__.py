"""jaxsr: video super-resolution of single-photon (SPAD) lidar depth, in pure functional JAX.

The public API is re-exported here; see README.md and DESIGN.md for the pipeline.
"""

__version__ = "0.1.0"

from .adaptive import choose_tr as choose_tr
from .adaptive import estimate_motion as estimate_motion
from .baselines import bicubic as bicubic
from .baselines import lanczos as lanczos
from .checkpoint import load_model as load_model
from .checkpoint import read_metadata as read_metadata
from .checkpoint import save_model as save_model
from .config import DEFAULT_MEAN_SIGNAL as DEFAULT_MEAN_SIGNAL
from .config import PRESETS as PRESETS
from .config import ModelConfig as ModelConfig
from .config import SensorConfig as SensorConfig
from .config import TrainConfig as TrainConfig
from .model import Model as Model
from .model import apply_model as apply_model
from .model import apply_model_sequence as apply_model_sequence
from .model import apply_model_sequence_train as apply_model_sequence_train
from .model import apply_model_train as apply_model_train
from .model import count_params as count_params
from .model import init_model as init_model
from .inference import Stream as Stream
from .inference import iter_super_resolve as iter_super_resolve
from .inference import super_resolve as super_resolve
from .inference import super_resolve_histograms as super_resolve_histograms
from .io import read_airsim as read_airsim
from .io import read_depth as read_depth
from .io import read_histograms as read_histograms
from .io import read_sequence as read_sequence
from .io import write_depth as write_depth
from .io import write_histograms as write_histograms
from .io import write_sequence as write_sequence
from .previews import write_comparison as write_comparison
from .previews import write_preview as write_preview
from .metrics import TemporalCoherence as TemporalCoherence
from .metrics import huber_loss as huber_loss
from .metrics import psnr as psnr
from .metrics import ssim as ssim
from .metrics import ssim_global as ssim_global
from .metrics import temporal_coherence as temporal_coherence
from .peaks import centre_of_mass as centre_of_mass
from .peaks import maximum_likelihood_depth as maximum_likelihood_depth
from .pipeline import pipeline_metric as pipeline_metric
from .poisson import poisson_pathwise as poisson_pathwise
from .poisson import sample_poisson as sample_poisson
from .optim import adam_init as adam_init
from .optim import adam_update as adam_update
from .optim import step_decay as step_decay
from .recon import tv_super_resolve as tv_super_resolve
from .runtime import compiler_options as compiler_options
from .runtime import enable_compilation_cache as enable_compilation_cache
from .runtime import use_cpu_cores as use_cpu_cores
from .scenes import Scene as Scene
from .scenes import render as render
from .scenes import mean_lr_shift as mean_lr_shift
from .scenes import sample_scene as sample_scene
from .scenes import sequence as sequence
from .scenes import test_sequences as test_sequences
from .scenes import training_clip as training_clip
from .streaming import stream_init as stream_init
from .streaming import stream_step as stream_step
from .sensor import calibrate as calibrate
from .sensor import denormalise_depth as denormalise_depth
from .sensor import expected_histograms as expected_histograms
from .sensor import normalise_depth as normalise_depth
from .sensor import planar_to_radial as planar_to_radial
from .sensor import simulate_histograms as simulate_histograms
from .temporal import change_frame_rate as change_frame_rate
from .temporal import windows as windows
from .train import evaluate as evaluate
from .train import fit as fit
from .train import make_train_step as make_train_step
