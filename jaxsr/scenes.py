"""Procedural depth-video scenes: streets, roads, courtyards and walkers, their sequences, training clips, the
paper's test sequences and temporal windows.

A scene (`jaxsr.render.Scene`) is a pytree of fixed-size arrays: `N_BOXES` boxes, `N_CYLINDERS` cylinders and
`N_ELLIPSOIDS` ellipsoids, each with an `active` mask, whatever the kind, so scenes of any kind sampled under
`jax.vmap` stack, and `kind=None` picks a kind per key with traced selection. Motion is in physical units: speeds
in m/s (drawn in km/h), times in seconds, frame rates in frames per second; the shift per frame in LR pixels of an
object at depth z moving across the view at speed v is v / (fps z) * focal_px / scale (`mean_lr_shift`).

World coordinates as in `jaxsr.render`: X right, Y up (ground Y = 0), Z forward; the camera starts at X = Z = 0.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .config import SensorConfig
from .render import (Boxes, Camera, Cylinders, Ellipsoids, Ground, Motion, Scene, _pose_all, _project_bounds,
                     render_sequence)
from .temporal import change_frame_rate as change_frame_rate  # re-exported: part of the scenes API
from .temporal import windows as windows

__all__ = [
    "KINDS",
    "N_BOXES",
    "N_CYLINDERS",
    "N_ELLIPSOIDS",
    "TEST_SEQUENCES",
    "TestSequence",
    "change_frame_rate",
    "empty_scene",
    "place",
    "mean_lr_shift",
    "sample_scene",
    "sequence",
    "test_scene",
    "test_sequence",
    "test_sequences",
    "training_clip",
    "training_scene",
    "windows",
]

N_BOXES = 32
N_CYLINDERS = 44
N_ELLIPSOIDS = 28
KINDS = ("street", "road", "courtyard", "walkers")

KMH = 1.0 / 3.6  # m/s per km/h
_STATIC_WRAP = 80.0  # m: static objects recycle around a sideways-moving camera beyond this distance


# ---------------------------------------------------------------------------------------------------------
# Parts: small groups of primitives with a leading count, concatenated and padded into a Scene.


def _motion(n, velocity, anchor, wrap_axis, wrap_half):
    b = lambda a, s: jnp.broadcast_to(jnp.asarray(a, jnp.float32), s)
    return Motion(b(velocity, (n, 3)), b(wrap_axis, (n, 3)), b(wrap_half, (n,)), b(anchor, (n, 3)))


def _object_motion(n, base, heading, speed, wrap_half):
    """Motion of an object at `base` (3,) moving at `speed` m/s along heading (rad in the X-Z plane)."""
    direction = jnp.array([jnp.cos(heading), 0.0, jnp.sin(heading)])
    moving = speed > 0
    axis = jnp.where(moving, direction, jnp.array([1.0, 0.0, 0.0]))
    half = jnp.where(moving, wrap_half, _STATIC_WRAP)
    return _motion(n, speed * direction, base, axis, half)


def _tex(period_s, period_h, amp, phase):
    return jnp.stack(jnp.broadcast_arrays(*(jnp.asarray(a, jnp.float32) for a in (period_s, period_h, amp, phase))),
                     -1)


def _empty(cls, n):
    m = _motion(n, 0.0, 0.0, jnp.array([1.0, 0.0, 0.0]), jnp.inf)
    z = lambda *s: jnp.zeros((n,) + s, jnp.float32)
    if cls is Boxes:
        return Boxes(z(3), jnp.ones((n, 2)), jnp.ones((n,)), z(), z(), jnp.ones((n, 4)), jnp.zeros((n,), bool), m)
    if cls is Cylinders:
        return Cylinders(z(3), jnp.ones((n,)), jnp.ones((n, 2)) * 0.1, z(), z(), z(3), z(), jnp.ones((n, 4)),
                         jnp.zeros((n,), bool), m)
    return Ellipsoids(z(3), jnp.ones((n, 3)), z(), z(), jnp.ones((n, 4)), jnp.zeros((n,), bool), m)


def _cat(parts, cls, n_max):
    parts = [p for p in parts if p is not None]
    total = sum(p.active.shape[0] for p in parts)
    if total > n_max:
        raise ValueError(f"scene needs {total} {cls.__name__.lower()} but the pytree holds {n_max}")
    parts = parts + [_empty(cls, n_max - total)]
    return jax.tree.map(lambda *xs: jnp.concatenate([jnp.asarray(x, jnp.float32) if x.dtype != bool else x
                                                     for x in xs], 0), *parts)


class _Parts(NamedTuple):
    boxes: list
    cylinders: list
    ellipsoids: list

    def add(self, other):
        self.boxes.extend(other.boxes)
        self.cylinders.extend(other.cylinders)
        self.ellipsoids.extend(other.ellipsoids)


def _parts(boxes=(), cylinders=(), ellipsoids=()):
    return _Parts(list(boxes), list(cylinders), list(ellipsoids))


def _gate(part, active):
    """The same part, active only where `active` (a traced bool) holds."""
    return part._replace(active=part.active & active)


class _Stream:
    """Uniform random numbers handed out in order from one pool drawn with a single PRNG call (hundreds of separate
    `jax.random` calls made the scene samplers take 10+ s to compile). Deterministic per key."""

    def __init__(self, pool):
        self.pool = pool
        self.offset = 0

    @classmethod
    def from_key(cls, key, size=2048):
        return cls(jax.random.uniform(key, (size,)))

    def take(self, shape=()):
        n = math.prod(shape)
        if self.offset + n > self.pool.shape[0]:
            raise RuntimeError("scene sampler ran out of random numbers; enlarge the pool")
        out = self.pool[self.offset:self.offset + n].reshape(shape)
        self.offset += n
        return out

    def split(self, n, size):
        """n independent child streams of `size` numbers each, as a (n, size) pool (for vmapped builders)."""
        return self.take((n, size))


class _Iter:
    """`next(k)` hands out the same stream (each use draws fresh numbers from it)."""

    def __init__(self, r):
        self.r = r

    def __iter__(self):
        return self

    def __next__(self):
        return self.r


class _Index(_Iter):
    def __getitem__(self, i):
        return self.r


def _u(r, lo, hi, shape=()):
    return lo + (hi - lo) * r.take(shape)


def _rot(heading, along, lateral):
    """World (X, Z) offset of a point `along` the heading and `lateral` to its left (towards +e2)."""
    c, s = jnp.cos(heading), jnp.sin(heading)
    return along * c - lateral * s, along * s + lateral * c


def _at(base, heading, along, lateral, height):
    ox, oz = _rot(heading, along, lateral)
    return jnp.stack(jnp.broadcast_arrays(base[0] + ox, jnp.asarray(height, jnp.float32) + 0.0, base[2] + oz), -1)


# ---------------------------------------------------------------------------------------------------------
# Objects


def person(key, base, heading, speed, *, running=False, active=True, wrap_half=30.0):
    """A person walking (3-6 km/h) or running: straight legs and arms swinging with a pendulum gait whose
    frequency matches the speed (stride = 4 L sin(amplitude)); torso and head. 5 cylinders + 1 ellipsoid."""
    k = _Index(key)
    height = _u(k[0], 1.55, 1.95)
    leg = 0.5 * height
    amp = jnp.where(running, 0.6, 0.38)
    freq = speed / (4.0 * leg * jnp.sin(amp))
    phase = _u(k[1], 0.0, 2 * math.pi)
    trousers, shirt, skin = _u(k[2], 0.05, 0.7), _u(k[3], 0.05, 0.95), _u(k[4], 0.3, 0.7)
    lean = jnp.where(running, -0.12, -0.03)
    m = _object_motion(5, base, heading, speed, wrap_half)
    hip, shoulder = leg, 0.81 * height
    pivots = jnp.concatenate([
        _at(base, heading, 0.0, jnp.array([0.1, -0.1]), hip),  # legs
        _at(base, heading, 0.0, jnp.array([0.23, -0.23]), shoulder - 0.02),  # arms
        _at(base, heading, 0.0, 0.0, shoulder + 0.02)[None],  # torso
    ])
    cyl = Cylinders(
        pivot=pivots,
        length=jnp.stack([leg, leg, 0.37 * height, 0.37 * height, shoulder + 0.02 - hip + 0.05]),
        radius=jnp.array([[0.075, 0.075], [0.075, 0.075], [0.045, 0.045], [0.045, 0.045], [0.12, 0.2]]),
        yaw=jnp.full((5,), heading),
        lean=jnp.array([0.0, 0.0, 0.0, 0.0, 1.0]) * lean,
        swing=jnp.stack([
            jnp.stack([amp, amp, 0.8 * amp, 0.8 * amp, 0.0 * amp]),
            jnp.full((5,), freq),
            jnp.stack([phase, phase + math.pi, phase + math.pi, phase, phase]),
        ], -1),
        reflectivity=jnp.stack([trousers, trousers, shirt, shirt, shirt]),
        texture=_tex(0.3, 0.15, jnp.array([0.1, 0.1, 0.2, 0.2, 0.25]), phase),
        active=jnp.full((5,), active),
        motion=m,
    )
    head = Ellipsoids(
        centre=_at(base, heading, 0.02, 0.0, 0.92 * height)[None],
        radii=jnp.array([[0.1, 0.12, 0.085]]),
        yaw=jnp.full((1,), heading),
        reflectivity=skin[None],
        texture=_tex(0.2, 0.2, 0.2, phase)[None],
        active=jnp.full((1,), active),
        motion=_object_motion(1, base, heading, speed, wrap_half),
    )
    return _parts(cylinders=[cyl], ellipsoids=[head])


def cyclist(key, base, heading, speed, *, active=True, wrap_half=40.0):
    """A cyclist (typically 10-25 km/h): two thin wheels, top tube, rider leaning forward, pedalling legs.
    1 box + 5 cylinders + 3 ellipsoids."""
    k = _Index(key)
    cadence = _u(k[0], 1.0, 1.5)
    phase = _u(k[1], 0.0, 2 * math.pi)
    clothes, bike = _u(k[2], 0.05, 0.9), _u(k[3], 0.05, 0.6)
    mb = _object_motion(1, base, heading, speed, wrap_half)
    frame = Boxes(
        centre=_at(base, heading, 0.0, 0.0, 0.72)[None], half=jnp.array([[0.42, 0.03]]), height=jnp.array([0.07]),
        yaw=jnp.full((1,), heading), reflectivity=bike[None], texture=_tex(1.0, 1.0, 0.0, 0.0)[None],
        active=jnp.full((1,), active), motion=mb,
    )
    cyl = Cylinders(
        pivot=jnp.concatenate([
            _at(base, heading, 0.12, 0.0, 1.42)[None],  # torso from the shoulders
            _at(base, heading, -0.22, jnp.array([0.11, -0.11]), 0.98),  # legs from the hips
            _at(base, heading, 0.12, jnp.array([0.19, -0.19]), 1.38),  # arms from the shoulders
        ]),
        length=jnp.array([0.6, 0.82, 0.82, 0.58, 0.58]),
        radius=jnp.array([[0.11, 0.18], [0.07, 0.07], [0.07, 0.07], [0.045, 0.045], [0.045, 0.045]]),
        yaw=jnp.full((5,), heading),
        lean=jnp.array([-0.75, 0.25, 0.25, 0.85, 0.85]),
        swing=jnp.stack([jnp.array([0.0, 0.35, 0.35, 0.0, 0.0]), jnp.full((5,), cadence),
                         jnp.stack([phase, phase, phase + math.pi, phase, phase])], -1),
        reflectivity=jnp.full((5,), clothes),
        texture=_tex(0.3, 0.2, 0.15, phase)[None].repeat(5, 0),
        active=jnp.full((5,), active),
        motion=_object_motion(5, base, heading, speed, wrap_half),
    )
    ell = Ellipsoids(
        centre=jnp.concatenate([_at(base, heading, jnp.array([0.52, -0.52]), 0.0, 0.34),
                                _at(base, heading, 0.3, 0.0, 1.6)[None]]),
        radii=jnp.array([[0.34, 0.34, 0.03], [0.34, 0.34, 0.03], [0.11, 0.13, 0.1]]),
        yaw=jnp.full((3,), heading),
        reflectivity=jnp.stack([jnp.array(0.08), jnp.array(0.08), _u(k[2], 0.3, 0.6)]),
        texture=_tex(0.2, 0.2, 0.1, 0.0)[None].repeat(3, 0),
        active=jnp.full((3,), active),
        motion=_object_motion(3, base, heading, speed, wrap_half),
    )
    return _parts(boxes=[frame], cylinders=[cyl], ellipsoids=[ell])


def vehicle(key, base, heading, speed, *, kind=0, active=True, wrap_half=45.0):
    """A car (kind 0), van (1) or truck (2): body and cabin boxes and up to three wheel pairs (each one ellipsoid
    spanning the track). `kind` may be traced. 2 boxes + 3 ellipsoids."""
    k = _Index(key)
    kind = jnp.asarray(kind)
    pick = lambda car, van, truck: jnp.select([kind == 0, kind == 1], [jnp.asarray(car, jnp.float32),
                                                                       jnp.asarray(van, jnp.float32)],
                                              jnp.asarray(truck, jnp.float32))
    length = pick(_u(k[0], 3.8, 4.8), _u(k[0], 4.8, 5.6), _u(k[0], 7.0, 9.5))
    width = pick(1.8, 2.0, 2.5)
    # Body: car and van lower body; truck cargo box.
    body_len = pick(length, length, length - 2.4)
    body_off = pick(0.0, 0.0, -1.2)
    body_y0, body_h = pick(0.3, 0.35, 1.0), pick(0.7, 0.85, _u(k[1], 2.5, 3.0))
    # Cabin: car greenhouse, van upper body, truck cab.
    cab_len = pick(0.5 * length, 0.75 * length, 2.3)
    cab_off = pick(-0.15 * length / 2, -0.1 * length / 2, length / 2 - 1.15)
    cab_y0, cab_h = pick(1.0, 1.2, 0.5), pick(0.45, 1.0, 2.6)
    cab_w = pick(1.55, 1.95, 2.45)
    paint = _u(k[2], 0.05, 0.95)
    m2 = _object_motion(2, base, heading, speed, wrap_half)
    boxes = Boxes(
        centre=jnp.stack([_at(base, heading, body_off, 0.0, body_y0), _at(base, heading, cab_off, 0.0, cab_y0)]),
        half=jnp.stack([jnp.stack([body_len / 2, width / 2]), jnp.stack([cab_len / 2, cab_w / 2])]),
        height=jnp.stack([body_h, cab_h]),
        yaw=jnp.full((2,), heading),
        reflectivity=jnp.stack([paint, paint]),
        # Cabin windows: dark rectangles (negative amplitude would lighten).
        texture=jnp.stack([_tex(1.3, 0.6, 0.15, 0.0), _tex(pick(1.1, 1.3, 1.2), pick(0.9, 1.3, 2.0), 0.7, 0.25)]),
        active=jnp.full((2,), active),
        motion=m2,
    )
    r = pick(0.33, 0.36, 0.5)
    axle = length / 2 - pick(0.85, 0.9, 1.2)
    along = jnp.stack([axle, -axle, -axle + 1.35])
    wheels = Ellipsoids(
        centre=_at(base, heading, along, 0.0, r),
        radii=jnp.stack([jnp.stack([r, r, width / 2 + 0.02])] * 3),
        yaw=jnp.full((3,), heading),
        reflectivity=jnp.full((3,), 0.06),
        texture=_tex(0.3, 0.3, 0.0, 0.0)[None].repeat(3, 0),
        active=jnp.stack([active, active, active & (kind == 2)]),
        motion=_object_motion(3, base, heading, speed, wrap_half),
    )
    return _parts(boxes=[boxes], ellipsoids=[wheels])


def _static_boxes(centre, half, height, yaw, reflectivity, texture, active=True):
    n = centre.shape[0]
    return Boxes(centre, half, height, jnp.broadcast_to(yaw, (n,)), reflectivity, texture,
                 jnp.broadcast_to(active, (n,)), _motion(n, 0.0, centre, jnp.array([1.0, 0.0, 0.0]), _STATIC_WRAP))


def buildings(key, n, *, z_range, x_span, height_range, active=None):
    """A row of `n` building facades facing the camera (window grids), with random gaps."""
    k = _Index(key)
    width = _u(k[0], 6.0, 20.0, (n,))
    gap = _u(k[1], 0.0, 8.0, (n,)) * _coin(k[2], 0.5, (n,))
    x = -x_span + jnp.cumsum(width + gap) - width / 2 + _u(k[3], -5.0, 5.0)
    depth = _u(k[4], 8.0, 20.0, (n,))
    z = _u(k[5], *z_range, (n,)) + depth / 2
    centre = jnp.stack([x, jnp.zeros(n), z], -1)
    tex = _tex(_u(k[6], 2.0, 4.0, (n,)), _u(k[6], 2.8, 3.6, (n,)), _u(k[7], -0.3, 0.7, (n,)), _u(k[7], 0, 1, (n,)))
    act = jnp.ones((n,), bool) if active is None else active
    return _static_boxes(centre, jnp.stack([width / 2, depth / 2], -1), _u(k[3], *height_range, (n,)),
                         _u(k[2], -0.08, 0.08, (n,)), _u(k[4], 0.2, 0.8, (n,)), tex, act)


def tree(key, base, *, active=True):
    """A tree: trunk (cylinder) and crown (ellipsoid)."""
    k = _Index(key)
    trunk_h = _u(k[0], 1.8, 3.2)
    crown = jnp.stack([_u(k[1], 1.0, 2.2), _u(k[2], 1.2, 2.6), _u(k[1], 1.0, 2.2)])
    m = _motion(1, 0.0, base, jnp.array([1.0, 0.0, 0.0]), _STATIC_WRAP)
    trunk = Cylinders(
        pivot=(base + jnp.array([0.0, 1.0, 0.0]) * (trunk_h + 0.5))[None], length=(trunk_h + 0.5)[None],
        radius=jnp.full((1, 2), _u(k[3], 0.12, 0.3)), yaw=jnp.zeros(1), lean=jnp.zeros(1), swing=jnp.zeros((1, 3)),
        reflectivity=jnp.full((1,), _u(k[3], 0.15, 0.4)), texture=_tex(0.15, 0.4, 0.3, 0.0)[None],
        active=jnp.full((1,), active), motion=m,
    )
    crown_e = Ellipsoids(
        centre=(base + jnp.array([0.0, 1.0, 0.0]) * (trunk_h + 0.8 * crown[1]))[None], radii=crown[None],
        yaw=_u(k[0], 0, 3)[None], reflectivity=_u(k[2], 0.15, 0.45)[None], texture=_tex(0.35, 0.3, 0.5, 0.0)[None],
        active=jnp.full((1,), active), motion=m,
    )
    return _parts(cylinders=[trunk], ellipsoids=[crown_e])


def pole(key, base, *, active=True):
    """A lamp post or sign pole: a thin tall cylinder."""
    k = _Index(key)
    h = _u(k[0], 2.5, 7.0)
    return _parts(cylinders=[Cylinders(
        pivot=(base + jnp.array([0.0, 1.0, 0.0]) * h)[None], length=h[None],
        radius=jnp.full((1, 2), _u(k[1], 0.05, 0.12)), yaw=jnp.zeros(1), lean=jnp.zeros(1), swing=jnp.zeros((1, 3)),
        reflectivity=_u(k[1], 0.2, 0.8)[None], texture=_tex(0.5, 0.5, 0.1, 0.0)[None],
        active=jnp.full((1,), active), motion=_motion(1, 0.0, base, jnp.array([1.0, 0.0, 0.0]), _STATIC_WRAP),
    )])


def bench(key, base, yaw, *, active=True):
    """A bench or sofa: seat and backrest boxes (the gap under the seat shows the ground)."""
    k = _Index(key)
    length = _u(k[0], 1.2, 2.2)
    back = _rot(yaw, 0.0, 0.22)
    centre = jnp.stack([base + jnp.array([0.0, 0.38, 0.0]),
                        base + jnp.stack([back[0], jnp.array(0.5), back[1]])])
    refl = _u(k[1], 0.1, 0.7)
    return _parts(boxes=[_static_boxes(centre, jnp.stack([jnp.stack([length / 2, 0.25]),
                                                          jnp.stack([length / 2, 0.04])]),
                                       jnp.array([0.08, 0.4]), yaw, jnp.stack([refl, refl]),
                                       _tex(0.12, 1.0, 0.25, 0.0)[None].repeat(2, 0), active)])


def table(key, base, yaw, *, active=True):
    """A table: top (box) on a central pedestal (cylinder)."""
    k = _Index(key)
    half = jnp.stack([_u(k[0], 0.4, 0.9), _u(k[1], 0.35, 0.6)])
    refl = _u(k[2], 0.2, 0.9)
    top = _static_boxes((base + jnp.array([0.0, 0.71, 0.0]))[None], half[None], jnp.array([0.05]), yaw,
                        refl[None], _tex(0.5, 0.5, 0.1, 0.0)[None], active)
    leg = Cylinders(
        pivot=(base + jnp.array([0.0, 0.71, 0.0]))[None], length=jnp.array([0.71]), radius=jnp.full((1, 2), 0.05),
        yaw=jnp.zeros(1), lean=jnp.zeros(1), swing=jnp.zeros((1, 3)), reflectivity=jnp.full((1,), 0.3),
        texture=_tex(0.5, 0.5, 0.0, 0.0)[None], active=jnp.full((1,), active),
        motion=_motion(1, 0.0, base, jnp.array([1.0, 0.0, 0.0]), _STATIC_WRAP),
    )
    return _parts(boxes=[top], cylinders=[leg])


def block(key, base, yaw, *, size_range=((0.3, 1.2), (0.2, 0.6), (0.4, 2.0)), active=True):
    """A box-shaped piece of furniture or street furniture (shelf, cabinet, crate, bin, kiosk)."""
    k = _Index(key)
    half = jnp.stack([_u(k[0], *size_range[0]), _u(k[1], *size_range[1])])
    h = _u(k[2], *size_range[2])
    tex = _tex(_u(k[3], 0.2, 0.8), _u(k[3], 0.2, 0.5), _u(k[3], -0.3, 0.5), 0.0)
    return _parts(boxes=[_static_boxes(base[None], half[None], h[None], yaw, _u(k[3], 0.1, 0.9)[None], tex[None],
                                       active)])


def wall(centre, half, height, yaw, reflectivity, texture, active=True):
    """A wall, fence or hedge: one box."""
    return _parts(boxes=[_static_boxes(centre[None], half[None], jnp.asarray(height)[None], yaw,
                                       jnp.asarray(reflectivity)[None], texture[None], active)])


# ---------------------------------------------------------------------------------------------------------
# Scene kinds. Each returns (parts, ground, default camera); positions in world metres.


def _camera(key, mode, *, height_range=(1.5, 2.0), tilt_range=(0.03, 0.12), speed_range=(0.5, 8.0)):
    """Static camera, or ('moving') one translating sideways along X with a slow pan; 'random': 35 % moving."""
    k = _Index(key)
    h = _u(k[0], *height_range)
    if mode == "static":
        moving = jnp.array(False)
    elif mode == "moving":
        moving = jnp.array(True)
    elif mode == "random":
        moving = _coin(k[1], 0.35)
    else:
        raise ValueError(f"camera must be 'static', 'moving' or 'random', got {mode!r}")
    speed = _u(k[2], *speed_range) * jnp.where(_coin(k[3], 0.5), 1.0, -1.0)
    yaw = _u(k[4], -0.15, 0.15)
    yaw_rate = jnp.where(moving, _u(k[4], -0.05, 0.05), 0.0)
    return Camera(jnp.stack([jnp.array(0.0), h, jnp.array(0.0)]),
                  jnp.stack([jnp.where(moving, speed, 0.0), jnp.array(0.0), jnp.array(0.0)]),
                  jnp.where(moving, yaw * 0.3, yaw), yaw_rate, _u(k[0], *tilt_range))


_CAMERA_OPTIONS = {
    "street": dict(),
    "road": dict(),
    "courtyard": dict(height_range=(1.1, 1.6), tilt_range=(0.1, 0.2), speed_range=(0.3, 1.5)),
    "walkers": dict(height_range=(1.5, 1.9), tilt_range=(0.03, 0.1)),
}


def _ground(key, kind, lane_z=1e6):
    k = _Index(key)
    if kind == "asphalt":
        tex = _tex(_u(k[0], 3.0, 6.0), _u(k[1], 3.0, 6.0), 0.08, _u(k[2], 0, 1))
        refl = _u(k[0], 0.12, 0.3)
    elif kind == "paving":
        tex = _tex(_u(k[0], 0.4, 1.2), _u(k[1], 0.4, 1.2), _u(k[2], -0.25, 0.3), _u(k[2], 0, 1))
        refl = _u(k[0], 0.25, 0.6)
    else:  # grass / gravel
        tex = _tex(_u(k[0], 0.2, 0.6), _u(k[1], 0.2, 0.6), 0.3, _u(k[2], 0, 1))
        refl = _u(k[0], 0.2, 0.45)
    return Ground(refl, tex, jnp.asarray(lane_z, jnp.float32), _u(k[2], 0.75, 1.0))


def _count(r, lo, hi):
    return jnp.minimum(jnp.floor(lo + (hi - lo + 1) * r.take()), hi).astype(jnp.int32)


def _lanes(r, n, z_lo, z_hi):
    """n distinct depths in [z_lo, z_hi], spread out (strata with jitter), in random order."""
    edges = jnp.linspace(z_lo, z_hi, n + 1)
    z = edges[:-1] + r.take((n,)) * (edges[1:] - edges[:-1]) * 0.8
    return z[jnp.argsort(r.take((n,)))]


def _many(fn, key, n, *args, static=None, **kwargs):
    """Build `n` objects at once: fn(key_i, *args_i, **kwargs_i, **static) vmapped over the leading axis of every
    argument (scalars are broadcast), the resulting parts flattened to one group per type."""
    pools = key.split(n, 64)
    bcast = lambda a: jnp.broadcast_to(jnp.asarray(a), (n,)) if jnp.ndim(a) == 0 else jnp.asarray(a)
    args = [bcast(a) for a in args]
    names = list(kwargs)
    kw = [bcast(kwargs[k]) for k in names]
    out = jax.vmap(lambda k, a, w: fn(_Stream(k), *a, **dict(zip(names, w)), **(static or {})))(pools, args, kw)
    return jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), out)


def _bases(x, z):
    return jnp.stack([x, jnp.zeros_like(x), z], -1)


def _coin(r, p, shape=()):
    return r.take(shape) < p


def _street(key, *, n_people=(2, 5), n_cyclists=(0, 2)):
    """A pedestrian street: people walking and running across the view at 3.5-20 m, cyclists, poles, trees,
    benches; building facades at 14-45 m with gaps to the sky."""
    k = _Iter(key)
    parts = _parts()
    max_people, max_cyc = 5, 2
    np_ = _count(next(k), *n_people)
    nc_ = _count(next(k), *n_cyclists)
    zs = _lanes(next(k), max_people, 3.5, 20.0)
    running = _coin(next(k), 0.2, (max_people,))
    speed = jnp.where(running, _u(next(k), 8.0, 14.0, (max_people,)), _u(next(k), 3.0, 6.0, (max_people,))) * KMH
    heading = jnp.where(_coin(next(k), 0.5, (max_people,)), 0.0, math.pi) + _u(next(k), -0.5, 0.5, (max_people,))
    bases = _bases(_u(next(k), -12.0, 12.0, (max_people,)), zs)
    parts.add(_many(person, next(k), max_people, bases, heading, speed, running=running,
                    active=jnp.arange(max_people) < np_, wrap_half=14.0))
    speed = _u(next(k), 10.0, 25.0, (max_cyc,)) * KMH
    heading = jnp.where(_coin(next(k), 0.5, (max_cyc,)), 0.0, math.pi)
    bases = _bases(_u(next(k), -20.0, 20.0, (max_cyc,)), _u(next(k), 7.0, 16.0, (max_cyc,)) + jnp.arange(max_cyc))
    parts.add(_many(cyclist, next(k), max_cyc, bases, heading, speed, active=jnp.arange(max_cyc) < nc_,
                    wrap_half=25.0))
    parts.add(_many(pole, next(k), 3, _bases(_u(next(k), -8.0, 8.0, (3,)), _u(next(k), 4.0, 14.0, (3,))),
                    active=_coin(next(k), 0.8, (3,))))
    parts.add(_many(tree, next(k), 3, _bases(_u(next(k), -12.0, 12.0, (3,)), _u(next(k), 9.0, 16.0, (3,))),
                    active=_coin(next(k), 0.6, (3,))))
    parts.add(_many(bench, next(k), 2, _bases(_u(next(k), -6.0, 6.0, (2,)), _u(next(k), 4.0, 12.0, (2,))),
                    _u(next(k), -0.3, 0.3, (2,)), active=_coin(next(k), 0.6, (2,))))
    parts.add(block(next(k), jnp.stack([_u(next(k), -8.0, 8.0), jnp.array(0.0), _u(next(k), 6.0, 14.0)]),
                    _u(next(k), -0.5, 0.5), active=_coin(next(k), 0.6)))
    parts.boxes.append(buildings(next(k), 7, z_range=(14.0, 30.0), x_span=40.0, height_range=(4.0, 22.0)))
    parts.boxes.append(buildings(next(k), 4, z_range=(40.0, 70.0), x_span=60.0, height_range=(8.0, 30.0)))
    return parts, _ground(next(k), "paving")


def _road(key, *, n_vehicles=(2, 6), truck=None):
    """A road across the view: two lanes of traffic (cars, vans, trucks at 10-60 km/h) at 8-20 m, a parked car,
    pedestrians on the far pavement, trees and poles, buildings and a fence behind."""
    k = _Iter(key)
    parts = _parts()
    z_near = _u(next(k), 8.0, 14.0)
    n_veh = jnp.maximum(_count(next(k), *n_vehicles), 1)
    lane = jnp.repeat(jnp.stack([z_near, z_near + 3.5]), 3)
    heading = jnp.repeat(jnp.array([0.0, math.pi]), 3)
    speed = jnp.repeat(_u(next(k), 10.0, 60.0, (2,)) * KMH, 3)  # one flow per lane: vehicles keep their spacing
    x = jnp.repeat(_u(next(k), -45.0, 45.0, (2,)), 3) + jnp.tile(jnp.arange(3) * 30.0, 2) + _u(next(k), -4, 4, (6,))
    u1, u2 = next(k).take((2, 6))
    kind = jnp.where(u1 < 0.15, 2, jnp.where(u2 < 0.25, 1, 0))
    if truck is not None:
        kind = kind.at[0].set(2 if truck else 0)
    parts.add(_many(vehicle, next(k), 6, _bases(x, lane), heading, speed, kind=kind,
                    active=jnp.arange(6) < n_veh, wrap_half=45.0))
    base = jnp.stack([_u(next(k), -6.0, 6.0), jnp.array(0.0), z_near - 3.0])
    parts.add(vehicle(next(k), base, 0.0, jnp.array(0.0), kind=0, active=_coin(next(k), 0.5)))
    parts.add(_many(person, next(k), 2, _bases(_u(next(k), -10.0, 10.0, (2,)), z_near + 6.5 + jnp.arange(2.0)),
                    jnp.where(_coin(next(k), 0.5, (2,)), 0.0, math.pi), _u(next(k), 3.0, 6.0, (2,)) * KMH,
                    active=_coin(next(k), 0.6, (2,)), wrap_half=20.0))
    parts.add(_many(tree, next(k), 3, _bases(_u(next(k), -15.0, 15.0, (3,)), z_near + _u(next(k), 6.0, 9.0, (3,))),
                    active=_coin(next(k), 0.7, (3,))))
    parts.add(_many(pole, next(k), 3, _bases(_u(next(k), -10.0, 10.0, (3,)), z_near - _u(next(k), 1.5, 2.5, (3,))),
                    active=_coin(next(k), 0.6, (3,))))
    fence_z = z_near + _u(next(k), 9.0, 12.0)
    parts.add(wall(jnp.stack([jnp.array(0.0), jnp.array(0.0), fence_z]), jnp.array([60.0, 0.05]),
                   _u(next(k), 1.0, 2.2), 0.0, _u(next(k), 0.2, 0.7),
                   _tex(_u(next(k), 0.1, 0.3), 5.0, 0.4, 0.0), active=_coin(next(k), 0.6)))
    parts.boxes.append(buildings(next(k), 7, z_range=(z_near + 13.0, z_near + 30.0), x_span=45.0,
                                 height_range=(4.0, 20.0)))
    return parts, _ground(next(k), "asphalt", lane_z=z_near + 1.75)


def _planter(key, base, *, active=True):
    kk = _Index(key)
    m = _motion(1, 0.0, base, jnp.array([1.0, 0.0, 0.0]), _STATIC_WRAP)
    pot = Cylinders(
        pivot=(base + jnp.array([0.0, 0.6, 0.0]))[None], length=jnp.array([0.6]),
        radius=jnp.full((1, 2), _u(kk[0], 0.25, 0.45)), yaw=jnp.zeros(1), lean=jnp.zeros(1),
        swing=jnp.zeros((1, 3)), reflectivity=_u(kk[1], 0.2, 0.8)[None], texture=_tex(0.3, 0.3, 0.1, 0.0)[None],
        active=jnp.full((1,), active), motion=m)
    bush = Ellipsoids(
        centre=(base + jnp.array([0.0, 1.0, 0.0]))[None], radii=jnp.full((1, 3), 0.5) * _u(kk[0], 0.8, 1.4),
        yaw=jnp.zeros(1), reflectivity=_u(kk[1], 0.15, 0.4)[None], texture=_tex(0.25, 0.25, 0.4, 0.0)[None],
        active=jnp.full((1,), active), motion=m)
    return _parts(cylinders=[pot], ellipsoids=[bush])


def _courtyard(key, *, n_people=(0, 2)):
    """A courtyard or open room: walls on three sides at 4-15 m, tables, chairs and sofas, shelves, crates,
    planters, and a few people walking slowly."""
    k = _Iter(key)
    parts = _parts()
    back = _u(next(k), 8.0, 15.0)
    left, right = -_u(next(k), 4.0, 7.0), _u(next(k), 4.0, 7.0)
    h = _u(next(k), 2.6, 6.0)
    wall_tex = _tex(_u(next(k), 1.0, 3.0), _u(next(k), 1.5, 3.0), _u(next(k), -0.2, 0.5), 0.3)
    refl = _u(next(k), 0.3, 0.85)
    parts.add(wall(jnp.stack([jnp.array(0.0), jnp.array(0.0), back + 0.2]), jnp.stack([right - left, jnp.array(0.2)]),
                   h, 0.0, refl, wall_tex))
    for x in (left, right):
        parts.add(wall(jnp.stack([x, jnp.array(0.0), back / 2]), jnp.stack([back / 2 + 0.4, jnp.array(0.2)]),
                       h, math.pi / 2, refl * 0.9, wall_tex))
    span = lambda n: _bases(_u(next(k), left + 0.8, right - 0.8, (n,)), _u(next(k), 3.0, back - 1.0, (n,)))
    parts.add(_many(table, next(k), 3, span(3), _u(next(k), -0.4, 0.4, (3,)), active=_coin(next(k), 0.8, (3,))))
    parts.add(_many(bench, next(k), 5, span(5), _u(next(k), -3.1, 3.1, (5,)), active=_coin(next(k), 0.7, (5,))))
    shelves = _bases(_u(next(k), left + 1.0, right - 1.0, (3,)), jnp.full((3,), back - 0.4))
    parts.add(_many(block, next(k), 3, shelves, 0.0, static=dict(size_range=((0.4, 1.0), (0.2, 0.35), (1.2, 2.2))),
                    active=_coin(next(k), 0.7, (3,))))
    parts.add(_many(block, next(k), 3, span(3), _u(next(k), -0.5, 0.5, (3,)),
                    static=dict(size_range=((0.2, 0.5), (0.2, 0.5), (0.3, 1.0))), active=_coin(next(k), 0.6, (3,))))
    parts.add(_many(_planter, next(k), 2, span(2), active=_coin(next(k), 0.7, (2,))))
    np_ = _count(next(k), *n_people)
    parts.add(_many(person, next(k), 2, _bases(_u(next(k), left, right, (2,)), _u(next(k), 3.0, back - 1.5, (2,))),
                    jnp.where(_coin(next(k), 0.5, (2,)), 0.0, math.pi) + _u(next(k), -0.3, 0.3, (2,)),
                    _u(next(k), 2.5, 5.0, (2,)) * KMH, active=jnp.arange(2) < np_, wrap_half=(right - left) / 2 + 1.0))
    return parts, _ground(next(k), "paving")


def _walkers(key, *, depth=9.0, speed_kmh=4.3, n_people=(3, 5)):
    """The frame-rate study: people walking across the view at `speed_kmh` and about `depth` m, in front of a
    wall and buildings."""
    k = _Iter(key)
    parts = _parts()
    max_people = 5
    np_ = _count(next(k), *n_people)
    spacing = 24.0 / max_people
    x = -12.0 + spacing * jnp.arange(max_people) + _u(next(k), -1.0, 1.0, (max_people,))
    z = depth + _u(next(k), -0.6, 0.6, (max_people,))
    heading = jnp.where(jnp.arange(max_people) % 2 == 0, 0.0, math.pi)
    parts.add(_many(person, next(k), max_people, _bases(x, z), heading, jnp.asarray(speed_kmh * KMH, jnp.float32),
                    active=jnp.arange(max_people) < np_, wrap_half=12.0))
    parts.add(wall(jnp.stack([jnp.array(0.0), jnp.array(0.0), _u(next(k), 16.0, 22.0)]), jnp.array([40.0, 0.2]),
                   _u(next(k), 2.0, 3.5), 0.0, _u(next(k), 0.3, 0.8), _tex(_u(next(k), 0.3, 1.5), 0.5, 0.3, 0.0)))
    parts.add(_many(tree, next(k), 2, _bases(_u(next(k), -8.0, 8.0, (2,)), _u(next(k), 12.0, 15.0, (2,))),
                    active=_coin(next(k), 0.6, (2,))))
    parts.boxes.append(buildings(next(k), 6, z_range=(25.0, 45.0), x_span=40.0, height_range=(6.0, 25.0)))
    return parts, _ground(next(k), "grass")


_KIND_FNS = {"street": _street, "road": _road, "courtyard": _courtyard, "walkers": _walkers}


def empty_scene(*, camera_height=1.7, tilt=0.0, sky=0.9):
    """A scene with every primitive slot inactive: flat ground (reflectivity 0.3), sky, and a static, level
    camera at `camera_height` m (X = Z = 0, looking along +Z). A base for hand-built scenes and tests: set slots
    with `scene._replace(boxes=...)` or `place(...)`.

    Returns a `jaxsr.render.Scene` with the shapes of `sample_scene` (N_BOXES, N_CYLINDERS, N_ELLIPSOIDS)."""
    camera = Camera(jnp.array([0.0, camera_height, 0.0]), jnp.zeros(3), jnp.array(0.0), jnp.array(0.0),
                    jnp.asarray(tilt, jnp.float32))
    ground = Ground(jnp.array(0.3), _tex(1.0, 1.0, 0.0, 0.0), jnp.array(1e6), jnp.asarray(sky, jnp.float32))
    return _assemble(_parts(), ground, camera)


def place(scene, part):
    """Put the primitives of `part` (a Boxes, Cylinders or Ellipsoids with a leading count n) into the first n
    slots of that type in `scene` (shapes (N, ...) unchanged). Returns the new scene.

    Args: scene (Scene), part (a group with leading count n <= the slots of its type).
    """
    name = {Boxes: "boxes", Cylinders: "cylinders", Ellipsoids: "ellipsoids"}[type(part)]
    group = getattr(scene, name)
    n = part.active.shape[0]
    new = jax.tree.map(lambda g, p: g.at[:n].set(jnp.asarray(p, g.dtype)), group, part)
    return scene._replace(**{name: new})


def _assemble(parts, ground, camera):
    return Scene(camera, ground, _cat(parts.boxes, Boxes, N_BOXES), _cat(parts.cylinders, Cylinders, N_CYLINDERS),
                 _cat(parts.ellipsoids, Ellipsoids, N_ELLIPSOIDS))


def sample_scene(key, *, kind=None, camera="random", **options):
    """Draw a random scene.

    key: a PRNG key. kind (static): "street", "road", "courtyard", "walkers", or None for a random kind per key
    (chosen with traced selection, so `jax.vmap(sample_scene)(keys)` mixes kinds). camera (static): "static",
    "moving" (sideways at 0.5-8 m/s with a slow pan) or "random" (35 % moving). options (static): passed to the
    kind's layout (e.g. n_people=(4, 5), n_cyclists=(2, 2), truck=True); only with a named kind.
    Returns a `jaxsr.render.Scene` of fixed shape. Jitted (compiled once per kind, camera and options).
    """
    if kind is not None and kind not in _KIND_FNS:
        raise ValueError(f"unknown scene kind {kind!r}; expected one of {KINDS} or None")
    if camera not in ("static", "moving", "random"):
        raise ValueError(f"camera must be 'static', 'moving' or 'random', got {camera!r}")
    if options and kind is None:
        raise ValueError("layout options need a named kind")
    return _sample_scene_jit(key, kind, camera, tuple(sorted(options.items())))


@functools.partial(jax.jit, static_argnums=(1, 2, 3))
def _sample_scene_jit(key, kind, camera, options):
    k_layout, k_cam, k_kind = jax.random.split(key, 3)
    if kind is not None:
        k_layout, k_cam = _Stream.from_key(k_layout), _Stream.from_key(k_cam, 16)
        parts, ground = _KIND_FNS[kind](k_layout, **dict(options))
        cam_mode = "static" if (kind == "walkers" and camera == "random") else camera
        return _assemble(parts, ground, _camera(k_cam, cam_mode, **_CAMERA_OPTIONS[kind]))
    scenes = [_sample_scene_jit(key, name, camera, ()) for name in KINDS]
    choice = jax.random.randint(k_kind, (), 0, len(KINDS))
    return jax.tree.map(lambda *xs: jnp.stack(xs)[choice], *scenes)


# ---------------------------------------------------------------------------------------------------------
# Sequences, motion statistics, training clips


def sequence(key, n_frames, fps, *, kind=None, sensor: SensorConfig = SensorConfig(), t0=0.0, camera="random",
             **options):
    """Render a random scene for `n_frames` (static int) frames at `fps` frames per second from time `t0` (s).

    Returns (depth, intensity), each (n_frames, H, W) float32: radial metres (inf = no return) and [0, 1].
    jit- and vmap-able over key, fps and t0.
    """
    sample_scene(key, kind=kind, camera=camera, **options)  # validates the arguments eagerly (cheap checks)
    return _sequence_jit(key, n_frames, fps, t0, sensor, kind, camera, tuple(sorted(options.items())))


@functools.partial(jax.jit, static_argnums=(1, 5, 6, 7))
def _sequence_jit(key, n_frames, fps, t0, sensor, kind, camera, options):
    scene = _sample_scene_jit(key, kind, camera, options)
    times = t0 + jnp.arange(n_frames, dtype=jnp.float32) / fps
    return render_sequence(scene, times, sensor=sensor)


@jax.jit
def mean_lr_shift(scene: Scene, fps, *, sensor: SensorConfig = SensorConfig(), t=0.0):
    """Mean image motion of the moving objects, in LR pixels per frame at `fps`.

    Args: scene (a `Scene`), fps (frames per second, scalar), t (s, scalar). For every active primitive whose
    projected bounding box overlaps the frame widened by half a frame on each side at time t, the image velocity
    of its bounding-box centre (HR px/s, the exact derivative of the projection, camera motion and pan included)
    is divided by `sensor.scale` and `fps`; the mean is over those that move (> 1e-3 LR px/s).
    Returns a scalar (0 if nothing moves). An object at depth z crossing the view at speed v moves
    v / (fps z) * focal_px / scale LR px per frame: 35 m, 50 km/h, 100 FPS -> 0.47 (the paper's "about 0.5").
    """
    h, w = sensor.hr_shape
    f = sensor.focal_px
    tilt = scene.camera.tilt

    def project(t):
        groups, _, _ = _pose_all(scene, t)
        c = jnp.concatenate([(g.aabb[:, 0::2] + g.aabb[:, 1::2]) / 2 for g in groups], 0)
        z = jnp.maximum(c[:, 2], 1e-3)
        return jnp.stack([f * c[:, 0] / z, -f * (c[:, 1] / z + tilt)], -1)

    t = jnp.asarray(t, jnp.float32)
    _, duv = jax.jvp(project, (t,), (jnp.ones_like(t),))
    groups, _, _ = _pose_all(scene, t)
    in_view = []
    for g in groups:
        bounds, visible = _project_bounds(g.aabb, sensor, tilt)
        in_view.append(g.active & visible & (bounds[:, 1] > -w / 2) & (bounds[:, 0] < 1.5 * w)
                       & (bounds[:, 3] > -h / 2) & (bounds[:, 2] < 1.5 * h) & (g.aabb[:, 5] > 0.5))
    in_view = jnp.concatenate(in_view)
    speed = jnp.sqrt(jnp.sum(duv ** 2, -1)) / sensor.scale  # LR px per second
    moving = in_view & (speed > 1e-3)
    mean = jnp.sum(jnp.where(moving, speed, 0.0)) / jnp.maximum(jnp.sum(moving), 1)
    return mean / fps


def training_scene(key, *, sensor: SensorConfig = SensorConfig(), shift_range=(0.2, 5.0)):
    """Draw the scene, frame rate and start time of a training clip (see `training_clip`), without rendering.

    Returns (scene, fps, t0): a `Scene`, frames per second (scalar) and the start time (s, scalar). The mean
    shift `mean_lr_shift(scene, fps, t=t0)` is log-uniform in `shift_range` (up to the fps clip to [1, 2000]);
    scenes where nothing in view moves are replaced by the same kind of draw with a moving camera."""
    return _training_scene_jit(key, sensor, tuple(float(v) for v in shift_range))


@functools.partial(jax.jit, static_argnums=(2,))
def _training_scene_jit(key, sensor, shift_range):
    k_scene, k_moving, k_shift, k_t0 = jax.random.split(key, 4)
    t0 = _u(_Stream.from_key(k_t0, 1), 0.0, 10.0)
    scene = sample_scene(k_scene)
    per_second = mean_lr_shift(scene, 1.0, sensor=sensor, t=t0)
    moving = sample_scene(k_moving, camera="moving")
    use_moving = per_second <= 0
    scene = jax.tree.map(lambda a, b: jnp.where(use_moving, b, a), scene, moving)
    per_second = jnp.where(use_moving, mean_lr_shift(moving, 1.0, sensor=sensor, t=t0), per_second)
    lo, hi = shift_range
    target = jnp.exp(_u(_Stream.from_key(k_shift, 1), math.log(lo), math.log(hi)))
    fps = jnp.where(per_second > 0, jnp.clip(per_second / target, 1.0, 2000.0), 25.0)
    return scene, fps, t0


def training_clip(key, n_frames, *, sensor: SensorConfig = SensorConfig(), shift_range=(0.2, 5.0),
                  return_info=False):
    """A random training clip whose mean motion is log-uniform in `shift_range` LR pixels per frame.

    Draws a random kind and scene (35 % with a moving camera), a target shift, and the frame rate that gives it
    (fps = mean LR shift per second / target, clipped to [1, 2000]); starts at a random time in [0, 10) s.
    Returns (depth, intensity), each (n_frames, H, W) float32 (radial metres, inf = no return; [0, 1]); with
    return_info also a dict(fps=, shift=) of scalars. jit- and vmap-able over key (n_frames static).
    """
    return _training_clip_jit(key, int(n_frames), sensor, tuple(float(v) for v in shift_range), bool(return_info))


@functools.partial(jax.jit, static_argnums=(1, 3, 4))
def _training_clip_jit(key, n_frames, sensor, shift_range, return_info):
    scene, fps, t0 = _training_scene_jit(key, sensor, shift_range)
    times = t0 + jnp.arange(n_frames, dtype=jnp.float32) / fps
    depth, intensity = render_sequence(scene, times, sensor=sensor)
    if return_info:
        return depth, intensity, dict(fps=fps, shift=mean_lr_shift(scene, fps, sensor=sensor, t=t0))
    return depth, intensity


# ---------------------------------------------------------------------------------------------------------
# Temporal windows and frame-rate changes


# ---------------------------------------------------------------------------------------------------------
# Fixed test and validation sequences


class TestSequence(NamedTuple):
    """A named, fixed sequence: depth and intensity (T, H, W), frame rate (FPS), the frame SNR to simulate
    at, the kind and a description."""

    name: str
    depth: np.ndarray
    intensity: np.ndarray
    fps: float
    snr: float
    kind: str
    description: str


# name: (kind, seed, fps, snr, camera, layout options, description)
TEST_SEQUENCES = {
    "scene1_street": ("street", 1001, 30.0, 1.3, "static", dict(n_people=(4, 5), n_cyclists=(2, 2)),
                      "test scene 1: a street with people walking and cyclists (SNR 1.3)"),
    "scene2_road": ("road", 1002, 60.0, 1.3, "static", dict(n_vehicles=(5, 6), truck=True),
                    "test scene 2: a road with cars, vans and a truck (SNR 1.3)"),
    "scene3_courtyard": ("courtyard", 1003, 30.0, 3.0, "static", dict(n_people=(1, 1)),
                         "test scene 3: a courtyard with furniture (SNR 3)"),
    "val1_street": ("street", 2001, 30.0, 1.3, "moving", dict(n_people=(3, 5), n_cyclists=(1, 2)),
                    "validation: a street, moving camera (SNR 1.3)"),
    "val2_road": ("road", 2002, 60.0, 1.3, "static", dict(n_vehicles=(4, 6), truck=True),
                  "validation: a road with traffic (SNR 1.3)"),
    "val3_courtyard": ("courtyard", 2003, 30.0, 3.0, "moving", dict(n_people=(1, 2)),
                       "validation: a courtyard, moving camera (SNR 3)"),
    "walkers_100fps": ("walkers", 3001, 100.0, 1.3, "static", dict(depth=9.0, speed_kmh=4.3, n_people=(4, 4)),
                       "frame-rate study: people walking at 4.3 km/h at 9 m, 100 FPS; subsample with "
                       "change_frame_rate (SNR 1.3)"),
}


_render_jit = jax.jit(render_sequence, static_argnames=("sensor", "tiles", "k_max"))


def test_scene(name):
    """The fixed scene of a named test sequence (see `TEST_SEQUENCES`).

    Returns (scene, fps): a `jaxsr.render.Scene` and the sequence's frame rate (frames per second)."""
    if name not in TEST_SEQUENCES:
        raise ValueError(f"unknown test sequence {name!r}; expected one of {sorted(TEST_SEQUENCES)}")
    kind, seed, fps, _, camera, options, _ = TEST_SEQUENCES[name]
    return sample_scene(jax.random.key(seed), kind=kind, camera=camera, **options), fps


def test_sequence(name, *, n_frames=500, sensor: SensorConfig = SensorConfig()):
    """Render one named fixed sequence (deterministic). See `TEST_SEQUENCES` for the names.

    Returns a `TestSequence`: depth (n_frames, H, W) radial metres (inf = no return), intensity (n_frames, H, W)
    in [0, 1] (numpy float32), fps, snr, kind, description."""
    scene, fps = test_scene(name)
    kind, _, _, snr, _, _, description = TEST_SEQUENCES[name]
    times = jnp.arange(n_frames, dtype=jnp.float32) / fps
    chunks = [_render_jit(scene, times[i:i + 50], sensor=sensor) for i in range(0, n_frames, 50)]
    depth = np.concatenate([np.asarray(c[0]) for c in chunks])
    intensity = np.concatenate([np.asarray(c[1]) for c in chunks])
    return TestSequence(name, depth, intensity, fps, snr, kind, description)


def test_sequences(*, n_frames=500, names=None, sensor: SensorConfig = SensorConfig()):
    """The paper's three test scenes, three validation sequences and the frame-rate study sequence.

    Returns a dict name -> `TestSequence` (depth and intensity of shape (n_frames, H, W), fps, snr).
    `names` selects a subset (each 500-frame sequence is 131 MB)."""
    names = list(TEST_SEQUENCES) if names is None else list(names)
    return {name: test_sequence(name, n_frames=n_frames, sensor=sensor) for name in names}


test_scene.__test__ = False  # not pytest tests
test_sequence.__test__ = False
test_sequences.__test__ = False
TestSequence.__test__ = False
