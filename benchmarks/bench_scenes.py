"""Scene rendering throughput: HR frames rendered per second (target >= 500 on 2 CPU cores), and a training
batch's clips (`training_clip`, scene sampling included).

    pytest benchmarks/bench_scenes.py --benchmark-enable

frames/s = frames per call / mean call time, recorded in extra_info["items_per_s"]. Steady state after compiling;
the batch is a vmap over scenes or a leading time axis, as the trainer uses it.
"""

import jax
import jax.numpy as jnp
import pytest

from jaxsr import scenes
from jaxsr.scenes import render_sequence

FRAMES = 32


@pytest.mark.parametrize("name", ["scene1_street", "scene2_road", "scene3_courtyard", "walkers_100fps"])
def test_render_frames_per_second(timed, name):
    scene, fps = scenes.test_scene(name)
    times = jnp.arange(FRAMES, dtype=jnp.float32) / fps
    render = jax.jit(render_sequence)
    timed(render, scene, times, rounds=5, items=FRAMES)


def test_render_full_casting_frames_per_second(timed):
    """The reference renderer without screen-space culling (every primitive against every pixel)."""
    scene, fps = scenes.test_scene("scene1_street")
    times = jnp.arange(FRAMES, dtype=jnp.float32) / fps
    render = jax.jit(lambda s, t: render_sequence(s, t, tiles=None))
    timed(render, scene, times, rounds=3, items=FRAMES)


def test_training_batch_clips(timed):
    """A training batch's data: 4 clips of 9 frames (TR 4), random kinds, scenes sampled inside the step."""
    keys = jax.random.split(jax.random.key(0), 4)
    clips = jax.jit(jax.vmap(lambda k: scenes.training_clip(k, 9)))
    timed(clips, keys, rounds=5, items=4 * 9)
