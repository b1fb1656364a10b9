"""Training: the data sources, Adam and the step-decay schedule, each architecture's recipe, the one `fit`
loop that trains them all (`loop`, with its run folders, saved state, epochs, records and processes in modules of
their own), and the runs from a preset (`train`) or to a sensor described in a file (`finetune`,
`read_sensor_file`).
"""

from .optim import AdamState, adam_init, adam_update, lr_schedule, step_decay
from .data import (
    draw_batches,
    log_uniform,
    random_crop,
    regime_batches,
    regime_clips,
    regime_draws,
    regime_parameters,
    run_keys,
    scene_batches,
    scene_clips,
    sequence_batches,
    sequence_clips,
    validation_set,
)
from .recipes import Recipe, recipe, register_recipe
from .duf import (
    data_mesh,
    default_data,
    evaluate,
    evaluate_sequences,
    initial_weights,
    make_train_step,
    sequence_loss,
)
from .baselines import (
    BASELINES,
    BaselineModel,
    baseline_validation_set,
    evaluate_baseline,
    fit_baseline,
    histogram_batches,
    init_adam_pair,
    load_baseline,
    make_histnet_train_step,
    make_iseebetter_train_step,
    make_rbpn_train_step,
    save_baseline,
    super_resolve_baseline,
)
from .processes import choose_mesh, replicate
from .folders import RESUME_FILE, RUN_FILES, resume_config, seed_folder
from .loop import fit
from .presets import FINETUNE_LR_FACTOR, MAX_TR, PHOTON_INPUTS, finetune, regime_validation, sequence_data, train
from .sensor_file import fit_irf, parse_sensor_file, read_irf_file, read_sensor, read_sensor_file, training_sensor
from .no_return import (CALIBRATION_SEED, calibrate_no_return, choose_no_return_logit, no_return_outputs,
                        no_return_set, no_return_table)

__all__ = [
    "AdamState", "adam_init", "adam_update", "lr_schedule", "step_decay",
    "draw_batches", "log_uniform", "random_crop", "regime_batches", "regime_clips", "regime_draws", "regime_parameters",
    "run_keys",
    "scene_batches", "scene_clips", "sequence_batches", "sequence_clips",
    "validation_set",
    "Recipe", "recipe", "register_recipe",
    "data_mesh", "default_data", "evaluate", "evaluate_sequences", "initial_weights", "make_train_step",
    "sequence_loss",
    "BASELINES", "baseline_validation_set", "evaluate_baseline", "histogram_batches", "init_adam_pair",
    "make_histnet_train_step", "make_iseebetter_train_step", "make_rbpn_train_step",
    "fit", "resume_config", "seed_folder", "train", "sequence_data", "MAX_TR", "choose_mesh", "replicate", "RUN_FILES",
    "RESUME_FILE",
    "finetune", "regime_validation", "FINETUNE_LR_FACTOR", "PHOTON_INPUTS",
    "read_sensor", "read_sensor_file", "parse_sensor_file", "training_sensor", "fit_irf", "read_irf_file",
    "calibrate_no_return", "choose_no_return_logit", "no_return_outputs", "no_return_set", "no_return_table",
    "CALIBRATION_SEED",
    # deprecated (jaxsr 0.1): jaxsr.nn.Model, jaxsr.save_model / load_model, jaxsr.super_resolve*, jaxsr.fit
    "BaselineModel", "fit_baseline", "load_baseline", "save_baseline", "super_resolve_baseline",
]
