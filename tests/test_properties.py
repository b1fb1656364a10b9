"""Property tests (hypothesis) over arbitrary inputs: ranges and invariances that must always hold."""

import jax.numpy as jnp
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import jaxsr

SENSOR = jaxsr.Sensor()
counts_strategy = arrays(np.float32, (5, 16), elements=st.floats(0, 1e6, width=32).map(np.floor))


@settings(max_examples=60, deadline=None)
@given(counts_strategy)
def test_centre_of_mass_in_range_and_no_return_iff_flat(counts):
    depth, valid = jaxsr.centre_of_mass(counts, SENSOR, return_mask=True)
    depth, valid = np.asarray(depth), np.asarray(valid)
    assert np.all((depth >= 0) & (depth <= 1))
    above_median = (counts > np.median(counts, axis=-1, keepdims=True)).any(-1)
    np.testing.assert_array_equal(valid, above_median)


@settings(max_examples=40, deadline=None)
@given(counts_strategy, st.integers(0, 15))
def test_centre_of_mass_follows_a_dominant_peak(counts, k):
    peaked = counts.copy()
    peaked[:, k] = 1e7 + counts.max()  # a peak far above everything else
    depth = np.asarray(jaxsr.centre_of_mass(peaked, SENSOR)) * 16
    assert np.all(np.abs(depth - (k + 0.5)) < 1.0)


@settings(max_examples=40, deadline=None)
@given(arrays(np.float64, (2, 4, 6), elements=st.floats(-1e3, 1e3)), st.sampled_from([2, 4]))
def test_upsampling_preserves_constants_and_commutes_with_affine_maps(lr, scale):
    for fn in (jaxsr.bicubic, jaxsr.lanczos):
        up = np.asarray(fn(lr, scale=scale))
        np.testing.assert_allclose(np.asarray(fn(3 * lr + 2, scale=scale)), 3 * up + 2, rtol=1e-4, atol=1e-2)
        const = np.asarray(fn(jnp.full((3, 5), 0.25), scale=scale))
        np.testing.assert_allclose(const, 0.25, atol=1e-6)


@settings(max_examples=40, deadline=None)
@given(arrays(np.float32, (16, 16), elements=st.floats(-2, 3, width=32)),
       arrays(np.float32, (16, 16), elements=st.floats(0, 1, width=32)))
def test_metrics_bounded_and_symmetric_where_defined(pred, gt):
    assert np.isfinite(jaxsr.psnr(pred, gt)) and float(jaxsr.psnr(pred, gt)) >= 0
    s = float(jaxsr.ssim(pred, gt))
    assert -1 - 1e-5 <= s <= 1 + 1e-5
    clipped = np.clip(pred, 0, 1)
    assert abs(float(jaxsr.ssim(clipped, gt)) - float(jaxsr.ssim(gt, clipped))) < 1e-5
