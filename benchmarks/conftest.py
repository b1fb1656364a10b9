"""Shared helpers for the pytest-benchmark suites (run: pytest benchmarks --benchmark-enable)."""

import jax
import pytest


def run_compiled(benchmark, fn, *args, rounds=5, iterations=1, items=1):
    """Compile and warm `fn` once, then time steady-state calls; records items/s in extra_info."""
    jax.block_until_ready(fn(*args))
    result = benchmark.pedantic(
        lambda: jax.block_until_ready(fn(*args)), rounds=rounds, iterations=iterations, warmup_rounds=1
    )
    if benchmark.stats is not None:  # None when benchmarks are disabled
        benchmark.extra_info["items_per_s"] = items / benchmark.stats.stats.mean
        benchmark.extra_info["device"] = str(jax.devices()[0])
    return result


@pytest.fixture
def timed(benchmark):
    return lambda fn, *args, **kw: run_compiled(benchmark, fn, *args, **kw)
