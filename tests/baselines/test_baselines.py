"""Bicubic and Lanczos baselines against PIL (interior) and closed-form properties."""

import jax
import numpy as np
import pytest
from PIL import Image

import jaxsr
from jaxsr.baselines.interpolation import keys_cubic, resampling_matrix


def pil_resize(img, scale, method):
    h, w = img.shape
    return np.asarray(Image.fromarray(img.astype(np.float32), mode="F").resize((w * scale, h * scale), method))


@pytest.mark.parametrize("fn,method,margin", [(jaxsr.bicubic, Image.BICUBIC, 8), (jaxsr.lanczos, Image.LANCZOS, 12)])
def test_interior_matches_pil(fn, method, margin):
    img = np.random.default_rng(0).uniform(0, 1, (20, 28))
    got = np.asarray(fn(img, scale=4))
    want = pil_resize(img, 4, method)
    np.testing.assert_allclose(got[margin:-margin, margin:-margin], want[margin:-margin, margin:-margin], atol=2e-5)


def test_bicubic_reproduces_linear_ramps_and_constants():
    y, x = np.mgrid[0:8, 0:10].astype(float)
    ramp = 0.3 * x - 0.2 * y + 1.0
    up = np.asarray(jaxsr.bicubic(ramp, scale=4))
    yy, xx = np.mgrid[0:32, 0:40]
    want = 0.3 * ((xx + 0.5) / 4 - 0.5) - 0.2 * ((yy + 0.5) / 4 - 0.5) + 1.0
    np.testing.assert_allclose(up[8:-8, 8:-8], want[8:-8, 8:-8], atol=1e-5)
    np.testing.assert_allclose(jaxsr.bicubic(np.full((4, 4), 0.7), scale=4), 0.7, atol=1e-6)  # edges too


def test_kernel_and_matrix_properties():
    assert keys_cubic(0.0) == 1.0 and keys_cubic(1.0) == 0.0 and keys_cubic(2.0) == 0.0
    m = resampling_matrix(6, 4, "bicubic")
    np.testing.assert_allclose(m.sum(1), 1.0)
    assert m.shape == (24, 6)


def test_leading_axes_vmap_jit_and_scale8():
    lr = np.random.default_rng(1).uniform(0, 1, (3, 2, 8, 16)).astype(np.float32)
    out = jaxsr.bicubic(lr, scale=4)
    assert out.shape == (3, 2, 32, 64)
    np.testing.assert_allclose(jax.vmap(lambda f: jaxsr.bicubic(f, scale=4))(lr), out, atol=1e-6)
    np.testing.assert_allclose(jax.jit(lambda f: jaxsr.lanczos(f, scale=4))(lr), jaxsr.lanczos(lr, scale=4), atol=1e-6)
    assert jaxsr.bicubic(lr, scale=8).shape == (3, 2, 64, 128)


def test_bad_input_raises():
    with pytest.raises(ValueError, match=r"\(\.\.\., h, w\)"):
        jaxsr.bicubic(np.zeros(5), scale=4)
    with pytest.raises(ValueError, match="positive integer"):
        jaxsr.bicubic(np.zeros((4, 4)), scale=2.5)
