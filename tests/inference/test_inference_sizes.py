"""Any LR frame size through inference: (T, h, w) -> (T, 4h, 4w), spatial tiles that reproduce the
whole frame, the receptive radius the tiles' margins rely on, and sizes that are refused."""

import jax
import numpy as np
import pytest

from jaxsr.config import ModelConfig
from jaxsr.inference import iter_super_resolve, super_resolve, super_resolve_histograms, tile_spans
from jaxsr.nn import Model, init_model, spatial_radius

TINY = {"base": 8, "growth": 4, "head": 16, "filter_hidden": 16}


def _model(tr, temporal="window"):
    """A tiny model with random weights (equal configs share compilations across tests)."""
    cfg = ModelConfig(tr=tr, temporal=temporal, **TINY)
    return Model(*init_model(jax.random.key(0), cfg), cfg)


@pytest.fixture(scope="module")
def lr():
    return np.random.default_rng(0).uniform(0, 1, (3, 48, 80)).astype(np.float32)


@pytest.mark.parametrize("temporal", ["window", pytest.param("sequence", marks=pytest.mark.slow)])
def test_tiled_equals_whole_frame(lr, temporal):
    """(3, 48, 80) -> (3, 192, 320); tiles of 2R + 6 LR pixels a side (3 x 5 tiles of 18 x 18) give the whole
    frame's output, because each core has the receptive radius as margin or the frame's own edge."""
    model = _model(1, temporal)
    whole = super_resolve(model, lr, tile=None)
    assert whole.shape == (3, 192, 320)
    tiled = super_resolve(model, lr, tile=2 * spatial_radius(model.config) + 6)
    np.testing.assert_allclose(tiled, whole, atol=1e-6)


def test_spatial_radius_is_the_receptive_field(lr):
    """Changing one LR pixel changes HR outputs exactly within +-spatial_radius LR pixels of it (so a smaller
    tile margin would change the output, and this radius is not larger than needed; with freshly initialised
    weights no ReLU path is dead, so the change reaches the radius)."""
    model = _model(1)
    base = super_resolve(model, lr[:1], tile=None)
    bumped = lr[:1].copy()
    bumped[0, 24, 40] += 0.3
    rows, cols = np.nonzero(np.abs(super_resolve(model, bumped, tile=None) - base)[0] > 0)
    radius = spatial_radius(model.config)
    assert radius == 6  # 1 (stem) + 3 + tr blocks + 1 (head)
    assert (rows.min() // 4, rows.max() // 4, cols.min() // 4, cols.max() // 4) == (24 - radius, 24 + radius,
                                                                                    40 - radius, 40 + radius)


def test_tile_spans_cover_each_pixel_once_with_margins():
    for n, radius, side in [(160, 9, 128), (100, 5, 20), (33, 6, 13), (64, 6, 128)]:
        size, spans = tile_spans(n, radius, side)
        assert size <= max(side, n if n <= side else 0) and size <= n
        covered = np.zeros(n, int)
        for start, lo, hi in spans:
            covered[lo:hi] += 1
            assert start <= lo and hi <= start + size and start + size <= n
            assert lo - start >= radius or start == 0
            assert start + size - hi >= radius or start + size == n
        assert (covered == 1).all()


def test_histograms_and_streams_of_other_sizes(lr):
    model = _model(1)
    counts = np.random.default_rng(1).poisson(1.0, (2, 48, 80, 16)).astype(np.float32)
    assert super_resolve_histograms(model, counts).shape == (2, 192, 320)
    frames = iter(lr)  # a generator: no length known in advance
    np.testing.assert_array_equal(np.stack(list(iter_super_resolve(model, frames))), super_resolve(model, lr))


@pytest.mark.parametrize("shape,kwargs,match", [((2, 3, 64), {}, "h, w >= 4"), ((2, 32, 64), {"tile": 12},
                                                                                 "twice the receptive radius")])
def test_refused_sizes(shape, kwargs, match):
    with pytest.raises(ValueError, match=match):
        super_resolve(_model(1), np.full(shape, 0.5, np.float32), **kwargs)
