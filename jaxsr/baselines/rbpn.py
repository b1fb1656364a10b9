"""iSeeBetter (Chadha, Britto & Roja 2020): the RBPN generator, the SRGAN discriminator and the GAN losses.

Followed (read from the papers and their public PyTorch code, then written anew here):
- Generator: RBPN, "Recurrent Back-Projection Network for Video Super-Resolution" (Haris, Shakhnarovich & Ukita,
  CVPR 2019), at iSeeBetter's settings (its `rbpn.py`, `iSeeBetterTrain.py`): base_filter 256, feat 64, 3
  back-projection stages, 5 residual blocks per module, 7 frames, x4 (8x8 kernels, stride 4, padding 2). Per
  neighbour frame j (in the order t-3 .. t-1, t+1 .. t+3): the single-image branch (DBPN-S: 1x1 conv 256 -> 64,
  up-down-up-down-up back-projection units, 1x1 conv 192 -> 64) of the running LR state, the multi-image branch
  (5 residual blocks, 8x8 stride-4 deconvolution 256 -> 64) of [centre, neighbour j, flow j], their difference
  refined by 5 residual blocks and a 3x3 conv, added back (H_j); a new LR state from H_j by 5 residual blocks and
  an 8x8 stride-4 conv 64 -> 256. Output: a 3x3 conv of the concatenated H_j. PReLU (one slope each) after every
  conv but the DBPN-S output and the final conv; a residual block's one PReLU is shared by its two uses.
- Inputs: RBPN's 3 colour channels become 1 (depth), so the first convolutions take 1 (centre) and 1 + 1 + 2
  (centre, neighbour, flow) channels instead of 3 and 8, and the output has 1 channel. No bicubic residual
  (RBPN's default `residual=False`).
- Flow: RBPN/iSeeBetter ran pyflow (Liu's coarse-to-fine variational flow) as preprocessing; here the classical
  pyramidal Lucas-Kanade of `jaxsr.baselines.flow.optical_flow`, computed inside `apply_rbpn` from the window
  (no gradient).
- Discriminator: SRGAN's (Ledig et al. 2017), as iSeeBetter's `SRGAN/model.py`: eight 3x3 convs 64, 64/2, 128,
  128/2, 256, 256/2, 512, 512/2 (/2 = stride 2), batch norm after all but the first, LeakyReLU 0.2, global
  average pooling, 1x1 convs 512 -> 1024 -> 1, sigmoid. Input 1 channel instead of 3. Batch norm with torch's
  conventions (momentum 0.1 i.e. 0.9 here, eps 1e-5). It returns logits; the losses apply the sigmoid.
- Losses (iSeeBetter paper, eq. of the generator loss): MSE + 1e-3 adversarial (-log D(G(x)), SRGAN's form) +
  2e-8 TV (its `TVLoss`: 2 (mean dy^2 + mean dx^2)); discriminator: binary cross-entropy of real vs generated.
  Left out: the perceptual loss (6e-3 MSE of VGG-16 features), whose ImageNet-pretrained weights cannot be
  downloaded here. (iSeeBetter's released trainer used L1 for the generator and 1 - D(x) + D(G(z)) for the
  discriminator; we follow the paper's losses.) `charbonnier=True` swaps MSE for the Charbonnier loss.

Where we chose: He-normal init (the published code's `kaiming_normal_`); the transposed convolution's kernel is
not flipped (a re-parametrisation of a learned kernel). Widths and depths are `RBPNConfig` fields; the defaults
are the published ones (`count_params`: 12.7 M generator for 1 channel, 12.8 M for RGB; Haris et al. report 12.2 M
for RBPN) and tests use reduced ones.
"""

from __future__ import annotations

import dataclasses
import functools
import numbers

import jax
import jax.numpy as jnp

from .flow import optical_flow
from ..config import MODEL_LIMITS, check_int_field
from ..nn.model import Architecture, register_architecture
from ..nn.layers import batch_norm, conv2d, conv2d_transpose, init_batch_norm, init_conv2d, init_from_normals, prelu

__all__ = [
    "RBPNConfig",
    "init_rbpn",
    "apply_rbpn",
    "rbpn_flows",
    "init_discriminator",
    "apply_discriminator",
    "generator_loss",
    "discriminator_loss",
    "tv_loss",
]

_PRELU0 = 0.25  # torch's initial PReLU slope
_BN = {"momentum": 0.9, "eps": 1e-5}  # torch BatchNorm2d defaults (momentum 0.1 of the new batch)


@dataclasses.dataclass(frozen=True)
class RBPNConfig:
    """RBPN / iSeeBetter sizes. Defaults: the published ones (iSeeBetter's RBPN: base_filter 256, feat 64, 3
    stages, 5 residual blocks, 7 frames, x4). `channels` 1 (depth; RBPN had 3). Flow: `flow_levels`,
    `flow_iterations` of `jaxsr.baselines.flow.optical_flow`. Discriminator widths: `disc_widths` (SRGAN: 64 .. 512) and
    `disc_hidden` (1024). Every field is an integer bounded by `jaxsr.config.MODEL_LIMITS` (ValueError otherwise)."""

    channels: int = 1
    base_filter: int = 256
    feat: int = 64
    n_resblock: int = 5
    frames: int = 7
    scale: int = 4
    flow_levels: int = 3
    flow_iterations: int = 8
    disc_widths: tuple[int, ...] = (64, 64, 128, 128, 256, 256, 512, 512)
    disc_hidden: int = 1024

    def __post_init__(self):
        # bounded like `ModelConfig` (`MODEL_LIMITS`): a config read from a file builds its template block by block,
        # and n_resblock = 10^6 or base_filter = 10^6 (a damaged or hostile checkpoint) would take minutes and
        # gigabytes before any shape is checked
        scale = self.scale
        if isinstance(scale, bool) or not isinstance(scale, numbers.Integral) or scale not in (2, 4, 8):
            raise ValueError(f"RBPNConfig: scale must be 2, 4 or 8 (RBPN's projection kernels), got {self.scale!r}")
        check_int_field("RBPNConfig", "frames", self.frames, 2, 2 * MODEL_LIMITS["tr"] + 1,
                        " (a centre and at least one neighbour)")
        width = MODEL_LIMITS["width"]
        for name in ("channels", "base_filter", "feat", "disc_hidden"):
            check_int_field("RBPNConfig", name, getattr(self, name), 1, width, " channels")
        check_int_field("RBPNConfig", "n_resblock", self.n_resblock, 0, MODEL_LIMITS["blocks"])
        check_int_field("RBPNConfig", "flow_levels", self.flow_levels, 1, MODEL_LIMITS["flow_levels"])
        check_int_field("RBPNConfig", "flow_iterations", self.flow_iterations, 0, MODEL_LIMITS["flow_iterations"])
        disc = self.disc_widths
        if (not isinstance(disc, (list, tuple)) or not 1 <= len(disc) <= MODEL_LIMITS["blocks"]
                or any(isinstance(c, bool) or not isinstance(c, numbers.Integral) or not 1 <= c <= width
                       for c in disc)):
            shown = repr(disc) if not isinstance(disc, (list, tuple)) or len(disc) <= 10 else f"{len(disc)} widths"
            raise ValueError(f"RBPNConfig: disc_widths must be 1..{MODEL_LIMITS['blocks']} integers 1..{width} "
                             f"(channels per discriminator conv), got {shown}")
        object.__setattr__(self, "disc_widths", tuple(disc))  # a list (from JSON) hashes as the tuple it means

    @property
    def projection(self) -> tuple[int, int, int]:
        """(kernel, stride, padding) of the up/down projections: x2 (6, 2, 2), x4 (8, 4, 2), x8 (12, 8, 2)."""
        return {2: (6, 2, 2), 4: (8, 4, 2), 8: (12, 8, 2)}[self.scale]


# --- building blocks: {"conv": {w, b}, "a": slope} -------------------------------------------------------------


def _conv_block(normal, k, cin, cout, act=True):
    p = {"conv": init_conv2d(normal, k, cin, cout)}
    if act:
        p["a"] = jnp.asarray(_PRELU0, jnp.float32)
    return p


def _apply_conv(p, x, *, stride=1, padding=None, transpose=False):
    if transpose:
        y = conv2d_transpose(p["conv"], x, stride=stride, padding=(padding, padding))
    else:
        y = conv2d(p["conv"], x, stride=stride, padding=padding)
    return prelu(p["a"], y) if "a" in p else y


def _resnet_block(normal, c):
    return {"conv1": init_conv2d(normal, 3, c, c), "conv2": init_conv2d(normal, 3, c, c), "a": jnp.asarray(_PRELU0)}


def _apply_resnet(p, x):
    """conv, PReLU, conv, + x, PReLU (RBPN's ResnetBlock, one shared slope, no norm)."""
    y = prelu(p["a"], conv2d(p["conv1"], x))
    return prelu(p["a"], conv2d(p["conv2"], y) + x)


def _projection_unit(normal, c, k):
    """Up (deconv, conv, deconv) or down (conv, deconv, conv) projection unit: three k x k layers c -> c."""
    return [_conv_block(normal, k, c, c) for _ in range(3)]


def _up(p, x, cfg):
    _, s, pad = cfg.projection
    h0 = _apply_conv(p[0], x, stride=s, padding=pad, transpose=True)
    l0 = _apply_conv(p[1], h0, stride=s, padding=pad)
    h1 = _apply_conv(p[2], l0 - x, stride=s, padding=pad, transpose=True)
    return h1 + h0


def _down(p, x, cfg):
    _, s, pad = cfg.projection
    l0 = _apply_conv(p[0], x, stride=s, padding=pad)
    h0 = _apply_conv(p[1], l0, stride=s, padding=pad, transpose=True)
    l1 = _apply_conv(p[2], h0 - x, stride=s, padding=pad)
    return l1 + l0


def init_rbpn(key, cfg: RBPNConfig = RBPNConfig()) -> dict:
    """Initial RBPN generator parameters (He-normal convs, zero biases, PReLU slopes 0.25).

    Returns a dict pytree: feat0 {conv: {w (3, 3, C, base), b}, a}, feat1 (input C + C + 2 channels), dbpn {feat1,
    up1, down1, up2, down2, up3, output}, res_feat1 {blocks: [...], tail}, res_feat2, res_feat3, output
    (3, 3, (frames - 1) feat, C); C = cfg.channels. Jitted (one compilation, not one per kernel shape).
    """
    return _init_rbpn(key, cfg)


@functools.partial(jax.jit, static_argnums=1)
def _init_rbpn(key, cfg: RBPNConfig) -> dict:
    return init_from_normals(key, lambda normal: _build_rbpn(normal, cfg))


def _build_rbpn(normal, cfg: RBPNConfig) -> dict:
    k, _, _ = cfg.projection
    b, f, c, n = cfg.base_filter, cfg.feat, cfg.channels, cfg.n_resblock
    dbpn = {"feat1": _conv_block(normal, 1, b, f)}
    for name in ("up1", "down1", "up2", "down2", "up3"):
        dbpn[name] = _projection_unit(normal, f, k)
    dbpn["output"] = _conv_block(normal, 1, 3 * f, f, act=False)

    def res_feat(width, tail_k, tail_in, tail_out):
        return {"blocks": [_resnet_block(normal, width) for _ in range(n)],
                "tail": _conv_block(normal, tail_k, tail_in, tail_out)}

    return {
        "feat0": _conv_block(normal, 3, c, b),
        "feat1": _conv_block(normal, 3, 2 * c + 2, b),
        "dbpn": dbpn,
        "res_feat1": res_feat(b, k, b, f),  # tail: deconvolution LR -> HR
        "res_feat2": res_feat(f, 3, f, f),
        "res_feat3": res_feat(f, k, f, b),  # tail: strided convolution HR -> LR
        "output": _conv_block(normal, 3, (cfg.frames - 1) * f, c, act=False),
    }


def _dbpn(p, x, cfg):
    x = _apply_conv(p["feat1"], x, padding=0)
    h1 = _up(p["up1"], x, cfg)
    h2 = _up(p["up2"], _down(p["down1"], h1, cfg), cfg)
    h3 = _up(p["up3"], _down(p["down2"], h2, cfg), cfg)
    return _apply_conv(p["output"], jnp.concatenate([h3, h2, h1], axis=-1), padding=0)


def _res_feat(p, x, cfg, *, tail):
    for blk in p["blocks"]:
        x = _apply_resnet(blk, x)
    _, s, pad = cfg.projection
    if tail == "up":
        return _apply_conv(p["tail"], x, stride=s, padding=pad, transpose=True)
    if tail == "down":
        return _apply_conv(p["tail"], x, stride=s, padding=pad)
    return _apply_conv(p["tail"], x)


def _neighbour_order(frames: int) -> list[int]:
    """Window indices of the neighbours, t - r .. t - 1, t + 1 .. (RBPN's order with future frames)."""
    centre = frames // 2
    return [i for i in range(frames) if i != centre]


def rbpn_flows(windows, cfg: RBPNConfig = RBPNConfig()):
    """Optical flow from the centre frame to each neighbour of each window (`jaxsr.baselines.flow.optical_flow`).

    windows: (B, frames, h, w) LR frames, centre at index frames // 2. Returns (B, frames - 1, h, w, 2), (u, v)
    in LR pixels, neighbours in the order t - r .. t - 1, t + 1 .. t + r.
    """
    centre = windows[:, cfg.frames // 2]
    neighbours = windows[:, jnp.asarray(_neighbour_order(cfg.frames))]
    centres = jnp.broadcast_to(centre[:, None], neighbours.shape)
    return optical_flow(centres, neighbours, levels=cfg.flow_levels, iterations=cfg.flow_iterations)


def apply_rbpn(params, windows, cfg: RBPNConfig = RBPNConfig(), *, flows=None):
    """The RBPN generator: LR windows -> HR centre frames.

    windows: (B, frames, h, w) LR normalised depth (centre at frames // 2; e.g. `jaxsr.training.data.scene_batches` with
    tr = frames // 2) or (B, frames, h, w, C) for C = cfg.channels > 1. flows: (B, frames - 1, h, w, 2) or None
    to compute them with `rbpn_flows`. Returns `(B, h * scale, w * scale)` ((B, H, W, C) for C > 1); not
    clipped.
    """
    if windows.ndim == 4:
        windows = windows[..., None]
    if windows.ndim != 5 or windows.shape[1] != cfg.frames or windows.shape[-1] != cfg.channels:
        raise ValueError(f"apply_rbpn: expected windows (B, {cfg.frames}, h, w) (channels {cfg.channels}), got "
                         f"{windows.shape}")
    if flows is None:
        flows = rbpn_flows(windows[..., 0], cfg)
    centre = windows[:, cfg.frames // 2]
    feat_input = _apply_conv(params["feat0"], centre)
    hs = []
    for j, t in enumerate(_neighbour_order(cfg.frames)):
        feat_frame = _apply_conv(params["feat1"], jnp.concatenate([centre, windows[:, t], flows[:, j]], axis=-1))
        h0 = _dbpn(params["dbpn"], feat_input, cfg)  # single-image projection of the running LR state
        h1 = _res_feat(params["res_feat1"], feat_frame, cfg, tail="up")  # multi-image projection
        h = h0 + _res_feat(params["res_feat2"], h0 - h1, cfg, tail="same")
        hs.append(h)
        feat_input = _res_feat(params["res_feat3"], h, cfg, tail="down")
    out = _apply_conv(params["output"], jnp.concatenate(hs, axis=-1))
    return out[..., 0] if cfg.channels == 1 else out


# --- discriminator ---------------------------------------------------------------------------------------------


def init_discriminator(key, cfg: RBPNConfig = RBPNConfig()) -> tuple[dict, dict]:
    """Initial SRGAN discriminator parameters and batch-norm state.

    Returns (params, state): params {convs: [{w (3, 3, cin, cout), b}] * 8, bns: [{scale, shift}] * 7,
    fc1 {w (1, 1, last, hidden), b}, fc2 {w (1, 1, hidden, 1), b}}; state {bns: [{mean, var}] * 7}. Jitted.
    """
    return _init_discriminator(key, cfg)


@functools.partial(jax.jit, static_argnums=1)
def _init_discriminator(key, cfg: RBPNConfig) -> tuple[dict, dict]:
    return init_from_normals(key, lambda normal: _build_discriminator(normal, cfg))


def _build_discriminator(normal, cfg: RBPNConfig) -> tuple[dict, dict]:
    convs, bns, states = [], [], []
    cin = cfg.channels
    for i, cout in enumerate(cfg.disc_widths):
        convs.append(init_conv2d(normal, 3, cin, cout))
        if i > 0:
            bn, st = init_batch_norm(cout)
            bns.append(bn)
            states.append(st)
        cin = cout
    params = {"convs": convs, "bns": bns, "fc1": init_conv2d(normal, 1, cin, cfg.disc_hidden),
              "fc2": init_conv2d(normal, 1, cfg.disc_hidden, 1)}
    return params, {"bns": states}


def apply_discriminator(params, state, hr, cfg: RBPNConfig = RBPNConfig(), *, train: bool):
    """SRGAN discriminator logits of HR frames.

    hr: (B, H, W) (or (B, H, W, C)), H and W divisible by 16. With `train` the batch statistics normalise and
    the running statistics move. Returns (logits (B,), new_state); D = sigmoid(logits) is the probability "real".
    """
    x = hr[..., None] if hr.ndim == 3 else hr
    new_states = []
    for i, conv in enumerate(params["convs"]):
        x = conv2d(conv, x, stride=2 if i % 2 else 1, padding=1)
        if i > 0:
            x, st = batch_norm(params["bns"][i - 1], state["bns"][i - 1], x, train=train, **_BN)
            new_states.append(st)
        x = jax.nn.leaky_relu(x, 0.2)
    x = jnp.mean(x, axis=(1, 2), keepdims=True)  # AdaptiveAvgPool2d(1)
    x = jax.nn.leaky_relu(conv2d(params["fc1"], x), 0.2)
    return conv2d(params["fc2"], x)[:, 0, 0, 0], {"bns": new_states}


# --- losses ----------------------------------------------------------------------------------------------------


def tv_loss(hr):
    """iSeeBetter's / SRGAN-PyTorch's total variation: 2 (mean (dy)^2 + mean (dx)^2) over (B, H, W). Returns a
    scalar."""
    dy = hr[..., 1:, :] - hr[..., :-1, :]
    dx = hr[..., :, 1:] - hr[..., :, :-1]
    return 2.0 * (jnp.mean(dy**2) + jnp.mean(dx**2))


def generator_loss(hr, gt, fake_logits, *, adversarial: float = 1e-3, tv: float = 2e-8, charbonnier: bool = False,
                   eps: float = 1e-3):
    """iSeeBetter's generator loss without the perceptual (VGG) term.

    hr, gt: (B, H, W) generated and true HR frames; fake_logits: (B,) discriminator logits of hr. Content: MSE
    (or the Charbonnier loss mean sqrt((hr - gt)^2 + eps^2) with `charbonnier`); adversarial: mean -log D(hr)
    (non-saturating, SRGAN's form); tv: `tv_loss`. Returns (loss, {"content", "adversarial", "tv"}).
    """
    diff = hr - gt
    content = jnp.mean(jnp.sqrt(diff**2 + eps**2)) if charbonnier else jnp.mean(diff**2)
    adv = jnp.mean(jax.nn.softplus(-fake_logits))  # -log sigmoid(logit)
    t = tv_loss(hr)
    return content + adversarial * adv + tv * t, {"content": content, "adversarial": adv, "tv": t}


def discriminator_loss(real_logits, fake_logits):
    """Binary cross-entropy of the discriminator: mean -log D(gt) - log(1 - D(hr)).

    real_logits, fake_logits: (B,) logits. Returns a scalar.
    """
    return jnp.mean(jax.nn.softplus(-real_logits)) + jnp.mean(jax.nn.softplus(fake_logits))



ISEEBETTER = register_architecture(Architecture(
    "iseebetter", RBPNConfig, lambda key, cfg: (init_rbpn(key, cfg), {}),
    lambda params, state, windows, cfg, conv3d_impl="auto": apply_rbpn(params, windows, cfg)))
