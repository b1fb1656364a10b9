"""Layers: conv3d implementations against each other and a slow loop, batch norm semantics, the dynamic
filter with hand-set filters, depth_to_space's sub-pixel convention."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsr.nn.layers import (
    batch_norm,
    conv2d,
    conv3d,
    conv3d_native,
    conv3d_stacked,
    conv3d_stacked_taps_grad,
    conv3d_taps,
    default_conv3d_impl,
    depth_to_space,
    dynamic_upsample,
    init_batch_norm,
    neighbourhoods,
    stacked_use,
)


def _conv3d_loop(x, w, pads):
    """Independent slow reference: explicit zero padding and a loop over output positions."""
    x = np.pad(np.asarray(x, np.float64), ((0, 0), *pads, (0, 0)))
    w = np.asarray(w, np.float64)
    kt, kh, kw, _, cout = w.shape
    b, t, h, wd, _ = x.shape
    out = np.zeros((b, t - kt + 1, h - kh + 1, wd - kw + 1, cout))
    for i in range(out.shape[1]):
        for j in range(out.shape[2]):
            for k in range(out.shape[3]):
                patch = x[:, i : i + kt, j : j + kh, k : k + kw, :]
                out[:, i, j, k] = np.einsum("btxyc,txyco->bo", patch, w)
    return out


PADS = [
    ((1, 1), (1, 1), (1, 1)),  # "same" blocks
    ((0, 0), (1, 1), (1, 1)),  # "valid" blocks
    ((2, 0), (0, 1), (1, 0)),  # asymmetric
]


@pytest.mark.parametrize("pads", PADS)
@pytest.mark.parametrize("t", [1, 4])
def test_conv3d_implementations_match_loop(pads, t):
    kx, kw = jax.random.split(jax.random.key(0))
    x = jax.random.normal(kx, (2, t, 5, 6, 3))
    w = jax.random.normal(kw, (3, 3, 3, 3, 4))
    if t + sum(pads[0]) < 3:
        pytest.skip("fewer padded frames than taps")
    ref = _conv3d_loop(x, w, pads)
    for f in (conv3d_native, conv3d_taps, conv3d_stacked, conv3d_stacked_taps_grad):
        np.testing.assert_allclose(f(x, w, padding=pads), ref, rtol=1e-4, atol=1e-4)


def test_conv3d_dispatch_and_bias():
    x = jax.random.normal(jax.random.key(1), (2, 3, 4, 5, 3))
    w = jax.random.normal(jax.random.key(2), (1, 3, 3, 3, 2))
    b = jnp.array([1.0, -2.0])
    ref = conv3d_native(x, w, b)
    np.testing.assert_allclose(jax.jit(lambda x: conv3d(x, w, b, impl="taps"))(x), ref, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(conv3d(x, w, b, impl="taps"), ref, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(conv3d(x, w, b, impl="stacked"), ref, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(conv3d(x, w, b, impl="auto"), ref, rtol=1e-5, atol=1e-5)
    w1 = jax.random.normal(jax.random.key(3), (1, 1, 1, 3, 2))  # 1x1x1: a matrix product
    np.testing.assert_allclose(conv3d(x, w1, b), conv3d_native(x, w1, b), rtol=1e-5, atol=1e-5)
    assert default_conv3d_impl("cpu") == "taps" and default_conv3d_impl("gpu") == "native"
    with pytest.raises(ValueError, match="impl"):
        conv3d(x, w, impl="fft")
    with pytest.raises(ValueError, match="Cin"):
        conv3d(x[..., :2], w)


@pytest.mark.parametrize("pads", PADS[:2])
def test_conv3d_gradients_match_native(pads):
    x = jax.random.normal(jax.random.key(4), (1, 3, 4, 4, 2))
    w = jax.random.normal(jax.random.key(5), (3, 3, 3, 2, 3))
    g = [jax.grad(lambda x, w: jnp.sum(f(x, w, padding=pads) ** 2), argnums=(0, 1))(x, w)
         for f in (conv3d_native, conv3d_taps, conv3d_stacked, conv3d_stacked_taps_grad)]
    for other in g[1:]:
        for a, b in zip(g[0], other):
            np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-3)


def test_stacked_use_counts_the_products_that_reach_an_output():
    """Brute force: tap k of input frame s reaches output s + t_lo - k when that lies in 0 .. t_out - 1."""
    for t_in, (t_lo, t_hi) in [(9, (1, 1)), (9, (0, 0)), (3, (0, 0)), (1, (1, 1)), (4, (2, 0))]:
        t_out = t_in + t_lo + t_hi - 2
        used = sum(0 <= s + t_lo - k < t_out for s in range(t_in) for k in range(3))
        assert stacked_use(t_in, ((t_lo, t_hi), (1, 1), (1, 1))) == pytest.approx(used / (3 * t_in))
    assert stacked_use(9, "same") == pytest.approx(25 / 27) and stacked_use(3, "valid") == pytest.approx(1 / 3)
    with pytest.raises(ValueError, match="fewer than the temporal kernel"):
        stacked_use(1, "valid")


def test_batch_norm_train_and_eval():
    params, state = init_batch_norm(2)
    params = {"scale": jnp.array([2.0, 1.0]), "shift": jnp.array([0.5, -1.0])}
    # channel 0 = (1, 3), channel 1 = (10, 10) over the (B=2, T=1, H=1, W=1) axes
    x = jnp.array([1.0, 10.0, 3.0, 10.0]).reshape(2, 1, 1, 1, 2)
    y, new = batch_norm(params, state, x, train=True, momentum=0.9, eps=1e-3)
    # mean (2, 10), biased var (1, 0)
    np.testing.assert_allclose(y[:, 0, 0, 0, 0], 2.0 * np.array([-1, 1]) / np.sqrt(1 + 1e-3) + 0.5, rtol=1e-6)
    np.testing.assert_allclose(y[:, 0, 0, 0, 1], [-1.0, -1.0], rtol=1e-6)
    np.testing.assert_allclose(new["mean"], [0.1 * 2.0, 0.1 * 10.0], rtol=1e-6)
    np.testing.assert_allclose(new["var"], [0.9 + 0.1 * 1.0, 0.9 + 0.0], rtol=1e-6)
    # inference: running statistics, state unchanged
    y_eval, same = batch_norm(params, new, x, train=False, eps=1e-3)
    expect = (np.asarray(x) - np.asarray(new["mean"])) / np.sqrt(np.asarray(new["var"]) + 1e-3)
    np.testing.assert_allclose(y_eval, expect * np.array([2.0, 1.0]) + np.array([0.5, -1.0]), rtol=1e-5)
    assert same is new


def test_neighbourhoods_offsets_and_padding():
    frame = jnp.arange(12.0).reshape(1, 3, 4)
    nb = neighbourhoods(frame, size=5, padding="edge")
    assert nb.shape == (1, 3, 4, 25)
    for i in range(5):
        for j in range(5):
            k = 5 * i + j
            # pixel (1, 1): offset (i-2, j-2), clamped to the frame by edge replication
            y, x = np.clip(1 + i - 2, 0, 2), np.clip(1 + j - 2, 0, 3)
            assert nb[0, 1, 1, k] == frame[0, y, x]
    nz = neighbourhoods(frame, size=5, padding="zero")
    assert nz[0, 0, 0, 0] == 0.0 and nb[0, 0, 0, 0] == frame[0, 0, 0]
    assert nz[0, 1, 1, 12] == frame[0, 1, 1]


def test_one_hot_filter_is_nearest_upsampling():
    r = 4
    frame = jax.random.uniform(jax.random.key(6), (2, 3, 5))
    filters = jnp.zeros((2, 3, 5, 25, r * r)).at[..., 12, :].set(1.0)  # centre tap for every sub-pixel
    hr = depth_to_space(dynamic_upsample(frame, filters), r)[..., 0]
    np.testing.assert_array_equal(hr, jnp.repeat(jnp.repeat(frame, r, axis=1), r, axis=2))


@pytest.mark.parametrize("padding", ["edge", "zero"])
def test_uniform_filter_is_box_average(padding):
    r = 2
    frame = jax.random.uniform(jax.random.key(7), (1, 6, 7))
    filters = jnp.full((1, 6, 7, 25, r * r), 1 / 25)
    sub = dynamic_upsample(frame, filters, padding=padding)
    padded = np.pad(np.asarray(frame[0], np.float64), 2, mode="edge" if padding == "edge" else "constant")
    box = np.array([[padded[y : y + 5, x : x + 5].mean() for x in range(7)] for y in range(6)])
    for s in range(r * r):
        np.testing.assert_allclose(sub[0, :, :, s], box, rtol=1e-5, atol=1e-6)


def test_offset_filter_shifts_frame():
    """A one-hot filter on tap k = 5i + j reads the pixel at offset (i-2, j-2)."""
    frame = jnp.arange(20.0).reshape(1, 4, 5)
    filters = jnp.zeros((1, 4, 5, 25, 1)).at[..., 5 * 3 + 0, :].set(1.0)  # offset (+1, -2)
    out = dynamic_upsample(frame, filters)[0, :, :, 0]
    assert out[1, 3] == frame[0, 2, 1]
    assert out[3, 0] == frame[0, 3, 0]  # both offsets clamped at the border (edge replication)


def test_depth_to_space_subpixel_convention():
    r = 3
    h, w = 2, 4
    # channel s of LR pixel (y, x) holds a code of (y, x, s)
    y, x, s = np.meshgrid(np.arange(h), np.arange(w), np.arange(r * r), indexing="ij")
    code = 1000 * y + 100 * x + s
    out = np.asarray(depth_to_space(jnp.asarray(code, jnp.float32)[None], r))[0, ..., 0]
    assert out.shape == (h * r, w * r)
    for yy in range(h):
        for xx in range(w):
            for dy in range(r):
                for dx in range(r):
                    assert out[r * yy + dy, r * xx + dx] == 1000 * yy + 100 * xx + dy * r + dx
    with pytest.raises(ValueError, match="divisible"):
        depth_to_space(jnp.zeros((1, 2, 2, 5)), 2)


def products(f, *args):
    """(primitive, operand dtypes, precision) of every convolution and matrix product in f's jaxpr, nested jaxprs
    (custom gradients, jit) included."""
    found = []

    def walk(jaxpr):
        for e in jaxpr.eqns:
            if e.primitive.name in ("conv_general_dilated", "dot_general"):
                found.append((e.primitive.name, tuple(str(v.aval.dtype) for v in e.invars[:2]),
                              str(e.params.get("precision"))))
            for v in e.params.values():
                for sub in v if isinstance(v, (list, tuple)) else [v]:
                    inner = getattr(sub, "jaxpr", sub)
                    if hasattr(inner, "eqns"):
                        walk(inner)

    walk(jax.make_jaxpr(f)(*args).jaxpr)
    return found


@pytest.mark.slow  # 3.4 s a case; bfloat16 is emulated on most CPUs
@pytest.mark.parametrize("impl", ["native", "taps", "stacked", "stacked-taps-grad"])
def test_conv3d_precisions(impl):
    """Each precision reaches every product of the forward pass and of both gradients (read from the jaxpr, so
    the test holds on a CPU, where float32 and the default compute alike): float32 asks for HIGHEST, bfloat16
    multiplies bfloat16 operands. Results: float32 as close to the loop as float32 gets, bfloat16 in bfloat16's
    band, float32 outputs and gradients; an unknown precision refused."""
    kx, kw = jax.random.split(jax.random.key(4))
    x = jax.random.normal(kx, (2, 4, 6, 5, 8))
    w = jax.random.normal(kw, (3, 3, 3, 8, 4))
    pads = PADS[0]

    def loss(w, x, precision):
        return jnp.sum(conv3d(x, w, padding=pads, impl=impl, precision=precision) ** 2)

    for precision, want in (("float32", (("float32", "float32"), "(Precision.HIGHEST, Precision.HIGHEST)")),
                            ("bfloat16", (("bfloat16", "bfloat16"), "None"))):
        found = products(jax.grad(lambda w, x: loss(w, x, precision), argnums=(0, 1)), w, x)
        assert len(found) >= 3 and {(dtypes, prec) for _, dtypes, prec in found} == {want}, found
    ref = _conv3d_loop(x, w, pads)
    rel = lambda y: float(np.linalg.norm(np.asarray(y, np.float64) - ref) / np.linalg.norm(ref))  # noqa: E731
    y32 = conv3d(x, w, padding=pads, impl=impl, precision="float32")
    ybf = conv3d(x, w, padding=pads, impl=impl, precision="bfloat16")
    assert y32.dtype == ybf.dtype == jnp.float32
    assert rel(y32) < 1e-6
    assert 1e-4 < rel(ybf) < 1e-2  # rounded operands: visibly not float32, but no worse than bfloat16's band
    g = jax.grad(lambda w: loss(w, x, "bfloat16"))(w)
    g_ref = jax.grad(lambda w: loss(w, x, "default"))(w)
    assert g.dtype == jnp.float32
    assert float(jnp.linalg.norm(g - g_ref) / jnp.linalg.norm(g_ref)) < 2e-2
    with pytest.raises(ValueError, match="precision"):
        conv3d(x, w, precision="tf16")


def test_a_dilated_conv2d_is_the_kernel_spread_with_zeros():
    rng = np.random.default_rng(0)
    x = jnp.asarray(rng.normal(size=(2, 9, 11, 3)), jnp.float32)
    w = rng.normal(size=(3, 3, 3, 4)).astype(np.float32)
    spread = np.zeros((5, 5, 3, 4), np.float32)
    spread[::2, ::2] = w  # taps two pixels apart
    b = jnp.arange(4.0)
    dilated = conv2d({"w": jnp.asarray(w), "b": b}, x, dilation=2)
    assert dilated.shape == (2, 9, 11, 4)  # "same" by default
    np.testing.assert_allclose(dilated, conv2d({"w": jnp.asarray(spread), "b": b}, x), rtol=1e-5, atol=1e-5)
