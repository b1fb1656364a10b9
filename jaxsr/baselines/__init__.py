"""What the network is compared with: bicubic and Lanczos interpolation, TV-regularised multi-frame
reconstruction, and the learned baselines HistNet and iSeeBetter (RBPN generator + GAN).
"""

from .interpolation import (
    keys_cubic,
    lanczos_kernel,
    resampling_matrix,
    bicubic,
    lanczos,
)
from .tv import (
    DEFAULT_LAM,
    DEFAULT_EPS,
    DEFAULT_DELTA,
    DEFAULT_NEIGHBOUR_WEIGHT,
    DEFAULT_MAX_STEPS,
    block_mean,
    smoothed_tv,
    charbonnier,
    tv_super_resolve,
)
from .flow import (
    warp,
    optical_flow,
)
from .histnet import (
    HistNetConfig,
    second_peak_depth,
    histnet_features,
    init_histnet,
    apply_histnet_features,
    apply_histnet,
    HISTNET,
)
from .rbpn import (
    RBPNConfig,
    init_rbpn,
    rbpn_flows,
    apply_rbpn,
    init_discriminator,
    apply_discriminator,
    tv_loss,
    generator_loss,
    discriminator_loss,
    ISEEBETTER,
)

__all__ = [
    "keys_cubic",
    "lanczos_kernel",
    "resampling_matrix",
    "bicubic",
    "lanczos",
    "DEFAULT_LAM",
    "DEFAULT_EPS",
    "DEFAULT_DELTA",
    "DEFAULT_NEIGHBOUR_WEIGHT",
    "DEFAULT_MAX_STEPS",
    "block_mean",
    "smoothed_tv",
    "charbonnier",
    "tv_super_resolve",
    "warp",
    "optical_flow",
    "HistNetConfig",
    "second_peak_depth",
    "histnet_features",
    "init_histnet",
    "apply_histnet_features",
    "apply_histnet",
    "HISTNET",
    "RBPNConfig",
    "init_rbpn",
    "rbpn_flows",
    "apply_rbpn",
    "init_discriminator",
    "apply_discriminator",
    "tv_loss",
    "generator_loss",
    "discriminator_loss",
    "ISEEBETTER",
]
