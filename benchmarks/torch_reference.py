"""A PyTorch port of the jaxsr network, used only to compare CPU inference speed (benchmarks/compare_torch.py).

Not part of the package and not a dependency of it: it needs `pip install torch==2.13.0` (a CPU build).
The port is inference-only: batch norm uses the running statistics (eval mode), and everything runs under
`torch.inference_mode()`. It loads the parameters of a `jaxsr.Model` (params and BN state as `apply_model`
uses them) and computes what `apply_model` computes, to about 1e-5 (`check_equivalence`).

Weight layouts. JAX stores a convolution kernel as (kt, kh, kw, Cin, Cout) and applies it as a
cross-correlation (Keras); torch's `conv3d` wants (Cout, Cin, kt, kh, kw), also a cross-correlation, so the
kernel is only transposed (4, 3, 0, 1, 2), never flipped. A 1x1x1 kernel is a matrix: `F.linear` wants
(Cout, Cin) = w[0, 0, 0].T. Batch norm in eval mode is the per-channel affine map x * inv + (shift - mean *
inv) with inv = scale / sqrt(var + eps).

Variants (all give the same result; `compare_torch.py --sweep` times each, so torch gets its best):
- `layout="channels_last"`: activations (B, T, H, W, C) in memory, 1x1x1 convolutions as `F.linear` (one
  GEMM), the others as oneDNN convolutions on channels-last strided views (no copies);
  `layout="channels_first"`: (B, C, T, H, W) (or (B, T, C, H, W) with `conv="taps"`), every convolution a
  torch convolution.
- `conv="native"`: one `F.conv3d` per 3D convolution (frames in the temporal zero padding are convolved);
  `conv="taps"`: a sum over the temporal taps of `F.conv2d` calls with time folded into the batch, skipping
  taps that fall in the zero padding (as `jaxsr.nn.layers.conv3d_taps` does; with one frame, tr = 0, that
  saves 2 of 3 taps).
- `fold_bn=True`: the second batch norm of each block follows a 1x1x1 convolution directly, so it is folded
  into that convolution's weights (a standard inference transformation; exact up to rounding).
- `compile=True`: `torch.compile` (inductor, needs a C++ compiler; works offline).

    python benchmarks/torch_reference.py            # equivalence with jaxsr.apply_model for tr 0..4
"""

from __future__ import annotations


import jax
import numpy as np
import torch
import torch.nn.functional as F

import jaxsr
from jaxsr.config import ModelConfig

__all__ = ["TorchNet", "build_torch_net", "torch_forward", "torch_super_resolve", "random_model", "check_equivalence",
           "VARIANTS"]

LAYOUTS = ("channels_last", "channels_first")
CONVS = ("native", "taps")
# every (layout, conv) combination, for sweeps
VARIANTS = tuple((layout, conv) for layout in LAYOUTS for conv in CONVS)


def _t(a) -> torch.Tensor:
    """float64 NumPy array -> float32 torch tensor (contiguous, owns its memory)."""
    return torch.from_numpy(np.ascontiguousarray(np.asarray(a, np.float64).astype(np.float32)))


def _bn_affine(p, s, eps):
    """Eval-mode batch norm as (inv, offset), float64: y = x * inv + offset."""
    inv = np.asarray(p["scale"], np.float64) / np.sqrt(np.asarray(s["var"], np.float64) + eps)
    return inv, np.asarray(p["shift"], np.float64) - np.asarray(s["mean"], np.float64) * inv


class TorchNet(torch.nn.Module):
    """The 3+TR-block dynamic-upsampling-filter network of `jaxsr.apply_model`, in PyTorch, eval mode only.

    forward(windows): (B, 2 tr + 1, H, W) float32 LR windows -> (B, H r, W r) HR normalised depth.
    Build it with `build_torch_net(model)`; see the module docstring for `layout`, `conv` and `fold_bn`.
    """

    def __init__(self, params, state, cfg: ModelConfig, *, layout="channels_last", conv="taps", fold_bn=True):
        super().__init__()
        if layout not in LAYOUTS:
            raise ValueError(f"TorchNet: layout must be one of {LAYOUTS}, got {layout!r}")
        if conv not in CONVS:
            raise ValueError(f"TorchNet: conv must be one of {CONVS}, got {conv!r}")
        self.cfg, self.layout, self.conv, self.fold_bn = cfg, layout, conv, fold_bn
        # (B, T, H, W, C) or (B, C, T, H, W) or (B, T, C, H, W): which axis holds channels and time
        self._c_axis = {("channels_last", "native"): 4, ("channels_last", "taps"): 4,
                        ("channels_first", "native"): 1, ("channels_first", "taps"): 2}[(layout, conv)]
        self._t_axis = 2 if (layout, conv) == ("channels_first", "native") else 1
        params = jax.tree_util.tree_map(lambda a: np.asarray(a, np.float64), params)
        state = jax.tree_util.tree_map(lambda a: np.asarray(a, np.float64), state)
        eps = cfg.bn_eps
        self.stem = self._conv(params["stem"], pad_t=0)
        self.blocks = []
        for i, (p, s) in enumerate(zip(params["blocks"], state["blocks"])):
            inv1, off1 = _bn_affine(p["bn1"], s["bn1"], eps)
            inv2, off2 = _bn_affine(p["bn2"], s["bn2"], eps)
            w1, b1 = p["conv1"]["w"], p["conv1"]["b"]
            block = {"bn1": (self._channel(inv1), self._channel(off1))}
            if fold_bn:  # bn2(conv1(z)) = z @ (w1 * inv2) + (b1 * inv2 + off2)
                block["conv1"] = self._pointwise({"w": w1 * inv2, "b": b1 * inv2 + off2})
                block["bn2"] = None
            else:
                block["conv1"] = self._pointwise({"w": w1, "b": b1})
                block["bn2"] = (self._channel(inv2), self._channel(off2))
            valid = i >= cfg.same_blocks
            block["valid"] = valid
            block["conv2"] = self._conv(p["conv2"], pad_t=0 if valid else 1)
            self.blocks.append(block)
        inv, off = _bn_affine(params["head"]["bn"], state["head"]["bn"], eps)
        self.head_bn = (self._channel(inv), self._channel(off))
        self.head_conv = self._conv(params["head"]["conv"], pad_t=0)
        # after the head T = 1 and the layout is 2D: (B, H, W, C) for channels_last, (B, C, H, W) otherwise
        self.dense = {name: self._dense(params[g][c])
                      for name, (g, c) in {"res1": ("residual", "conv1"), "res2": ("residual", "conv2"),
                                           "fil1": ("filter", "conv1"), "fil2": ("filter", "conv2")}.items()}

    # ---- parameter conversion ----------------------------------------------------------------------------
    def _channel(self, v):
        """A (C,) vector shaped to broadcast over the channel axis of this layout's 5D activations."""
        shape = [1] * 5
        shape[self._c_axis] = -1
        return _t(v).reshape(shape)

    def _pointwise(self, p):
        """A 1x1x1 convolution: F.linear weights (Cout, Cin) for channels_last, else a conv2d/conv3d kernel."""
        w, b = np.asarray(p["w"])[0, 0, 0], np.asarray(p["b"])  # (Cin, Cout)
        if self.layout == "channels_last":
            return ("linear", _t(w.T), _t(b))
        if self.conv == "native":
            return ("conv3d", _t(w.T[:, :, None, None, None]), _t(b))
        return ("conv2d", _t(w.T[:, :, None, None]), _t(b))

    def _conv(self, p, *, pad_t):
        """A (kt, kh, kw) convolution, zero-padded 'same' in H and W and by pad_t in T."""
        w, b = np.asarray(p["w"]), np.asarray(p["b"])  # (kt, kh, kw, Cin, Cout)
        kt, kh, kw = w.shape[:3]
        pads = (pad_t, (kh - 1) // 2, (kw - 1) // 2)
        if self.conv == "native":
            w5 = _t(w.transpose(4, 3, 0, 1, 2))  # (Cout, Cin, kt, kh, kw)
            if self.layout == "channels_last":
                w5 = w5.contiguous(memory_format=torch.channels_last_3d)
            return ("conv3d", w5, _t(b), pads)
        taps = [_t(w[k].transpose(3, 2, 0, 1)) for k in range(kt)]  # (Cout, Cin, kh, kw) per temporal tap
        if self.layout == "channels_last":
            taps = [t.contiguous(memory_format=torch.channels_last) for t in taps]
        return ("taps", taps, _t(b), pads)

    def _dense(self, p):
        w, b = np.asarray(p["w"])[0, 0, 0], np.asarray(p["b"])
        if self.layout == "channels_last":
            return (_t(w.T), _t(b))
        return (_t(w.T[:, :, None, None]), _t(b))

    # ---- layers --------------------------------------------------------------------------------------------
    def _apply_pointwise(self, x, layer):
        kind, w, b = layer
        if kind == "linear":
            return F.linear(x, w, b)
        if kind == "conv3d":
            return F.conv3d(x, w, b)
        bsz, t = x.shape[:2]  # (B, T, C, H, W)
        y = F.conv2d(x.reshape(bsz * t, *x.shape[2:]), w, b)
        return y.reshape(bsz, t, *y.shape[1:])

    def _apply_conv(self, x, layer):
        kind, w, b, (pt, ph, pw) = layer
        if kind == "conv3d":
            if self.layout == "channels_last":  # (B, T, H, W, C) seen as a channels_last_3d NCDHW tensor
                y = F.conv3d(x.permute(0, 4, 1, 2, 3), w, b, padding=(pt, ph, pw))
                return y.permute(0, 2, 3, 4, 1)
            return F.conv3d(x, w, b, padding=(pt, ph, pw))
        # taps: output frame t reads input frame t + k - pt; taps in the zero padding are skipped. The first
        # tap that covers every output frame (the middle one) starts the sum and carries the bias.
        bsz, t_in = x.shape[:2]
        kt = len(w)
        t_out = t_in + 2 * pt - kt + 1
        spans = [(k, max(0, pt - k), min(t_out, t_in + pt - k)) for k in range(kt)]
        spans = [s for s in spans if s[2] > s[1]]
        spans.sort(key=lambda s: (s[1], s[2]) != (0, t_out))  # a full-span tap first (stable otherwise)
        y = None
        for k, t0, t1 in spans:
            o = k - pt
            full = (t0, t1) == (0, t_out)
            xs = x[:, t0 + o : t1 + o]
            xs = xs.reshape(bsz * (t1 - t0), *xs.shape[2:])
            bias = b if y is None and full else None
            if self.layout == "channels_last":
                yk = F.conv2d(xs.permute(0, 3, 1, 2), w[k], bias, padding=(ph, pw)).permute(0, 2, 3, 1)
            else:
                yk = F.conv2d(xs, w[k], bias, padding=(ph, pw))
            yk = yk.reshape(bsz, t1 - t0, *yk.shape[1:])
            if y is None:
                if full:
                    y = yk.contiguous()
                else:
                    y = yk.new_zeros((bsz, t_out, *yk.shape[2:]))
                    y[:, t0:t1] = yk
                    bias_shape = [1] * y.ndim
                    bias_shape[-1 if self.layout == "channels_last" else 2] = -1
                    y += b.reshape(bias_shape)
            else:
                y[:, t0:t1] += yk
        if y is None:
            raise ValueError(f"TorchNet: {t_in} frames (padded by {pt}) are fewer than the temporal kernel {kt}")
        return y

    @staticmethod
    def _bn_relu(x, bn):
        inv, off = bn
        return torch.relu_(torch.addcmul(off, x, inv))

    def _dense_apply(self, z, layer):
        w, b = layer
        return F.linear(z, w, b) if self.layout == "channels_last" else F.conv2d(z, w, b)

    # ---- the network ---------------------------------------------------------------------------------------
    def forward(self, windows: torch.Tensor) -> torch.Tensor:
        cfg = self.cfg
        c_ax, t_ax = self._c_axis, self._t_axis
        x = windows.unsqueeze(c_ax)  # (B, T, H, W) -> the layout's 5D form with C = 1
        x = self._apply_conv(x, self.stem)
        for block in self.blocks:
            y = self._bn_relu(x, block["bn1"])
            y = self._apply_pointwise(y, block["conv1"])
            y = torch.relu_(y) if block["bn2"] is None else self._bn_relu(y, block["bn2"])
            y = self._apply_conv(y, block["conv2"])
            if block["valid"]:  # the skip path keeps the middle frames
                x = x.narrow(t_ax, 1, x.shape[t_ax] - 2)
            x = torch.cat([x, y], dim=c_ax)
        h = self._bn_relu(x, self.head_bn)
        h = torch.relu_(self._apply_conv(h, self.head_conv))
        h = h.select(t_ax, 0)  # T = 1: (B, H, W, C) or (B, C, H, W)
        residual = self._dense_apply(torch.relu_(self._dense_apply(h, self.dense["res1"])), self.dense["res2"])
        logits = self._dense_apply(torch.relu_(self._dense_apply(h, self.dense["fil1"])), self.dense["fil2"])
        r, size = cfg.scale, cfg.filter_size
        r2, taps, c = r * r, size * size, size // 2
        centre = windows[:, cfg.tr]  # (B, H, W)
        bsz, hh, ww = centre.shape
        mode = "replicate" if cfg.filter_padding == "edge" else "constant"
        padded = F.pad(centre.unsqueeze(1), (c, c, c, c), mode=mode)[:, 0]  # (B, H + 2c, W + 2c)
        if self.layout == "channels_last":
            filters = torch.softmax(logits.reshape(bsz, hh, ww, taps, r2), dim=-2)
            patches = torch.stack([padded[:, i : i + hh, j : j + ww] for i in range(size) for j in range(size)], -1)
            sub = torch.einsum("bhwk,bhwks->bhws", patches, filters) + residual  # (B, H, W, r^2)
            sub = sub.permute(0, 3, 1, 2)
        else:
            filters = torch.softmax(logits.reshape(bsz, taps, r2, hh, ww), dim=1)
            patches = torch.stack([padded[:, i : i + hh, j : j + ww] for i in range(size) for j in range(size)], 1)
            sub = (patches.unsqueeze(2) * filters).sum(1) + residual  # (B, r^2, H, W)
        # sub-pixel s = dy * r + dx -> HR pixel (r y + dy, r x + dx): torch's pixel_shuffle with one channel
        return F.pixel_shuffle(sub, r)[:, 0]


def build_torch_net(model: jaxsr.Model, *, layout: str = "channels_last", conv: str = "taps", fold_bn: bool = True,
                    compile: bool = False):
    """The torch port of `model` (a `jaxsr.Model`), in eval mode. With `compile=True`, `torch.compile`d
    (the first call compiles). Returns a callable module for `torch_forward`."""
    net = TorchNet(model.params, model.state, model.config, layout=layout, conv=conv, fold_bn=fold_bn).eval()
    if compile:
        net = torch.compile(net, dynamic=False)
    return net


def torch_forward(torch_net, windows_np) -> np.ndarray:
    """Run the port on LR windows: (B, 2 tr + 1, H, W) NumPy -> (B, H r, W r) float32 NumPy."""
    windows = torch.from_numpy(np.ascontiguousarray(windows_np, dtype=np.float32))
    with torch.inference_mode():
        return torch_net(windows).numpy()


def torch_super_resolve(torch_net, lr_seq, *, batch_size: int = 1) -> np.ndarray:
    """The port's `jaxsr.super_resolve`: (T, h, w) LR sequence -> (T, h r, w r) float32 NumPy.

    Frame t is the centre of the edge-replicated window clip(t - tr .. t + tr, 0, T - 1) (as
    `jaxsr.temporal.windows`); windows go through the network `batch_size` at a time, the last batch padded
    by repeating its final window so that every call has one shape (as `jaxsr.super_resolve` does, which
    keeps a compiled torch module to one compilation and the work the same as on the JAX side)."""
    cfg = getattr(torch_net, "_orig_mod", torch_net).cfg
    lr_seq = np.asarray(lr_seq, np.float32)
    n, h, w = lr_seq.shape
    r = cfg.scale
    idx = np.clip(np.arange(n)[:, None] + np.arange(-cfg.tr, cfg.tr + 1)[None, :], 0, n - 1)
    out = np.empty((n, h * r, w * r), np.float32)
    for start in range(0, n, batch_size):
        rows = idx[start : start + batch_size]
        count = rows.shape[0]
        if count < batch_size:
            rows = np.concatenate([rows, np.repeat(rows[-1:], batch_size - count, 0)])
        out[start : start + count] = torch_forward(torch_net, lr_seq[rows])[:count]
    return out


def random_model(tr: int, *, seed: int = 0, **cfg_fields) -> jaxsr.Model:
    """A randomly initialised `jaxsr.Model` (`init_model(jax.random.key(seed), ModelConfig(tr=tr))`) with
    random biases, BN scales, shifts and running statistics too, so that no conversion can hide behind a
    zero or a one (means and shifts ~ N(0, 0.1), scales and variances ~ U(0.5, 1.5), biases ~ N(0, 0.02))."""
    cfg = ModelConfig(tr=tr, **cfg_fields)
    params, state = jaxsr.init_model(jax.random.key(seed), cfg)
    rng = np.random.default_rng(seed + 1)

    def perturb(path, a):
        name = getattr(path[-1], "key", None)
        if name in ("mean", "shift"):
            return rng.normal(0.0, 0.1, a.shape).astype(np.float32)
        if name in ("var", "scale"):
            return rng.uniform(0.5, 1.5, a.shape).astype(np.float32)
        if name == "b":
            return rng.normal(0.0, 0.02, a.shape).astype(np.float32)
        return np.asarray(a)

    params = jax.tree_util.tree_map_with_path(perturb, params)
    state = jax.tree_util.tree_map_with_path(perturb, state)
    return jaxsr.Model(params, state, cfg)


# the reference: jaxsr's own network, jitted once per config and shape
apply_model_jit = jax.jit(jaxsr.apply_model, static_argnums=3)


def check_equivalence(trs=range(5), *, batch: int = 2, lr_shape=(16, 32), seed: int = 0, atol: float = 1e-4,
                      variants=VARIANTS, fold_bn=(True, False), verbose: bool = False, **cfg_fields) -> dict:
    """Compare `torch_forward` with `jaxsr.apply_model` on random windows for random models, every tr in `trs`
    and every (layout, conv) variant and `fold_bn` setting; `cfg_fields` go to `ModelConfig` (e.g.
    `filter_padding="zero"`, `scale=8`). Returns {(tr, layout, conv, fold_bn): max abs error}; raises
    AssertionError when one exceeds `atol`."""
    errors = {}
    for tr in trs:
        model = random_model(tr, seed=seed, **cfg_fields)
        rng = np.random.default_rng(seed + tr)
        windows = rng.uniform(0.0, 1.0, (batch, model.config.frames, *lr_shape)).astype(np.float32)
        ref = np.asarray(apply_model_jit(model.params, model.state, windows, model.config))
        for layout, conv in variants:
            for fold in fold_bn:
                out = torch_forward(build_torch_net(model, layout=layout, conv=conv, fold_bn=fold), windows)
                if out.shape != ref.shape:
                    raise AssertionError(f"tr={tr} {layout}/{conv}: shape {out.shape} != {ref.shape}")
                err = float(np.max(np.abs(out - ref)))
                errors[(tr, layout, conv, fold)] = err
                if verbose:
                    print(f"tr={tr} {layout:14s} {conv:6s} fold_bn={fold!s:5s} max|torch - jax| = {err:.2e} "
                          f"(output range {ref.min():.3f} .. {ref.max():.3f})")
    bad = {k: v for k, v in errors.items() if not v <= atol}
    if bad:
        raise AssertionError(f"torch port differs from apply_model by more than {atol}: {bad}")
    return errors


if __name__ == "__main__":
    torch.set_num_threads(max(1, min(2, torch.get_num_threads())))
    errs = check_equivalence(verbose=True)
    print(f"all {len(errs)} comparisons within 1e-4; largest {max(errs.values()):.2e}")
