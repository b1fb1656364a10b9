"""Studies share code through one module (`experiments/studies/_photon_benchmark.py`, the harness in
`experiments/harness/`) or through the library's public API: no study imports another."""

import ast
from pathlib import Path

STUDIES = Path(__file__).resolve().parents[2] / "experiments" / "studies"


def imported_modules(path: Path) -> set[str]:
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.add(node.module.split(".")[0])
    return out


def test_no_study_imports_another():
    studies = {p.stem for p in STUDIES.glob("*.py") if not p.stem.startswith("_")}
    crossing = {p.stem: sorted(imported_modules(p) & studies - {p.stem}) for p in STUDIES.glob("*.py")}
    assert not {k: v for k, v in crossing.items() if v}
