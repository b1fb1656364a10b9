"""Dense optical flow by pyramidal (coarse-to-fine) iterative Lucas-Kanade, in JAX.

iSeeBetter (Chadha et al. 2020) and RBPN (Haris et al. 2019) feed the generator the optical flow between the
centre frame and each neighbour, computed by a classical estimator (pyflow, Liu's coarse-to-fine variational
method). This is a classical estimator written in JAX instead (no extra dependency, jit/vmap-able): the
Lucas-Kanade least-squares flow (Lucas & Kanade 1981) in a Gaussian window around every pixel, refined by
Gauss-Newton iterations on the warped neighbour and run coarse to fine over an image pyramid (Bouguet 2000) so
that shifts of several pixels are found. Our inputs are LR normalised depth frames (32 x 64), so the defaults are
small: 3 levels (8 x 16 at the top), a window of sigma 2 pixels.

Convention: flow[..., 0] = u (along x, columns), flow[..., 1] = v (along y, rows), in pixels of the input, such
that neighbour(y + v, x + u) ~ centre(y, x) (the neighbour pixel the centre pixel moved to). Samples outside the
frame repeat its edge. The flow is not differentiated through (RBPN computes it as a preprocessing step).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["optical_flow", "warp"]

# the binomial 5-tap approximation of a Gaussian (Burt & Adelson's pyramid kernel); NumPy, so that importing
# jaxsr starts no JAX backend (`use_cpu_cores` must come first)
_BINOMIAL = np.array([1.0, 4.0, 6.0, 4.0, 1.0], np.float32) / 16.0


def _separable(img, taps):
    """img (H, W) convolved with the 1D `taps` along both axes, edges replicated (two 1D convolutions: a small
    graph to compile)."""
    r = taps.shape[0] // 2
    pad = jnp.pad(img, r, mode="edge")[None, None]
    k = taps.astype(img.dtype)
    out = jax.lax.conv_general_dilated(pad, k[None, None, :, None], (1, 1), "VALID")
    out = jax.lax.conv_general_dilated(out, k[None, None, None, :], (1, 1), "VALID")
    return out[0, 0]


def _gaussian_taps(sigma: float):
    r = max(1, round(2.5 * sigma))
    x = jnp.arange(-r, r + 1, dtype=jnp.float32)
    g = jnp.exp(-0.5 * (x / sigma) ** 2)
    return g / g.sum()


def _keys(t):
    """Keys' cubic convolution weights (a = -0.5) of the 4 taps at offsets -1, 0, 1, 2 from floor(x),
    t = x - floor(x)."""
    a = -0.5
    d = jnp.stack([1 + t, t, 1 - t, 2 - t])  # distances to the 4 taps
    near = (a + 2) * d**3 - (a + 3) * d**2 + 1
    far = a * d**3 - 5 * a * d**2 + 8 * a * d - 4 * a
    return jnp.where(d <= 1, near, far)


def warp(img, flow):
    """Bicubic (Keys, a = -0.5) sample of img (H, W) at (y + v, x + u), edges replicated: the neighbour brought
    onto the centre frame's grid (bicubic rather than bilinear: bilinear's position-dependent blur biases the
    flow by a few hundredths of a pixel). flow: (H, W, 2) as (u, v). Returns (H, W)."""
    h, w = img.shape
    yy, xx = jnp.meshgrid(jnp.arange(h, dtype=img.dtype), jnp.arange(w, dtype=img.dtype), indexing="ij")
    y = jnp.clip(yy + flow[..., 1], 0, h - 1)
    x = jnp.clip(xx + flow[..., 0], 0, w - 1)
    y0, x0 = jnp.floor(y), jnp.floor(x)
    wy, wx = _keys(y - y0), _keys(x - x0)  # (4, H, W)
    iy = jnp.clip(y0.astype(jnp.int32)[None] + jnp.arange(-1, 3)[:, None, None], 0, h - 1)
    ix = jnp.clip(x0.astype(jnp.int32)[None] + jnp.arange(-1, 3)[:, None, None], 0, w - 1)
    taps = img[iy[:, None], ix[None, :]]  # (4, 4, H, W)
    return jnp.einsum("ihw,jhw,ijhw->hw", wy, wx, taps)


def _inside(flow):
    """(H, W) mask of the pixels whose sample (y + v, x + u) lies within the frame."""
    h, w = flow.shape[:2]
    yy, xx = jnp.meshgrid(jnp.arange(h), jnp.arange(w), indexing="ij")
    y, x = yy + flow[..., 1], xx + flow[..., 0]
    return (y >= 0) & (y <= h - 1) & (x >= 0) & (x <= w - 1)


def _gradients(img):
    """Central differences (one-sided at the border): (d/dx, d/dy), each (H, W)."""
    return jnp.gradient(img, axis=1), jnp.gradient(img, axis=0)


def _lk_level(centre, neighbour, flow, taps, iterations: int, eps: float):
    """Gauss-Newton refinement of `flow` (H, W, 2) at one pyramid level."""
    gx_c, gy_c = _gradients(centre)

    def step(flow, _):
        warped = warp(neighbour, flow)
        gx_w, gy_w = _gradients(warped)
        # pixels whose match lies outside the neighbour frame carry no evidence (their edge-replicated samples
        # would push them further out for ever); they take their flow from the smoothing below
        inside = _inside(flow).astype(centre.dtype)
        # the mean of both frames' gradients (symmetric, second-order accurate in the remaining shift)
        ix, iy = 0.5 * inside * (gx_c + gx_w), 0.5 * inside * (gy_c + gy_w)
        it = inside * (warped - centre)
        s = functools.partial(_separable, taps=taps)
        axx, axy, ayy = s(ix * ix), s(ix * iy), s(iy * iy)
        # regulariser relative to the frame's gradient energy: textureless windows get (almost) no update
        reg = eps * jnp.mean(axx + ayy) + 1e-12
        axx, ayy = axx + reg, ayy + reg
        bx, by = -s(ix * it), -s(iy * it)
        det = axx * ayy - axy * axy
        # at most one pixel per step: the linearisation holds only within about a pixel
        du = jnp.clip((ayy * bx - axy * by) / det, -1.0, 1.0)
        dv = jnp.clip((axx * by - axy * bx) / det, -1.0, 1.0)
        # each pixel's residual was taken at its own flow, so a smooth flow keeps the window sums consistent
        du, dv = s(du), s(dv)
        return flow + jnp.stack([du, dv], axis=-1), None

    flow, _ = jax.lax.scan(step, flow, None, length=iterations)
    return flow


def _pyramid(img, levels: int):
    out = [img]
    for _ in range(levels - 1):
        out.append(_separable(out[-1], _BINOMIAL)[::2, ::2])
    return out[::-1]  # coarse first


@functools.partial(jax.jit, static_argnames=("levels", "iterations", "sigma"))
def optical_flow(centre, neighbour, *, levels: int = 3, iterations: int = 8, sigma: float = 2.0, eps: float = 1e-3):
    """Dense flow from `centre` to `neighbour` by pyramidal iterative Lucas-Kanade.

    Args:
      centre: (..., H, W) frame (leading axes are vmapped); H and W divisible by 2^(levels - 1).
      neighbour: (..., H, W) frame of the same shape as `centre`.
      levels: pyramid levels (1 = no pyramid); each halves the frame (binomial blur, then every other pixel).
      iterations: Gauss-Newton steps per level.
      sigma: standard deviation (pixels) of the Gaussian window of the least-squares fit.
      eps: Tikhonov regulariser of the 2x2 normal equations, relative to the mean gradient energy of the frame
        (textureless windows get no flow rather than NaN).
    Returns:
      (..., H, W, 2) flow (u, v) in pixels with neighbour(y + v, x + u) ~ centre(y, x).
    """
    centre = jnp.asarray(centre, jnp.float32)
    neighbour = jnp.asarray(neighbour, jnp.float32)
    if centre.shape != neighbour.shape or centre.ndim < 2:
        raise ValueError(f"optical_flow: expected two (..., H, W) frames of one shape, got {centre.shape} and "
                         f"{neighbour.shape}")
    h, w = centre.shape[-2:]
    if h % 2 ** (levels - 1) or w % 2 ** (levels - 1):
        raise ValueError(f"optical_flow: frame {(h, w)} must be divisible by 2^(levels - 1) = {2 ** (levels - 1)}")
    taps = _gaussian_taps(sigma)

    def single(c, n):
        flow = None
        for c_l, n_l in zip(_pyramid(c, levels), _pyramid(n, levels)):
            if flow is None:
                flow = jnp.zeros((*c_l.shape, 2), c_l.dtype)
            else:  # the coarser level's flow, at twice the resolution and in pixels of this level
                flow = 2.0 * jnp.repeat(jnp.repeat(flow, 2, axis=0), 2, axis=1)
            flow = _lk_level(c_l, n_l, flow, taps, iterations, eps)
        return flow

    fn = single
    for _ in range(centre.ndim - 2):
        fn = jax.vmap(fn)
    return jax.lax.stop_gradient(fn(centre, neighbour))
