"""The sequence form of the network as a stream: one LR frame in, the HR frame R frames earlier out.

Every block of the sequence form is temporally valid (docs/network.md, `model.apply_model_sequence`),
so a block's output for frame m needs its input features of frames m-1, m and m+1 only. The stream keeps, per
block, the skip features of the previous frame and the partial sums of its 3x3x3 convolution for the next two
outputs (each new frame is convolved once with the three temporal taps' kernels side by side, and each tap is
added to the output it belongs to), plus the last R + 1 LR frames for the dynamic filter. The buffers are a
pytree of fixed shape: memory does not grow with the length of the stream.

Step n takes padded input frame n and returns the output whose centre is padded frame n - R, i.e. output
n - 2R of the sequence; it is valid once n >= 2R (the first R + 1 steps feed the first frame, the edge
padding). `jaxsr.inference.Stream` wraps this for live input. A `lax.scan` of the step over a whole sequence
ran no faster than a Python loop over the jitted step, and both slower than the sequence form in chunks
(experiments/results/sequence_form.md), so whole sequences go through `apply_model_sequence` instead.
"""

from __future__ import annotations

import jax.numpy as jnp

from ..config import ModelConfig
from .duf import (_block_input, _depth, _has_channels, _head, _stem, check_conv, convolution, merge_no_return,
                  sequence_radius)

__all__ = ["stream_init", "stream_step"]


def stream_init(cfg: ModelConfig, lr_shape: tuple[int, int], *, batch: int = 1, dtype=jnp.float32) -> dict:
    """Empty (zero) stream buffers for `batch` streams of (h, w) = lr_shape LR frames.

    Returns {"lr": (batch, R + 1, h, w) the last LR frames' depth, "blocks": [{"skip": (batch, h, w, F_i) the
    block's input features of the previous frame, "partial": (batch, 2, h, w, growth) the partial sums of
    the next two outputs}] * (same_blocks + tr)}, F_i = base + i * growth. The first 2R outputs of a stream
    depend on these zeros and are to be discarded (`Stream` does).
    """
    h, w = (int(v) for v in lr_shape)
    blocks = []
    f = cfg.base
    for _ in range(cfg.same_blocks + cfg.tr):
        blocks.append({"skip": jnp.zeros((batch, h, w, f), dtype),
                       "partial": jnp.zeros((batch, 2, h, w, cfg.growth), dtype)})
        f += cfg.growth
    return {"lr": jnp.zeros((batch, sequence_radius(cfg) + 1, h, w), dtype), "blocks": blocks}


def _stream_block(p, s, buf, x, *, bn: dict, conv):
    """One valid dense block, one frame: input features x (B, 1, h, w, F) of frame m -> (its output for frame
    m - 1, (B, 1, h, w, F + growth), the new buffers)."""
    z, _ = _block_input(p, s, x, bn=bn, conv=conv)
    w = p["conv2"]["w"]  # (3, kh, kw, F, G): the taps' kernels side by side, one 2D convolution
    kt, kh, kw, cin, cout = w.shape
    stacked = jnp.moveaxis(w, 0, 3).reshape(1, kh, kw, cin, kt * cout)
    pad = ((0, 0), ((kh - 1) // 2, kh // 2), ((kw - 1) // 2, kw // 2))
    taps = conv(z, stacked, padding=pad)[:, 0]
    taps = taps.reshape(*taps.shape[:-1], kt, cout)
    # frame m is tap 2 of output m - 1, tap 1 of output m and tap 0 of output m + 1
    y = buf["partial"][:, 0] + taps[..., 2, :] + p["conv2"]["b"]
    partial = jnp.stack([buf["partial"][:, 1] + taps[..., 1, :], taps[..., 0, :]], axis=1)
    return jnp.concatenate([buf["skip"], y], axis=-1)[:, None], {"skip": x[:, 0], "partial": partial}


def stream_step(params, state, buffers: dict, frame, cfg: ModelConfig, *, conv3d_impl: str = "auto",
                precision: str = "default"):
    """One step of the stream, BN in inference mode: feed LR frame n, get the output centred on frame n - R.

    frame: (B, h, w) LR normalised depth ((B, h, w, C) for a network reading more `cfg.inputs`); buffers: as
    `stream_init` (or the previous step) returns them.
    Returns (new buffers, hr `(B, h*r, w*r)`). With the stream's input edge-padded (R + 1 copies of its first
    frame, then the rest, then R copies of the last), the hr of step n >= 2R equals output n - 2R of
    `apply_model_sequence` to float32 rounding. R = `sequence_radius(cfg)`; the weights run in the sequence
    form whatever `cfg.temporal` says. conv3d_impl, precision: as for `apply_model`.
    """
    want = buffers["lr"].shape[:1] + buffers["lr"].shape[2:] + ((cfg.channels,) if cfg.channels > 1 else ())
    if not _has_channels(frame, cfg, 3) or frame.shape != want:
        axes = "(B, h, w)" if cfg.channels == 1 else f"(B, h, w, C) for inputs {cfg.inputs}"
        raise ValueError(f"stream_step: expected a frame {axes} = {want} matching the stream's buffers, got shape "
                         f"{frame.shape}")
    check_conv(conv3d_impl, precision, "stream_step")
    conv = convolution(conv3d_impl, precision)
    bn = {"train": False, "momentum": cfg.bn_momentum, "eps": cfg.bn_eps}
    depth = _depth(frame[:, None], cfg).astype(buffers["lr"].dtype)
    lr = jnp.concatenate([buffers["lr"][:, 1:], depth], axis=1)
    x = _stem(params, frame[:, None], conv=conv)  # (B, 1, h, w, base)
    new_blocks = []
    for p, s, buf in zip(params["blocks"], state["blocks"], buffers["blocks"]):
        x, buf = _stream_block(p, s, buf, x, bn=bn, conv=conv)
        new_blocks.append(buf)
    hr, _ = _head(params, state, x, lr[:, :1], cfg, bn=bn, conv=conv, precision=precision)
    return {"lr": lr, "blocks": new_blocks}, merge_no_return(hr[:, 0], cfg)
