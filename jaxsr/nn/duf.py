"""The 3+TR-block dynamic-upsampling-filter network (VSR-DUF adapted; docs/network.md).

`init_model(key, cfg) -> (params, state)`, `apply_model(params, state, windows, cfg) -> hr` (BN in inference
mode) and `apply_model_train(...) -> (hr, new_state)` (BN with batch statistics) are pure functions of nested
dicts/lists of arrays (pytree key paths such as `blocks/0/conv2/w` name every array). `Model` bundles params,
state and config as one pytree; `super_resolve` runs a model over a whole LR sequence. How the convolutions
are computed (`conv3d_impl`) and to what precision (`precision`) are arguments of the call, not part of the model's
config.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp

from ..config import TEMPORAL_FORMS, ModelConfig
from .layers import (
    CONV3D_IMPLS,
    PRECISIONS,
    batch_norm,
    conv3d,
    depth_to_space,
    dynamic_upsample,
    glorot_limit,
    init_batch_norm,
    lax_precision_of,
)
from ..sensor.peaks import NO_RETURN
from .model import Architecture, Model, register_architecture

NO_RETURN_PRIOR = -4.0  # a new no-return branch's logit: p = 0.018, "a return" everywhere

__all__ = [
    "init_model",
    "apply_model",
    "apply_model_raw",
    "apply_model_train",
    "apply_model_features",
    "apply_model_sequence",
    "apply_model_sequence_train",
    "edge_pad_sequence",
    "sequence_radius",
    "spatial_radius",
    "count_params",
    "flops_per_frame",
    "grow_tr",
    "with_photon_inputs",
    "merge_no_return",
    "with_no_return_logit",
    "no_return_branch",
    "no_return_logits",
]


def init_model(key, cfg: ModelConfig) -> tuple[dict, dict]:
    """Initial parameters and batch-norm state of the network described by `cfg`.

    Convolutions: Glorot-uniform kernels, zero biases (Keras defaults); BN: scale 1, shift 0, running mean 0,
    running variance 1. Returns (params, state), nested dicts/lists of float32 arrays:
    params = {stem, blocks: [{bn1, conv1, bn2, conv2}] * (3 + tr), head: {bn, conv}, residual: {conv1, conv2},
    filter: {conv1, conv2}}; state = {blocks: [{bn1, bn2}], head: {bn}} with {mean, var} per BN.
    Jitted (one compilation per config instead of one per layer shape).
    """
    return _init_model(key, cfg)


def _conv_shapes(cfg: ModelConfig) -> dict:
    """{(group, index or None, name): (kernel, cin, cout)} of every convolution, in a fixed order."""
    r2 = cfg.scale * cfg.scale
    shapes = {("stem", None, None): ((1, 3, 3), cfg.channels, cfg.base)}
    f = cfg.base
    for i in range(cfg.same_blocks + cfg.tr):
        shapes[("blocks", i, "conv1")] = ((1, 1, 1), f, f)
        shapes[("blocks", i, "conv2")] = ((3, 3, 3), f, cfg.growth)
        f += cfg.growth
    shapes[("head", None, "conv")] = ((1, 3, 3), f, cfg.head)
    shapes[("residual", None, "conv1")] = ((1, 1, 1), cfg.head, cfg.head)
    shapes[("residual", None, "conv2")] = ((1, 1, 1), cfg.head, r2)
    shapes[("filter", None, "conv1")] = ((1, 1, 1), cfg.head, cfg.filter_hidden)
    shapes[("filter", None, "conv2")] = ((1, 1, 1), cfg.filter_hidden, cfg.filter_size**2 * r2)
    if cfg.no_return_head:
        shapes[("no_return", None, "conv1")] = ((1, 1, 1), cfg.head, cfg.head)
        shapes[("no_return", None, "conv2")] = ((1, 1, 1), cfg.head, r2)
    return shapes


@functools.partial(jax.jit, static_argnums=1)
def _init_model(key, cfg: ModelConfig) -> tuple[dict, dict]:
    shapes = _conv_shapes(cfg)
    sizes = [math.prod(k) * cin * cout for k, cin, cout in shapes.values()]
    # one flat uniform draw sliced per layer (one random kernel to compile instead of one per shape)
    u = jax.random.uniform(key, (sum(sizes),), jnp.float32, -1.0, 1.0)
    convs, offset = {}, 0
    for (name, (kernel, cin, cout)), n in zip(shapes.items(), sizes):
        w = glorot_limit(kernel, cin, cout) * u[offset : offset + n].reshape(*kernel, cin, cout)
        convs[name] = {"w": w, "b": jnp.zeros((cout,), jnp.float32)}
        offset += n
    params = {"stem": convs[("stem", None, None)], "blocks": []}
    state = {"blocks": []}
    f = cfg.base
    for i in range(cfg.same_blocks + cfg.tr):
        bn1, s1 = init_batch_norm(f)
        bn2, s2 = init_batch_norm(f)
        params["blocks"].append(
            {"bn1": bn1, "conv1": convs[("blocks", i, "conv1")], "bn2": bn2, "conv2": convs[("blocks", i, "conv2")]}
        )
        state["blocks"].append({"bn1": s1, "bn2": s2})
        f += cfg.growth
    bn, s = init_batch_norm(f)
    params["head"] = {"bn": bn, "conv": convs[("head", None, "conv")]}
    state["head"] = {"bn": s}
    params["residual"] = {"conv1": convs[("residual", None, "conv1")], "conv2": convs[("residual", None, "conv2")]}
    params["filter"] = {"conv1": convs[("filter", None, "conv1")], "conv2": convs[("filter", None, "conv2")]}
    if cfg.no_return_head:
        params["no_return"] = no_return_branch(convs[("no_return", None, "conv1")], cfg)
    return params, state


def no_return_branch(conv1, cfg: ModelConfig) -> dict:
    """The no-return branch's params from its first convolution: the second's weights zero and its bias
    `NO_RETURN_PRIOR`, so that a new branch starts by calling every pixel a return, changing nothing."""
    r2 = cfg.scale * cfg.scale
    return {"conv1": conv1, "conv2": {"w": jnp.zeros((1, 1, 1, cfg.head, r2), jnp.float32),
                                      "b": jnp.full((r2,), NO_RETURN_PRIOR, jnp.float32)}}


def with_photon_inputs(key, model: Model, inputs=("depth", "signal", "background"), *,
                       no_return_head: bool = True) -> Model:
    """A model widened to read more `inputs` and (optionally) to mark no return, computing exactly what `model`
    computes until training moves the new weights: the stem's kernels on the added channels are zero (those on
    the channels `model` reads are its own, by name), and a new no-return branch (first convolution drawn from
    `key`) starts at "return everywhere"; a head `model` has is kept. `inputs` must hold every input of `model`.
    Returns the widened `Model` (same form, widths and TR)."""
    cfg = model.config
    inputs = tuple(inputs)
    if (not set(cfg.inputs) <= set(inputs) or (cfg.no_return_head and not no_return_head)
            or (inputs == cfg.inputs and no_return_head == cfg.no_return_head)):
        raise ValueError(f"with_photon_inputs: expects a model to widen: its inputs {cfg.inputs} within {inputs} "
                         f"and its no-return head ({cfg.no_return_head}) kept, with something added")
    new_cfg = dataclasses.replace(cfg, inputs=inputs, no_return_head=no_return_head)
    stem = model.params["stem"]
    w = jnp.zeros((*stem["w"].shape[:3], new_cfg.channels, stem["w"].shape[-1]), stem["w"].dtype)
    for i, name in enumerate(cfg.inputs):
        w = w.at[..., inputs.index(name), :].set(stem["w"][..., i, :])
    params = {**model.params, "stem": {"w": w, "b": stem["b"]}}
    if no_return_head and not cfg.no_return_head:
        fresh, _ = init_model(key, new_cfg)
        params["no_return"] = fresh["no_return"]
    return Model(params, model.state, new_cfg)


def grow_tr(key, model: Model, tr: int) -> Model:
    """A warm start for a larger temporal radius: the network of radius `tr` (>= model's) that starts from a
    trained `model`'s function.

    The stem, the 3 + model.tr blocks, the head's residual and filter branches and all BN state are carried
    over; the added blocks are drawn from `key` as `init_model` draws them, and the head convolution's weights
    on their features are zero (their head BN fresh), so the added blocks change nothing until training moves
    those weights. In the sequence form the grown network computes the trained one's output exactly (cropped
    by the added radius at each end); in the window form nearly, since its wider window shows real frames where
    the trained one's temporally padded blocks read zeros (for a windowed TR0, whose window is one frame, the
    outer temporal taps of those blocks never saw anything but zeros and are still at their initial values).
    Returns the grown `Model` (same scale, widths and form as `model`).
    """
    cfg = model.config
    if tr < cfg.tr:
        raise ValueError(f"grow_tr: tr must be >= the model's {cfg.tr}, got {tr}")
    new_cfg = dataclasses.replace(cfg, tr=tr)
    fresh, fresh_state = init_model(key, new_cfg)
    n = len(model.params["blocks"])
    old_head, new_head = model.params["head"], fresh["head"]
    f_old = old_head["conv"]["w"].shape[-2]

    def extend(old, new):  # per-channel BN leaves: the trained channels, then the fresh ones
        return jnp.concatenate([old, new[f_old:]])

    w_new = new_head["conv"]["w"]
    head = {
        "bn": jax.tree_util.tree_map(extend, old_head["bn"], new_head["bn"]),
        "conv": {"w": jnp.zeros_like(w_new).at[..., :f_old, :].set(old_head["conv"]["w"]),
                 "b": old_head["conv"]["b"]},
    }
    params = {**model.params, "blocks": list(model.params["blocks"]) + fresh["blocks"][n:], "head": head}
    state = {"blocks": list(model.state["blocks"]) + fresh_state["blocks"][n:],
             "head": {"bn": jax.tree_util.tree_map(extend, model.state["head"]["bn"], fresh_state["head"]["bn"])}}
    return Model(params, state, new_cfg)


def count_params(params) -> int:
    """Number of scalars in a params pytree (weights, biases, BN scale and shift).

    Returns an int; docs/network.md: TR0 1,056,608 ... TR4 2,253,088 at the paper's widths.
    """
    return sum(math.prod(x.shape) for x in jax.tree_util.tree_leaves(params))


def flops_per_frame(cfg: ModelConfig, lr_shape=(32, 64), *, clip_frames: int | None = None) -> int:
    """Floating-point operations (2 per multiply-add) of the convolutions and the dynamic filter for one output
    frame of `lr_shape` (h, w) LR pixels; batch norm, ReLU and softmax (under 1 %) are not counted.

    In the form `cfg.temporal` says. "window": "same" blocks on all 2 tr + 1 frames, temporally valid blocks on
    the frames they keep, taps that fall in the temporal zero padding skipped (as `conv3d_taps` computes it;
    `conv3d_stacked` layers compute more products, `layers.stacked_use` says how many reach an output).
    "sequence": with clip_frames None, a long sequence or a stream (every layer computes each frame once);
    with clip_frames = L >= 2R + 1, one pass over a clip of L frames ("valid", L - 2R outputs) per output.
    Returns an int.
    """
    shapes = _conv_shapes(cfg)
    n_blocks = cfg.same_blocks + cfg.tr

    def conv(key, frames):
        (_, kh, kw), cin, cout = shapes[key]
        return frames * kh * kw * cin * cout

    if cfg.temporal == "window":
        if clip_frames is not None:
            raise ValueError("flops_per_frame: clip_frames applies to the sequence form only")
        t, outputs = cfg.frames, 1
        stem_t, block_t, conv2_taps = t, [], []
        for i in range(n_blocks):
            block_t.append(t)
            if i < cfg.same_blocks:  # taps inside a T-frame window, zero padding 1 at each end
                conv2_taps.append(sum(min(j + 1, t - 1) - max(j - 1, 0) + 1 for j in range(t)))
            else:
                t -= 2
                conv2_taps.append(3 * t)
    else:
        r = sequence_radius(cfg)
        if clip_frames is None:
            stem_t, block_t, conv2_taps, outputs = 1, [1] * n_blocks, [3] * n_blocks, 1
        elif clip_frames < 2 * r + 1:
            raise ValueError(f"flops_per_frame: a clip needs at least 2R + 1 = {2 * r + 1} frames, got {clip_frames}")
        else:
            stem_t, outputs = clip_frames, clip_frames - 2 * r
            block_t = [clip_frames - 2 * i for i in range(n_blocks)]
            conv2_taps = [3 * (t - 2) for t in block_t]
    macs = conv(("stem", None, None), stem_t)
    for i in range(n_blocks):
        macs += conv(("blocks", i, "conv1"), block_t[i]) + conv(("blocks", i, "conv2"), conv2_taps[i])
    macs += conv(("head", None, "conv"), outputs)
    for group in ("residual", "filter") + (("no_return",) if cfg.no_return_head else ()):
        macs += conv((group, None, "conv1"), outputs) + conv((group, None, "conv2"), outputs)
    macs += outputs * cfg.filter_size**2 * cfg.scale**2  # the dynamic filter, per LR pixel
    return int(round(2 * macs * lr_shape[0] * lr_shape[1] / outputs))


def _input_shape(cfg: ModelConfig, lead: str) -> str:
    """How a network's input looks, for error messages: "(B, T, H, W)" or "(B, T, H, W, C)"."""
    return f"({lead}, H, W)" if cfg.channels == 1 else f"({lead}, H, W, {cfg.channels})"


def _has_channels(x, cfg: ModelConfig, ndim: int) -> bool:
    """x is (..., H, W) for a depth-only network, (..., H, W, C) for one reading `cfg.inputs`."""
    if cfg.channels == 1:
        return x.ndim == ndim
    return x.ndim == ndim + 1 and x.shape[-1] == cfg.channels


def _check_inputs(windows, cfg: ModelConfig, conv3d_impl: str, precision: str, who: str):
    if not _has_channels(windows, cfg, 4) or windows.shape[1] != cfg.frames:
        raise ValueError(f"{who}: expected windows {_input_shape(cfg, f'B, {cfg.frames}')} for tr={cfg.tr} and "
                         f"inputs {cfg.inputs}, got shape {windows.shape}")
    check_conv(conv3d_impl, precision, who)


def check_conv(conv3d_impl: str, precision: str, who: str) -> None:
    """Refuse an unknown `conv3d_impl` or `precision`, naming the caller and the choices."""
    if conv3d_impl not in CONV3D_IMPLS:
        raise ValueError(f"{who}: conv3d_impl must be one of {', '.join(map(repr, CONV3D_IMPLS))}, got {conv3d_impl!r}")
    if precision not in PRECISIONS:
        raise ValueError(f"{who}: precision must be one of {', '.join(map(repr, PRECISIONS))}, got {precision!r}")


def convolution(conv3d_impl: str = "auto", precision: str = "default"):
    """The network's convolution, `conv3d` with its impl and precision fixed: conv(x, w, b, padding=...)."""
    return functools.partial(conv3d, impl=conv3d_impl, precision=precision)


def apply_model(params, state, windows, cfg: ModelConfig, *, conv3d_impl: str = "auto", precision: str = "default"):
    """Super-resolve the centre frame of each window, batch norm in inference mode (running statistics).

    windows: `(B, 2*tr+1, H, W)` LR normalised depth (0..1, 1 = no return), the centre frame at index tr; a
    network with more `cfg.inputs` reads `(B, 2*tr+1, H, W, C)`, depth in channel 0 (`jaxsr.nn.inputs`).
    Returns hr `(B, H*r, W*r)` normalised depth, neither clipped nor passed through an activation; with a
    no-return head, 1.0 where it says no return (`merge_no_return`).
    conv3d_impl: how the 3x3x3 convolutions run, not what they compute (`jaxsr.nn.layers.conv3d`): "auto" (the
    faster one on the current backend), "native" (one 3D convolution), "taps" (a sum of 2D convolutions over
    the temporal taps), "stacked" (the taps' kernels side by side in one 2D convolution) or "stacked-taps-grad"
    (the stacked forward with the taps' gradients, what "auto" trains with on CPU).
    precision: how the convolutions multiply, `jaxsr.nn.layers.PRECISIONS`: "default" (the backend's), "float32"
    or "bfloat16" (bfloat16 operands, float32 accumulation); the output is float32 in every case.
    """
    _check_inputs(windows, cfg, conv3d_impl, precision, "apply_model")
    out, _ = _forward(params, state, windows, cfg, train=False, conv3d_impl=conv3d_impl, precision=precision)
    return merge_no_return(out, cfg)


def apply_model_raw(params, state, windows, cfg: ModelConfig, *, conv3d_impl: str = "auto",
                    precision: str = "default"):
    """`apply_model` before the no-return decision: BN in inference mode, the output as the network computes it,
    hr `(B, H*r, W*r)`, or with a no-return head `(B, H*r, W*r, 2)` [depth, no-return logit]; `merge_no_return`
    of it is `apply_model`'s output. For calibrating the decision (`ModelConfig.no_return_logit`) on logits
    computed once. windows, conv3d_impl, precision: as for `apply_model`.
    """
    _check_inputs(windows, cfg, conv3d_impl, precision, "apply_model_raw")
    out, _ = _forward(params, state, windows, cfg, train=False, conv3d_impl=conv3d_impl, precision=precision)
    return out


def apply_model_train(params, state, windows, cfg: ModelConfig, *, conv3d_impl: str = "auto",
                      precision: str = "default"):
    """The network as it trains: batch norm normalises with the batch's own statistics.

    windows: as for `apply_model`. Returns (out, new_state): out the raw output, hr `(B, H*r, W*r)`, or with a
    no-return head `(B, H*r, W*r, 2)` [depth, no-return logit] (what the loss needs; `merge_no_return` makes
    it `apply_model`'s output); new_state holds the running BN statistics moved towards this batch's (same
    structure as `state`). conv3d_impl, precision: as for `apply_model`.
    """
    _check_inputs(windows, cfg, conv3d_impl, precision, "apply_model_train")
    return _forward(params, state, windows, cfg, train=True, conv3d_impl=conv3d_impl, precision=precision)


def spatial_radius(cfg: ModelConfig) -> int:
    """The network's spatial receptive radius in LR pixels (an int): output pixel (y, x) depends on input pixels
    within +-radius rows and columns, in either form. Each 3x3 spatial convolution (stem, the 3x3x3 of every block,
    head) widens it by 1; the dynamic filter reads +-filter_size // 2 of the input frame. TR0: 5, TR4: 9."""
    return max(1 + cfg.same_blocks + cfg.tr + 1, cfg.filter_size // 2)


def sequence_radius(cfg: ModelConfig) -> int:
    """R = same_blocks + tr: in the sequence form output t depends on input frames t-R .. t+R (an int)."""
    return cfg.same_blocks + cfg.tr


def _check_sequence(lr_seq, cfg: ModelConfig, padding: str, conv3d_impl: str, precision: str, who: str):
    r = sequence_radius(cfg)
    if padding not in ("edge", "valid"):
        raise ValueError(f"{who}: padding must be 'edge' or 'valid', got {padding!r}")
    need = 1 if padding == "edge" else 2 * r + 1
    if not _has_channels(lr_seq, cfg, 4) or lr_seq.shape[1] < need:
        raise ValueError(
            f"{who}: expected an LR sequence {_input_shape(cfg, 'B, T')} with T >= {need} for tr={cfg.tr} and padding "
            f"{padding!r} (R = {r}), got shape {lr_seq.shape}"
        )
    check_conv(conv3d_impl, precision, who)


def apply_model_sequence(params, state, lr_seq, cfg: ModelConfig, *, padding: str = "edge",
                         conv3d_impl: str = "auto", precision: str = "default", raw: bool = False):
    """The network in its sequence form, BN in inference mode: every output frame of a sequence in one pass.

    All 3 + tr blocks are temporally valid, so with R = `sequence_radius(cfg)` = same_blocks + tr, output t is
    the network applied to input frames t-R .. t+R (the dynamic filter on frame t) and neighbouring outputs
    share every intermediate frame. Same parameters as `apply_model` (any checkpoint runs in either form).
    lr_seq: (B, T, H, W) LR normalised depth. padding: "edge" (the ends padded with R copies of the first and
    last frame; T >= 1) returns `(B, T, H*r, W*r)`; "valid" (no padding; T >= 2R + 1) returns the T - 2R
    frames whose inputs all lie inside the sequence, `(B, T - 2R, H*r, W*r)`. conv3d_impl, precision: as for
    `apply_model`. raw: the output before the no-return decision, as `apply_model_raw` gives it (with a
    no-return head a last axis [depth, logit]).
    """
    _check_sequence(lr_seq, cfg, padding, conv3d_impl, precision, "apply_model_sequence")
    out, _ = _forward_sequence(params, state, lr_seq, cfg, padding=padding, train=False, conv3d_impl=conv3d_impl,
                               precision=precision)
    return out if raw else merge_no_return(out, cfg)


def apply_model_sequence_train(params, state, lr_seq, cfg: ModelConfig, *, padding: str = "valid",
                               conv3d_impl: str = "auto", precision: str = "default"):
    """The sequence form as it trains: BN normalises with the statistics of the whole clip, (B, T', H, W).

    lr_seq: (B, T, H, W) training clips; padding: "valid" (default: only outputs whose inputs all lie inside
    the clip, T' = T - 2R) or "edge" (T' = T), as for `apply_model_sequence`. Returns (out, new_state): out
    the raw output `(B, T', H*r, W*r)` (with a no-return head a last axis [depth, logit], as
    `apply_model_train`), new_state the running BN statistics moved towards the clip's.
    """
    _check_sequence(lr_seq, cfg, padding, conv3d_impl, precision, "apply_model_sequence_train")
    return _forward_sequence(params, state, lr_seq, cfg, padding=padding, train=True, conv3d_impl=conv3d_impl,
                             precision=precision)


def edge_pad_sequence(lr_seq, radius: int):
    """(B, T, ...) -> (B, T + 2 radius, ...): `radius` copies of the first frame before, of the last after."""
    first = jnp.repeat(lr_seq[:, :1], radius, axis=1)
    last = jnp.repeat(lr_seq[:, -1:], radius, axis=1)
    return jnp.concatenate([first, lr_seq, last], axis=1)


def _forward_sequence(params, state, lr_seq, cfg: ModelConfig, *, padding: str, train: bool, conv3d_impl: str,
                      precision: str):
    """The sequence form's body for both BN modes: (hr (B, T', H*r, W*r), new_state)."""
    conv = convolution(conv3d_impl, precision)
    r = sequence_radius(cfg)
    x_in = edge_pad_sequence(lr_seq, r) if padding == "edge" else lr_seq
    bn = {"train": train, "momentum": cfg.bn_momentum, "eps": cfg.bn_eps}
    x, block_states = _blocks(params, state, x_in, cfg, bn=bn, conv=conv, valid_from=0)
    new_state = {"blocks": block_states}
    hr, new_state["head"] = _head(params, state, x, _depth(x_in[:, r : x_in.shape[1] - r], cfg), cfg, bn=bn,
                                  conv=conv, precision=precision)
    return hr, new_state


def _blocks(params, state, lr, cfg: ModelConfig, *, bn: dict, conv, valid_from: int | None = None):
    """Stem and blocks: (features (B, T', H, W, F), their new BN states). Blocks from `valid_from` on (default
    `cfg.same_blocks`: the window form, T' = 1) are temporally valid; the sequence form makes all of them so (0)."""
    valid_from = cfg.same_blocks if valid_from is None else valid_from
    x = _stem(params, lr, conv=conv)
    states = []
    for i, (p, s) in enumerate(zip(params["blocks"], state["blocks"])):
        x, s_i = _block(p, s, x, valid=i >= valid_from, bn=bn, conv=conv)
        states.append(s_i)
    return x, states


def apply_model_features(params, state, windows, cfg: ModelConfig, *, conv3d_impl: str = "auto",
                         precision: str = "default"):
    """The head's features of each window's centre frame, BN in inference mode: (B, H, W, cfg.head), what the
    residual, filter and no-return branches read (`no_return_logits` of them, with a time axis, is the
    no-return logit `apply_model_raw` gives). For refitting a branch on features computed once
    (experiments/studies/no_return_head.py). windows, conv3d_impl, precision: as for `apply_model`."""
    _check_inputs(windows, cfg, conv3d_impl, precision, "apply_model_features")
    conv = convolution(conv3d_impl, precision)
    bn = dict(train=False, momentum=cfg.bn_momentum, eps=cfg.bn_eps)
    x, _ = _blocks(params, state, windows, cfg, bn=bn, conv=conv)
    return _head_features(params, state, x, bn=bn, conv=conv)[0][:, 0]


def _forward(params, state, windows, cfg: ModelConfig, *, train: bool, conv3d_impl: str, precision: str):
    """The windowed network for both BN modes: (hr (B, H*r, W*r), new_state)."""
    conv = convolution(conv3d_impl, precision)
    bn = dict(train=train, momentum=cfg.bn_momentum, eps=cfg.bn_eps)
    x, block_states = _blocks(params, state, windows, cfg, bn=bn, conv=conv)
    new_state = {"blocks": block_states}
    hr, new_state["head"] = _head(params, state, x, _depth(windows[:, cfg.tr : cfg.tr + 1], cfg), cfg, bn=bn,
                                  conv=conv, precision=precision)
    return hr[:, 0], new_state  # T = 1 after tr valid blocks


def _depth(lr, cfg: ModelConfig):
    """The depth channel of network inputs: (B, T, H, W) either way."""
    return lr if cfg.channels == 1 else lr[..., 0]


def _stem(params, lr, *, conv):
    """lr (B, T, H, W) or (B, T, H, W, C) -> stem features (B, T, H, W, base): conv 1x3x3, spatial zero padding."""
    x = lr[..., None] if lr.ndim == 4 else lr
    return conv(x, params["stem"]["w"], params["stem"]["b"], padding="same")


def _block_input(p, s, x, *, bn: dict, conv):
    """The per-frame part of a dense block: BN, ReLU, conv 1x1x1, BN, ReLU; (..., F) -> ((..., F), (s1, s2))."""
    y, s1 = batch_norm(p["bn1"], s["bn1"], x, **bn)
    y = conv(jax.nn.relu(y), p["conv1"]["w"], p["conv1"]["b"])
    y, s2 = batch_norm(p["bn2"], s["bn2"], y, **bn)
    return jax.nn.relu(y), {"bn1": s1, "bn2": s2}


def _block(p, s, x, *, valid: bool, bn: dict, conv):
    """One dense block: x (B, T, H, W, F) -> (B, T', H, W, F + growth) and its new BN state.

    `valid`: the 3x3x3 conv is not padded in time (T' = T - 2) and the skip path is cropped to the middle
    frames; otherwise T' = T (temporal zero padding 1).
    """
    y, new_state = _block_input(p, s, x, bn=bn, conv=conv)
    pad = ((0, 0) if valid else (1, 1), (1, 1), (1, 1))
    y = conv(y, p["conv2"]["w"], p["conv2"]["b"], padding=pad)
    if valid:
        x = x[:, 1:-1]
    return jnp.concatenate([x, y], axis=-1), new_state


def _head(params, state, x, centre, cfg: ModelConfig, *, bn: dict, conv, precision: str):
    """Features (B, T, H, W, F) and the LR frames they belong to, centre (B, T, H, W) -> (hr (B, T, H*r, W*r),
    new head BN state): head conv, residual and filter branches, dynamic upsampling of `centre` (at `precision`,
    float32 for "bfloat16": the filters weigh depths)."""
    h, sh = _head_features(params, state, x, bn=bn, conv=conv)

    def dense(p, z):  # a 1x1x1 convolution: a matrix product
        return conv(z, p["w"], p["b"])

    residual = dense(params["residual"]["conv2"], jax.nn.relu(dense(params["residual"]["conv1"], h)))
    logits = dense(params["filter"]["conv2"], jax.nn.relu(dense(params["filter"]["conv1"], h)))
    r2 = cfg.scale * cfg.scale
    filters = jax.nn.softmax(logits.reshape(*logits.shape[:-1], cfg.filter_size**2, r2), axis=-2)
    b, t = centre.shape[:2]
    sub = dynamic_upsample(centre.reshape(b * t, *centre.shape[2:]), filters.reshape(b * t, *filters.shape[2:]),
                           padding=cfg.filter_padding, lax_precision=lax_precision_of(precision))
    sub = sub.reshape(b, t, *sub.shape[1:]) + residual  # (B, T, H, W, r^2)
    hr = depth_to_space(sub, cfg.scale)[..., 0]
    if cfg.no_return_head:
        hr = jnp.stack([hr, no_return_logits(params["no_return"], h, cfg, conv=conv)], axis=-1)
    return hr, {"bn": sh}


def _head_features(params, state, x, *, bn: dict, conv):
    """The blocks' features (B, T, H, W, F) -> the head's (B, T, H, W, cfg.head), which the residual, filter and
    no-return branches read, and the head's new BN state."""
    h, sh = batch_norm(params["head"]["bn"], state["head"]["bn"], x, **bn)
    return jax.nn.relu(conv(jax.nn.relu(h), params["head"]["conv"]["w"], params["head"]["conv"]["b"])), sh


def no_return_logits(p, h, cfg: ModelConfig, *, conv=conv3d):
    """The no-return branch `p` (params["no_return"]) on the head's features h (B, T, H, W, cfg.head): the logit
    of "no return" for each HR pixel, (B, T, H*r, W*r); two 1x1x1 convolutions, r^2 logits per LR pixel."""
    z = conv(jax.nn.relu(conv(h, p["conv1"]["w"], p["conv1"]["b"])), p["conv2"]["w"], p["conv2"]["b"])
    return depth_to_space(z, cfg.scale)[..., 0]


def merge_no_return(out, cfg: ModelConfig):
    """The network's depth from its raw output: `out` itself for a model without a no-return head; with one,
    out[..., 0] where the logit out[..., 1] <= `cfg.no_return_logit` (0.0 unless calibrated) and 1.0 (no return)
    where it is above."""
    if not cfg.no_return_head:
        return out
    return jnp.where(out[..., 1] > cfg.no_return_logit, NO_RETURN, out[..., 0])


def with_no_return_logit(model, logit):
    """The same weights deciding "no return" at another threshold: a copy of `model` (a `Model` whose network
    has a no-return head) whose output is 1.0 where the head's logit is above `logit`. Raising it drops fewer true
    returns and leaves more pixels without one as depth (0.0: p = 0.5; +2.0: p = 0.88); the trade is measured
    in experiments/results/photon_regimes.md and real_photons.md. Raises ValueError for a model without the
    head or a logit that is not a finite number."""
    if not (isinstance(model, Model) and model.has_no_return_head):
        raise ValueError("no_return_logit applies to models with a no-return head (such as tr4-ambient and "
                         f"tr4-photons); this one has none ({type(getattr(model, 'config', model)).__name__})")
    return dataclasses.replace(model, config=dataclasses.replace(model.config, no_return_logit=logit))


def feature_bytes(cfg: ModelConfig, batch_size: int = 1) -> float:
    """Bytes the network holds per LR pixel of a tile and output frame in inference, batch_size outputs at a
    time: float32 twice over the frames each output reads (the dense blocks' activations and their batch norm; in
    the sequence form the chunk's batch_size + 2R frames shared by its outputs) and once in the head. Measured on
    XLA:CPU: TR0 5.3 kB, TR4 20 kB per pixel (this gives 5.3 and 25)."""
    window = (batch_size + 2 * cfg.input_radius) / batch_size if cfg.temporal == "sequence" else cfg.frames
    blocks = 8 * window * (cfg.base + (cfg.same_blocks + cfg.tr) * cfg.growth)
    return blocks + 4 * (cfg.head + cfg.filter_hidden + cfg.filter_size**2 * cfg.scale**2)


def _describe(cfg: ModelConfig, lr_shape) -> dict:
    return {"temporal": cfg.temporal, "frames_per_window": cfg.frames, "input_radius": cfg.input_radius,
            "gflops_per_frame": round(flops_per_frame(cfg, lr_shape) / 1e9, 3)}


DUF = register_architecture(Architecture(
    "duf", ModelConfig, init_model, apply_model, input_radius=lambda cfg: cfg.input_radius,
    sequence_form=lambda cfg: cfg.temporal == "sequence", receptive_radius=spatial_radius, describe=_describe,
    channels=lambda cfg: cfg.inputs, no_return_head=lambda cfg: cfg.no_return_head, forms=TEMPORAL_FORMS,
    form=lambda cfg: cfg.temporal, with_form=lambda cfg, form: dataclasses.replace(cfg, temporal=form),
    precisions=PRECISIONS, feature_bytes=feature_bytes))
