"""The objects scenes are made of: people, cyclists, vehicles, buildings, trees, poles and furniture.

Each builder takes a `Draws` (its random numbers, by name) and returns `Parts`: small groups of primitives
with a leading count, which a layout concatenates and pads into a `Scene`. Positions are world metres (X right,
Y up, Z forward), headings radians in the X-Z plane, speeds m/s; `active` (a traced bool) switches an object off
so that scenes of any content keep one shape. Builders are vmapped over many objects by `many`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from .draws import Draws
from .primitives import Boxes, Cylinders, Ellipsoids, Motion

__all__ = ["KMH", "Parts", "bench", "block", "buildings", "cyclist", "many", "parts", "person", "planter", "pole",
           "table", "texture", "tree", "vehicle", "vehicle_length", "wall"]

KMH = 1.0 / 3.6  # m/s per km/h
STATIC_WRAP = 80.0  # m: static objects recycle around a sideways-moving camera beyond this distance
_X = (1.0, 0.0, 0.0)


# ---------------------------------------------------------------------------------------------------------
# Parts: groups of primitives with a leading count


class Parts(NamedTuple):
    """Lists of `Boxes`, `Cylinders` and `Ellipsoids` groups, to be concatenated into a `Scene`."""

    boxes: list
    cylinders: list
    ellipsoids: list

    def add(self, other: Parts):
        self.boxes.extend(other.boxes)
        self.cylinders.extend(other.cylinders)
        self.ellipsoids.extend(other.ellipsoids)


def parts(boxes=(), cylinders=(), ellipsoids=()) -> Parts:
    return Parts(list(boxes), list(cylinders), list(ellipsoids))


def motion(n, velocity, anchor, wrap_axis, wrap_half) -> Motion:
    """`n` primitives' `Motion`, each argument broadcast to its per-primitive shape."""
    b = lambda a, s: jnp.broadcast_to(jnp.asarray(a, jnp.float32), s)
    return Motion(b(velocity, (n, 3)), b(wrap_axis, (n, 3)), b(wrap_half, (n,)), b(anchor, (n, 3)))


def static_motion(n, anchor) -> Motion:
    return motion(n, 0.0, anchor, jnp.array(_X), STATIC_WRAP)


def _object_motion(n, base, heading, speed, wrap_half):
    """Motion of an object at `base` (3,) moving at `speed` m/s along heading (rad in the X-Z plane)."""
    direction = jnp.array([jnp.cos(heading), 0.0, jnp.sin(heading)])
    moving = speed > 0
    axis = jnp.where(moving, direction, jnp.array(_X))
    half = jnp.where(moving, wrap_half, STATIC_WRAP)
    return motion(n, speed * direction, base, axis, half)


def texture(period_s, period_h, amp, phase):
    """Texture parameters (..., 4): periods along the surface and in height (m), amplitude, phase."""
    return jnp.stack(jnp.broadcast_arrays(*(jnp.asarray(a, jnp.float32) for a in (period_s, period_h, amp, phase))),
                     -1)


def _rot(heading, along, lateral):
    """World (X, Z) offset of a point `along` the heading and `lateral` to its left (towards +e2)."""
    c, s = jnp.cos(heading), jnp.sin(heading)
    return along * c - lateral * s, along * s + lateral * c


def _at(base, heading, along, lateral, height):
    ox, oz = _rot(heading, along, lateral)
    return jnp.stack(jnp.broadcast_arrays(base[0] + ox, jnp.asarray(height, jnp.float32) + 0.0, base[2] + oz), -1)


def many(fn, draws: Draws, name: str, n: int, *args, static=None, **kwargs) -> Parts:
    """Build `n` objects at once: `fn(draws_i, *args_i, **kwargs_i, **static)` vmapped over the leading axis of
    every argument (scalars are broadcast); each object's draws live under `name/`. The resulting parts are
    flattened to one group per type."""
    table, make = draws.batched(name, n)
    bcast = lambda a: jnp.broadcast_to(jnp.asarray(a), (n,)) if jnp.ndim(a) == 0 else jnp.asarray(a)
    args = [bcast(a) for a in args]
    names = list(kwargs)
    kw = [bcast(kwargs[k]) for k in names]
    out = jax.vmap(lambda t, a, w: fn(make(t), *a, **dict(zip(names, w)), **(static or {})))(table, args, kw)
    return jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), out)


# ---------------------------------------------------------------------------------------------------------
# Moving objects


def person(d: Draws, base, heading, speed, *, running=False, active=True, wrap_half=30.0) -> Parts:
    """A person walking (3-6 km/h) or running: straight legs and arms swinging with a pendulum gait whose
    frequency matches the speed (stride = 4 L sin(amplitude)); torso and head. 5 cylinders + 1 ellipsoid."""
    height = d.uniform("height", 1.55, 1.95)
    leg = 0.5 * height
    amp = jnp.where(running, 0.6, 0.38)
    freq = speed / (4.0 * leg * jnp.sin(amp))
    phase = d.uniform("phase", 0.0, 2 * math.pi)
    trousers, shirt = d.uniform("trousers", 0.05, 0.7), d.uniform("shirt", 0.05, 0.95)
    skin = d.uniform("skin", 0.3, 0.7)
    lean = jnp.where(running, -0.12, -0.03)
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
        texture=texture(0.3, 0.15, jnp.array([0.1, 0.1, 0.2, 0.2, 0.25]), phase),
        active=jnp.full((5,), active),
        motion=_object_motion(5, base, heading, speed, wrap_half),
    )
    head = Ellipsoids(
        centre=_at(base, heading, 0.02, 0.0, 0.92 * height)[None],
        radii=jnp.array([[0.1, 0.12, 0.085]]),
        yaw=jnp.full((1,), heading),
        reflectivity=skin[None],
        texture=texture(0.2, 0.2, 0.2, phase)[None],
        active=jnp.full((1,), active),
        motion=_object_motion(1, base, heading, speed, wrap_half),
    )
    return parts(cylinders=[cyl], ellipsoids=[head])


def cyclist(d: Draws, base, heading, speed, *, active=True, wrap_half=40.0) -> Parts:
    """A cyclist (typically 10-25 km/h): two thin wheels, top tube, rider leaning forward, pedalling legs.
    1 box + 5 cylinders + 3 ellipsoids."""
    cadence = d.uniform("cadence", 1.0, 1.5)
    phase = d.uniform("phase", 0.0, 2 * math.pi)
    clothes, bike = d.uniform("clothes", 0.05, 0.9), d.uniform("bike", 0.05, 0.6)
    frame = Boxes(
        centre=_at(base, heading, 0.0, 0.0, 0.72)[None], half=jnp.array([[0.42, 0.03]]), height=jnp.array([0.07]),
        yaw=jnp.full((1,), heading), reflectivity=bike[None], texture=texture(1.0, 1.0, 0.0, 0.0)[None],
        active=jnp.full((1,), active), motion=_object_motion(1, base, heading, speed, wrap_half),
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
        texture=texture(0.3, 0.2, 0.15, phase)[None].repeat(5, 0),
        active=jnp.full((5,), active),
        motion=_object_motion(5, base, heading, speed, wrap_half),
    )
    ell = Ellipsoids(
        centre=jnp.concatenate([_at(base, heading, jnp.array([0.52, -0.52]), 0.0, 0.34),
                                _at(base, heading, 0.3, 0.0, 1.6)[None]]),
        radii=jnp.array([[0.34, 0.34, 0.03], [0.34, 0.34, 0.03], [0.11, 0.13, 0.1]]),
        yaw=jnp.full((3,), heading),
        reflectivity=jnp.stack([jnp.array(0.08), jnp.array(0.08), d.uniform("skin", 0.3, 0.6)]),
        texture=texture(0.2, 0.2, 0.1, 0.0)[None].repeat(3, 0),
        active=jnp.full((3,), active),
        motion=_object_motion(3, base, heading, speed, wrap_half),
    )
    return parts(boxes=[frame], cylinders=[cyl], ellipsoids=[ell])


def _by_kind(kind, car, van, truck):
    """The value for a car (kind 0), van (1) or truck (2); kind may be traced."""
    return jnp.select([kind == 0, kind == 1], [jnp.asarray(car, jnp.float32), jnp.asarray(van, jnp.float32)],
                      jnp.asarray(truck, jnp.float32))


def vehicle_length(kind, u):
    """Length (m) of a car (kind 0: 3.8-4.8 m), van (1: 4.8-5.6 m) or truck (2: 7-9.5 m) at the quantile u in
    [0, 1) of its range."""
    kind = jnp.asarray(kind)
    return _by_kind(kind, 3.8 + 1.0 * u, 4.8 + 0.8 * u, 7.0 + 2.5 * u)


def vehicle(d: Draws, base, heading, speed, *, kind=0, active=True, wrap_half=45.0, length_u=None) -> Parts:
    """A car (kind 0), van (1) or truck (2): body and cabin boxes and up to three wheel pairs (each one ellipsoid
    spanning the track). `kind` may be traced. `length_u`: the quantile of its length (`vehicle_length`), drawn
    here if None (a layout that spaces vehicles by their lengths draws it). 2 boxes + 3 ellipsoids."""
    kind = jnp.asarray(kind)
    pick = lambda car, van, truck: _by_kind(kind, car, van, truck)
    length = vehicle_length(kind, d.uniform("length") if length_u is None else length_u)
    width = pick(1.8, 2.0, 2.5)
    # Body: car and van lower body; truck cargo box.
    body_len = pick(length, length, length - 2.4)
    body_off = pick(0.0, 0.0, -1.2)
    body_y0, body_h = pick(0.3, 0.35, 1.0), pick(0.7, 0.85, d.uniform("cargo_height", 2.5, 3.0))
    # Cabin: car greenhouse, van upper body, truck cab.
    cab_len = pick(0.5 * length, 0.75 * length, 2.3)
    cab_off = pick(-0.15 * length / 2, -0.1 * length / 2, length / 2 - 1.15)
    cab_y0, cab_h = pick(1.0, 1.2, 0.5), pick(0.45, 1.0, 2.6)
    cab_w = pick(1.55, 1.95, 2.45)
    paint = d.uniform("paint", 0.05, 0.95)
    boxes = Boxes(
        centre=jnp.stack([_at(base, heading, body_off, 0.0, body_y0), _at(base, heading, cab_off, 0.0, cab_y0)]),
        half=jnp.stack([jnp.stack([body_len / 2, width / 2]), jnp.stack([cab_len / 2, cab_w / 2])]),
        height=jnp.stack([body_h, cab_h]),
        yaw=jnp.full((2,), heading),
        reflectivity=jnp.stack([paint, paint]),
        # Cabin windows: dark rectangles (negative amplitude would lighten).
        texture=jnp.stack([texture(1.3, 0.6, 0.15, 0.0),
                           texture(pick(1.1, 1.3, 1.2), pick(0.9, 1.3, 2.0), 0.7, 0.25)]),
        active=jnp.full((2,), active),
        motion=_object_motion(2, base, heading, speed, wrap_half),
    )
    r = pick(0.33, 0.36, 0.5)
    axle = length / 2 - pick(0.85, 0.9, 1.2)
    along = jnp.stack([axle, -axle, -axle + 1.35])
    wheels = Ellipsoids(
        centre=_at(base, heading, along, 0.0, r),
        radii=jnp.stack([jnp.stack([r, r, width / 2 + 0.02])] * 3),
        yaw=jnp.full((3,), heading),
        reflectivity=jnp.full((3,), 0.06),
        texture=texture(0.3, 0.3, 0.0, 0.0)[None].repeat(3, 0),
        active=jnp.stack([active, active, active & (kind == 2)]),
        motion=_object_motion(3, base, heading, speed, wrap_half),
    )
    return parts(boxes=[boxes], ellipsoids=[wheels])


# ---------------------------------------------------------------------------------------------------------
# Static objects


def static_boxes(centre, half, height, yaw, reflectivity, tex, active=True) -> Boxes:
    """`n` boxes that do not move (centre (n, 3), half (n, 2), height, yaw, reflectivity (n,), tex (n, 4))."""
    n = centre.shape[0]
    return Boxes(centre, half, height, jnp.broadcast_to(yaw, (n,)), reflectivity, tex,
                 jnp.broadcast_to(active, (n,)), static_motion(n, centre))


def buildings(d: Draws, n, *, z_range, x_span, height_range, active=None) -> Boxes:
    """A row of `n` building facades facing the camera (window grids), with random gaps."""
    width = d.uniform("width", 6.0, 20.0, (n,))
    gap = d.uniform("gap", 0.0, 8.0, (n,)) * d.coin("has_gap", 0.5, (n,))
    x = -x_span + jnp.cumsum(width + gap) - width / 2 + d.uniform("offset", -5.0, 5.0)
    depth = d.uniform("depth", 8.0, 20.0, (n,))
    z = d.uniform("z", *z_range, (n,)) + depth / 2
    centre = jnp.stack([x, jnp.zeros(n), z], -1)
    tex = texture(d.uniform("window_width", 2.0, 4.0, (n,)), d.uniform("storey", 2.8, 3.6, (n,)),
                  d.uniform("window_contrast", -0.3, 0.7, (n,)), d.uniform("window_phase", 0, 1, (n,)))
    act = jnp.ones((n,), bool) if active is None else active
    return static_boxes(centre, jnp.stack([width / 2, depth / 2], -1), d.uniform("height", *height_range, (n,)),
                        d.uniform("yaw", -0.08, 0.08, (n,)), d.uniform("reflectivity", 0.2, 0.8, (n,)), tex, act)


def tree(d: Draws, base, *, active=True) -> Parts:
    """A tree: trunk (cylinder) and crown (ellipsoid)."""
    trunk_h = d.uniform("trunk_height", 1.8, 3.2)
    crown = jnp.stack([d.uniform("crown_x", 1.0, 2.2), d.uniform("crown_y", 1.2, 2.6), d.uniform("crown_z", 1.0, 2.2)])
    m = static_motion(1, base)
    trunk = Cylinders(
        pivot=(base + jnp.array([0.0, 1.0, 0.0]) * (trunk_h + 0.5))[None], length=(trunk_h + 0.5)[None],
        radius=jnp.full((1, 2), d.uniform("trunk_radius", 0.12, 0.3)), yaw=jnp.zeros(1), lean=jnp.zeros(1),
        swing=jnp.zeros((1, 3)), reflectivity=jnp.full((1,), d.uniform("bark", 0.15, 0.4)),
        texture=texture(0.15, 0.4, 0.3, 0.0)[None], active=jnp.full((1,), active), motion=m,
    )
    crown_e = Ellipsoids(
        centre=(base + jnp.array([0.0, 1.0, 0.0]) * (trunk_h + 0.8 * crown[1]))[None], radii=crown[None],
        yaw=d.uniform("crown_yaw", 0, 3)[None], reflectivity=d.uniform("leaves", 0.15, 0.45)[None],
        texture=texture(0.35, 0.3, 0.5, 0.0)[None], active=jnp.full((1,), active), motion=m,
    )
    return parts(cylinders=[trunk], ellipsoids=[crown_e])


def pole(d: Draws, base, *, active=True) -> Parts:
    """A lamp post or sign pole: a thin tall cylinder."""
    h = d.uniform("height", 2.5, 7.0)
    return parts(cylinders=[Cylinders(
        pivot=(base + jnp.array([0.0, 1.0, 0.0]) * h)[None], length=h[None],
        radius=jnp.full((1, 2), d.uniform("radius", 0.05, 0.12)), yaw=jnp.zeros(1), lean=jnp.zeros(1),
        swing=jnp.zeros((1, 3)), reflectivity=d.uniform("reflectivity", 0.2, 0.8)[None],
        texture=texture(0.5, 0.5, 0.1, 0.0)[None], active=jnp.full((1,), active), motion=static_motion(1, base),
    )])


def bench(d: Draws, base, yaw, *, active=True) -> Parts:
    """A bench or sofa: seat and backrest boxes (the gap under the seat shows the ground)."""
    length = d.uniform("length", 1.2, 2.2)
    back = _rot(yaw, 0.0, 0.22)
    centre = jnp.stack([base + jnp.array([0.0, 0.38, 0.0]),
                        base + jnp.stack([back[0], jnp.array(0.5), back[1]])])
    refl = d.uniform("reflectivity", 0.1, 0.7)
    return parts(boxes=[static_boxes(centre, jnp.stack([jnp.stack([length / 2, 0.25]), jnp.stack([length / 2, 0.04])]),
                                     jnp.array([0.08, 0.4]), yaw, jnp.stack([refl, refl]),
                                     texture(0.12, 1.0, 0.25, 0.0)[None].repeat(2, 0), active)])


def table(d: Draws, base, yaw, *, active=True) -> Parts:
    """A table: top (box) on a central pedestal (cylinder)."""
    half = jnp.stack([d.uniform("half_length", 0.4, 0.9), d.uniform("half_width", 0.35, 0.6)])
    top = static_boxes((base + jnp.array([0.0, 0.71, 0.0]))[None], half[None], jnp.array([0.05]), yaw,
                       d.uniform("reflectivity", 0.2, 0.9)[None], texture(0.5, 0.5, 0.1, 0.0)[None], active)
    leg = Cylinders(
        pivot=(base + jnp.array([0.0, 0.71, 0.0]))[None], length=jnp.array([0.71]), radius=jnp.full((1, 2), 0.05),
        yaw=jnp.zeros(1), lean=jnp.zeros(1), swing=jnp.zeros((1, 3)), reflectivity=jnp.full((1,), 0.3),
        texture=texture(0.5, 0.5, 0.0, 0.0)[None], active=jnp.full((1,), active), motion=static_motion(1, base),
    )
    return parts(boxes=[top], cylinders=[leg])


def block(d: Draws, base, yaw, *, size_range=((0.3, 1.2), (0.2, 0.6), (0.4, 2.0)), active=True) -> Parts:
    """A box-shaped piece of furniture or street furniture (shelf, cabinet, crate, bin, kiosk)."""
    half = jnp.stack([d.uniform("half_length", *size_range[0]), d.uniform("half_width", *size_range[1])])
    h = d.uniform("height", *size_range[2])
    tex = texture(d.uniform("period_s", 0.2, 0.8), d.uniform("period_h", 0.2, 0.5),
                  d.uniform("contrast", -0.3, 0.5), 0.0)
    return parts(boxes=[static_boxes(base[None], half[None], h[None], yaw, d.uniform("reflectivity", 0.1, 0.9)[None],
                                     tex[None], active)])


def planter(d: Draws, base, *, active=True) -> Parts:
    """A planter: a pot (cylinder) with a bush (ellipsoid)."""
    m = static_motion(1, base)
    pot = Cylinders(
        pivot=(base + jnp.array([0.0, 0.6, 0.0]))[None], length=jnp.array([0.6]),
        radius=jnp.full((1, 2), d.uniform("pot_radius", 0.25, 0.45)), yaw=jnp.zeros(1), lean=jnp.zeros(1),
        swing=jnp.zeros((1, 3)), reflectivity=d.uniform("pot", 0.2, 0.8)[None],
        texture=texture(0.3, 0.3, 0.1, 0.0)[None], active=jnp.full((1,), active), motion=m)
    bush = Ellipsoids(
        centre=(base + jnp.array([0.0, 1.0, 0.0]))[None], radii=jnp.full((1, 3), 0.5) * d.uniform("bush", 0.8, 1.4),
        yaw=jnp.zeros(1), reflectivity=d.uniform("leaves", 0.15, 0.4)[None],
        texture=texture(0.25, 0.25, 0.4, 0.0)[None], active=jnp.full((1,), active), motion=m)
    return parts(cylinders=[pot], ellipsoids=[bush])


def wall(centre, half, height, yaw, reflectivity, tex, active=True) -> Parts:
    """A wall, fence or hedge: one box (no random draws)."""
    return parts(boxes=[static_boxes(centre[None], half[None], jnp.asarray(height)[None], yaw,
                                     jnp.asarray(reflectivity)[None], tex[None], active)])
