"""How JAX runs this project's programs: processes, CPU devices, XLA compiler options and the compilation cache.

These are process-wide settings, not pipeline stages: call `init_distributed` (training across processes) first,
then `use_cpu_cores` and `enable_compilation_cache` once, right after `import jax`; pass `compiler_options()` to
`jax.jit` around code that calls `apply_model`.
"""

from __future__ import annotations

import contextlib
import functools
import importlib.metadata
import os
import math
import re
from pathlib import Path

import jax
import jax.numpy as jnp

from .joining import gather, meet

__all__ = ["MAX_CPU_DEVICES", "use_cpu_cores", "compiler_options", "enable_compilation_cache", "limit_cpu_fusions",
           "BFLOAT16_CPU_FLAGS", "cpu_bfloat16_features",
           "init_distributed", "distributed_settings", "DISTRIBUTED_ENV", "JOIN_TIMEOUT_S"]

# `use_cpu_cores` exposes at most this many: the speed-up was measured on 2 cores only.
MAX_CPU_DEVICES = 8
# XLA:CPU hands convolutions to the YNNPACK library by default. On this network's 3x3 convolutions with 32
# output channels YNNPACK ran on one thread (135 GFLOP/s on 2 cores), XLA's own Eigen convolution on both
# (240 GFLOP/s); TR4 inference went from 4.6 to 7.0 frames/s on one device (benchmarks/compare_torch.py).
# The empty list turns YNNPACK fusions off.
_CPU_OPTIONS = {"xla_cpu_experimental_ynn_fusion_type": ""}


# XLA:CPU's YNNPACK element-wise and reduction fusions crash the process (SIGSEGV) on an x86 host without AVX-512:
# a 2-core AMD EPYC with AVX2 only, JAX 0.10.2 (2026-11-24), running the vmapped gradient of `pipeline_metric`
# over two or more sensors (tests/inference/test_pipeline.py), with either fusion type alone; with YNNPACK kept to
# dots and convolutions it runs. Hosts with AVX-512 ran the whole suite with XLA's defaults on the same JAX (sessions of
# 2026-11-21 to 23): the instruction set is the difference seen, not an established cause. Older jaxlibs may not
# know the option, and XLA aborts on an unknown flag, so it is set only from the version where it was seen.
_YNN_OPTION = "xla_cpu_experimental_ynn_fusion_type"
_YNN_WITHOUT_AVX512 = "individual_dot,individual_convolution"
_YNN_SINCE = (0, 10, 2)  # the jaxlib that crashed, and knows the option


def limit_cpu_fusions(xla_flags: str, cpu_flags) -> str:
    """The XLA_FLAGS a host should run with: returns `xla_flags` plus YNNPACK fusions limited to dots and
    convolutions when the host is x86 without AVX-512 (see the note above `_YNN_OPTION`), `xla_flags` unchanged on
    other hosts or when it sets that option already (the user's choice stands).

    cpu_flags: the host's CPU feature names (/proc/cpuinfo's "flags"), None when unknown (then unchanged). Pure:
    `import jaxsr` applies it to the environment (`guard_cpu_fusions`)."""
    x86_without_avx512 = cpu_flags is not None and "sse2" in cpu_flags and "avx512f" not in cpu_flags
    if not x86_without_avx512 or _YNN_OPTION in xla_flags:
        return xla_flags
    return f"{xla_flags} --{_YNN_OPTION}={_YNN_WITHOUT_AVX512}".strip()


def _host_cpu_flags() -> frozenset | None:
    """The CPU feature names of /proc/cpuinfo's first "flags" line (x86 Linux), None elsewhere."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("flags"):
                    return frozenset(line.split(":", 1)[1].split())
    except OSError:
        pass
    return None


# The x86 CPU features that multiply bfloat16 in hardware (/proc/cpuinfo's names): AVX512-BF16's dot products and
# AMX's tiles. A CPU without them emulates bfloat16 arithmetic.
BFLOAT16_CPU_FLAGS = ("avx512_bf16", "amx_bf16")


def cpu_bfloat16_features(cpu_flags=None) -> tuple[str, ...]:
    """The host CPU's bfloat16 features among `BFLOAT16_CPU_FLAGS` (e.g. ("avx512_bf16",)), () when it has none
    or they cannot be read (not x86 Linux). cpu_flags: the feature names to look in (default /proc/cpuinfo's).

    Having them does not make bfloat16 convolutions faster by itself: XLA:CPU must also run them in bfloat16
    (docs/network.md, "Precision"; experiments/results/inference_forms.md measured whether it does)."""
    flags = _host_cpu_flags() if cpu_flags is None else frozenset(cpu_flags)
    return tuple(f for f in BFLOAT16_CPU_FLAGS if flags and f in flags)


def _jaxlib_version() -> tuple:
    """The installed jaxlib's (major, minor, patch), (0,) when unknown."""
    try:
        return tuple(int(x) for x in re.findall(r"\d+", importlib.metadata.version("jaxlib"))[:3])
    except importlib.metadata.PackageNotFoundError:
        return (0,)


def guard_cpu_fusions() -> None:
    """Apply `limit_cpu_fusions` to this process's XLA_FLAGS. XLA reads them when JAX's CPU backend starts, so this
    works only before the first JAX computation: `import jaxsr` calls it; code that ran JAX before importing jaxsr
    on such a host should set the option in XLA_FLAGS itself."""
    if _jaxlib_version() < _YNN_SINCE:
        return
    flags = os.environ.get("XLA_FLAGS", "")
    limited = limit_cpu_fusions(flags, _host_cpu_flags())
    if limited != flags:
        os.environ["XLA_FLAGS"] = limited


def use_cpu_cores(*, n: int | None = None) -> int:
    """Expose the host's CPU cores as n JAX CPU devices, so that `super_resolve` can split a batch over them.

    Call it right after `import jax`, before any JAX operation: once the backend is running the device count is
    fixed, and this leaves it as it is. n: a scalar count (default: the cores this process may use, at most
    MAX_CPU_DEVICES). It does nothing if XLA_FLAGS already sets --xla_force_host_platform_device_count. Returns
    the number of devices JAX will use (asking starts the backend: call `jax.distributed.initialize` first).
    On a JAX without the `jax_num_cpu_devices` option it leaves the devices as they are.
    """
    if n is None:
        n = min(len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1,
                MAX_CPU_DEVICES)
    if n < 1:
        raise ValueError(f"use_cpu_cores: n must be >= 1, got {n}")
    if "xla_force_host_platform_device_count" not in os.environ.get("XLA_FLAGS", ""):
        try:
            jax.config.update("jax_num_cpu_devices", int(n))
        except (RuntimeError, AttributeError):  # backend already running, or an older JAX: keep its devices
            pass
    return jax.local_device_count()


def compiler_options() -> dict:
    """XLA compiler options under which the network's inference runs fastest on the default backend.

    `jax.jit(f, compiler_options=jaxsr.runtime.compiler_options())`; `super_resolve` uses them. On CPU: XLA's own
    convolutions instead of YNNPACK (see `_CPU_OPTIONS`); elsewhere, or on an XLA that does not know the option,
    {} (the defaults). Not for training: the TR4 train step ran 1.8x slower with them (its gradient
    convolutions are faster in YNNPACK). Probed once per process, by compiling a one-element function (this
    starts the backend). Returns a new dict.
    """
    return dict(_CPU_OPTIONS) if _cpu_options_apply() else {}


@functools.cache
def _cpu_options_apply() -> bool:
    if jax.default_backend() != "cpu":
        return False
    try:
        jax.jit(lambda x: x + 1, compiler_options=_CPU_OPTIONS).lower(jnp.zeros(())).compile()
    except Exception:  # noqa: BLE001 - an XLA without the option: INVALID_ARGUMENT, "No such compile option"
        return False
    return True


def enable_compilation_cache(*, path=None) -> Path | None:
    """Turn on JAX's persistent compilation cache, so that a second run skips XLA compilation.

    path: the cache folder (default: $JAXSR_CACHE_DIR, else $XDG_CACHE_HOME/jaxsr/xla, else ~/.cache/jaxsr/xla).
    JAXSR_CACHE_DIR=off disables it. The folder may be copied or moved, also to another machine of the same kind
    (device, jaxlib, XLA flags): its entries' keys do not hold its path. Takes no arrays (path is a scalar
    option); returns the folder used, or None when disabled."""
    if path is None:
        path = os.environ.get("JAXSR_CACHE_DIR")
        if path is None:
            base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
            path = Path(base) / "jaxsr" / "xla"
    if str(path).lower() == "off":
        return None
    path = Path(path).expanduser()
    path.mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    with contextlib.suppress(AttributeError):  # a JAX without XLA's own caches
        # XLA's GPU autotuning cache would live inside the folder, and its path would enter every entry's key: a
        # copy elsewhere (the next slot's machine) would then miss on every entry
        jax.config.update("jax_persistent_cache_enable_xla_caches", "none")
    return path


# Training across processes (JAX's multi-controller runtime): the environment variables `init_distributed` reads when
# its arguments are not given, as (coordinator "HOST:PORT", number of processes, this process's id).
DISTRIBUTED_ENV = ("JAXSR_COORDINATOR", "JAXSR_NUM_PROCESSES", "JAXSR_PROCESS_ID")
# How long a process waits for the others to join by default (seconds): JAX's own default; processes a scheduler
# starts minutes apart need more (`init_distributed(timeout=...)`, `jaxsr train --join-timeout`).
JOIN_TIMEOUT_S = 300.0
# The variables of a Slurm job step that JAX's own detection (`jax.distributed.initialize()` with no arguments) reads.
_SLURM_ENV = ("SLURM_JOB_ID", "SLURM_STEP_NODELIST", "SLURM_NTASKS", "SLURM_PROCID", "SLURM_LOCALID")


def _whole(text, what: str, lo: int) -> int:
    try:
        value = int(text)
    except (TypeError, ValueError):
        raise ValueError(f"init_distributed: {what} must be an integer >= {lo}, got {text!r}") from None
    if value < lo:
        raise ValueError(f"init_distributed: {what} must be an integer >= {lo}, got {value}")
    return value


def distributed_settings(coordinator=None, num_processes=None, process_id=None, *, environ=None) -> dict | None:
    """How `init_distributed` starts this process, computing nothing: None for one process (no runtime to start),
    else {"coordinator_address", "num_processes", "process_id"} for `jax.distributed.initialize` (each None where
    JAX's own Slurm detection fills it in).

    Each argument left None comes from `environ` (default os.environ): JAXSR_COORDINATOR ("HOST:PORT", process 0's
    host and a free port on it), JAXSR_NUM_PROCESSES, JAXSR_PROCESS_ID. When none of the three is set anywhere, a
    Slurm job step of several tasks (`srun`: SLURM_NTASKS > 1 and the step's variables) runs one process per task,
    as JAX detects it; otherwise, or with a count of 1, one process. Raises ValueError for a malformed value, a
    process id outside 0..count-1, or a partial set of the three outside Slurm."""
    env = os.environ if environ is None else environ
    names = dict(zip(("coordinator", "num_processes", "process_id"), DISTRIBUTED_ENV))
    given = {"coordinator": coordinator, "num_processes": num_processes, "process_id": process_id}
    given = {k: env.get(names[k]) if v is None or v == "" else v for k, v in given.items()}
    given = {k: None if v is None or v == "" else v for k, v in given.items()}
    if given["coordinator"] is not None:
        host, _, port = str(given["coordinator"]).rpartition(":")
        if not host or not port.isdigit() or not 0 < int(port) < 65536:
            raise ValueError(f"init_distributed: the coordinator must be HOST:PORT (process 0's host and a free port "
                             f"on it, e.g. 10.0.0.1:8476), got {given['coordinator']!r}")
        given["coordinator"] = str(given["coordinator"])
    if given["num_processes"] is not None:
        given["num_processes"] = _whole(given["num_processes"], "the number of processes", 1)
    if given["process_id"] is not None:
        given["process_id"] = _whole(given["process_id"], "the process id", 0)
    n, i = given["num_processes"], given["process_id"]
    if n is not None and i is not None and i >= n:
        raise ValueError(f"init_distributed: process id {i} is outside 0..{n - 1} (ids run from 0 to the number of "
                         "processes - 1)")
    if n == 1:
        return None
    slurm = all(v in env for v in _SLURM_ENV)
    if all(v is None for v in given.values()):
        if not slurm or _whole(env["SLURM_NTASKS"], "SLURM_NTASKS", 1) == 1:
            return None
    elif not slurm and any(v is None for v in given.values()):
        missing = [f"{k} (${names[k]})" for k, v in given.items() if v is None]
        raise ValueError("init_distributed: training across processes needs the coordinator, the number of processes "
                         f"and this process's id; missing: {', '.join(missing)}")
    return {"coordinator_address": given["coordinator"], "num_processes": n, "process_id": i}


def init_distributed(coordinator: str | None = None, num_processes: int | None = None,
                     process_id: int | None = None, *, timeout: float = JOIN_TIMEOUT_S, say=None) -> tuple[int, int]:
    """Join a training run across processes (and hosts): start JAX's multi-controller runtime
    (`jax.distributed.initialize`), after which `jax.devices()` lists every process's devices and `jaxsr.fit`
    splits each global batch over them all. Returns (this process's index, the number of processes).

    Call it first, before any other JAX use (an array, `jax.devices()`, `use_cpu_cores`...): the runtime can only
    start before JAX's backend does; afterwards this raises RuntimeError saying so. Every process calls it with
    the same coordinator and count and its own id; process 0 hosts the coordinator, bound to the address given
    (HOST must be one of process 0's own addresses). The arguments, or the environment variables
    JAXSR_COORDINATOR / JAXSR_NUM_PROCESSES / JAXSR_PROCESS_ID, or under `srun` Slurm's own variables decide
    (`distributed_settings`). With one process it does nothing and returns (0, 1); called again in a process that
    joined, it returns the same pair. On CPU the processes exchange data with gloo (JAX's default CPU collectives);
    on GPUs JAX gives each process under Slurm the GPU of its local task id.

    Before JAX's runtime starts, the processes meet at the coordinator's address (`jaxsr.joining`): each waits at
    most `timeout` seconds (default `JOIN_TIMEOUT_S`) for the others, and Ctrl-C ends the wait. say(line), when
    given, is told what is waited for (the address, the process ids). Raises `jaxsr.joining.JoinError` (one line)
    for a process missing at the timeout, the coordinator's port in use or its host not process 0's, or processes
    told different counts or the same id; ValueError for a timeout that is not a positive number of seconds.
    Under Slurm with no coordinator given, JAX's own detection and wait run (bounded by `timeout` too)."""
    settings = distributed_settings(coordinator, num_processes, process_id)
    if isinstance(timeout, bool) or not isinstance(timeout, (int, float)) or not 0 < timeout < math.inf:
        raise ValueError(f"init_distributed: the timeout must be a positive number of seconds, got {timeout!r}")
    if jax.distributed.is_initialized():
        return jax.process_index(), jax.process_count()
    if settings is None:
        return 0, 1
    extra = {"initialization_timeout": min(max(1, math.ceil(timeout)), 2**31 - 1)}  # a C int
    address, n, i = settings["coordinator_address"], settings["num_processes"], settings["process_id"]
    if address is not None and n is not None and i is not None:
        if _backend_started():  # before the wait: JAX would refuse only after it, leaving the others waiting
            raise _started_error(None)
        if i == 0:
            gather(address, n, timeout, say)
            extra["coordinator_bind_address"] = address  # JAX's default listens on every interface ([::])
        else:
            meet(address, i, n, timeout, say)
    elif say is not None:
        say(f"joining the Slurm job's run as JAX detects it (up to {timeout:g} s)")
    try:
        jax.distributed.initialize(**settings, **extra)
    except RuntimeError as e:
        if "before" not in str(e):
            raise
        raise _started_error(e) from None
    # the pair without asking JAX (which would start the backend: use_cpu_cores may still set the devices); under
    # Slurm, the task variables JAX read
    index = settings["process_id"] if settings["process_id"] is not None else int(os.environ["SLURM_PROCID"])
    count = settings["num_processes"] if settings["num_processes"] is not None else int(os.environ["SLURM_NTASKS"])
    return index, count


def _backend_started() -> bool:
    """Whether JAX's backend already runs in this process (then it can no longer join a run across processes);
    False where this JAX does not tell (`jax.distributed.initialize` then refuses)."""
    try:
        from jax._src import xla_bridge  # JAX's own test, the one jax.distributed.initialize makes
        return bool(xla_bridge.backends_are_initialized())
    except (ImportError, AttributeError):
        return False


def _started_error(cause) -> RuntimeError:
    return RuntimeError("init_distributed must be called before any other JAX use (arrays, jax.devices(), "
                        "use_cpu_cores ...): JAX's backend is already running in this process, so it can no longer "
                        "join a run across processes" + (f" ({cause})" if cause is not None else ""))
