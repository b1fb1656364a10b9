"""The README and the docs site stay true: the README's example runs, `jaxsr.__all__` and the API pages agree, the
README stays short with the newcomer's two commands on top, and no tracked file names notes kept outside the
repository."""

import importlib
import re
import subprocess
import types
from pathlib import Path

import jax
import numpy as np
import pytest

import jaxsr

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = ROOT / "docs"
MAIN_JOB = "python experiments/sweep_tr.py"
TESTS = "python -m pytest -q"
# Notes that live outside the repository: never to be named in it (spelt in pieces so that this file does not).
OUTSIDE_NOTES = [name + ".md" for name in ("DESIGN", "PHYSICS", "STYLE")]


def readme_python_blocks():
    return re.findall(r"^```python\n(.*?)^```", README.read_text(encoding="utf-8"), flags=re.S | re.M)


def docs_pages():
    """Every Markdown page of the site (the experiments' result files stay in experiments/results/, linked)."""
    return sorted(DOCS.rglob("*.md"))


def test_readme_example_runs(capsys):
    blocks = readme_python_blocks()
    assert blocks, "README.md has no ```python block"
    namespace = {"__name__": "readme_example"}
    exec(compile(blocks[0], "README.md (first python block)", "exec"), namespace)
    hr, lr, gt = (np.asarray(namespace[name]) for name in ("hr", "lr", "gt"))
    t = lr.shape[0]
    assert lr.shape == (t, 32, 64) and hr.shape == gt.shape == (t, 128, 256)
    assert np.all(np.isfinite(hr)) and np.all((lr >= 0) & (lr <= 1))
    net = float(np.mean(jaxsr.psnr(hr, gt)))
    bicubic = float(np.mean(jaxsr.psnr(jaxsr.bicubic(lr), gt)))
    # Table 1 of the results: the bundled networks score 25-39 dB, 7-12 dB above bicubic, on the test scenes
    assert 20.0 < net < 60.0 and net > bicubic + 3.0, (net, bicubic)
    assert "dB" in capsys.readouterr().out


@pytest.mark.slow  # a TR4 gradient through 8 frames: minutes on 2 busy cores (the same route, fast: test_traced.py)
def test_readme_jax_example_jits_and_differentiates():
    """The README's "From your own JAX code": `apply_sequence` inside jax.jit gives what `super_resolve` gives, and
    jax.grad through it is finite; `super_resolve` itself, traced, says which function to use."""
    blocks = readme_python_blocks()
    assert len(blocks) >= 2, "README.md's second ```python block (From your own JAX code) is missing"
    namespace = {"__name__": "readme_example"}
    exec(compile(blocks[0], "README.md (first python block)", "exec"), namespace)
    exec(compile(blocks[1], "README.md (second python block)", "exec"), namespace)
    lr, hr, grad = (np.asarray(namespace[name]) for name in ("lr", "hr", "grad"))
    traced = np.asarray(namespace["sharpened"](namespace["model"], namespace["lr"]))
    np.testing.assert_allclose(traced, hr, atol=1e-4)
    assert grad.shape == lr.shape and np.all(np.isfinite(grad)) and np.abs(grad).max() > 0
    with pytest.raises(TypeError, match=r"super_resolve runs on the host .* use jaxsr.apply_sequence"):
        jax.jit(lambda x: jaxsr.super_resolve(namespace["model"], x))(namespace["lr"])


def test_all_names_are_documented():
    text = "\n".join(p.read_text(encoding="utf-8") for p in docs_pages())
    missing = []
    for name in jaxsr.__all__:
        pattern = rf"jaxsr\.{name}\b" if isinstance(getattr(jaxsr, name), types.ModuleType) else rf"\b{name}\b"
        if not re.search(pattern, text):
            missing.append(name)
    assert not missing, f"in jaxsr.__all__ but nowhere in docs/: {missing}"


def _resolve(path: str):
    """The object a mkdocstrings identifier such as `jaxsr.sensor` or `jaxsr.config.Gate` names."""
    parts = path.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        for attr in parts[i:]:
            obj = getattr(obj, attr)
        return obj
    raise ImportError(path)


def api_directives():
    """(page, identifier, [members listed under its options]) for every `::: identifier` in docs/api."""
    found = []
    for page in sorted((DOCS / "api").glob("*.md")):
        lines = page.read_text(encoding="utf-8").splitlines()
        for i, line in enumerate(lines):
            m = re.match(r"^::: (\S+)\s*$", line)
            if not m:
                continue
            members, in_members = [], False
            for option in lines[i + 1:]:
                if option and not option.startswith(" "):
                    break
                if re.match(r"^\s+members:\s*$", option):
                    in_members = True
                elif in_members and (item := re.match(r"^\s+- (\S+)\s*$", option)):
                    members.append(item.group(1))
                else:
                    in_members = False
            found.append((page.name, m.group(1), members))
    return found


def test_api_pages_refer_to_importable_objects():
    directives = api_directives()
    assert any(ident == "jaxsr" for _, ident, _ in directives), "docs/api has no `::: jaxsr` page"
    for page, ident, members in directives:
        assert ident.startswith("jaxsr"), (page, ident)
        obj = _resolve(ident)  # raises if the identifier names nothing
        for member in members:
            assert hasattr(obj, member), f"docs/api/{page}: {ident} has no member {member!r}"


def test_dotted_names_in_the_docs_exist():
    """Every `jaxsr.a.b` the README and the pages name is importable, so that a move or rename updates them too."""
    missing = []
    for page in [README, *docs_pages()]:
        for name in sorted(set(re.findall(r"\bjaxsr(?:\.[A-Za-z_]\w*)+", page.read_text(encoding="utf-8")))):
            if name.endswith(".__all__"):
                name = name.removesuffix(".__all__")
            try:
                _resolve(name)
            except (ImportError, AttributeError):
                missing.append(f"{page.relative_to(ROOT)}: {name}")
    assert not missing, missing


def in_git_at(path: str, paragraph: str) -> bool:
    """Whether the paragraph names a commit ("at commit <hash>") that holds `path`: a study removed from the tree."""
    return any(subprocess.run(["git", "cat-file", "-e", f"{commit}:{path}"], cwd=ROOT, capture_output=True).returncode
               == 0 for commit in re.findall(r"at commit ([0-9a-f]{7,40})\b", paragraph))


# A link to a file of the repository, as the site makes them (mkdocs.yml's repo_url: the raw result files are
# linked there, not copied into the site).
REPO_LINK = re.compile(r"https://github\.com/jaxsr/jaxsr/(blob|raw|tree)/main/([^)\s#?]+)")


def named_paths(text: str) -> set[str]:
    """The repository paths a text names: experiment scripts, benchmarks and result files written out, and the
    targets of its links to the repository (a folder for a `tree/` link, written with a trailing slash)."""
    paths = set(re.findall(r"\b(?:experiments|benchmarks)/[\w/.-]*\w\.(?:py|md|csv|png|json|jsonl|gif|mp4)\b", text))
    return paths | {path + "/" if kind == "tree" else path for kind, path in REPO_LINK.findall(text)}


def test_repository_links_are_recognised():
    text = ("[a](https://github.com/jaxsr/jaxsr/blob/main/experiments/results/real_photons_ambient.md#the-table), "
            "![b](https://github.com/jaxsr/jaxsr/raw/main/experiments/results/readme.gif) "
            "[c](https://github.com/jaxsr/jaxsr/tree/main/experiments/results)")
    assert named_paths(text) == {"experiments/results/real_photons_ambient.md", "experiments/results/readme.gif",
                                 "experiments/results/"}


def test_scripts_and_result_files_named_in_the_docs_exist():
    """The experiment scripts, benchmarks and result files the README and the pages name or link (in the
    repository: `repo_url` links) are where they say, or, for a study no longer in the tree, in git at the commit
    its paragraph names."""
    missing = []
    for page in [README, *docs_pages()]:
        for paragraph in page.read_text(encoding="utf-8").split("\n\n"):
            for path in sorted(named_paths(paragraph)):
                found = (ROOT / path).is_dir() if path.endswith("/") else (ROOT / path).is_file()
                if not found and not in_git_at(path, paragraph):
                    missing.append(f"{page.relative_to(ROOT)}: {path}")
    assert not missing, missing


# History (dates, what changed when, leases) belongs in CHANGELOG.md and the results' own dates, not in the README
# or the guide: they say what a user can do now.
HISTORY = re.compile(r"\b20\d\d-\d\d-\d\d\b|\b(?:since|before|until) 20\d\d\b|\bleases?\b|\bno longer\b|"
                     r"\bat commit\b|\bgit checkout\b")


def test_the_readme_and_the_guide_hold_no_history():
    pages = [README, *(p for p in docs_pages() if "results" not in p.relative_to(DOCS).parts)]
    found = [f"{page.relative_to(ROOT)}:{i}: {m.group(0)!r}" for page in pages
             for i, line in enumerate(page.read_text(encoding="utf-8").splitlines(), 1) if (m := HISTORY.search(line))]
    assert not found, found


def test_top_level_api_page_lists_exactly_all():
    (members,) = [members for _, ident, members in api_directives() if ident == "jaxsr"]
    modules = {n for n in jaxsr.__all__ if isinstance(getattr(jaxsr, n), types.ModuleType)}
    assert set(members) == set(jaxsr.__all__) - modules, "docs/api/index.md's members and jaxsr.__all__ differ"
    for module in modules:
        assert (DOCS / "api" / f"{module}.md").is_file(), f"no API page for jaxsr.{module}"


def test_readme_is_short_and_starts_with_the_two_commands():
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 150, f"README.md has {len(lines)} lines; the rest belongs in docs/"
    top = "\n".join(lines[:12])
    assert MAIN_JOB in top and TESTS in top, "README.md's first 12 lines must give the main job and the tests"
    assert top.index("pip install") < top.index(MAIN_JOB) and top.index("pip install") < top.index(TESTS)


def test_no_tracked_file_names_outside_notes():
    try:
        listed = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    needles = [n.encode() for n in OUTSIDE_NOTES]
    offenders = []
    for name in listed.decode().split("\0"):
        path = ROOT / name
        if not name or path.is_symlink() or not path.is_file():
            continue
        data = path.read_bytes()
        offenders += [f"{name}: {n.decode()}" for n in needles if n in data]
    assert not offenders, offenders
