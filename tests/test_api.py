"""Conventions every public function follows (docs/api-conventions.md)."""

import inspect
import re

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
             "simulate_histograms", "expected_histograms", "centre_of_mass", "SensorConfig", "ModelConfig",
             "init_model", "apply_model", "save_model", "read_metadata", "read_depth", "write_depth", "read_sequence",
             "write_sequence", "pipeline_metric", "fit", "bicubic", "psnr", "ssim", "scenes"]


def test_the_top_level_is_deliberate_and_keeps_the_main_path():
    import warnings

    assert len(jaxsr.__all__) <= 60 and len(set(jaxsr.__all__)) == len(jaxsr.__all__)
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
