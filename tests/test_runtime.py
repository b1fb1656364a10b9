"""Runtime settings: the compilation cache folder, CPU devices, and the inference compiler options."""

import os
import subprocess
import sys

import jax
import numpy as np
import pytest

from jaxsr.config import ModelConfig
from jaxsr.nn import apply_model, init_model
from jaxsr.runtime import compiler_options, enable_compilation_cache, limit_cpu_fusions, use_cpu_cores


def test_compilation_cache_folder(tmp_path, monkeypatch):
    before = jax.config.jax_compilation_cache_dir
    try:
        monkeypatch.setenv("JAXSR_CACHE_DIR", "off")
        assert enable_compilation_cache() is None
        monkeypatch.setenv("JAXSR_CACHE_DIR", str(tmp_path / "xla"))
        assert enable_compilation_cache() == tmp_path / "xla"
        assert jax.config.jax_compilation_cache_dir == str(tmp_path / "xla")
        assert jax.config.jax_persistent_cache_enable_xla_caches == "none"  # no path in the entries' keys
    finally:
        jax.config.update("jax_compilation_cache_dir", before)
        jax.config.update("jax_persistent_cache_enable_xla_caches", "xla_gpu_per_fusion_autotune_cache_dir")


_MOVED_CACHE_SCRIPT = """
import sys, jax, jax.numpy as jnp
from jaxsr.runtime import enable_compilation_cache
enable_compilation_cache(path=sys.argv[1])
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)  # this small program is kept too
jax.jit(lambda x: jnp.sin(x) @ x).lower(jnp.ones((64, 64))).compile()
"""


def test_compilation_cache_hits_from_a_copied_folder(tmp_path):
    """A cache folder copied elsewhere (the next slot's machine) serves the same programs: nothing new compiled."""
    import shutil

    env = dict(os.environ, JAX_PLATFORMS="cpu")
    run = [sys.executable, "-c", _MOVED_CACHE_SCRIPT]
    subprocess.run([*run, str(tmp_path / "a")], check=True, env=env, timeout=120)
    shutil.copytree(tmp_path / "a", tmp_path / "b")
    subprocess.run([*run, str(tmp_path / "b")], check=True, env=env, timeout=120)
    kept = sorted(p.name for p in (tmp_path / "a").iterdir())
    assert kept and sorted(p.name for p in (tmp_path / "b").iterdir()) == kept


_CORES_SCRIPT = """
import os, jax, jax.numpy as jnp
from jaxsr.runtime import use_cpu_cores
first = use_cpu_cores(n=3)            # before any operation: the backend starts with 3 CPU devices
jnp.zeros(1).block_until_ready()
later = use_cpu_cores(n=5)            # the backend runs: the count can no longer change, and no error
print(first, later, jax.local_device_count())
"""


@pytest.mark.parametrize("xla_flags,expected", [("", "3 3 3"), ("--xla_force_host_platform_device_count=2", "2 2 2")])
def test_use_cpu_cores_sets_the_device_count_once(xla_flags, expected):
    """In a fresh process: n devices when called first, unchanged once the backend runs, and XLA_FLAGS wins."""
    env = dict(os.environ, XLA_FLAGS=xla_flags, JAX_PLATFORMS="cpu")
    proc = subprocess.run([sys.executable, "-c", _CORES_SCRIPT], env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.split()[-3:] == expected.split()


def test_importing_jaxsr_starts_no_backend():
    """The device count can only be set before JAX's backend starts, so no module may make an array at import."""
    script = "import jax, jaxsr; jax.config.update('jax_num_cpu_devices', 3); print(jax.local_device_count())"
    env = dict(os.environ, XLA_FLAGS="", JAX_PLATFORMS="cpu")
    proc = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and proc.stdout.split()[-1:] == ["3"], proc.stderr[-2000:]


def test_importing_jaxsr_limits_the_fusions_as_the_host_needs():
    """In a fresh process with no XLA_FLAGS: after `import jaxsr` they are what `limit_cpu_fusions` gives this host
    (on a host with AVX-512 or a jaxlib before the option: none), and flags the user set stay first."""
    script = ("import os, jaxsr; from jaxsr import runtime as r; "
              "print(repr(os.environ.get('XLA_FLAGS', ''))); "
              "print(repr(r.limit_cpu_fusions('--xla_cpu_enable_fast_math=false', r._host_cpu_flags()) "
              "if r._jaxlib_version() >= r._YNN_SINCE else '--xla_cpu_enable_fast_math=false'))")
    env = dict(os.environ, XLA_FLAGS="--xla_cpu_enable_fast_math=false", JAX_PLATFORMS="cpu")
    proc = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    got, expected = proc.stdout.split("\n")[-3:-1]
    assert got == expected and got.startswith("'--xla_cpu_enable_fast_math=false")


AVX2_ONLY = {"fpu", "sse", "sse2", "avx", "avx2", "fma"}
LIMITED = "--xla_cpu_experimental_ynn_fusion_type=individual_dot,individual_convolution"


@pytest.mark.parametrize("xla_flags, cpu_flags, expected", [
    ("", AVX2_ONLY, LIMITED),  # x86 without AVX-512: YNNPACK kept to dots and convolutions
    ("--xla_force_host_platform_device_count=2", AVX2_ONLY, "--xla_force_host_platform_device_count=2 " + LIMITED),
    ("", AVX2_ONLY | {"avx512f", "avx512bw"}, ""),  # AVX-512: XLA's defaults
    ("", frozenset({"fp", "asimd"}), ""),  # not x86
    ("", None, ""),  # unknown host
    ("--xla_cpu_experimental_ynn_fusion_type=", AVX2_ONLY, "--xla_cpu_experimental_ynn_fusion_type="),  # the user's
])
def test_ynnpack_fusions_are_limited_only_on_x86_without_avx512(xla_flags, cpu_flags, expected):
    assert limit_cpu_fusions(xla_flags, cpu_flags) == expected


def test_use_cpu_cores_rejects_a_bad_count():
    with pytest.raises(ValueError, match="n must be >= 1"):
        use_cpu_cores(n=0)


def test_compiler_options_change_the_convolutions_not_the_results():
    """On CPU the options take the convolutions away from YNNPACK; the network's output does not change."""
    opts = compiler_options()
    if jax.default_backend() != "cpu":
        assert opts == {}
        return
    cfg = ModelConfig(tr=1, base=8, growth=4, head=16, filter_hidden=16)
    params, state = init_model(jax.random.key(0), cfg)
    windows = jax.random.uniform(jax.random.key(1), (2, 3, 8, 12))
    f = lambda p, s, w: apply_model(p, s, w, cfg)  # noqa: E731
    default = jax.jit(f).lower(params, state, windows).compile()
    tuned = jax.jit(f, compiler_options=opts).lower(params, state, windows).compile()
    np.testing.assert_allclose(tuned(params, state, windows), default(params, state, windows), rtol=1e-5, atol=1e-5)
    if opts:  # this XLA knows the option: no convolution may go to YNNPACK
        assert "__ynn_fusion" not in tuned.as_text()
    opts["extra"] = 1  # a new dict each call: the caller may change it
    assert "extra" not in compiler_options()
