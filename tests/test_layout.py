"""The package's shape: the stages as subpackages, a few flat modules, imports that point one way.

Module by module, the import graph (imports inside functions count too) has no cycle, the flat modules at the
bottom import no stage, nothing in the library imports the CLI, and no module imports another package's private
name. A move that breaks any of these fails here."""

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "jaxsr"
STAGES = {"sensor", "scenes", "nn", "baselines", "training", "inference", "io", "eval", "app", "cli"}
# The stages from the bottom up: a stage imports only stages below it (the command on top, then the application,
# training, the engine of inference, the metrics, the files, the networks and the physics)
LAYERS = ("sensor", "scenes", "nn", "baselines", "io", "eval", "inference", "training", "app", "cli")
FLAT = {"config", "spad", "runtime", "joining", "checks", "temporal"}  # besides __init__: at most 8 modules stay flat
BOTTOM = FLAT | {"eval", "eval.metrics", "eval.stats", "eval.calibration", "nn.layers", "nn.model", "io.files", "sensor.poisson"}


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports(path: Path, source: str | None = None) -> set[tuple[str, tuple[str, ...]]]:
    """(module below jaxsr, names imported from it) for every jaxsr import of `path` (or `source` as if at
    `path`); `from . import x` gives the module of x."""
    here = list(path.relative_to(PACKAGE).parts[:-1])
    out = set()
    for node in ast.walk(ast.parse(path.read_text() if source is None else source)):
        if isinstance(node, ast.ImportFrom) and node.level > 0:
            base = here[: len(here) - (node.level - 1)]
            if node.module:
                out.add((".".join(base + node.module.split(".")), tuple(a.name for a in node.names)))
            else:
                out.update((".".join(base + [a.name]), ()) for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("jaxsr."):
            out.add((node.module.removeprefix("jaxsr."), tuple(a.name for a in node.names)))
        elif isinstance(node, ast.Import):
            out.update((a.name.removeprefix("jaxsr."), ()) for a in node.names if a.name.startswith("jaxsr."))
    return out


FILES = {module_name(p): p for p in PACKAGE.rglob("*.py") if p != PACKAGE / "__init__.py"}


def resolve(module: str) -> str:
    """The module file an import reaches: itself, or the nearest package above that exists."""
    while module and module not in FILES:
        module = module.rpartition(".")[0]
    return module


def graph() -> dict[str, set[str]]:
    return {m: {resolve(d) for d, _ in imports(p)} - {m, ""} for m, p in FILES.items()}


def test_the_top_level_is_the_stages_and_a_few_flat_modules():
    flat = {p.stem for p in PACKAGE.glob("*.py")} - {"__init__"}
    assert flat == FLAT and len(flat) <= 8
    packages = {p.name for p in PACKAGE.iterdir() if (p / "__init__.py").is_file()}
    assert packages == STAGES


def test_imports_point_one_way():
    edges, done, path = graph(), set(), []

    def visit(m):
        if m in done:
            return
        assert m not in path, "import cycle: " + " -> ".join(path[path.index(m):] + [m])
        path.append(m)
        for d in edges.get(m, ()):
            if d in edges:
                visit(d)
        path.pop()
        done.add(m)

    for m in edges:
        visit(m)


@pytest.mark.parametrize("module", sorted(BOTTOM))
def test_the_bottom_modules_import_no_stage(module):
    for dep in graph()[module]:
        assert dep in BOTTOM, f"jaxsr.{module} imports jaxsr.{dep}, above it"


def test_no_import_runs_back_up_the_layers():
    """`io` (files and checkpoints) and `eval` (metrics) import no stage above them; the engine does not import the
    application, nor the application the command."""
    rank = {stage: i for i, stage in enumerate(LAYERS)}
    for module, deps in graph().items():
        here = rank.get(module.split(".")[0])
        for dep in deps:
            there = rank.get(dep.split(".")[0])
            if here is not None and there is not None and dep not in BOTTOM:
                assert there <= here, f"jaxsr.{module} imports jaxsr.{dep}, a stage above it"


def test_nothing_in_the_library_imports_the_cli():
    for module, deps in graph().items():
        if not module.startswith("cli"):
            assert not any(d.startswith("cli") for d in deps), f"jaxsr.{module} imports the CLI"


def test_no_private_name_crosses_a_package():
    for module, path in FILES.items():
        package = module.rpartition(".")[0] if "." in module else ""
        for dep, names in imports(path):
            dep_package = dep.rpartition(".")[0] if "." in dep else dep
            if dep_package != package:
                private = [n for n in names if n.startswith("_") and not n.startswith("__")]
                assert not private, f"jaxsr.{module} imports {private} from jaxsr.{dep}"


def test_the_checker_sees_violations():
    """The parser finds relative, absolute and in-function imports and private names (so the tests can fail)."""
    code = "def f():\n    from ..training.loop import _fit\n    import jaxsr.cli\nfrom ..scenes.layouts import x\n"
    found = imports(PACKAGE / "sensor" / "forward.py", code)
    assert found == {("training.loop", ("_fit",)), ("cli", ()), ("scenes.layouts", ("x",))}
