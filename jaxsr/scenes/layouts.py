"""Scene layouts: streets, roads, courtyards and the frame-rate study's walkers, their cameras, and
`sample_scene`, which draws one.

A scene of any kind is a `Scene` with `N_BOXES` boxes, `N_CYLINDERS` cylinders and `N_ELLIPSOIDS` ellipsoids
(unused slots inactive), so scenes of any kind sampled under `jax.vmap` stack, and `kind=None` picks a kind per
key with traced selection. Every random number is drawn by name (`jaxsr.scenes.draws`): a new draw in one
layout or object leaves every other draw, and so every other scene, unchanged in distribution and in value.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp

from .draws import Draws, with_draws
from .objects import (
    KMH,
    Parts,
    bench,
    block,
    buildings,
    cyclist,
    many,
    motion,
    parts,
    person,
    planter,
    pole,
    table,
    texture,
    tree,
    vehicle,
    vehicle_length,
    wall,
)
from .primitives import Boxes, Camera, Cylinders, Ellipsoids, Ground, Scene

__all__ = ["KINDS", "N_BOXES", "N_CYLINDERS", "N_ELLIPSOIDS", "empty_scene", "place", "sample_scene"]

N_BOXES = 32
N_CYLINDERS = 44
N_ELLIPSOIDS = 28
KINDS = ("street", "road", "courtyard", "walkers")


# ---------------------------------------------------------------------------------------------------------
# Camera and ground


# A static camera's view, for layouts that keep moving objects in it: the default sensor's half field of view
# (`Optics.fov_deg` = 30) and the largest yaw `_camera` draws.
HALF_FOV = math.radians(15.0)
MAX_YAW = 0.15
PERSON_HALF_LENGTH = 0.45  # m: a walking person's extent along the heading (swinging legs), each way


def _edge_of_view(z):
    """X (m) beyond which nothing at depth z (m) is in sight of any static camera of `_camera`, either side."""
    return z * jnp.tan(HALF_FOV + MAX_YAW)


def _camera(d: Draws, mode, *, height_range=(1.5, 2.0), tilt_range=(0.03, 0.12), speed_range=(0.5, 8.0)):
    """Static camera, or ('moving') one translating sideways along X with a slow pan; 'random': 35 % moving."""
    moving = {"static": jnp.array(False), "moving": jnp.array(True)}.get(mode)
    if moving is None:
        moving = d.coin("moving", 0.35)
    speed = d.uniform("speed", *speed_range) * jnp.where(d.coin("leftwards", 0.5), 1.0, -1.0)
    yaw = d.uniform("yaw", -MAX_YAW, MAX_YAW)
    yaw_rate = jnp.where(moving, d.uniform("yaw_rate", -0.05, 0.05), 0.0)
    return Camera(jnp.stack([jnp.array(0.0), d.uniform("height", *height_range), jnp.array(0.0)]),
                  jnp.stack([jnp.where(moving, speed, 0.0), jnp.array(0.0), jnp.array(0.0)]),
                  jnp.where(moving, yaw * 0.3, yaw), yaw_rate, d.uniform("tilt", *tilt_range))


_CAMERA_OPTIONS = {
    "street": dict(),
    "road": dict(),
    "courtyard": dict(height_range=(1.1, 1.6), tilt_range=(0.1, 0.2), speed_range=(0.3, 1.5)),
    "walkers": dict(height_range=(1.5, 1.9), tilt_range=(0.03, 0.1)),
}

# Ground surfaces: (texture period range (m), texture contrast range, reflectivity range).
_SURFACES = {
    "asphalt": ((3.0, 6.0), (0.08, 0.08), (0.12, 0.3)),
    "paving": ((0.4, 1.2), (-0.25, 0.3), (0.25, 0.6)),
    "grass": ((0.2, 0.6), (0.3, 0.3), (0.2, 0.45)),
}


def _ground(d: Draws, surface, lane_z=1e6):
    period, contrast, reflectivity = _SURFACES[surface]
    tex = texture(d.uniform("period_x", *period), d.uniform("period_z", *period), d.uniform("contrast", *contrast),
                  d.uniform("phase", 0, 1))
    return Ground(d.uniform("reflectivity", *reflectivity), tex, jnp.asarray(lane_z, jnp.float32),
                  d.uniform("sky", 0.75, 1.0))


# ---------------------------------------------------------------------------------------------------------
# Layouts. Each returns (parts, ground); positions in world metres, the camera at X = Z = 0 looking along +Z.


def _lanes(d: Draws, name, n, z_lo, z_hi):
    """n distinct depths in [z_lo, z_hi], spread out (strata with jitter), in random order."""
    edges = jnp.linspace(z_lo, z_hi, n + 1)
    z = edges[:-1] + d.uniform(f"{name}_jitter", shape=(n,)) * (edges[1:] - edges[:-1]) * 0.8
    return z[jnp.argsort(d.uniform(f"{name}_order", shape=(n,)))]


def _bases(x, z):
    return jnp.stack([x, jnp.zeros_like(x), z], -1)


def _scatter(d: Draws, name, n, x_range, z_range):
    """n ground positions (n, 3) uniform in the given X and Z ranges (m)."""
    return _bases(d.uniform(f"{name}_x", *x_range, (n,)), d.uniform(f"{name}_z", *z_range, (n,)))


def _street(d: Draws, *, n_people=(2, 5), n_cyclists=(0, 2)):
    """A pedestrian street: people walking and running across the view at 3.5-20 m, cyclists, poles, trees,
    benches; building facades at 14-45 m with gaps to the sky."""
    out = parts()
    max_people, max_cyc = 5, 2
    np_ = d.count("n_people", *n_people)
    nc_ = d.count("n_cyclists", *n_cyclists)
    zs = _lanes(d, "people_lanes", max_people, 3.5, 20.0)
    running = d.coin("running", 0.2, (max_people,))
    speed = jnp.where(running, d.uniform("run_kmh", 8.0, 14.0, (max_people,)),
                      d.uniform("walk_kmh", 3.0, 6.0, (max_people,))) * KMH
    heading = (jnp.where(d.coin("people_rightwards", 0.5, (max_people,)), 0.0, math.pi)
               + d.uniform("people_heading", -0.5, 0.5, (max_people,)))
    bases = _bases(d.uniform("people_x", -12.0, 12.0, (max_people,)), zs)
    out.add(many(person, d, "people", max_people, bases, heading, speed, running=running,
                 active=jnp.arange(max_people) < np_, wrap_half=14.0))
    speed = d.uniform("cyclist_kmh", 10.0, 25.0, (max_cyc,)) * KMH
    heading = jnp.where(d.coin("cyclists_rightwards", 0.5, (max_cyc,)), 0.0, math.pi)
    bases = _bases(d.uniform("cyclists_x", -20.0, 20.0, (max_cyc,)),
                   d.uniform("cyclists_z", 7.0, 16.0, (max_cyc,)) + jnp.arange(max_cyc))
    out.add(many(cyclist, d, "cyclists", max_cyc, bases, heading, speed, active=jnp.arange(max_cyc) < nc_,
                 wrap_half=25.0))
    out.add(many(pole, d, "poles", 3, _scatter(d, "poles", 3, (-8.0, 8.0), (4.0, 14.0)),
                 active=d.coin("poles_present", 0.8, (3,))))
    out.add(many(tree, d, "trees", 3, _scatter(d, "trees", 3, (-12.0, 12.0), (9.0, 16.0)),
                 active=d.coin("trees_present", 0.6, (3,))))
    out.add(many(bench, d, "benches", 2, _scatter(d, "benches", 2, (-6.0, 6.0), (4.0, 12.0)),
                 d.uniform("benches_yaw", -0.3, 0.3, (2,)), active=d.coin("benches_present", 0.6, (2,))))
    kiosk = jnp.stack([d.uniform("kiosk_x", -8.0, 8.0), jnp.array(0.0), d.uniform("kiosk_z", 6.0, 14.0)])
    out.add(block(d.child("kiosk"), kiosk, d.uniform("kiosk_yaw", -0.5, 0.5), active=d.coin("kiosk_present", 0.6)))
    out.boxes.append(buildings(d.child("buildings"), 7, z_range=(14.0, 30.0), x_span=40.0, height_range=(4.0, 22.0)))
    out.boxes.append(buildings(d.child("far_buildings"), 4, z_range=(40.0, 70.0), x_span=60.0,
                               height_range=(8.0, 30.0)))
    return out, _ground(d.child("ground"), "paving")


def _queues(d: Draws, lane_z, kind, gap_range):
    """Two lanes of queued traffic, 3 vehicles each, nose to tail.

    lane_z (2,) m; kind (2, 3) vehicle kinds, lane by lane, front to back. Each vehicle draws its length and the
    gap behind it (`gap_range`, m); the lane wraps with the period of its queue (the lengths and gaps), so the
    spacing holds for ever. Where that period would let a wrap show to a static camera (`_edge_of_view` plus
    half the lane's longest vehicle and 0.1 m, each way), the gaps are stretched alike until it does not.
    Returns the offsets along the lane (2, 3) m, front vehicle at 0 and the others behind it (negative), the
    lanes' wrap half-periods (2,) m and the length quantiles (2, 3) (`vehicle_length`)."""
    length_u = d.uniform("queue_length", shape=(2, 3))
    length = vehicle_length(kind, length_u)
    gap = d.uniform("queue_gap", *gap_range, (2, 3))
    hidden_half = _edge_of_view(lane_z) + length.max(-1) / 2 + 0.1
    gap = gap + jnp.maximum(2 * hidden_half - jnp.sum(length + gap, -1), 0.0)[:, None] / 3
    wrap_half = jnp.sum(length + gap, -1) / 2
    behind = length[:, :-1] / 2 + gap[:, :-1] + length[:, 1:] / 2  # centre to centre, each to the one behind
    offset = -jnp.concatenate([jnp.zeros((2, 1)), jnp.cumsum(behind, -1)], -1)
    return offset, wrap_half, length_u


def _road(d: Draws, *, n_vehicles=(2, 6), truck=None, traffic="free", lane_kmh=(10.0, 60.0), queue_gap=(2.0, 4.0)):
    """A road across the view: two lanes of traffic (cars, vans, trucks) at 8-20 m, a parked car, pedestrians
    on the far pavement, trees and poles, buildings and a fence behind.

    traffic (static): "free": three vehicles per lane 30 m apart (+-4 m), flows at `lane_kmh` (10-60 km/h), so
    the view (5-10 m wide at these depths) is often empty of traffic. "queue": congested traffic, each lane a
    queue of three vehicles nose to tail with gaps drawn in `queue_gap` m (`_queues`); with gaps below the width
    of the view at the near lane (4.3 m at 8 m), its queue keeps a vehicle in view at every time, the far lane
    one most of the time. With 2-4 m gaps, 7-9 m from front to front, and 10-25 km/h, vehicles follow 1-3 s
    apart: a busy street in slow traffic.
    """
    if traffic not in ("free", "queue"):
        raise ValueError(f"road: traffic must be 'free' or 'queue', got {traffic!r}")
    out = parts()
    z_near = d.uniform("near_lane_z", 8.0, 14.0)
    n_veh = jnp.maximum(d.count("n_vehicles", *n_vehicles), 1)
    lane = jnp.repeat(jnp.stack([z_near, z_near + 3.5]), 3)
    heading = jnp.repeat(jnp.array([0.0, math.pi]), 3)
    speed = jnp.repeat(d.uniform("lane_kmh", *lane_kmh, (2,)) * KMH, 3)  # one flow per lane: vehicles keep spacing
    kind = jnp.where(d.coin("is_truck", 0.15, (6,)), 2, jnp.where(d.coin("is_van", 0.25, (6,)), 1, 0))
    if truck is not None:
        kind = kind.at[0].set(2 if truck else 0)
    lane_x = d.uniform("lane_x", -45.0, 45.0, (2,))
    if traffic == "free":
        x = jnp.repeat(lane_x, 3) + jnp.tile(jnp.arange(3) * 30.0, 2) + d.uniform("vehicle_x", -4, 4, (6,))
        extra = {"wrap_half": 45.0}
    else:
        offset, wrap_half, length_u = _queues(d, lane[::3], kind.reshape(2, 3), queue_gap)
        forward = jnp.array([[1.0], [-1.0]])  # the near lane drives along +X, the far one along -X
        x = (lane_x[:, None] / 45.0 * wrap_half[:, None] + forward * offset).ravel()
        extra = {"wrap_half": jnp.repeat(wrap_half, 3), "length_u": length_u.ravel()}
    out.add(many(vehicle, d, "vehicles", 6, _bases(x, lane), heading, speed, kind=kind,
                 active=jnp.arange(6) < n_veh, **extra))
    parked = jnp.stack([d.uniform("parked_x", -6.0, 6.0), jnp.array(0.0), z_near - 3.0])
    out.add(vehicle(d.child("parked"), parked, 0.0, jnp.array(0.0), kind=0, active=d.coin("parked_present", 0.5)))
    out.add(many(person, d, "people", 2, _bases(d.uniform("people_x", -10.0, 10.0, (2,)),
                                                 z_near + 6.5 + jnp.arange(2.0)),
                 jnp.where(d.coin("people_rightwards", 0.5, (2,)), 0.0, math.pi),
                 d.uniform("walk_kmh", 3.0, 6.0, (2,)) * KMH, active=d.coin("people_present", 0.6, (2,)),
                 wrap_half=20.0))
    out.add(many(tree, d, "trees", 3, _bases(d.uniform("trees_x", -15.0, 15.0, (3,)),
                                             z_near + d.uniform("trees_dz", 6.0, 9.0, (3,))),
                 active=d.coin("trees_present", 0.7, (3,))))
    out.add(many(pole, d, "poles", 3, _bases(d.uniform("poles_x", -10.0, 10.0, (3,)),
                                             z_near - d.uniform("poles_dz", 1.5, 2.5, (3,))),
                 active=d.coin("poles_present", 0.6, (3,))))
    fence_z = z_near + d.uniform("fence_dz", 9.0, 12.0)
    out.add(wall(jnp.stack([jnp.array(0.0), jnp.array(0.0), fence_z]), jnp.array([60.0, 0.05]),
                 d.uniform("fence_height", 1.0, 2.2), 0.0, d.uniform("fence_reflectivity", 0.2, 0.7),
                 texture(d.uniform("fence_slats", 0.1, 0.3), 5.0, 0.4, 0.0), active=d.coin("fence_present", 0.6)))
    out.boxes.append(buildings(d.child("buildings"), 7, z_range=(z_near + 13.0, z_near + 30.0), x_span=45.0,
                               height_range=(4.0, 20.0)))
    return out, _ground(d.child("ground"), "asphalt", lane_z=z_near + 1.75)


def _courtyard(d: Draws, *, n_people=(0, 2)):
    """A courtyard or open room: walls on three sides at 4-15 m, tables, chairs and sofas, shelves, crates,
    planters, and a few people walking slowly."""
    out = parts()
    back = d.uniform("back", 8.0, 15.0)
    left, right = -d.uniform("left", 4.0, 7.0), d.uniform("right", 4.0, 7.0)
    h = d.uniform("wall_height", 2.6, 6.0)
    wall_tex = texture(d.uniform("wall_period_s", 1.0, 3.0), d.uniform("wall_period_h", 1.5, 3.0),
                       d.uniform("wall_contrast", -0.2, 0.5), 0.3)
    refl = d.uniform("wall_reflectivity", 0.3, 0.85)
    out.add(wall(jnp.stack([jnp.array(0.0), jnp.array(0.0), back + 0.2]), jnp.stack([right - left, jnp.array(0.2)]),
                 h, 0.0, refl, wall_tex))
    for x in (left, right):
        out.add(wall(jnp.stack([x, jnp.array(0.0), back / 2]), jnp.stack([back / 2 + 0.4, jnp.array(0.2)]),
                     h, math.pi / 2, refl * 0.9, wall_tex))
    span = lambda name, n: _scatter(d, name, n, (left + 0.8, right - 0.8), (3.0, back - 1.0))
    out.add(many(table, d, "tables", 3, span("tables", 3), d.uniform("tables_yaw", -0.4, 0.4, (3,)),
                 active=d.coin("tables_present", 0.8, (3,))))
    out.add(many(bench, d, "seats", 5, span("seats", 5), d.uniform("seats_yaw", -3.1, 3.1, (5,)),
                 active=d.coin("seats_present", 0.7, (5,))))
    shelves = _bases(d.uniform("shelves_x", left + 1.0, right - 1.0, (3,)), jnp.full((3,), back - 0.4))
    out.add(many(block, d, "shelves", 3, shelves, 0.0, static=dict(size_range=((0.4, 1.0), (0.2, 0.35), (1.2, 2.2))),
                 active=d.coin("shelves_present", 0.7, (3,))))
    out.add(many(block, d, "crates", 3, span("crates", 3), d.uniform("crates_yaw", -0.5, 0.5, (3,)),
                 static=dict(size_range=((0.2, 0.5), (0.2, 0.5), (0.3, 1.0))),
                 active=d.coin("crates_present", 0.6, (3,))))
    out.add(many(planter, d, "planters", 2, span("planters", 2), active=d.coin("planters_present", 0.7, (2,))))
    np_ = d.count("n_people", *n_people)
    out.add(many(person, d, "people", 2, _bases(d.uniform("people_x", left, right, (2,)),
                                                d.uniform("people_z", 3.0, back - 1.5, (2,))),
                 jnp.where(d.coin("people_rightwards", 0.5, (2,)), 0.0, math.pi)
                 + d.uniform("people_heading", -0.3, 0.3, (2,)),
                 d.uniform("walk_kmh", 2.5, 5.0, (2,)) * KMH, active=jnp.arange(2) < np_,
                 wrap_half=(right - left) / 2 + 1.0))
    return out, _ground(d.child("ground"), "paving")


def _walkers(d: Draws, *, depth=9.0, speed_kmh=4.3, n_lanes=4, lane_gap=1.0):
    """The frame-rate study: a stream of people walking across the view at `speed_kmh`, both ways, in `n_lanes`
    lanes `lane_gap` m apart centred on `depth` m (each +-0.15 m), in front of a wall, trees and buildings.

    The paper's sequence has people in view throughout, and its slowest rate (1 FPS) spans 48 s of walking,
    57 m at 4.3 km/h; a group of walkers would leave the 4.8 m wide view at 9 m within seconds. So each lane is a
    stream: two people half a wrap period W apart, with W the smallest wrap that stays out of sight of any static
    camera (`_edge_of_view` plus half a person's length and 0.1 m). At these depths W is below the width of the
    view (2 z tan 15 deg, from 3.9 m at 7.35 m), so at every time, not just the frames of one sequence, each lane
    has at least one person whose centre is in the frame: `n_lanes` people at least, more when a lane's second
    person is also in view, some partly hidden while passing people of a nearer lane. Adjacent lanes walk in
    opposite directions, as people do on a busy pavement; 1 m apart, people in adjacent lanes never touch. All
    walk at the paper's one speed, so the spacing holds for ever; the people differ in height, clothes and gait
    phase. With a moving camera (a fallback of the training sampler) the wraps are not kept out of sight.
    """
    max_lanes = 4  # 2 people each: 40 of the 44 cylinders, the 2 trees take 2 more
    if not 1 <= n_lanes <= max_lanes:
        raise ValueError(f"walkers: n_lanes must be 1 to {max_lanes}, got {n_lanes}")
    nearest = depth - lane_gap * (n_lanes - 1) / 2 - 0.15
    if 2 * nearest * math.tan(HALF_FOV) <= nearest * math.tan(HALF_FOV + MAX_YAW) + PERSON_HALF_LENGTH + 0.1:
        raise ValueError(f"walkers: lanes from {nearest:.2f} m are too near for a stream that keeps people in view")
    out = parts()
    lane_z = (depth + lane_gap * (jnp.arange(n_lanes) - (n_lanes - 1) / 2)
              + d.uniform("lane_dz", -0.15, 0.15, (n_lanes,)))
    wrap_half = _edge_of_view(lane_z) + PERSON_HALF_LENGTH + 0.1
    rightwards = (jnp.arange(n_lanes) + d.coin("first_lane_rightwards", 0.5)) % 2 == 1
    # Two people per lane, W apart; the lane's phase anywhere in its period.
    x = (d.uniform("lane_phase", -1.0, 1.0, (n_lanes,))[:, None] + jnp.array([0.0, 1.0])) * wrap_half[:, None]
    per_person = lambda a: jnp.repeat(a, 2)
    out.add(many(person, d, "people", 2 * n_lanes, _bases(x.ravel(), per_person(lane_z)),
                 per_person(jnp.where(rightwards, 0.0, math.pi)), jnp.asarray(speed_kmh * KMH, jnp.float32),
                 wrap_half=per_person(wrap_half)))
    out.add(wall(jnp.stack([jnp.array(0.0), jnp.array(0.0), d.uniform("wall_z", 16.0, 22.0)]), jnp.array([40.0, 0.2]),
                 d.uniform("wall_height", 2.0, 3.5), 0.0, d.uniform("wall_reflectivity", 0.3, 0.8),
                 texture(d.uniform("wall_period", 0.3, 1.5), 0.5, 0.3, 0.0)))
    out.add(many(tree, d, "trees", 2, _scatter(d, "trees", 2, (-8.0, 8.0), (12.0, 15.0)),
                 active=d.coin("trees_present", 0.6, (2,))))
    out.boxes.append(buildings(d.child("buildings"), 6, z_range=(25.0, 45.0), x_span=40.0, height_range=(6.0, 25.0)))
    return out, _ground(d.child("ground"), "grass")


_KIND_FNS = {"street": _street, "road": _road, "courtyard": _courtyard, "walkers": _walkers}


# ---------------------------------------------------------------------------------------------------------
# Assembling and sampling scenes


def _empty(cls, n):
    m = motion(n, 0.0, 0.0, jnp.array([1.0, 0.0, 0.0]), jnp.inf)
    z = lambda *s: jnp.zeros((n,) + s, jnp.float32)
    if cls is Boxes:
        return Boxes(z(3), jnp.ones((n, 2)), jnp.ones((n,)), z(), z(), jnp.ones((n, 4)), jnp.zeros((n,), bool), m)
    if cls is Cylinders:
        return Cylinders(z(3), jnp.ones((n,)), jnp.ones((n, 2)) * 0.1, z(), z(), z(3), z(), jnp.ones((n, 4)),
                         jnp.zeros((n,), bool), m)
    return Ellipsoids(z(3), jnp.ones((n, 3)), z(), z(), jnp.ones((n, 4)), jnp.zeros((n,), bool), m)


def _cat(groups, cls, n_max):
    total = sum(g.active.shape[0] for g in groups)
    if total > n_max:
        raise ValueError(f"scene needs {total} {cls.__name__.lower()} but the pytree holds {n_max}")
    groups = list(groups) + [_empty(cls, n_max - total)]
    return jax.tree.map(lambda *xs: jnp.concatenate([jnp.asarray(x, jnp.float32) if x.dtype != bool else x
                                                     for x in xs], 0), *groups)


def _assemble(p: Parts, ground, camera) -> Scene:
    return Scene(camera, ground, _cat(p.boxes, Boxes, N_BOXES), _cat(p.cylinders, Cylinders, N_CYLINDERS),
                 _cat(p.ellipsoids, Ellipsoids, N_ELLIPSOIDS))


def empty_scene(*, camera_height=1.7, tilt=0.0, sky=0.9):
    """A scene with every primitive slot inactive: flat ground (reflectivity 0.3), sky, and a static, level
    camera at `camera_height` m (X = Z = 0, looking along +Z). A base for hand-built scenes and tests: set slots
    with `scene._replace(boxes=...)` or `place(...)`.

    Returns a `Scene` with the shapes of `sample_scene` (N_BOXES, N_CYLINDERS, N_ELLIPSOIDS)."""
    camera = Camera(jnp.array([0.0, camera_height, 0.0]), jnp.zeros(3), jnp.array(0.0), jnp.array(0.0),
                    jnp.asarray(tilt, jnp.float32))
    ground = Ground(jnp.array(0.3), texture(1.0, 1.0, 0.0, 0.0), jnp.array(1e6), jnp.asarray(sky, jnp.float32))
    return _assemble(parts(), ground, camera)


def place(scene: Scene, part) -> Scene:
    """Put the primitives of `part` (a Boxes, Cylinders or Ellipsoids with a leading count n) into the first n
    slots of that type in `scene` (shapes (N, ...) unchanged). Returns the new scene.

    Args: scene (Scene), part (a group with leading count n <= the slots of its type).
    """
    name = {Boxes: "boxes", Cylinders: "cylinders", Ellipsoids: "ellipsoids"}[type(part)]
    group = getattr(scene, name)
    n = part.active.shape[0]
    new = jax.tree.map(lambda g, p: g.at[:n].set(jnp.asarray(p, g.dtype)), group, part)
    return scene._replace(**{name: new})


def sample_scene(key, *, kind=None, camera="random", **options):
    """Draw a random scene.

    key: a PRNG key. kind (static): "street", "road", "courtyard", "walkers", or None for a random kind per key
    (chosen with traced selection, so `jax.vmap(sample_scene)(keys)` mixes kinds). camera (static): "static",
    "moving" (sideways at 0.5-8 m/s with a slow pan) or "random" (35 % moving; the walkers' camera is static).
    options (static): passed to the kind's layout (e.g. n_people=(4, 5), n_cyclists=(2, 2), truck=True); only
    with a named kind. Returns a `Scene` of fixed shape (scalar key -> one scene). Jitted (compiled once per
    kind, camera and options).
    """
    if kind is not None and kind not in _KIND_FNS:
        raise ValueError(f"unknown scene kind {kind!r}; expected one of {KINDS} or None")
    if camera not in ("static", "moving", "random"):
        raise ValueError(f"camera must be 'static', 'moving' or 'random', got {camera!r}")
    if options and kind is None:
        raise ValueError("layout options need a named kind")
    return _sample_scene_jit(key, kind, camera, tuple(sorted(options.items())))


def _build(d: Draws, kind, camera, options):
    p, ground = _KIND_FNS[kind](d.child("layout"), **dict(options))
    mode = "static" if (kind == "walkers" and camera == "random") else camera
    return _assemble(p, ground, _camera(d.child("camera"), mode, **_CAMERA_OPTIONS[kind]))


@functools.partial(jax.jit, static_argnums=(1, 2, 3))
def _sample_scene_jit(key, kind, camera, options):
    if kind is not None:
        return with_draws(lambda d: _build(d, kind, camera, options), key)
    k_scene, k_kind = jax.random.split(key)
    scenes = [_sample_scene_jit(k_scene, name, camera, ()) for name in KINDS]
    choice = jax.random.randint(k_kind, (), 0, len(KINDS))
    return jax.tree.map(lambda *xs: jnp.stack(xs)[choice], *scenes)
