"""The depth of a surface that sends back no photon: quiet regions that returns enclose, filled from around them.

A black screen or a dark piece of furniture in a lit room sends back no photon at any light level; the no-return
decision keeps it a return where returns enclose it (`jaxsr.sensor.without_holes`), and its depth is then a guess.
The network's guess drifts with the distance from the hole's edge (its receptive field ends); the surfaces around
the hole say more. A plane's inverse depth is affine in the image, and an affine function is harmonic, so the hole
is filled with the harmonic interpolation of the inverse depth around it: a hole in a wall, a floor or a tilted
table is filled with that plane (exactly for depth along the optical axis; the library's radial depth departs
from it by about 3 mm over an 8 x 8 LR hole at the sensor's 30 degree field of view), and a hole between two
surfaces blends them smoothly. Which holes are black, and so filled, `jaxsr.sensor.black_holes` says from their
photons; the others (a far surface behind a nearer frame) keep the network's depth (docs/network.md, "The holes").
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np

from ..spad import DepthScale

__all__ = ["fill_holes", "filled_where_holes", "HOLE_FILL_ITERATIONS"]

# conjugate gradient steps per frame: CG's error on the Laplacian falls with the hole's narrowest width (an 8 x 8 LR
# hole of `jaxsr.sensor.HOLE_PIXELS` is 32 HR pixels across, a line of them 4 wide); 256 and 4000 steps give the
# same fill on 8 x 8, 1 x 62 and 3 x 21 LR holes
HOLE_FILL_ITERATIONS = 256
# the nearest distance (in the depth scale's spans, 0.35 m of 35 m) whose inverse the fill takes: the network's 0
# may be the gate's start at 0 m, and one pixel around a hole at or below 0 would otherwise pull the whole fill to it
_NEAREST = 1e-2


def _neighbour_sum(x):
    """Sum of each pixel's 4 neighbours in the frame (..., H, W), zero beyond it."""
    p = jnp.pad(x, [(0, 0)] * (x.ndim - 2) + [(1, 1), (1, 1)])
    return p[..., :-2, 1:-1] + p[..., 2:, 1:-1] + p[..., 1:-1, :-2] + p[..., 1:-1, 2:]


@functools.partial(jax.jit, static_argnames=("iterations",))
def _harmonic(values, hole, *, iterations: int):
    """`values` (H, W) with the pixels where `hole` (H, W) bool replaced by the harmonic function that equals
    `values` on the pixels around them (the discrete Laplace equation over 4-neighbours, nothing flowing across the
    frame's border), solved by conjugate gradients from `values`."""
    hole = hole & jnp.any(~hole)  # a frame that is all hole has no surface to take from (and no solution)
    inside = hole.astype(values.dtype)
    degree = _neighbour_sum(jnp.ones_like(values))  # 4 inside the frame, fewer at its border

    def laplacian(x):  # restricted to the hole: (degree x - the neighbours in the hole) at hole pixels
        return inside * (degree * x - _neighbour_sum(inside * x))

    b = inside * _neighbour_sum((1.0 - inside) * values)
    x, _ = jax.scipy.sparse.linalg.cg(laplacian, b, x0=inside * values, tol=1e-6, maxiter=iterations)
    return jnp.where(hole, x, values)


def fill_holes(hr, holes, scale: DepthScale = DepthScale(), *, iterations: int = HOLE_FILL_ITERATIONS):
    """HR normalised depth (..., H, W) with the HR pixels of each LR pixel in `holes` (..., h, w) bool, H = r h and
    W = r w (the default decision passes the black holes, `jaxsr.sensor.black_holes`: quiet regions that returns
    enclose, or lone quiet pixels, that reflect less of the ambient light than the surfaces around them), replaced
    by the harmonic interpolation of the inverse depth around them (`scale`'s metres: a
    plane is filled with that plane). Elsewhere `hr` unchanged, exactly. jit-able and differentiable in `hr`
    (`iterations` static; `scale` a concrete `DepthScale`); frames without a hole are returned as they are."""
    hr = jnp.asarray(hr, jnp.float32)
    holes = jnp.asarray(holes, bool)
    if hr.ndim < 2 or holes.shape[:-2] != hr.shape[:-2] or holes.ndim != hr.ndim:
        raise ValueError(f"fill_holes: hr (..., H, W) and holes (..., h, w) must have the same leading shape, got "
                         f"{hr.shape} and {holes.shape}")
    (h, w), (big_h, big_w) = holes.shape[-2:], hr.shape[-2:]
    r = big_w // w if w else 0
    if r < 1 or (big_h, big_w) != (h * r, w * r):
        raise ValueError(f"fill_holes: hr {hr.shape} must be holes {holes.shape} times an integer scale along "
                         "both axes")
    if not isinstance(scale, DepthScale):
        raise TypeError(f"fill_holes: scale is a jaxsr.DepthScale, got {type(scale).__name__}")
    near = jnp.float32(scale.offset / scale.span)  # metres / span: distance = (near + n) span
    at_hr = jnp.repeat(jnp.repeat(holes, r, axis=-2), r, axis=-1)
    inverse = 1.0 / jnp.maximum(near + jnp.clip(hr, 0.0, 1.0), _NEAREST)  # unclipped network output: to the span
    frames = inverse.reshape(-1, big_h, big_w)
    filled = jax.vmap(functools.partial(_harmonic, iterations=iterations))(frames, at_hr.reshape(frames.shape))
    farthest = jnp.maximum(near + 1.0, _NEAREST)  # no return: a hole is filled no further
    depth = 1.0 / jnp.maximum(filled.reshape(hr.shape), 1.0 / farthest) - near
    has_surface = jnp.any(~at_hr, axis=(-2, -1), keepdims=True)  # else left exactly as it is
    return jnp.where(at_hr & has_surface, depth, hr)


def filled_where_holes(hr, holes, scale: DepthScale) -> np.ndarray:
    """One HR frame (H, W) of normalised depth with `fill_holes` where its LR `holes` (h, w) hold any pixel, as it
    is otherwise (no solve for a frame without a hole), as NumPy: the last step of the photons' no-return decision
    in `super_resolve_histograms` and `jaxsr upscale`."""
    if not np.any(holes):
        return np.asarray(hr, np.float32)
    return np.asarray(fill_holes(hr, holes, scale))
