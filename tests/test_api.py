"""Conventions every public function follows (DESIGN.md "Public API", STYLE.md)."""

import inspect
import re

import pytest

import jaxsr

# Positional parameters that may carry a default: configs passed alongside the data.
CONFIG_PARAMS = {"sensor", "cfg", "config"}


def public_functions():
    for name in sorted(n for n in dir(jaxsr) if not n.startswith("_")):
        obj = getattr(jaxsr, name)
        if inspect.isfunction(obj):
            yield name, obj


@pytest.mark.parametrize("name,fn", list(public_functions()))
def test_function_conventions(name, fn):
    doc = inspect.getdoc(fn)
    assert doc and len([line for line in doc.splitlines() if line.strip()]) >= 2, f"{name}: needs a docstring"
    # a shape such as (..., H, W), (B, 2tr+1, h, w) or (T, H, W), or a statement that it takes pytrees/scalars
    assert re.search(r"\((\.\.\.|[A-Za-z0-9_*+ ]+,)", doc) or re.search(r"pytree|scalar", doc), (
        f"{name}: the docstring must state argument/return shapes"
    )
    params = list(inspect.signature(fn).parameters.values())
    names = [p.name for p in params]
    if "key" in names:
        assert names[0] == "key", f"{name}: the PRNG key must be the first argument"
    for p in params:
        if p.default is not inspect.Parameter.empty and p.kind == p.POSITIONAL_OR_KEYWORD:
            assert p.name in CONFIG_PARAMS, f"{name}: option {p.name!r} must be keyword-only"


def test_public_api_of_design_exists():
    for name in [
        "SensorConfig",
        "expected_histograms",
        "simulate_histograms",
        "centre_of_mass",
        "maximum_likelihood_depth",
        "calibrate",
        "planar_to_radial",
        "normalise_depth",
        "psnr",
        "ssim",
        "ssim_global",
        "temporal_coherence",
        "bicubic",
        "lanczos",
    ]:
        assert hasattr(jaxsr, name), name
