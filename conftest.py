"""pytest configuration shared by tests/ and benchmarks/: how many pytest-xdist processes `-n auto` starts."""

import os


def pytest_xdist_auto_num_workers(config):
    """Two processes at most: the suite is bound by single-threaded XLA compiles, and each process holds its own
    compiled functions. None when benchmarks are timed (pytest-benchmark times one process at a time and switches
    itself off under xdist)."""
    if config.getoption("benchmark_enable", False) or config.getoption("benchmark_only", False):
        return 0
    return min(2, os.cpu_count() or 1)
