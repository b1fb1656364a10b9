"""Layers of the dynamic-upsampling-filter network, as pure functions of arrays.

Layout: activations are (B, T, H, W, C) (channels last); convolution weights are (kt, kh, kw, cin, cout).
Convolution kernels are drawn by `jaxsr.nn.duf.init_model` (Glorot uniform, bound `glorot_limit`, in one flat
draw); batch norm has `init_batch_norm` and explicit running statistics (`state`) with a `train` flag.
Nothing here is jitted: jit the function that calls them.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp

from ..config import PRECISIONS

__all__ = [
    "CONV3D_IMPLS",
    "batch_norm",
    "conv2d",
    "conv2d_transpose",
    "conv3d",
    "conv3d_native",
    "conv3d_stacked",
    "conv3d_stacked_taps_grad",
    "conv3d_taps",
    "default_conv3d_impl",
    "depth_to_space",
    "dynamic_upsample",
    "glorot_limit",
    "init_batch_norm",
    "init_conv2d",
    "init_from_normals",
    "max_pool2",
    "neighbourhoods",
    "prelu",
    "stacked_use",
]


def glorot_limit(kernel: tuple[int, int, int], cin: int, cout: int) -> float:
    """Glorot-uniform bound sqrt(6 / (fan_in + fan_out)), fans counted over the receptive field (Keras)."""
    receptive = math.prod(kernel)
    return math.sqrt(6.0 / (receptive * (cin + cout)))


def _pads(padding, kernel) -> tuple[tuple[int, int], ...]:
    """Normalise `padding` ("same", "valid" or three (lo, hi) pairs) to three (lo, hi) pairs for (T, H, W)."""
    if padding == "same":
        return tuple(((k - 1) // 2, k - 1 - (k - 1) // 2) for k in kernel)
    if padding == "valid":
        return ((0, 0),) * 3
    pads = tuple(tuple(int(v) for v in p) for p in padding)
    if len(pads) != 3 or any(len(p) != 2 for p in pads):
        raise ValueError(f"conv3d: padding must be 'same', 'valid' or three (lo, hi) pairs, got {padding!r}")
    return pads


def conv3d_native(x, w, b=None, *, padding="same", lax_precision=None):
    """3D convolution (cross-correlation, as in Keras) with one `lax.conv_general_dilated` call.

    x: (B, T, H, W, Cin); w: (kt, kh, kw, Cin, Cout); b: (Cout,) or None; zero padding per `padding`
    ("same", "valid", or ((t_lo, t_hi), (h_lo, h_hi), (w_lo, w_hi))). Returns (B, T', H', W', Cout).
    lax_precision: the products' `jax.lax.Precision` (None: the backend's default), here and in the other impls.
    """
    pads = _pads(padding, w.shape[:3])
    y = jax.lax.conv_general_dilated(
        x, w, window_strides=(1, 1, 1), padding=pads, dimension_numbers=("NDHWC", "DHWIO", "NDHWC"),
        precision=lax_precision,
    )
    return y if b is None else y + b


def _conv2d(x, w, pads, lax_precision=None):
    """2D convolution of (N, H, W, Cin) by (kh, kw, Cin, Cout) with ((h_lo, h_hi), (w_lo, w_hi)) zero padding."""
    return jax.lax.conv_general_dilated(
        x, w, window_strides=(1, 1), padding=pads, dimension_numbers=("NHWC", "HWIO", "NHWC"),
        precision=lax_precision,
    )


def _widened(y):
    """y at least float32: partial sums of bfloat16 products (`conv3d(precision="bfloat16")`) add in float32."""
    return y.astype(jnp.promote_types(y.dtype, jnp.float32))


def _t_out(t_in, t_lo, t_hi, kt):
    t_out = t_in + t_lo + t_hi - kt + 1
    if t_out < 1:
        raise ValueError(f"conv3d: {t_in} frames (padded by {t_lo}, {t_hi}) are fewer than the temporal kernel {kt}")
    return t_out


def _tap_frames(k, t_lo, t_in, t_out) -> tuple[int, int]:
    """Output frames t0 .. t1 - 1 whose tap k reads a real input frame (t + k - t_lo), not the zero padding."""
    o = k - t_lo
    return max(0, -o), min(t_out, t_in - o)


def stacked_use(t_in: int, padding, kt: int = 3) -> float:
    """The share of the frame x tap products of `conv3d_stacked` that reach an output frame (1 = no waste).

    t_in input frames, temporal `padding` as in `conv3d` (its spatial part is ignored), kt temporal taps.
    E.g. "same" on 9 frames 25/27, temporally valid 9 -> 7 frames 21/27, 3 -> 1 frame 3/9.
    """
    (t_lo, t_hi), _, _ = _pads(padding, (kt, 1, 1))
    t_out = _t_out(t_in, t_lo, t_hi, kt)
    used = sum(max(0, t1 - t0) for t0, t1 in (_tap_frames(k, t_lo, t_in, t_out) for k in range(kt)))
    return used / (t_in * kt)


def conv3d_taps(x, w, b=None, *, padding="same", lax_precision=None):
    """The same 3D convolution as `conv3d_native`, as a sum over the kt temporal taps of 2D convolutions.

    Tap k convolves the frames t + k (after temporal padding) with w[k]; the batch and output-time axes are
    folded into one 2D batch. Same arguments and result as `conv3d_native`; on XLA:CPU it is faster.
    """
    (t_lo, t_hi), hpad, wpad = _pads(padding, w.shape[:3])
    kt = w.shape[0]
    bsz, t_in, h, wd, cin = x.shape
    t_out = _t_out(t_in, t_lo, t_hi, kt)
    y = None
    for k in range(kt):
        # Output frame t reads input frame t + k - t_lo; frames in the zero padding contribute nothing, so
        # they are skipped rather than convolved (with T = 1 and padding 1 that saves 2 of 3 taps).
        t0, t1 = _tap_frames(k, t_lo, t_in, t_out)
        if t1 <= t0:
            continue
        xs = x[:, t0 + k - t_lo : t1 + k - t_lo].reshape(bsz * (t1 - t0), h, wd, cin)
        yk = _widened(_conv2d(xs, w[k], (hpad, wpad), lax_precision))
        yk = yk.reshape(bsz, t1 - t0, *yk.shape[1:])
        if (t0, t1) != (0, t_out):
            yk = jnp.pad(yk, ((0, 0), (t0, t_out - t1), (0, 0), (0, 0), (0, 0)))
        y = yk if y is None else y + yk
    if y is None:  # every tap fell in the padding
        h_out = h + sum(hpad) - w.shape[1] + 1
        w_out = wd + sum(wpad) - w.shape[2] + 1
        y = jnp.zeros((bsz, t_out, h_out, w_out, w.shape[-1]), jnp.promote_types(jnp.result_type(x, w), jnp.float32))
    return y if b is None else y + b


def conv3d_stacked(x, w, b=None, *, padding="same", lax_precision=None):
    """The same 3D convolution as `conv3d_native`, as one 2D convolution with the temporal taps side by side.

    The kt taps' kernels are stacked along the output channels ((kh, kw, Cin, kt * Cout)) and applied to every
    input frame at once; tap k's channels, shifted by k frames, are then summed. Same arguments and result as
    `conv3d_native`. It computes every tap on every input frame, `stacked_use` of which reach an output, but
    XLA:CPU's convolutions run wider outputs at a higher rate: with Cout = 32 (the network's 3x3x3 layers) the
    stacked form was faster where 70 % or more of its products are used, and the TR4 network 1.1-1.3x faster
    with it there (`conv3d(impl="auto")`; benchmarks/bench_inference.py::test_network_tr4_one_window).
    """
    (t_lo, t_hi), hpad, wpad = _pads(padding, w.shape[:3])
    kt, kh, kw, cin, cout = w.shape
    bsz, t_in, h, wd, _ = x.shape
    t_out = _t_out(t_in, t_lo, t_hi, kt)
    z = _widened(_conv2d(x.reshape(bsz * t_in, h, wd, cin), jnp.moveaxis(w, 0, 3).reshape(kh, kw, cin, kt * cout),
                         (hpad, wpad), lax_precision))
    z = z.reshape(bsz, t_in, *z.shape[1:3], kt, cout)
    # output frame t takes tap k from (padded) input frame t + k
    z = jnp.pad(z, ((0, 0), (t_lo, t_hi), (0, 0), (0, 0), (0, 0), (0, 0)))
    y = sum(z[:, k : k + t_out, :, :, k] for k in range(kt))
    return y if b is None else y + b


def conv3d_stacked_taps_grad(x, w, b=None, *, padding="same", lax_precision=None):
    """The same 3D convolution, `conv3d_stacked` forward and `conv3d_taps`' gradients (for training).

    The stacked form's forward is the faster one where most of its products are used, but its gradients
    (a 3 Cout-channel input gradient over every input frame and a weight gradient of 3 Cout channels) cost
    more than the taps' in XLA:CPU: on TR4's layers the taps' forward + backward ran 1.15-1.4x faster.
    Same arguments and result as `conv3d_native`; gradients equal to float rounding.
    """
    y = _stacked_taps_grad(x, w, _pads(padding, w.shape[:3]), lax_precision)
    return y if b is None else y + b


@functools.partial(jax.custom_vjp, nondiff_argnums=(2, 3))
def _stacked_taps_grad(x, w, pads, lax_precision):
    return conv3d_stacked(x, w, padding=pads, lax_precision=lax_precision)


def _stacked_taps_grad_fwd(x, w, pads, lax_precision):
    return conv3d_stacked(x, w, padding=pads, lax_precision=lax_precision), (x, w)


def _stacked_taps_grad_bwd(pads, lax_precision, residuals, g):
    # the taps' primal output is not used, so XLA drops its forward convolutions
    _, vjp = jax.vjp(lambda x, w: conv3d_taps(x, w, padding=pads, lax_precision=lax_precision), *residuals)
    return vjp(g)


_stacked_taps_grad.defvjp(_stacked_taps_grad_fwd, _stacked_taps_grad_bwd)


# The ways `conv3d` can run a convolution; all give the same result (to float rounding).
CONV3D_IMPLS = ("auto", "native", "taps", "stacked", "stacked-taps-grad")


# `conv3d(impl="auto")` on CPU stacks the temporal taps of a layer when at least this share of the stacked
# products is used (`stacked_use`); below it the taps are convolved one by one.
STACKED_MIN_USE = 0.7

# How the layers that `conv3d(impl="auto")` stacks take their gradients: "taps" (`conv3d_stacked_taps_grad`,
# the default: faster in training on XLA:CPU, experiments/results/train_speed.md) or "stacked" (the stacked
# form's own, as before 2026-11-23). Read when a function is traced; the forward pass is the same either way.
STACKED_GRADIENT = "taps"


def default_conv3d_impl(backend: str | None = None) -> str:
    """The faster conv3d implementation family on `backend` (default: `jax.default_backend()`).

    "taps" on CPU (measured about 3x faster than the native 3D convolution on XLA:CPU, see
    benchmarks/bench_train.py; `conv3d(impl="auto")` then stacks the taps of layers where that pays, see
    `STACKED_MIN_USE`), "native" elsewhere (cuDNN has 3D convolutions).
    """
    backend = backend or jax.default_backend()
    return "taps" if backend == "cpu" else "native"


def conv3d(x, w, b=None, *, padding="same", impl: str = "auto", precision: str = "default"):
    """3D convolution of (B, T, H, W, Cin) by (kt, kh, kw, Cin, Cout) weights, plus bias.

    `impl`: "native", "taps", "stacked", "stacked-taps-grad" or "auto"; all give the same result. "auto" is
    "native" off CPU and, on CPU, the stacked forward where `stacked_use` >= `STACKED_MIN_USE` (with the taps'
    gradients, "stacked-taps-grad", unless `STACKED_GRADIENT` says "stacked"), else "taps". A 1x1x1 kernel is a
    matrix product whatever `impl` says. See `conv3d_native` for `padding`. `precision`: how the products are
    taken, one of `PRECISIONS` ("bfloat16": x and w rounded to bfloat16 here, so that the gradients' products
    take bfloat16 operands too; each convolution's output rounded to bfloat16, the taps' partial sums and the
    result float32); the result is at least float32 in every case.
    """
    if x.ndim != 5 or w.ndim != 5 or x.shape[-1] != w.shape[3]:
        raise ValueError(
            f"conv3d: expected x (B, T, H, W, Cin) and w (kt, kh, kw, Cin, Cout), got {x.shape} and {w.shape}"
        )
    if precision not in PRECISIONS:
        raise ValueError(f"conv3d: precision must be one of {', '.join(map(repr, PRECISIONS))}, got {precision!r}")
    lax_precision = lax_precision_of(precision)
    if precision == "bfloat16":
        x, w = x.astype(jnp.bfloat16), w.astype(jnp.bfloat16)
    y = _widened(_conv3d_by(impl, x, w, padding, lax_precision))
    return y if b is None else y + b


def lax_precision_of(precision: str):
    """The `jax.lax.Precision` of products at `precision` (one of `PRECISIONS`): HIGHEST for "float32", else None
    (the backend's default; bfloat16 is set by the operands' dtype)."""
    return jax.lax.Precision.HIGHEST if precision == "float32" else None


def _conv3d_by(impl: str, x, w, padding, lax_precision):
    """`conv3d` without bias, by `impl` ("auto" chosen here)."""
    if w.shape[:3] == (1, 1, 1) and padding in ("same", "valid"):
        return jnp.matmul(x, w[0, 0, 0], precision=lax_precision)
    if impl == "auto":
        impl = default_conv3d_impl()
        if impl == "taps" and stacked_use(x.shape[1], padding, w.shape[0]) >= STACKED_MIN_USE:
            impl = "stacked-taps-grad" if STACKED_GRADIENT == "taps" else "stacked"
    if impl == "native":
        return conv3d_native(x, w, padding=padding, lax_precision=lax_precision)
    if impl == "taps":
        return conv3d_taps(x, w, padding=padding, lax_precision=lax_precision)
    if impl == "stacked":
        return conv3d_stacked(x, w, padding=padding, lax_precision=lax_precision)
    if impl == "stacked-taps-grad":
        return conv3d_stacked_taps_grad(x, w, padding=padding, lax_precision=lax_precision)
    raise ValueError(f"conv3d: impl must be one of {', '.join(map(repr, CONV3D_IMPLS))}, got {impl!r}")


def init_batch_norm(channels: int, *, dtype=jnp.float32) -> tuple[dict, dict]:
    """Batch-norm parameters {"scale": ones, "shift": zeros} and state {"mean": zeros, "var": ones}, (C,)."""
    params = {"scale": jnp.ones((channels,), dtype), "shift": jnp.zeros((channels,), dtype)}
    state = {"mean": jnp.zeros((channels,), dtype), "var": jnp.ones((channels,), dtype)}
    return params, state


def batch_norm(params, state, x, *, train: bool, momentum: float = 0.99, eps: float = 1e-3):
    """Batch normalisation over every axis but the last (channels), with Keras's conventions.

    x: (..., C). With `train=True` the batch's own mean and biased variance normalise x and the running
    statistics move towards them: new = momentum * old + (1 - momentum) * batch. With `train=False` the
    running statistics normalise x and the state is returned unchanged.
    y = scale * (x - mean) / sqrt(var + eps) + shift. Returns (y, new_state).
    """
    if train:
        axes = tuple(range(x.ndim - 1))
        mean = jnp.mean(x, axis=axes)
        var = jnp.mean(jnp.square(x - mean), axis=axes)
        new_state = {
            "mean": momentum * state["mean"] + (1 - momentum) * jax.lax.stop_gradient(mean),
            "var": momentum * state["var"] + (1 - momentum) * jax.lax.stop_gradient(var),
        }
    else:
        mean, var, new_state = state["mean"], state["var"], state
    inv = params["scale"] * jax.lax.rsqrt(var + eps)
    return (x - mean) * inv + params["shift"], new_state


def neighbourhoods(frame, *, size: int = 5, padding: str = "edge"):
    """The size x size neighbourhood of every pixel: (B, H, W) -> `(B, H, W, size*size)`.

    Tap `k = size*i + j` holds the pixel at offset (i - size//2, j - size//2). Outside the frame the values
    are completed by `padding`: "edge" replicates the border (default; zero would mean "depth 0", the
    nearest possible return) or "zero" (DUF's convention).
    """
    if frame.ndim != 3:
        raise ValueError(f"neighbourhoods: expected a (B, H, W) frame, got shape {frame.shape}")
    if padding not in ("edge", "zero"):
        raise ValueError(f"neighbourhoods: padding must be 'edge' or 'zero', got {padding!r}")
    c = size // 2
    _, h, w = frame.shape
    padded = jnp.pad(frame, ((0, 0), (c, c), (c, c)), mode="edge" if padding == "edge" else "constant")
    taps = [padded[:, i : i + h, j : j + w] for i in range(size) for j in range(size)]
    return jnp.stack(taps, axis=-1)


def dynamic_upsample(frame, filters, *, padding: str = "edge", lax_precision=None):
    """Apply per-pixel dynamic filters to a frame's neighbourhoods (before depth_to_space).

    frame: (B, H, W) the centre LR input frame; filters: `(B, H, W, size*size, r*r)`, tap `k = size*i + j` at
    offset (i - size//2, j - size//2) (see `neighbourhoods`), one filter per sub-pixel `s = dy*r + dx`.
    Returns `(B, H, W, r*r)`: sub-pixel s of LR pixel (y, x) = sum_k filters[..., k, s] * neighbourhood[..., k].
    lax_precision: that sum's `jax.lax.Precision` (None: the backend's default, TF32 on NVIDIA GPUs).
    """
    taps = filters.shape[-2]
    size = math.isqrt(taps)
    if size * size != taps or filters.shape[:3] != frame.shape:
        raise ValueError(
            f"dynamic_upsample: filters {filters.shape} must be (B, H, W, size*size, r*r) over frame {frame.shape}"
        )
    patches = neighbourhoods(frame, size=size, padding=padding)
    return jnp.einsum("bhwk,bhwks->bhws", patches, filters, precision=lax_precision)


def depth_to_space(x, scale: int):
    """Pixel shuffle: `(..., H, W, r*r*C)` -> `(..., H*r, W*r, C)`.

    Channel `(dy*r + dx)*C + c` of LR pixel (y, x) goes to HR pixel `(r*y + dy, r*x + dx)`, channel c (the
    convention of `tf.nn.depth_to_space` and dm-pix).
    """
    *lead, h, w, ch = x.shape
    r = scale
    if ch % (r * r):
        raise ValueError(f"depth_to_space: channels {ch} not divisible by scale^2 = {r * r}")
    c = ch // (r * r)
    x = x.reshape(*lead, h, w, r, r, c)
    n = len(lead)
    perm = (*range(n), n, n + 2, n + 1, n + 3, n + 4)  # (..., h, dy, w, dx, c)
    return x.transpose(perm).reshape(*lead, h * r, w * r, c)


# --- 2D layers of the learned baselines (HistNet, RBPN / iSeeBetter): (B, H, W, C) activations, (kh, kw, cin, cout)
# kernels, the conventions of `torch.nn.Conv2d` / `tf.nn.conv2d` in the NHWC layout.


def init_from_normals(key, build):
    """Initial parameters from one flat standard-normal draw: `build(normal)` returns the params pytree, calling
    `normal(shape)` for each random array. `build` is traced twice (to learn the shapes, then to slice the draw),
    so XLA compiles one random kernel instead of one per shape (dozens of threefry kernels took ~30 s).
    Returns build's pytree."""
    shapes = []

    def record(shape):
        shapes.append(tuple(shape))
        return jnp.zeros(shape, jnp.float32)

    jax.eval_shape(lambda: build(record))
    sizes = [math.prod(s) for s in shapes]
    flat = jax.random.normal(key, (sum(sizes),), jnp.float32)
    starts = iter(zip(shapes, [sum(sizes[:i]) for i in range(len(sizes))]))

    def take(shape):
        want, start = next(starts)
        assert tuple(shape) == want, "build must ask for the same shapes in the same order"
        return flat[start : start + math.prod(want)].reshape(want)

    return build(take)


def init_conv2d(normal, kernel: int, cin: int, cout: int) -> dict:
    """He-normal (Kaiming, fan-in) kernel and zero bias: {"w": (k, k, cin, cout), "b": (cout,)}.

    normal: shape -> standard normals (see `init_from_normals`). The init RBPN's published code uses
    (`torch.nn.init.kaiming_normal_`). Returns the dict.
    """
    std = math.sqrt(2.0 / (kernel * kernel * cin))
    return {"w": std * normal((kernel, kernel, cin, cout)), "b": jnp.zeros((cout,), jnp.float32)}


def conv2d(params, x, *, stride: int = 1, padding: int | None = None, dilation: int = 1):
    """2D convolution (cross-correlation) of x (B, H, W, Cin) by params {"w": (k, k, Cin, Cout), "b": (Cout,)}.

    The kernel's taps `dilation` pixels apart (a field of d (k - 1) + 1 pixels); zero padding of `padding` pixels
    on every side (default d (k - 1) // 2, "same" for odd k at stride 1).
    Returns (B, (H + 2p - d (k - 1) - 1) // stride + 1, (W + 2p - d (k - 1) - 1) // stride + 1, Cout).
    """
    k = params["w"].shape[0]
    p = dilation * (k - 1) // 2 if padding is None else padding
    y = jax.lax.conv_general_dilated(x, params["w"], (stride, stride), ((p, p), (p, p)),
                                     rhs_dilation=(dilation, dilation), dimension_numbers=("NHWC", "HWIO", "NHWC"))
    return y + params["b"]


def conv2d_transpose(params, x, *, stride: int, padding: tuple[int, int]):
    """Transposed ("de-") convolution: x (B, H, W, Cin) dilated by `stride`, then convolved with
    params {"w": (k, k, Cin, Cout), "b": (Cout,)}; `padding` (lo, hi) is `torch`'s / TF's padding p seen from
    the output: the dilated input is padded by k - 1 - p_lo before and k - 1 - p_hi after.

    torch `ConvTranspose2d(k, s, p)` is padding (p, p) (output s (H - 1) - 2p + k); TF's 'SAME' 3x3 stride 2
    is (0, 1) (output 2H). The kernel is not flipped: it is learned, so that is only a re-parametrisation.
    Returns (B, H', W', Cout).
    """
    k = params["w"].shape[0]
    lo, hi = padding
    pads = ((k - 1 - lo, k - 1 - hi),) * 2
    y = jax.lax.conv_general_dilated(x, params["w"], (1, 1), pads, lhs_dilation=(stride, stride),
                                     dimension_numbers=("NHWC", "HWIO", "NHWC"))
    return y + params["b"]


def prelu(a, x):
    """PReLU with one learned slope `a` (a scalar, torch's default `num_parameters=1`): max(x, 0) + a min(x, 0).
    x: (...) any shape; returns the same shape."""
    return jnp.where(x >= 0, x, a * x)


def max_pool2(x):
    """2x2 max pooling with stride 2: (B, H, W, C) -> (B, H // 2, W // 2, C) (H, W even)."""
    b, h, w, c = x.shape
    return x.reshape(b, h // 2, 2, w // 2, 2, c).max(axis=(2, 4))
