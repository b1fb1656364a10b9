"""The experiments' harness, shared by the scripts in experiments/ and their tests; not part of the library.

- `harness.scoring`: models scored on the fixed test clips (importing it exposes the host's CPU cores as JAX
  devices, as `jaxsr upscale` does: import it before any JAX operation).
- `harness.reports`: result files: header (command, machine, date, load, CPU steal), tables, figures.
- `harness.score_cache`: per-frame scores kept between scorings.
- `harness.runs`: the training campaign's runs on disk.

Scripts in experiments/ import it as `harness` (experiments/ is on their path: `sweep_tr.py` sits there, the
scripts in paper/ and studies/ put it there); tests through pytest's `pythonpath` (pyproject.toml).
"""
