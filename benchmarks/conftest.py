"""Shared helpers for the pytest-benchmark suites (run: pytest benchmarks --benchmark-enable)."""

import jax
import pytest

import jaxsr

# As a user's run does (`jaxsr upscale`, the experiments): the host's cores as CPU devices, so that a batch of
# frames is split over them. Must run before any JAX operation, hence at import of this conftest.
N_DEVICES = jaxsr.runtime.use_cpu_cores()


def run_compiled(benchmark, fn, *args, rounds=5, iterations=1, items=1):
    """Compile and warm `fn` once, then time steady-state calls; records items/s in extra_info."""
    jax.block_until_ready(fn(*args))
    result = benchmark.pedantic(
        lambda: jax.block_until_ready(fn(*args)), rounds=rounds, iterations=iterations, warmup_rounds=1
    )
    if benchmark.stats is not None:  # None when benchmarks are disabled
        benchmark.extra_info["items_per_s"] = items / benchmark.stats.stats.mean
        benchmark.extra_info["device"] = (f"{jax.local_device_count()} x {jax.devices()[0]} "
                                          f"({jax.devices()[0].device_kind}, JAX {jax.__version__})")
    return result


@pytest.fixture
def timed(benchmark):
    return lambda fn, *args, **kw: run_compiled(benchmark, fn, *args, **kw)
