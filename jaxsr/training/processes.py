"""Data parallelism and runs across processes: the mesh `fit` splits each batch over, and process 0's word on
every process.

A data-parallel recipe (the DUF network) splits each batch over a `jax.sharding.Mesh` with a "data" axis (default:
all devices), also across processes and hosts (`jaxsr.runtime.init_distributed`): every process runs the same
steps on its share of the global batch, and process 0 alone reads and writes the run folder (`_on_lead`), telling
the others what it read or decided (`_share`).
"""

from __future__ import annotations

import builtins
import json

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from .duf import data_mesh

__all__ = ["choose_mesh", "replicate"]


def choose_mesh(mesh, batch_size: int) -> Mesh | None:
    """`fit`'s mesh argument resolved: "auto" shards over all devices when there are several that divide the
    batch evenly.

    Across processes (`jax.process_count()` > 1) the batch is the global one, and it must be split: the mesh
    ("auto", or a `Mesh`) must hold every process's devices and `batch_size` must be a multiple of their number,
    else ValueError (so must it be for mesh=None, which would have every process do the whole batch)."""
    n, processes = jax.device_count(), jax.process_count()
    if processes > 1:
        if not (mesh == "auto" or (isinstance(mesh, Mesh) and mesh.devices.size == n)):
            raise ValueError(f"fit: across {processes} processes the batch is split over a mesh of all {n} devices; "
                             f"got mesh={mesh!r} (pass 'auto')")
        if batch_size % n:
            raise ValueError(f"fit: the global batch of {batch_size} (TrainConfig.batch_size) does not split evenly "
                             f"over the {n} devices of {processes} processes; choose a multiple of {n}")
        return data_mesh() if mesh == "auto" else mesh
    if mesh != "auto":
        return mesh
    return data_mesh() if n > 1 and batch_size % n == 0 else None


def replicate(tree, mesh: Mesh | None):
    """`tree` with a copy on every device of `mesh`, as a sharded train step expects its carry (params, state,
    Adam state: the step shards only the batch), so that its first calls do not compile again for another
    placement; unchanged when `mesh` is None."""
    return tree if mesh is None else jax.device_put(tree, NamedSharding(mesh, P()))


def _lead() -> bool:
    """Whether this process reads and writes the run folder: process 0 of a run across processes, or the only one."""
    return jax.process_index() == 0


def _share(value):
    """Process 0's `value` (JSON-serialisable) on every process; `value` itself with one process. Sent as the bytes
    of its JSON text (padded to a power of two, so that few lengths compile), so that floats arrive exactly."""
    if jax.process_count() == 1:
        return value
    from jax.experimental import multihost_utils  # late: only runs across processes need it

    text = json.dumps(value).encode() if _lead() else b""
    size = int(multihost_utils.broadcast_one_to_all(np.int32(len(text))))
    buffer = np.full(max(256, 1 << (size - 1).bit_length()), ord(" "), np.uint8)
    buffer[: len(text)] = np.frombuffer(text, np.uint8)
    return json.loads(np.asarray(multihost_utils.broadcast_one_to_all(buffer), np.uint8).tobytes().decode())


def _on_lead(fn):
    """fn() run by process 0 alone (it reads and writes the run folder), its JSON-serialisable result on every
    process; an exception it raises is raised on every process, of the same built-in type with the same message
    (RuntimeError naming it for others), so that no process waits for one that failed. fn() itself with one process."""
    if jax.process_count() == 1:
        return fn()
    error = None
    if _lead():
        try:
            outcome = {"value": fn()}
        except Exception as e:  # noqa: BLE001 - every process must learn of it; re-raised below
            error, outcome = e, {"error": type(e).__name__, "message": str(e)}
    else:
        outcome = None
    outcome = _share(outcome)
    if error is not None:
        raise error
    if "error" in outcome:
        kind = getattr(builtins, outcome["error"], None)
        if isinstance(kind, type) and issubclass(kind, Exception):
            raise kind(outcome["message"])
        raise RuntimeError(f"process 0: {outcome['error']}: {outcome['message']}")
    return outcome["value"]
