"""HistNet (Ruget et al. 2021): histogram-based depth super-resolution guided by an HR intensity image.

Followed: A. Ruget, S. McLaughlin, R. K. Henderson, I. Gyongy, A. Halimi and J. Leach, "Robust super-resolution
depth imaging via a multi-feature fusion deep network", Optics Express 29(8), 11917 (2021), and its public
TensorFlow code (HWQuantum/HistNet, `model_network_hist.py`, `create_test_synthetic.py`), read and re-written.

Inputs built from the LR photon histograms (`histnet_features`, all at fixed fractions of the HR size H x W,
which must be divisible by 16; x4 sensor):
- D1: first-peak depth, the centre of mass of each LR histogram, nearest-upsampled to H x W (the paper's input
  depth and the skip that the output residual is added to);
- D2: second-peak depth: each histogram with its first peak (argmax +- 2 bins) replaced by the median, kept where
  its maximum exceeds b + 4 sqrt(b) (Ruget's "level" 4 used in training), its centre of mass, upsampled;
- multi-scale depth features from the histograms downsampled by summing neighbourhoods: H/2 (the LR depth
  upsampled x2), H/4 (the LR depth), H/8 and H/16 (centre of mass of 2x2- and 4x4-summed LR histograms);
- the HR intensity image (B, H, W).
Network (published widths, `width` = 64): an intensity branch (3x3 convs 1 -> 64, pool, 64 -> 128, pool, 128 ->
256, pool, 256 -> 512, ReLU) and a U-Net on [D1, D2]: encoder levels of two 3x3 convs (64, 128, 256, 512, 1024
channels) separated by 2x2 max pools, where after each pool the depth feature of that scale (one 3x3 conv 1 ->
as many channels as the pooled features) is concatenated; decoder: 3x3 stride-2 transposed conv halving the
channels, concatenated with the encoder skip and the intensity feature of that scale, two 3x3 convs; a final 3x3
conv to 1 channel, added to D1. ReLU after every conv but the last.

Where we chose / deviated:
- Our centre of mass (`jaxsr.centre_of_mass`: median background, window +-1 or 2 bins) replaces Ruget's (+-1 bin
  around the argmax, no background subtraction); invalid pixels are 1.0 ("no return", our convention) where
  Ruget's code divided by zero.
- The published code declares the first intensity-decoder conv as 1024 -> 512 and the first decoder conv as
  3072 -> 512, but its `conv2d` takes the input width from the tensor: the built network has 256 -> 512 and
  1536 -> 512, which is what is built here (45,473,025 parameters at width 64).
- He-normal init instead of the code's N(0, 0.02) (a 45 M-parameter U-Net at 0.02 starts with vanishing
  activations); the transposed conv's kernel is not flipped (re-parametrisation). Loss L1 (the code's
  `--loss_type l1`).
- The HR intensity: Ruget used the sum of the (simulated) HR histograms, min-max normalised; our data source gives
  the rendered HR intensity in [0, 1] (see `jaxsr.training.baselines.histogram_batches`).
- `width` scales every channel count (width 16: 2.8 M parameters, near TR4's 2.25 M) for CPU training.
"""

from __future__ import annotations

import dataclasses
import functools
import numbers

import jax
import jax.numpy as jnp

from ..config import MODEL_LIMITS, Sensor, check_int_field
from ..nn.model import Architecture, register_architecture
from ..nn.layers import conv2d, conv2d_transpose, init_conv2d, init_from_normals, max_pool2
from ..sensor.peaks import centre_of_mass, median_of_bins

__all__ = ["HistNetConfig", "histnet_features", "second_peak_depth", "init_histnet", "apply_histnet",
           "apply_histnet_features"]
_SENSOR = Sensor()  # the default sensor

_DEPTH_KEYS = ("pool1", "pool2", "pool3", "pool4")


@dataclasses.dataclass(frozen=True)
class HistNetConfig:
    """HistNet sizes: `width` channels at full resolution, doubled at each of the 4 pooled levels (published 64),
    `second_peak_z` the significance (in sqrt(background)) a second peak needs (Ruget's level, 4), `peak_half`
    the half-width in bins of the first peak removed before the second is looked for (2). Bounded by
    `jaxsr.config.MODEL_LIMITS` (width 1..256, so 16 x width <= its channel limit; ValueError otherwise)."""

    width: int = 64
    second_peak_z: float = 4.0
    peak_half: int = 2

    def __post_init__(self):
        # bounded like `ModelConfig` (`MODEL_LIMITS`): a config read from a file builds its template level by level,
        # and a width of 10^6 (a damaged or hostile checkpoint) would ask for absurd kernels before any shape is
        # checked; every level's channels (width * 16 at the bottom) stay within the width limit
        check_int_field("HistNetConfig", "width", self.width, 1, MODEL_LIMITS["width"] // 16,
                        f" channels (the bottom level has 16 x width, at most {MODEL_LIMITS['width']})")
        z = self.second_peak_z
        if isinstance(z, bool) or not isinstance(z, numbers.Real) or not 0 <= z < float("inf"):
            raise ValueError(f"HistNetConfig: second_peak_z must be a finite number >= 0, got {z!r}")
        check_int_field("HistNetConfig", "peak_half", self.peak_half, 0, MODEL_LIMITS["bins"], " bins")

    def widths(self) -> tuple[int, ...]:
        """Channels of the 5 encoder levels: width * (1, 2, 4, 8, 16)."""
        return tuple(self.width * 2**i for i in range(5))


def second_peak_depth(counts, cfg: HistNetConfig = HistNetConfig(), *, sensor: Sensor = _SENSOR):
    """Ruget's second-peak depth: the first peak (argmax +- peak_half bins) replaced by the median, then the
    centre of mass of what is left where its peak is significant (z = second_peak_z), else 1.0 (no return).

    counts: (..., K) photon counts. Returns (...) normalised depth in [0, 1].
    """
    n = jnp.asarray(counts, jnp.float32)
    k = jnp.arange(n.shape[-1])
    first = jnp.abs(k - jnp.argmax(n, axis=-1)[..., None]) <= cfg.peak_half
    rest = jnp.where(first, median_of_bins(n)[..., None], n)
    return centre_of_mass(rest, sensor, z=cfg.second_peak_z)


def _up(x, r):
    return jnp.repeat(jnp.repeat(x, r, axis=-2), r, axis=-1)


def _pooled_histograms(counts, r):
    """Sum r x r neighbourhoods of LR histograms: (B, h, w, K) -> (B, h / r, w / r, K)."""
    b, h, w, k = counts.shape
    return counts.reshape(b, h // r, r, w // r, r, k).sum(axis=(2, 4))


def histnet_features(counts, cfg: HistNetConfig = HistNetConfig(), *, sensor: Sensor = _SENSOR):
    """HistNet's depth inputs from LR photon histograms (x4 sensor).

    counts: (B, h, w, K) with h, w divisible by 4 (H = 4h, W = 4w). Returns {"d1": (B, H, W) first-peak depth,
    "d2": (B, H, W) second-peak depth, "pool1": (B, H/2, W/2), "pool2": (B, h, w), "pool3": (B, h/2, w/2),
    "pool4": (B, h/4, w/4)}, normalised depth in [0, 1] (1 = no return).
    """
    if counts.ndim != 4 or counts.shape[-1] != sensor.bins or sensor.scale != 4:
        raise ValueError(f"histnet_features: expected counts (B, h, w, {sensor.bins}) of a x4 sensor, got "
                         f"{counts.shape} (scale {sensor.scale})")
    if counts.shape[1] % 4 or counts.shape[2] % 4:
        raise ValueError(f"histnet_features: LR frame {counts.shape[1:3]} must be divisible by 4 (HR by 16)")
    counts = jnp.asarray(counts, jnp.float32)
    lr = centre_of_mass(counts, sensor)
    return {
        "d1": _up(lr, 4),
        "d2": _up(second_peak_depth(counts, cfg, sensor=sensor), 4),
        "pool1": _up(lr, 2),
        "pool2": lr,
        "pool3": centre_of_mass(_pooled_histograms(counts, 2), sensor),
        "pool4": centre_of_mass(_pooled_histograms(counts, 4), sensor),
    }


def init_histnet(key, cfg: HistNetConfig = HistNetConfig()) -> dict:
    """Initial HistNet parameters (He-normal 3x3 kernels, zero biases).

    Returns {"intensity": [4 convs], "encoder": [[2 convs] * 5], "depth_in": [4 convs (3, 3, 1, c)],
    "up": [4 transposed convs (3, 3, c, c/2)], "decoder": [[2 convs] * 4], "out": (3, 3, width, 1)}, each conv
    {"w": (3, 3, cin, cout), "b": (cout,)}. Jitted (one compilation instead of one per kernel shape).
    """
    return _init_histnet(key, cfg)


@functools.partial(jax.jit, static_argnums=1)
def _init_histnet(key, cfg: HistNetConfig) -> dict:
    return init_from_normals(key, lambda normal: _build_histnet(normal, cfg))


def _build_histnet(normal, cfg: HistNetConfig) -> dict:
    c = cfg.widths()
    conv = lambda cin, cout: init_conv2d(normal, 3, cin, cout)
    intensity = [conv(1, c[0]), conv(c[0], c[1]), conv(c[1], c[2]), conv(c[2], c[3])]
    encoder, depth_in, cin = [], [], 2
    for i in range(5):
        if i > 0:
            depth_in.append(conv(1, c[i - 1]))
            cin = 2 * c[i - 1]
        encoder.append([conv(cin, c[i]), conv(c[i], c[i])])
    up, decoder = [], []
    for i in range(4, 0, -1):  # from the bottom: c[i] -> c[i-1], concat skip and intensity: 3 c[i-1]
        up.append(conv(c[i], c[i - 1]))
        decoder.append([conv(3 * c[i - 1], c[i - 1]), conv(c[i - 1], c[i - 1])])
    return {"intensity": intensity, "encoder": encoder, "depth_in": depth_in, "up": up, "decoder": decoder,
            "out": conv(c[0], 1)}


def apply_histnet_features(params, features: dict, intensity):
    """HistNet's network on precomputed `histnet_features` and the HR intensity.

    features: as `histnet_features` returns ((B, H, W) d1, d2, ... pool4); intensity: (B, H, W) in [0, 1].
    Returns (B, H, W) HR normalised depth (D1 + the predicted residual; not clipped).
    """
    relu = jax.nn.relu
    x = intensity[..., None]
    guide = []
    for i, p in enumerate(params["intensity"]):  # features at H, H/2, H/4, H/8
        x = relu(conv2d(p, max_pool2(x) if i else x))
        guide.append(x)
    x = jnp.stack([features["d1"], features["d2"]], axis=-1)
    skips = []
    for i, (c1, c2) in enumerate(params["encoder"]):
        if i:
            pooled = max_pool2(skips[-1])
            side = relu(conv2d(params["depth_in"][i - 1], features[_DEPTH_KEYS[i - 1]][..., None]))
            x = jnp.concatenate([pooled, side], axis=-1)
        x = relu(conv2d(c2, relu(conv2d(c1, x))))
        skips.append(x)
    for j, (up, (c1, c2)) in enumerate(zip(params["up"], params["decoder"])):
        level = 3 - j  # the skip and intensity features of this scale
        x = relu(conv2d_transpose(up, x, stride=2, padding=(0, 1)))
        x = jnp.concatenate([x, skips[level], guide[level]], axis=-1)
        x = relu(conv2d(c2, relu(conv2d(c1, x))))
    return features["d1"] + conv2d(params["out"], x)[..., 0]


def apply_histnet(params, counts, intensity, cfg: HistNetConfig = HistNetConfig(), *,
                  sensor: Sensor = _SENSOR):
    """HistNet: LR photon histograms + HR intensity -> HR depth.

    counts: (B, h, w, K) photon counts (h, w divisible by 4); intensity: (B, 4h, 4w) HR intensity in [0, 1].
    Returns (B, 4h, 4w) HR normalised depth (not clipped).
    """
    features = histnet_features(counts, cfg, sensor=sensor)
    if intensity.shape != features["d1"].shape:
        raise ValueError(f"apply_histnet: intensity {intensity.shape} must be the HR frame {features['d1'].shape}")
    return apply_histnet_features(params, features, intensity)


def _apply(params, state, inputs, cfg: HistNetConfig, *, sensor: Sensor = _SENSOR, conv3d_impl: str = "auto"):
    counts, intensity = inputs
    return apply_histnet(params, counts, intensity, cfg, sensor=sensor)


HISTNET = register_architecture(Architecture("histnet", HistNetConfig, lambda key, cfg: (init_histnet(key, cfg), {}),
                                             _apply, inputs="histograms", frames=lambda cfg: 1, scale=lambda cfg: 4,
                                             input_radius=lambda cfg: 0))
