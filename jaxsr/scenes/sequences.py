"""Sequences of a random scene, their motion in LR pixels per frame, and the training clips.

Motion is in physical units: speeds in m/s (drawn in km/h), times in seconds, frame rates in frames per second;
the shift per frame in LR pixels of an object at depth z moving across the view at speed v is
v / (fps z) * focal_px / scale (`mean_lr_shift`; `in_view_lr_shift` counts only the objects in sight). Training
clips are drawn so that the motion they are drawn for is in sight (`training_scene`).
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp

from ..config import Sensor
from .layouts import sample_scene
from .pose import pose_all, project_bounds
from .primitives import Scene
from .raycast import grid_depth, render_sequence, seen_primitives

__all__ = ["MOVING_DEPTH", "in_view_lr_shift", "mean_lr_shift", "moving_share", "sequence", "training_clip",
           "training_scene"]


def sequence(key, n_frames, fps, *, kind=None, sensor: Sensor = Sensor(), t0=0.0, camera="random",
             **options):
    """Render a random scene for `n_frames` (static int) frames at `fps` frames per second from time `t0` (s).

    Returns (depth, intensity), each (n_frames, H, W) float32: radial metres (inf = no return) and [0, 1].
    jit- and vmap-able over key, fps and t0.
    """
    sample_scene(key, kind=kind, camera=camera, **options)  # validates the arguments eagerly (cheap checks)
    return _sequence_jit(key, n_frames, fps, t0, sensor, kind, camera, tuple(sorted(options.items())))


@functools.partial(jax.jit, static_argnums=(1, 5, 6, 7))
def _sequence_jit(key, n_frames, fps, t0, sensor, kind, camera, options):
    scene = sample_scene(key, kind=kind, camera=camera, **dict(options))
    times = t0 + jnp.arange(n_frames, dtype=jnp.float32) / fps
    return render_sequence(scene, times, sensor=sensor)


def _image_motion(scene: Scene, t, sensor: Sensor, margin):
    """Per primitive (P,), in the order of `pose_all`'s groups: the image speed of its bounding-box centre in LR
    px per second (the exact derivative of the projection, camera motion and pan included) and whether it is
    active, in front of the camera and its projected bounds overlap the frame widened by `margin` frames on
    each side."""
    h, w = sensor.hr_shape
    f = sensor.focal_px
    tilt = scene.camera.tilt

    def project(t):
        groups, _, _ = pose_all(scene, t)
        c = jnp.concatenate([(g.aabb[:, 0::2] + g.aabb[:, 1::2]) / 2 for g in groups], 0)
        z = jnp.maximum(c[:, 2], 1e-3)
        return jnp.stack([f * c[:, 0] / z, -f * (c[:, 1] / z + tilt)], -1)

    t = jnp.asarray(t, jnp.float32)
    _, duv = jax.jvp(project, (t,), (jnp.ones_like(t),))
    groups, _, _ = pose_all(scene, t)
    in_frame = []
    for g in groups:
        bounds, visible = project_bounds(g.aabb, sensor, tilt)
        in_frame.append(g.active & visible & (bounds[:, 1] > -margin * w) & (bounds[:, 0] < (1 + margin) * w)
                        & (bounds[:, 3] > -margin * h) & (bounds[:, 2] < (1 + margin) * h) & (g.aabb[:, 5] > 0.5))
    speed = jnp.sqrt(jnp.sum(duv ** 2, -1)) / sensor.scale
    return speed, jnp.concatenate(in_frame)


def _mean_moving(speed, counted, fps):
    """Mean of `speed` (LR px/s) over the counted primitives that move (> 1e-3 LR px/s), per frame at `fps`;
    0 if none moves."""
    moving = counted & (speed > 1e-3)
    return jnp.sum(jnp.where(moving, speed, 0.0)) / jnp.maximum(jnp.sum(moving), 1) / fps


@jax.jit
def mean_lr_shift(scene: Scene, fps, *, sensor: Sensor = Sensor(), t=0.0):
    """Mean image motion of the moving objects, in LR pixels per frame at `fps`.

    Args: scene (a `Scene`), fps (frames per second, scalar), t (s, scalar). For every active primitive whose
    projected bounding box overlaps the frame widened by half a frame on each side at time t, the image velocity
    of its bounding-box centre (HR px/s, the exact derivative of the projection, camera motion and pan included)
    is divided by `sensor.scale` and `fps`; the mean is over those that move (> 1e-3 LR px/s).
    Returns a scalar (0 if nothing moves). An object at depth z crossing the view at speed v moves
    v / (fps z) * focal_px / scale LR px per frame: 35 m, 50 km/h, 100 FPS -> 0.47 (the paper's "about 0.5").
    `in_view_lr_shift` counts only what is in sight.
    """
    speed, in_frame = _image_motion(scene, t, sensor, 0.5)
    return _mean_moving(speed, in_frame, fps)


@functools.partial(jax.jit, static_argnames="stride")
def in_view_lr_shift(scene: Scene, fps, *, sensor: Sensor = Sensor(), t=0.0, stride: int = 8):
    """Mean image motion of the moving objects in sight, in LR pixels per frame at `fps`.

    As `mean_lr_shift`, but the mean is over the moving primitives that are seen at time t: the nearest hit on
    at least one ray of a grid through every `stride`-th HR pixel (`jaxsr.scenes.raycast.seen_primitives`), so
    objects beside the frame or hidden behind others do not count. This is the motion a clip shows.
    Args: scene (a `Scene`), fps (scalar), t (s, scalar), stride (static int). Returns a scalar, 0 if nothing
    in sight moves.
    """
    speed, in_frame = _image_motion(scene, t, sensor, 0.0)
    return _mean_moving(speed, in_frame & seen_primitives(scene, t, sensor=sensor, stride=stride), fps)


# Times tried per drawn scene for one at which something in sight moves (a person crossing a street is in view for
# a small part of the 10 s); with none at any of them, a moving-camera draw is used instead. How often a clip still
# shows no motion: experiments/results/motion.md.
N_TIMES = 8


# A pixel moves when its radial depth (no return read as d_max) changes by more than this many metres between two
# frames; the ray grid `moving_share` checks it on (every MOTION_STRIDE-th HR pixel).
MOVING_DEPTH = 0.01
MOTION_STRIDE = 4


def moving_share(scene: Scene, t, dt, *, sensor: Sensor = Sensor(), stride: int = MOTION_STRIDE):
    """Share of the rays of a grid through every `stride`-th HR pixel whose radial depth (no return = d_max)
    changes by more than `MOVING_DEPTH` (1 cm) between times t and t + dt (s): the motion a depth clip shows.
    A grid ray is a pixel of `render`, so a share > 0 means the rendered frames differ there too. The image
    motion of a primitive (`in_view_lr_shift`) can be invisible in depth: a wall facing a camera that moves
    sideways slides its texture, not its depth. Args: scene, t, dt (scalars), stride (static int). Returns a
    scalar in [0, 1]."""
    def depth(time):
        d = grid_depth(scene, time, sensor=sensor, stride=stride)
        return jnp.clip(jnp.where(jnp.isfinite(d), d, sensor.d_max), 0.0, sensor.d_max)

    return jnp.mean(jnp.abs(depth(t + dt) - depth(t)) > MOVING_DEPTH)


def training_scene(key, *, sensor: Sensor = Sensor(), shift_range=(0.2, 5.0), motion: str = "drawn"):
    """Draw the scene, frame rate and time of a training clip (see `training_clip`), without rendering.

    Returns (scene, fps, t): a `Scene`, frames per second (scalar) and the time (s, scalar) the clip is centred
    on. The motion in sight `in_view_lr_shift(scene, fps, t=t)` is log-uniform in `shift_range` (up to the fps
    clip to [1, 2000]). t is the first of `N_TIMES` random times in [0, 10) s at which something in sight moves;
    a scene where nothing in sight moves at any of them is replaced by the same kind of draw with a moving
    camera (searched the same way). `motion="seen"` (opt-in) also requires, at that time, depth that changes:
    `moving_share(scene, t, 1 / fps) > 0` (`training_clip`)."""
    return _training_scene_jit(key, sensor, tuple(float(v) for v in shift_range), _motion_mode(motion))


def _motion_mode(motion):
    if motion not in ("drawn", "seen"):
        raise ValueError(f"training_clip: motion must be 'drawn' or 'seen', got {motion!r}")
    return motion


def _first_time_in_view(scene, times, sensor):
    """(motion in sight in LR px per second, time): at the first of `times` where something in sight moves
    (the first time and 0 if none)."""
    per_second = jax.vmap(lambda t: in_view_lr_shift(scene, 1.0, sensor=sensor, t=t))(times)
    i = jnp.argmax(per_second > 0)
    return per_second[i], times[i]


def _fps(per_second, target):
    """The frame rate that gives `target` LR px per frame to `per_second` LR px per second (25 if 0)."""
    return jnp.where(per_second > 0, jnp.clip(per_second / target, 1.0, 2000.0), 25.0)


def _first_time_seen(scene, times, target, sensor):
    """(motion in sight in LR px per second, time, found): at the first of `times` where something in sight
    moves and the depth changes between that time and the next frame at the frame rate the target gives (the
    first time, 0 and False if none)."""
    per_second = jax.vmap(lambda t: in_view_lr_shift(scene, 1.0, sensor=sensor, t=t))(times)
    fps = _fps(per_second, target)
    seen = jax.vmap(lambda t, f: moving_share(scene, t, 1.0 / f, sensor=sensor))(times, fps) > 0
    ok = (per_second > 0) & seen
    i = jnp.argmax(ok)
    return jnp.where(ok[i], per_second[i], 0.0), times[i], ok[i]


@functools.partial(jax.jit, static_argnums=(2, 3))
def _training_scene_jit(key, sensor, shift_range, motion="drawn"):
    k_scene, k_moving, k_shift, k_times = jax.random.split(key, 4)
    times = jax.random.uniform(k_times, (N_TIMES,), minval=0.0, maxval=10.0)
    lo, hi = shift_range
    if motion == "seen":
        target = jnp.exp(jax.random.uniform(k_shift, (), minval=math.log(lo), maxval=math.log(hi)))
        per_second, t, found = _first_time_seen(sample_scene(k_scene), times, target, sensor)
        per_second_moving, t_moving, _ = _first_time_seen(sample_scene(k_moving, camera="moving"), times, target,
                                                          sensor)
        use_moving = ~found
        scene = jax.tree.map(lambda a, b: jnp.where(use_moving, b, a), sample_scene(k_scene),
                             sample_scene(k_moving, camera="moving"))
        per_second = jnp.where(use_moving, per_second_moving, per_second)
        return scene, _fps(per_second, target), jnp.where(use_moving, t_moving, t)
    # "drawn": the bundled models' clips, computed exactly as before motion="seen" existed.
    scene = sample_scene(k_scene)
    per_second, t = _first_time_in_view(scene, times, sensor)
    moving = sample_scene(k_moving, camera="moving")
    per_second_moving, t_moving = _first_time_in_view(moving, times, sensor)
    use_moving = per_second <= 0
    scene = jax.tree.map(lambda a, b: jnp.where(use_moving, b, a), scene, moving)
    per_second = jnp.where(use_moving, per_second_moving, per_second)
    t = jnp.where(use_moving, t_moving, t)
    target = jnp.exp(jax.random.uniform(k_shift, (), minval=math.log(lo), maxval=math.log(hi)))
    fps = jnp.where(per_second > 0, jnp.clip(per_second / target, 1.0, 2000.0), 25.0)
    return scene, fps, t


def training_clip(key, n_frames, *, sensor: Sensor = Sensor(), shift_range=(0.2, 5.0),
                  return_info=False, motion: str = "drawn"):
    """A random training clip whose motion in sight is log-uniform in `shift_range` LR pixels per frame.

    Draws a random kind and scene (35 % with a moving camera), a target shift, a time at which something in
    sight moves, and the frame rate that gives the target shift to what is in sight at that time
    (fps = `in_view_lr_shift` per second / target, clipped to [1, 2000]); the clip's frames are centred on that
    time, so the motion is in view in its middle frame (the one the training loss of the window form scores).
    See `training_scene`. Returns (depth, intensity), each (n_frames, H, W) float32 (radial metres, inf = no
    return; [0, 1]); with return_info also a dict(fps=, shift=, t=, moving=) of scalars (shift: `in_view_lr_shift`
    at the centre time t; moving: `moving_share` from t to the next frame, the share of a 32 x 64 ray grid whose
    depth changes by more than 1 cm). jit- and vmap-able over key (n_frames static).

    motion: "drawn" (the default, the clips the bundled models were trained on) or "seen" (opt-in): the time
    and scene are searched for depth that changes as well, since image motion can be invisible in depth (a
    wall facing a camera that moves sideways). With "drawn", 4 of 200 clips (keys split from key 7, 3 frames)
    move no pixel by more than 1 cm (2 of them by less than 5 mm), though their shift is 0.2-3.7 LR px per
    frame; with "seen", none of the 200. With "seen" the reported shift is 0 if no time of either draw shows
    depth changing (then `moving` is 0 too; none of the 200 did)."""
    return _training_clip_jit(key, int(n_frames), sensor, tuple(float(v) for v in shift_range), bool(return_info),
                              _motion_mode(motion))


@functools.partial(jax.jit, static_argnums=(1, 3, 4, 5))
def _training_clip_jit(key, n_frames, sensor, shift_range, return_info, motion="drawn"):
    scene, fps, t = _training_scene_jit(key, sensor, shift_range, motion)
    times = t + (jnp.arange(n_frames, dtype=jnp.float32) - (n_frames - 1) / 2) / fps
    depth, intensity = render_sequence(scene, times, sensor=sensor)
    if return_info:
        moving = moving_share(scene, t, 1.0 / fps, sensor=sensor)
        shift = in_view_lr_shift(scene, fps, sensor=sensor, t=t)
        if motion == "seen":
            shift = jnp.where(moving > 0, shift, 0.0)
        return depth, intensity, dict(fps=fps, shift=shift, t=t, moving=moving)
    return depth, intensity
