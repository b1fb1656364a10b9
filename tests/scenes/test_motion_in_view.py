"""Motion in view: the frame-rate study's walkers keep people in sight at every time the study uses,
scene 2 keeps a moving vehicle in sight in every frame, and the training clips show the motion they draw.

"In sight" is `jaxsr.scenes.seen_primitives`: the primitives that are the nearest hit on a 16 x 32 grid of rays
(every 8th HR pixel), so a person hidden behind a nearer one does not count. A grid cast of all 500 frames costs
a few percent of rendering them; the render-based checks (moving pixels in every frame) are marked slow."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsr import scenes
from jaxsr.config import Sensor
from jaxsr.scenes.pose import pose_all

SENSOR = Sensor()
H, W = SENSOR.hr_shape
F = float(SENSOR.focal_px)
PERSON_CYLINDERS = 5  # legs, arms, torso (`jaxsr.scenes.objects.person`); the walkers' people come first
VEHICLE_BOXES = 2  # body and cabin (`jaxsr.scenes.objects.vehicle`); the road's six vehicles come first
# The frame-rate study (experiments/paper/fps_study.py): its rates, and 500 frames per rate (its --span) from t0 = 0 s
# (the table) and from t0 = 60 s (the held-out clips).
STUDY_RATES = (1.0, 2.5, 5.0, 10.0, 20.0, 25.0, 50.0, 100.0)
STUDY_FRAMES, STUDY_T0 = 500, (0.0, 60.0)
MOVING_DEPTH = 0.01  # m: a pixel moves when its depth (no return = d_max) changes by more than this


def sequence_times(name, n_frames=500):
    fps = scenes.TEST_SEQUENCES[name][2]
    return jnp.arange(n_frames, dtype=jnp.float32) / fps


def study_times():
    return jnp.concatenate([t0 + jnp.arange(STUDY_FRAMES, dtype=jnp.float32) / fps
                            for fps in STUDY_RATES for t0 in STUDY_T0])


def n_walkers():
    return 2 * scenes.TEST_SEQUENCES["walkers_100fps"][5]["n_lanes"]


_seen = jax.jit(scenes.seen_primitives)


@jax.jit
def _seen_at(scene, times):
    return jax.vmap(lambda t: scenes.seen_primitives(scene, t, sensor=SENSOR))(times)


def people_seen(scene, times, n_people):
    """(T,) how many of the first n_people people have some part in sight at each time."""
    seen = _seen_at(scene, times)[:, scenes.N_BOXES:scenes.N_BOXES + PERSON_CYLINDERS * n_people]
    return np.asarray(seen.reshape(len(times), n_people, PERSON_CYLINDERS).any(-1).sum(-1))


def moving_share(depth):
    """(T-1,) share of pixels whose depth changes by more than MOVING_DEPTH between consecutive frames."""
    d = np.clip(np.nan_to_num(np.asarray(depth), nan=SENSOR.d_max, posinf=SENSOR.d_max), 0.0, SENSOR.d_max)
    return (np.abs(np.diff(d, axis=0)) > MOVING_DEPTH).mean(axis=(1, 2))


# ---------------------------------------------------------------------------------------------------------
# The walkers


def test_walkers_have_people_in_sight_at_every_time_the_study_uses():
    scene, _ = scenes.test_scene("walkers_100fps")
    n = n_walkers()
    moving = np.linalg.norm(np.asarray(scene.cylinders.motion.velocity[:PERSON_CYLINDERS * n]), axis=-1)
    assert np.allclose(moving, 4.3 / 3.6, rtol=1e-5), "every walker walks at the paper's 4.3 km/h"
    seen = people_seen(scene, jnp.concatenate([sequence_times("walkers_100fps"), study_times()]), n)
    # One person per lane has its centre in the frame at every time (the layout's guarantee); one of them may be
    # hidden behind a nearer person while they pass.
    assert seen.min() >= 3, f"as few as {seen.min()} people in sight"
    assert seen.mean() >= 4.0


def test_walkers_layout_keeps_a_person_per_lane_in_the_frame_at_any_time():
    """The layout's guarantee, by projection (hidden or not), over random draws and times far beyond a sequence:
    in every lane a person's torso centre lies inside the frame's columns."""
    keys = jax.random.split(jax.random.key(11), 6)
    times = jax.random.uniform(jax.random.key(12), (64,), minval=0.0, maxval=1000.0)
    n_lanes = 3

    def torso_columns(scene, t):
        groups, _, _ = pose_all(scene, t)
        box = groups[1].aabb[PERSON_CYLINDERS - 1:PERSON_CYLINDERS * 2 * n_lanes:PERSON_CYLINDERS]
        x, z = (box[:, 0] + box[:, 1]) / 2, (box[:, 4] + box[:, 5]) / 2
        return F * x / z + W / 2

    @jax.jit
    def columns(key):
        scene = scenes.sample_scene(key, kind="walkers", camera="static", n_lanes=n_lanes)
        return jax.vmap(lambda t: torso_columns(scene, t))(times)

    for key in keys:
        cols = np.asarray(columns(key))
        inside = ((cols >= 0) & (cols < W)).reshape(len(times), n_lanes, 2).any(-1)
        assert inside.all(), "a lane without a person in the frame"


def test_walkers_layout_rejects_what_cannot_keep_people_in_view():
    with pytest.raises(ValueError, match="n_lanes"):
        scenes.sample_scene(jax.random.key(0), kind="walkers", n_lanes=5)
    with pytest.raises(ValueError, match="too near"):
        scenes.sample_scene(jax.random.key(0), kind="walkers", depth=4.0)


# ---------------------------------------------------------------------------------------------------------
# Scene 2


def test_scene2_has_a_moving_vehicle_in_sight_in_every_frame():
    scene, fps = scenes.test_scene("scene2_road")
    assert fps == 60.0 and scenes.TEST_SEQUENCES["scene2_road"][3] == 1.3
    vehicles = 6
    boxes = slice(0, VEHICLE_BOXES * vehicles)
    speed = np.linalg.norm(np.asarray(scene.boxes.motion.velocity[boxes]), axis=-1).reshape(vehicles, 2)
    assert np.all(speed > 0) and np.asarray(scene.boxes.active[boxes]).all()
    # Cars, vans and one truck (the body's bottom height tells them apart: 0.3, 0.35, 1.0 m).
    bottom = np.asarray(scene.boxes.centre[boxes][::VEHICLE_BOXES, 1])
    cars, vans, trucks = (int(np.isclose(bottom, b).sum()) for b in (0.3, 0.35, 1.0))
    assert cars >= 1 and vans >= 1 and trucks == 1
    seen = np.asarray(_seen_at(scene, sequence_times("scene2_road"))[:, boxes])
    vehicles_seen = seen.reshape(-1, vehicles, VEHICLE_BOXES).any(-1).sum(-1)
    assert vehicles_seen.min() >= 1


def test_queued_road_layout():
    """Queued traffic: three vehicles per lane nose to tail, bumper gaps (m) in the drawn range plus one stretch
    common to the lane (0 unless needed to hide the wrap), the gap at the wrap included: the lane's wrap period is
    the sum of its vehicles' lengths and gaps."""
    lo_gap, hi_gap = 2.0, 3.0
    scene = scenes.sample_scene(jax.random.key(4), kind="road", camera="static", n_vehicles=(6, 6),
                                traffic="queue", queue_gap=(lo_gap, hi_gap))
    centre = np.asarray(scene.boxes.centre[:12, 0]).reshape(2, 3, 2)  # lane, vehicle, (body, cabin)
    half = np.asarray(scene.boxes.half[:12, 0]).reshape(2, 3, 2)
    rear, front = (centre - half).min(-1), (centre + half).max(-1)  # along X; the near lane drives to +X
    rear[1], front[1] = -front[1], -rear[1]  # the far lane drives to -X: mirror it
    length = front - rear
    gap = rear[:, :-1] - front[:, 1:]  # behind vehicles 0 and 1
    wrap_half = np.asarray(scene.boxes.motion.wrap_half[:12:2]).reshape(2, 3)
    assert np.all(wrap_half == wrap_half[:, :1])
    wrap_gap = 2 * wrap_half[:, 0] - length.sum(-1) - gap.sum(-1)  # behind the last vehicle, ahead of the first
    gaps = np.concatenate([gap, wrap_gap[:, None]], -1)
    assert np.all(gaps >= lo_gap - 1e-3)
    stretch = gaps.min(-1, keepdims=True) - lo_gap
    assert np.all(gaps - stretch <= hi_gap + 1e-3)
    with pytest.raises(ValueError, match="traffic"):
        scenes.sample_scene(jax.random.key(0), kind="road", traffic="jam")


# ---------------------------------------------------------------------------------------------------------
# Sight and the motion in sight


def test_seen_primitives_sees_only_what_is_in_front_and_in_the_frame():
    wall = scenes.Boxes(jnp.array([[0.0, 0.0, 10.0], [0.0, 0.0, 20.0], [0.0, 0.0, 20.0]]),
                        jnp.array([[1.0, 0.1], [0.5, 0.1], [0.5, 0.1]]), jnp.full((3,), 3.0), jnp.zeros(3),
                        jnp.full((3,), 0.5), jnp.ones((3, 4)), jnp.ones(3, bool),
                        scenes.Motion(jnp.zeros((3, 3)), jnp.tile(jnp.array([1.0, 0.0, 0.0]), (3, 1)),
                                      jnp.full((3,), jnp.inf), jnp.zeros((3, 3))))
    # Box 1 stands right behind box 0 (hidden); box 2 stands 20 m to the side (out of the 30 deg view).
    wall = wall._replace(centre=wall.centre.at[2, 0].set(20.0))
    scene = scenes.place(scenes.empty_scene(camera_height=1.7), wall)
    seen = np.asarray(_seen(scene, 0.0))
    assert seen.shape == (scenes.N_BOXES + scenes.N_CYLINDERS + scenes.N_ELLIPSOIDS,)
    assert seen[0] and not seen[1] and not seen[2] and seen.sum() == 1
    moved = scene._replace(boxes=scene.boxes._replace(centre=scene.boxes.centre.at[0, 0].set(-20.0)))
    assert np.asarray(_seen(moved, 0.0))[1], "box 1 is seen once box 0 is out of the way"
    wide = moved.boxes._replace(half=moved.boxes.half.at[1].set(jnp.array([5.0, 0.1])))
    at = lambda z: moved._replace(boxes=wide._replace(centre=wide.centre.at[1, 2].set(z)))
    assert np.asarray(_seen(at(SENSOR.d_max - 5.0), 0.0))[1]
    assert not np.asarray(_seen(at(SENSOR.d_max + 5.0), 0.0)).any(), "beyond the range gate, nothing is in sight"


def test_in_view_shift_counts_only_what_is_in_sight():
    """An object crossing just beside the frame: `mean_lr_shift` (frame widened by half a frame) counts it,
    `in_view_lr_shift` does not until it enters; inside, both give the closed form v / (fps z) * f / scale."""
    v, z, fps = 5.0, 10.0, 50.0
    edge = z * math.tan(math.radians(SENSOR.fov_deg / 2))
    box = scenes.Boxes(jnp.array([[-edge - 1.5, 0.0, z]]), jnp.array([[0.5, 0.3]]), jnp.array([2.0]), jnp.zeros(1),
                       jnp.array([0.5]), jnp.ones((1, 4)), jnp.ones(1, bool),
                       scenes.Motion(jnp.array([[v, 0.0, 0.0]]), jnp.array([[1.0, 0.0, 0.0]]), jnp.array([jnp.inf]),
                                     jnp.zeros((1, 3))))
    scene = scenes.place(scenes.empty_scene(camera_height=1.7, tilt=0.08), box)
    closed = v / (fps * z) * F / SENSOR.scale
    assert float(scenes.mean_lr_shift(scene, fps)) == pytest.approx(closed, rel=0.02)
    assert float(scenes.in_view_lr_shift(scene, fps)) == 0.0
    t_in = 1.5 / v  # the box's centre at the frame's edge
    assert float(scenes.in_view_lr_shift(scene, fps, t=t_in)) == pytest.approx(closed, rel=0.02)


@pytest.mark.slow
def test_training_scene_draws_motion_in_sight():
    """Without rendering: the drawn scenes of 8 training clips have something in sight moving at the time the clip is
    centred on, at the drawn shift (within the paper's range where the frame-rate clip does not bind)."""
    keys = jnp.stack([jax.random.key(s) for s in range(500, 508)])

    @jax.jit
    @jax.vmap
    def draw(k):
        scene, fps, t = scenes.training_scene(k)
        return scenes.in_view_lr_shift(scene, fps, t=t), fps

    shift, fps = (np.asarray(a) for a in draw(keys))
    assert np.all(shift > 0)
    inside = (fps > 1.0) & (fps < 2000.0)
    assert np.all((shift[inside] > 0.2 * 0.999) & (shift[inside] < 5.0 * 1.001))


# ---------------------------------------------------------------------------------------------------------
# Rendered: moving pixels in every frame (slow: hundreds of frames)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["walkers_100fps", "scene2_road"])
def test_every_frame_has_moving_pixels(name):
    seq = scenes.test_sequence(name)
    share = moving_share(seq.depth)
    assert share.min() > 0.005, f"{name}: a frame pair with {share.min():.4f} of its pixels moving"


@pytest.mark.slow
def test_every_training_clip_moves_in_view():
    """40 `training_clip` draws (seeds 500-539, 3 frames) each move some pixel by > 1 cm
    (before the change, 9 of them moved none)."""
    keys = jnp.stack([jax.random.key(s) for s in range(500, 540)])
    depth, _, info = jax.jit(jax.vmap(lambda k: scenes.training_clip(k, 3, return_info=True)))(keys)
    d = np.clip(np.nan_to_num(np.asarray(depth), posinf=SENSOR.d_max), 0.0, SENSOR.d_max)
    largest = np.abs(np.diff(d, axis=1)).max(axis=(1, 2, 3))
    assert np.all(largest > MOVING_DEPTH), f"static clips: seeds {500 + np.flatnonzero(largest <= MOVING_DEPTH)}"
    assert np.all(np.asarray(info["shift"]) > 0)


# ---------------------------------------------------------------------------------------------------------
# The motion a clip reports is the motion its depth shows (motion="seen", the photon regimes' clips)

SEEN_KEYS_ROOT, SEEN_DRAWS = 7, 200
# Of the 200 keys split from key 7: clips 9 and 153 move no pixel by 1 cm over 3 frames with motion="drawn" (a
# moving camera sliding along a wall that faces it: image motion without depth motion), 156 and 180 none by more
# than 1 cm; their info reports 0.2, 3.7, 0.9 and 1.2 LR px per frame.
STILL_WITH_DRAWN = (9, 153, 156, 180)


def largest_depth_change(depth):
    """(N,) the largest change of radial depth (no return = d_max) between consecutive frames of each clip."""
    d = np.clip(np.nan_to_num(np.asarray(depth), nan=SENSOR.d_max, posinf=SENSOR.d_max), 0.0, SENSOR.d_max)
    return np.abs(np.diff(d, axis=1)).max(axis=(1, 2, 3))


def clips_of(indices, motion):
    keys = jax.random.split(jax.random.key(SEEN_KEYS_ROOT), SEEN_DRAWS)[np.asarray(indices)]
    clip = jax.jit(jax.vmap(lambda k: scenes.training_clip(k, 3, return_info=True, motion=motion)))
    largest, infos = [], []
    for i in range(0, len(keys), 20):
        depth, _, info = clip(keys[i:i + 20])
        largest.append(largest_depth_change(depth))
        infos.append({k: np.asarray(v) for k, v in info.items()})
    return np.concatenate(largest), {k: np.concatenate([i[k] for i in infos]) for k in infos[0]}


def check_seen(largest, info, indices):
    moving = info["moving"] > 0
    # what the grid sees moving, the rendered frames show moving (the grid's rays are pixels of the render)
    assert np.all(largest[moving] > MOVING_DEPTH)
    # motion="seen": every clip moves, and reports a shift only if it does
    still = np.asarray(indices)[largest <= MOVING_DEPTH]
    assert still.size == 0, f"clips {still} show no motion"
    assert np.all(moving) and np.all(info["shift"] > 0)


@pytest.mark.slow
def test_seen_motion_fixes_the_still_clips():
    """Without rendering: the 40 clips' scenes show no depth motion on the ray grid from their centre frame
    to the next with motion="drawn" though they report a shift; with motion="seen" each does."""
    keys = jax.random.split(jax.random.key(SEEN_KEYS_ROOT), SEEN_DRAWS)[np.asarray(STILL_WITH_DRAWN)]

    def draw(motion):
        @jax.jit
        @jax.vmap
        def one(k):
            scene, fps, t = scenes.training_scene(k, motion=motion)
            return scenes.in_view_lr_shift(scene, fps, t=t), scenes.moving_share(scene, t, 1.0 / fps)

        return (np.asarray(a) for a in one(keys))

    shift, moving = draw("drawn")
    assert np.all(shift > 0.1) and np.all(moving == 0)
    shift, moving = draw("seen")
    assert np.all(shift > 0) and np.all(moving > 0)


@pytest.mark.slow
def test_seen_motion_over_200_draws():
    """The check over all 200 draws, rendered (about 2.5 min on 2 cores): none is still with
    motion="seen"; with "drawn", the four of `STILL_WITH_DRAWN` are, and their info says `moving` 0."""
    largest, info = clips_of(STILL_WITH_DRAWN, "drawn")
    assert np.all(largest <= MOVING_DEPTH) and np.all(info["shift"] > 0.1) and np.all(info["moving"] == 0)
    indices = np.arange(SEEN_DRAWS)
    check_seen(*clips_of(indices, "seen"), indices)


@pytest.mark.slow  # 14 s of scene rendering
def test_moving_share_sees_depth_motion_not_image_motion():
    """A wall facing a camera that moves sideways: its image moves (`in_view_lr_shift` > 0), its depth does not
    (`moving_share` 0, the still clips' case); a narrow box crossing in front of it moves depth."""
    def box(x, half_x, z, height, v):
        return scenes.Boxes(jnp.array([[x, 0.0, z]]), jnp.array([[half_x, 0.1]]), jnp.array([height]), jnp.zeros(1),
                            jnp.array([0.5]), jnp.ones((1, 4)), jnp.ones(1, bool),
                            scenes.Motion(jnp.array([[v, 0.0, 0.0]]), jnp.array([[1.0, 0.0, 0.0]]),
                                          jnp.array([jnp.inf]), jnp.zeros((1, 3))))

    wall = scenes.place(scenes.empty_scene(camera_height=1.7, tilt=0.0), box(0.0, 40.0, 10.0, 40.0, 0.0))
    wall = wall._replace(camera=wall.camera._replace(velocity=jnp.array([5.0, 0.0, 0.0])))
    fps = 25.0
    assert float(scenes.in_view_lr_shift(wall, fps)) > 0.1
    assert float(scenes.moving_share(wall, 0.0, 1.0 / fps)) == 0.0
    crossing = scenes.place(scenes.empty_scene(camera_height=1.7, tilt=0.0), box(0.0, 0.5, 8.0, 2.0, 5.0))
    assert float(scenes.moving_share(crossing, 0.0, 1.0 / fps)) > 0.0


def test_motion_mode_is_checked():
    with pytest.raises(ValueError, match="motion"):
        scenes.training_clip(jax.random.key(0), 3, motion="visible")
