"""Procedural depth video: scenes, their ray casting, random sequences, training clips and the fixed test sets.

The modules, from the bottom up:

- `primitives`: the `Scene` pytree (camera, ground, boxes, cylinders, ellipsoids) and the world coordinates;
- `pose`, `raycast`: posing every primitive at a time t, then analytic ray casting to radial depth and
  intensity (`render`, `render_sequence`);
- `draws`: random numbers keyed by name, so that no new draw can shift another;
- `objects`: people, cyclists, vehicles, buildings, trees, poles and furniture;
- `layouts`: streets, roads, courtyards and walkers, their cameras, and `sample_scene`;
- `sequences`: `sequence`, `mean_lr_shift` and `in_view_lr_shift` (motion in LR pixels per frame: of what is
  near the frame, of what is in sight) and the training clips;
- `test_sets`: the fixed, stored test and validation scenes (`test_sequences`).

`windows` and `change_frame_rate` (from `jaxsr.temporal`) are re-exported here as part of the scenes API.
"""

from ..temporal import change_frame_rate as change_frame_rate
from ..temporal import windows as windows
from .draws import Draws as Draws
from .layouts import KINDS as KINDS
from .layouts import N_BOXES as N_BOXES
from .layouts import N_CYLINDERS as N_CYLINDERS
from .layouts import N_ELLIPSOIDS as N_ELLIPSOIDS
from .layouts import empty_scene as empty_scene
from .layouts import place as place
from .layouts import sample_scene as sample_scene
from .primitives import Boxes as Boxes
from .primitives import Camera as Camera
from .primitives import Cylinders as Cylinders
from .primitives import Ellipsoids as Ellipsoids
from .primitives import Ground as Ground
from .primitives import Motion as Motion
from .primitives import Scene as Scene
from .raycast import render as render
from .raycast import render_sequence as render_sequence
from .raycast import grid_depth as grid_depth
from .raycast import seen_primitives as seen_primitives
from .raycast import tile_overflow as tile_overflow
from .sequences import in_view_lr_shift as in_view_lr_shift
from .sequences import mean_lr_shift as mean_lr_shift
from .sequences import moving_share as moving_share
from .sequences import sequence as sequence
from .sequences import training_clip as training_clip
from .sequences import training_scene as training_scene
from .test_sets import SCENES_FILE as SCENES_FILE
from .test_sets import TEST_SEQUENCES as TEST_SEQUENCES
from .test_sets import TestSequence as TestSequence
from .test_sets import draw_test_scene as draw_test_scene
from .test_sets import freeze_test_scenes as freeze_test_scenes
from .test_sets import test_scene as test_scene
from .test_sets import test_sequence as test_sequence
from .test_sets import test_sequences as test_sequences

__all__ = [
    "change_frame_rate",
    "windows",
    "Draws",
    "KINDS",
    "N_BOXES",
    "N_CYLINDERS",
    "N_ELLIPSOIDS",
    "empty_scene",
    "place",
    "sample_scene",
    "Boxes",
    "Camera",
    "Cylinders",
    "Ellipsoids",
    "Ground",
    "Motion",
    "Scene",
    "render",
    "render_sequence",
    "grid_depth",
    "seen_primitives",
    "tile_overflow",
    "in_view_lr_shift",
    "mean_lr_shift",
    "moving_share",
    "sequence",
    "training_clip",
    "training_scene",
    "SCENES_FILE",
    "TEST_SEQUENCES",
    "TestSequence",
    "draw_test_scene",
    "freeze_test_scenes",
    "test_scene",
    "test_sequence",
    "test_sequences",
]
