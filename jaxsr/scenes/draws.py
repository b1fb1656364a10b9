"""Random numbers keyed by name, so that a new draw in one place cannot shift the numbers of another.

A scene builder takes a `Draws` and asks it for uniform numbers by name: `draws.uniform("height", 1.55, 1.95)`.
The numbers of a name depend only on the root key, the name's path (`street/people/height`) and its shape:
adding, removing or reordering draws elsewhere leaves them unchanged. Taking a name twice in one builder is an
error (two quantities that should be independent would silently be equal).

`with_draws(build, key)` runs a builder twice at trace time: once under `jax.eval_shape` with placeholders,
to learn every name and shape it asks for, then for real, with all its numbers from one counter-based hash
call. Hundreds of separate `jax.random` calls would make the scene samplers take 10+ s to compile.
"""

from __future__ import annotations

import math
import zlib

import jax
import jax.numpy as jnp
import numpy as np
from jax.extend.random import threefry_2x32

__all__ = ["Draws", "with_draws"]


def _name_id(path: str) -> int:
    """A stable 32-bit id of a draw's path (CRC-32: the same in every process, unlike `hash`)."""
    return zlib.crc32(path.encode())


class Draws:
    """Named uniform draws for a scene builder: either a recorder (first pass: notes names and shapes, returns
    placeholders) or a table of drawn numbers (second pass). Builders see the same interface in both."""

    def __init__(self, table=None, *, prefix="", requests=None, batch=()):
        self._table = table  # {path: array} of uniforms in [0, 1) (second pass)
        self._prefix = prefix
        self._requests = requests  # {path: shape} shared by every recorder of one build (first pass)
        self._batch = batch  # leading shape of a vmapped builder's draws, recorded with each request
        self._taken = set()

    @property
    def recording(self) -> bool:
        return self._requests is not None

    def _take(self, name: str, shape: tuple[int, ...]):
        if "/" in name:
            raise ValueError(f"draw name {name!r} must not contain '/'")
        if name in self._taken:
            raise ValueError(f"draw {self._prefix + name!r} taken twice: give each independent quantity its own name")
        self._taken.add(name)
        path = self._prefix + name
        if self.recording:
            self._requests[path] = self._batch + shape
            return jnp.zeros(shape, jnp.float32)
        return self._table[path]

    def uniform(self, name: str, lo=0.0, hi=1.0, shape=()):
        """Uniform numbers in [lo, hi) of `shape`, keyed by `name`."""
        return lo + (hi - lo) * self._take(name, tuple(shape))

    def coin(self, name: str, p, shape=()):
        """Booleans of `shape`, each True with probability p."""
        return self._take(name, tuple(shape)) < p

    def count(self, name: str, lo: int, hi: int):
        """An int32 uniform in {lo, ..., hi}."""
        u = self._take(name, ())
        return jnp.minimum(jnp.floor(lo + (hi - lo + 1) * u), hi).astype(jnp.int32)

    def child(self, name: str) -> Draws:
        """The draws of a sub-builder (e.g. one object), under the path `name/`."""
        self._take_child(name)
        return Draws(self._table, prefix=f"{self._prefix}{name}/", requests=self._requests, batch=self._batch)

    def batched(self, name: str, n: int):
        """The draws of `n` objects built by one vmapped builder, under `name/`.

        Returns (table, make): pass `table` (a pytree with leading axis n, or None while recording) through
        `jax.vmap` and call `make(table_i)` inside to get each object's `Draws`."""
        self._take_child(name)
        prefix = f"{self._prefix}{name}/"
        if self.recording:
            recorder = Draws(prefix=prefix, requests=self._requests, batch=self._batch + (n,))
            return None, lambda _: recorder
        table = {path: v for path, v in self._table.items() if path.startswith(prefix)}
        return table, lambda t: Draws(t, prefix=prefix)

    def _take_child(self, name):
        if name in self._taken:
            raise ValueError(f"draws {self._prefix + name!r}/ taken twice")
        self._taken.add(name)


def _uniform_from_bits(bits):
    """uint32 -> float32 uniform in [0, 1): the top 23 bits as the mantissa of a number in [1, 2), minus 1."""
    one_to_two = jax.lax.bitcast_convert_type((bits >> 9) | np.uint32(0x3F800000), jnp.float32)
    return one_to_two - 1.0


def _draw_table(key, requests: dict) -> dict:
    """Uniform numbers for every requested path: path -> array of its shape.

    Number i of a path is the Threefry-2x32 hash of the counter pair (CRC-32 of the path, i) under a seed drawn
    from `key`: it depends on nothing else, and one hash call serves every draw of a scene."""
    paths = sorted(requests)
    ids = [_name_id(p) for p in paths]
    if len(set(ids)) != len(ids):
        raise ValueError("two draw names share a CRC-32 id; rename one")
    sizes = [math.prod(requests[p]) for p in paths]
    counters = np.stack([np.repeat(np.asarray(ids, np.uint32), sizes),
                         np.concatenate([np.arange(s, dtype=np.uint32) for s in sizes])])
    seed = jax.random.bits(key, (2,), jnp.uint32)
    u = _uniform_from_bits(threefry_2x32((seed[0], seed[1]), jnp.asarray(counters))[0])
    offsets = np.cumsum([0] + sizes)
    return {p: u[offsets[i]:offsets[i + 1]].reshape(requests[p]) for i, p in enumerate(paths)}


def with_draws(build, key):
    """`build(draws)` with named uniform draws from the PRNG `key` (see the module docstring).

    build: a function of one `Draws` returning a pytree; it must not depend on the values of its draws for
    anything static (shapes, Python control flow). Returns what `build` returns."""
    requests: dict = {}
    jax.eval_shape(lambda: build(Draws(requests=requests)))
    return build(Draws(_draw_table(key, requests)))
