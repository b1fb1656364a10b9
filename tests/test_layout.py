"""The package's import graph points one way: a module imports only modules of lower layers (README "Layout").

Imports inside functions count too. A new module must be given a layer here; a move that breaks the order fails."""

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "jaxsr"

# Layers of the top-level modules, from the bottom. `scenes` is a subpackage; its modules have their own order.
LAYERS = [
    {"_checks", "_files", "config", "runtime", "optim", "metrics", "stats", "layers", "poisson", "temporal",
     "baselines", "flow"},
    {"sensor", "peaks", "model", "rbpn"},
    {"scenes", "io", "checkpoint", "recon", "streaming", "gates", "timetags", "pipeline", "histnet"},
    {"previews", "recordings", "data", "inference", "adaptive"},
    {"train", "baseline_training"},
    {"cli"},
]
SCENES_ORDER = ["primitives", "draws", "pose", "raycast", "objects", "layouts", "sequences", "test_sets"]


def layer_of(top: str) -> int:
    for i, names in enumerate(LAYERS):
        if top in names:
            return i
    raise AssertionError(f"jaxsr.{top} has no layer in tests/test_layout.py; give it one")


def imported_modules(path: Path, source: str | None = None) -> set[tuple[str, ...]]:
    """The jaxsr modules (as path tuples below jaxsr/) that `path` (or `source`, as if at `path`) imports."""
    here = list(path.relative_to(PACKAGE).parts[:-1])  # the package the file is in
    out = set()
    for node in ast.walk(ast.parse(path.read_text() if source is None else source)):
        if isinstance(node, ast.ImportFrom) and node.level > 0:
            base = here[: len(here) - (node.level - 1)]
            target = base + (node.module.split(".") if node.module else [])
            if target:
                out.add(tuple(target))
            else:  # `from . import io`: the names are modules
                out.update((a.name,) for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("jaxsr."):
            out.add(tuple(node.module.split(".")[1:]))
        elif isinstance(node, ast.Import):
            out.update(tuple(a.name.split(".")[1:]) for a in node.names if a.name.startswith("jaxsr."))
    return out


MODULES = sorted(p for p in PACKAGE.rglob("*.py") if p.name != "__init__.py" or p.parent != PACKAGE)


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_imports_point_down(path):
    parts = path.relative_to(PACKAGE).with_suffix("").parts
    top = parts[0]
    for dep in imported_modules(path):
        if dep[0] == top:  # inside a subpackage: the subpackage's own order
            if top == "scenes" and len(parts) > 1 and parts[1] != "__init__" and len(dep) > 1:
                assert SCENES_ORDER.index(dep[1]) < SCENES_ORDER.index(parts[1]), f"scenes.{parts[1]} imports {dep}"
            continue
        assert layer_of(dep[0]) < layer_of(top), f"jaxsr.{'.'.join(parts)} (layer {layer_of(top)}) imports " \
                                                  f"jaxsr.{'.'.join(dep)} (layer {layer_of(dep[0])})"


def test_every_module_has_a_layer():
    tops = {p.relative_to(PACKAGE).parts[0].removesuffix(".py") for p in MODULES}
    for top in tops:
        layer_of(top)
    scenes = {p.stem for p in (PACKAGE / "scenes").glob("*.py")} - {"__init__"}
    assert scenes == set(SCENES_ORDER)


def test_the_checker_sees_a_violation():
    """The parser finds relative, absolute and in-function imports (so the test above can fail)."""
    code = "def f():\n    from .train import fit\n    import jaxsr.cli\nfrom .scenes.layouts import sample_scene\n"
    deps = imported_modules(PACKAGE / "sensor.py", code)
    assert deps == {("train",), ("cli",), ("scenes", "layouts")}
    assert layer_of("train") > layer_of("sensor")
