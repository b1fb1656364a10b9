"""Conventions every public function follows (docs/api-conventions.md)."""

import inspect
import re

import jax
import numpy as np
import pytest

import jaxsr

# Positional parameters that may carry a default: configs passed alongside the data.
CONFIG_PARAMS = {"sensor", "cfg", "config", "gate", "scale"}


def public_functions():
    """The top level's public functions and those that left it for a subpackage (still reachable there)."""
    import importlib

    found = {name: getattr(jaxsr, name) for name in jaxsr.__all__}
    found.update({name: getattr(importlib.import_module(module), name) for name, module in jaxsr._MOVED_FROM.items()})
    yield from sorted((name, obj) for name, obj in found.items() if inspect.isfunction(obj))


# Public functions whose docstrings state no array shape, each with what it takes instead: no arrays, or pytrees
# of arrays of any shape.
NO_ARRAYS = {
    "adam_init": "a params pytree -> the optimiser state pytree",
    "adam_update": "pytrees of gradients, state and params, each leaf of any shape",
    "compiler_options": "nothing -> a dict of XLA options",
    "count_params": "a params pytree -> an int",
    "fit": "configs, a folder and a data source -> a Model and its history",
    "read_metadata": "a checkpoint path -> a dict",
    "step_decay": "scalars -> a schedule step -> lr",
    "enable_compilation_cache": "a folder",
    "load_model": "a path or bundled name -> a Model",
    "save_model": "a path and a Model",
    "use_cpu_cores": "a device count",
    "limit_cpu_fusions": "XLA flags and CPU feature names -> XLA flags",
    "gate_warnings": "a Gate and a DepthScale -> sentences",
    "gate_of_tags": "TimeTags -> a Gate",
    "read_time_tags": "a path -> TimeTags",
    "init_adam_pair": "two params pytrees -> two optimiser states",
    "load_baseline": "a path or bundled name -> a Model",
    "save_baseline": "a path and a Model",
    "fit_baseline": "configs, a folder and a data source -> a Model and its history",
    "BaselineModel": "a params pytree and a config -> a Model",
    "grow_tr": "a key, a Model and a TR -> a Model",
}
# A whole shape tuple of short dimension names or numbers: (..., H, W), (B, 2tr+1, h, w), (T,), (N, h*r, w*r).
_DIM = r"(\.\.\.|[A-Za-z0-9_*+/-]{1,10})"
SHAPE = re.compile(rf"\({_DIM}(, ?{_DIM})*(,|, ?{_DIM})\)|\({_DIM},\)|\(\.\.\.\)")  # (...): elementwise
RETURNS = re.compile(r"\b[Rr]eturn|\b[Yy]ield|->")


@pytest.mark.parametrize("name,fn", list(public_functions()))
def test_function_conventions(name, fn):
    doc = inspect.getdoc(fn)
    assert doc and len([line for line in doc.splitlines() if line.strip()]) >= 2, f"{name}: needs a docstring"
    if name in NO_ARRAYS:
        assert not SHAPE.search(doc), f"{name} states a shape: remove it from NO_ARRAYS"
    else:
        assert SHAPE.search(doc), f"{name}: the docstring must state its arrays' shapes (or list it in NO_ARRAYS)"
    assert RETURNS.search(doc), f"{name}: the docstring must say what it returns"
    params = list(inspect.signature(fn).parameters.values())
    names = [p.name for p in params]
    if "key" in names:
        assert names[0] == "key", f"{name}: the PRNG key must be the first argument"
    for p in params:
        if p.default is not inspect.Parameter.empty and p.kind == p.POSITIONAL_OR_KEYWORD:
            assert p.name in CONFIG_PARAMS, f"{name}: option {p.name!r} must be keyword-only"


def test_no_arrays_list_is_current():
    public = {name for name, _ in public_functions()}
    assert set(NO_ARRAYS) <= public, f"not public functions: {set(NO_ARRAYS) - public}"


# A user's script on the main path keeps working unchanged: these stay at the top level, without a warning.
MAIN_PATH = ["load_model", "Model", "super_resolve", "super_resolve_histograms", "iter_super_resolve", "Stream",
             "simulate_histograms", "expected_histograms", "centre_of_mass", "Sensor", "ModelConfig",
             "init_model", "apply_model", "save_model", "read_metadata", "read_depth", "write_depth", "read_sequence",
             "write_sequence", "pipeline_metric", "fit", "bicubic", "psnr", "ssim", "scenes"]


def test_the_top_level_is_deliberate_and_keeps_the_main_path():
    import warnings

    # 60 names, and the Sensor's parts Optics and Pulse beside Gate and DepthScale
    assert len(jaxsr.__all__) <= 62 and len(set(jaxsr.__all__)) == len(jaxsr.__all__)
    assert set(MAIN_PATH) <= set(jaxsr.__all__)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for name in jaxsr.__all__:
            getattr(jaxsr, name)
    assert set(dir(jaxsr)) >= set(jaxsr.__all__)


@pytest.mark.parametrize("name", sorted(jaxsr._MOVED_FROM))
def test_a_name_that_left_the_top_level_still_works_there_with_a_warning(name):
    import importlib

    with pytest.warns(DeprecationWarning, match=f"moved to {jaxsr._MOVED_FROM[name]}.{name}"):
        obj = getattr(jaxsr, name)
    assert obj is getattr(importlib.import_module(jaxsr._MOVED_FROM[name]), name)
    assert name not in jaxsr.__all__


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'no_such_name'"):
        jaxsr.no_such_name  # noqa: B018


# None, text and empty arrays (docs/api-conventions.md "Bad input is an error that says what was expected"): a
# TypeError or ValueError naming the argument, never JAX's or NumPy's words, or an empty result of the right shape.
HR, KEY = np.ones((1, 128, 256), np.float32), jax.random.key(0)
REFUSED = {
    "bicubic None": (lambda: jaxsr.bicubic(None), TypeError, "bicubic: lr must be an array of numbers, got None"),
    "bicubic text": (lambda: jaxsr.bicubic(np.array([["a", "b"]])), TypeError, "bicubic: lr must be an array of real"),
    "bicubic 1-d empty": (lambda: jaxsr.bicubic(np.zeros(0)), ValueError, r"expected \(\.\.\., h, w\) frames"),
    "lanczos None": (lambda: jaxsr.lanczos(None), TypeError, "lanczos: lr must be an array"),
    "centre_of_mass None": (lambda: jaxsr.centre_of_mass(None), TypeError,
                            "centre_of_mass: counts must be an array of numbers, got None"),
    "centre_of_mass sensor None": (lambda: jaxsr.centre_of_mass(np.ones((4, 4, 16)), None), TypeError,
                                   "centre_of_mass: sensor must be a jaxsr.Sensor, got NoneType"),
    "centre_of_mass 0 bins": (lambda: jaxsr.centre_of_mass(np.zeros((2, 4, 4, 0))), ValueError,
                              r"counts must have shape \(\.\.\., 16\)"),
    "simulate_histograms depth None": (lambda: jaxsr.simulate_histograms(KEY, None, HR, snr=1.0), TypeError,
                                       "simulate_histograms: depth must be an array of numbers, got None"),
    "simulate_histograms intensity None": (lambda: jaxsr.simulate_histograms(KEY, HR, None, snr=1.0), TypeError,
                                           "simulate_histograms: intensity must be an array"),
    "simulate_histograms key None": (lambda: jaxsr.simulate_histograms(None, HR, HR, snr=1.0), TypeError,
                                     r"key must be a jax.random key, e.g. jax.random.key\(seed\), got NoneType"),
    "simulate_histograms seed as key": (lambda: jaxsr.simulate_histograms(0, HR, HR, snr=1.0), TypeError,
                                        "key must be a jax.random key"),
    "simulate_histograms sensor None": (lambda: jaxsr.simulate_histograms(KEY, HR, HR, None, snr=1.0), TypeError,
                                        "sensor must be a jaxsr.Sensor"),
    "simulate_histograms 0 x 0 frames": (lambda: jaxsr.simulate_histograms(KEY, np.zeros((2, 0, 0)),
                                                                           np.zeros((2, 0, 0)), snr=1.0),
                                         ValueError, r"depth must have shape \(\.\.\., 128, 256\)"),
    "upscale model None": (lambda: jaxsr.upscale(np.full((2, 32, 64), 0.5), None, model=None), TypeError,
                           "model: expected 'default', 'tr0'..'tr4', 'auto', a checkpoint path or a loaded "
                           "jaxsr.Model, got NoneType None"),
    "upscale input None": (lambda: jaxsr.upscale(None, None, model="tr0"), TypeError,
                           "input: expected a path, a Recording, a NumPy array"),
    "upscale 0 frames": (lambda: jaxsr.upscale(np.zeros((0, 32, 64)), None, model="tr0"), ValueError,
                         "the recording has no frames"),
    "upscale 0 x 0 frames": (lambda: jaxsr.upscale(np.zeros((2, 0, 0)), None, model="tr0"), ValueError,
                             "frames of 0 x 0 pixels; expected LR frames of at least 4 x 4"),
    "upscale 0 histogram frames": (lambda: jaxsr.upscale(np.zeros((0, 32, 64, 16)), None, model="tr0"), ValueError,
                                   "the recording has no frames"),
}


@pytest.mark.parametrize("case", REFUSED)
def test_none_text_and_unusable_empty_arrays_are_clear_errors(case):
    call, error, message = REFUSED[case]
    with pytest.raises(error, match=message):
        call()


EMPTY = {
    "bicubic 0 frames": (lambda: jaxsr.bicubic(np.zeros((0, 32, 64))), (0, 128, 256)),
    "bicubic 0 x 0 frames": (lambda: jaxsr.bicubic(np.zeros((2, 0, 0))), (2, 0, 0)),
    "lanczos 0 frames": (lambda: jaxsr.lanczos(np.zeros((0, 32, 64)), scale=2), (0, 64, 128)),
    "centre_of_mass 0 frames": (lambda: jaxsr.centre_of_mass(np.zeros((0, 32, 64, 16))), (0, 32, 64)),
    "centre_of_mass 0 x 0 frames": (lambda: jaxsr.centre_of_mass(np.zeros((2, 0, 0, 16))), (2, 0, 0)),
    "simulate_histograms 0 frames": (lambda: jaxsr.simulate_histograms(KEY, HR[:0], HR[:0], snr=1.0),
                                     (0, 32, 64, 16)),
}


@pytest.mark.parametrize("case", EMPTY)
def test_empty_arrays_give_empty_results_of_the_right_shape(case):
    call, shape = EMPTY[case]
    assert np.asarray(call()).shape == shape


@pytest.mark.parametrize("call", [
    lambda: jaxsr.super_resolve(None, np.zeros((1, 8, 8), np.float32)),
    lambda: jaxsr.super_resolve("tr4", np.zeros((1, 8, 8), np.float32)),
    lambda: jaxsr.super_resolve_histograms(None, np.zeros((1, 8, 8, 16), np.float32)),
    lambda: jaxsr.inference.Stream(None),
    lambda: list(jaxsr.inference.iter_super_resolve(None, [])),
])
def test_inference_without_a_model_says_how_to_load_one(call):
    with pytest.raises(TypeError, match="load_model"):
        call()


@pytest.mark.parametrize("data", [None, "frames.npy"])
def test_inference_without_frames_says_what_it_expected(data, tiny_model_for_api):
    with pytest.raises(TypeError, match="expected|must be"):
        jaxsr.super_resolve(tiny_model_for_api, data)
    with pytest.raises(TypeError, match="expected"):
        jaxsr.super_resolve_histograms(tiny_model_for_api, data)


def test_empty_histograms_are_refused_with_the_shape(tiny_model_for_api):
    with pytest.raises(ValueError, match="T >= 1"):
        jaxsr.super_resolve_histograms(tiny_model_for_api, np.zeros((0, 8, 8, 16), np.float32))


@pytest.fixture(scope="module")
def tiny_model_for_api():
    cfg = jaxsr.ModelConfig(tr=0, base=8, growth=4, head=16, filter_hidden=16)
    return jaxsr.Model(*jaxsr.nn.init_model(jax.random.key(0), cfg), cfg)
