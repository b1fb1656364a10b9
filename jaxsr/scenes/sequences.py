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

from ..config import SensorConfig
from .layouts import sample_scene
from .pose import pose_all, project_bounds
from .primitives import Scene
from .raycast import render_sequence, seen_primitives

__all__ = ["in_view_lr_shift", "mean_lr_shift", "sequence", "training_clip", "training_scene"]


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
    scene = sample_scene(key, kind=kind, camera=camera, **dict(options))
    times = t0 + jnp.arange(n_frames, dtype=jnp.float32) / fps
    return render_sequence(scene, times, sensor=sensor)


def _image_motion(scene: Scene, t, sensor: SensorConfig, margin):
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
def mean_lr_shift(scene: Scene, fps, *, sensor: SensorConfig = SensorConfig(), t=0.0):
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
def in_view_lr_shift(scene: Scene, fps, *, sensor: SensorConfig = SensorConfig(), t=0.0, stride: int = 8):
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


def training_scene(key, *, sensor: SensorConfig = SensorConfig(), shift_range=(0.2, 5.0)):
    """Draw the scene, frame rate and time of a training clip (see `training_clip`), without rendering.

    Returns (scene, fps, t): a `Scene`, frames per second (scalar) and the time (s, scalar) the clip is centred
    on. The motion in sight `in_view_lr_shift(scene, fps, t=t)` is log-uniform in `shift_range` (up to the fps
    clip to [1, 2000]). t is the first of `N_TIMES` random times in [0, 10) s at which something in sight moves;
    a scene where nothing in sight moves at any of them is replaced by the same kind of draw with a moving
    camera (searched the same way)."""
    return _training_scene_jit(key, sensor, tuple(float(v) for v in shift_range))


def _first_time_in_view(scene, times, sensor):
    """(motion in sight in LR px per second, time): at the first of `times` where something in sight moves
    (the first time and 0 if none)."""
    per_second = jax.vmap(lambda t: in_view_lr_shift(scene, 1.0, sensor=sensor, t=t))(times)
    i = jnp.argmax(per_second > 0)
    return per_second[i], times[i]


@functools.partial(jax.jit, static_argnums=(2,))
def _training_scene_jit(key, sensor, shift_range):
    k_scene, k_moving, k_shift, k_times = jax.random.split(key, 4)
    times = jax.random.uniform(k_times, (N_TIMES,), minval=0.0, maxval=10.0)
    scene = sample_scene(k_scene)
    per_second, t = _first_time_in_view(scene, times, sensor)
    moving = sample_scene(k_moving, camera="moving")
    per_second_moving, t_moving = _first_time_in_view(moving, times, sensor)
    use_moving = per_second <= 0
    scene = jax.tree.map(lambda a, b: jnp.where(use_moving, b, a), scene, moving)
    per_second = jnp.where(use_moving, per_second_moving, per_second)
    t = jnp.where(use_moving, t_moving, t)
    lo, hi = shift_range
    target = jnp.exp(jax.random.uniform(k_shift, (), minval=math.log(lo), maxval=math.log(hi)))
    fps = jnp.where(per_second > 0, jnp.clip(per_second / target, 1.0, 2000.0), 25.0)
    return scene, fps, t


def training_clip(key, n_frames, *, sensor: SensorConfig = SensorConfig(), shift_range=(0.2, 5.0),
                  return_info=False):
    """A random training clip whose motion in sight is log-uniform in `shift_range` LR pixels per frame.

    Draws a random kind and scene (35 % with a moving camera), a target shift, a time at which something in
    sight moves, and the frame rate that gives the target shift to what is in sight at that time
    (fps = `in_view_lr_shift` per second / target, clipped to [1, 2000]); the clip's frames are centred on that
    time, so the motion is in view in its middle frame (the one the training loss of the window form scores).
    See `training_scene`. Returns (depth, intensity), each (n_frames, H, W) float32 (radial metres, inf = no
    return; [0, 1]); with return_info also a dict(fps=, shift=, t=) of scalars (shift: `in_view_lr_shift` at the
    centre time t). jit- and vmap-able over key (n_frames static).
    """
    return _training_clip_jit(key, int(n_frames), sensor, tuple(float(v) for v in shift_range), bool(return_info))


@functools.partial(jax.jit, static_argnums=(1, 3, 4))
def _training_clip_jit(key, n_frames, sensor, shift_range, return_info):
    scene, fps, t = _training_scene_jit(key, sensor, shift_range)
    times = t + (jnp.arange(n_frames, dtype=jnp.float32) - (n_frames - 1) / 2) / fps
    depth, intensity = render_sequence(scene, times, sensor=sensor)
    if return_info:
        return depth, intensity, dict(fps=fps, shift=in_view_lr_shift(scene, fps, sensor=sensor, t=t), t=t)
    return depth, intensity
