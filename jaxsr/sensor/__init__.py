"""The SPAD sensor: the forward model from depth and intensity to photon histograms, Poisson sampling,
calibration to a frame SNR, time gates, photon time tags, and depth extraction (centre of mass, maximum
likelihood).
"""

from .forward import (
    planar_to_radial,
    pixel_rays,
    ray_norm,
    has_return,
    normalise_depth,
    denormalise_depth,
    irf_bin_weights,
    check_photon_args,
    calibrate,
    expected_histograms,
    calibrated_rates,
    simulate_histograms,
)
from .poisson import (
    EXACT_BELOW,
    NORMAL_ABOVE,
    PATHWISE_ESTIMATORS,
    sample_poisson,
    poisson_pathwise,
)
from .peaks import (
    NO_RETURN,
    median_of_bins,
    default_window,
    centre_of_mass,
    maximum_likelihood_depth,
)
from .gates import (
    gate_depth,
    to_network_depth,
    from_network_depth,
    gate_warnings,
)
from .timetags import (
    TIME_TAG_FORMATS,
    TimeTags,
    time_tags_from_cells,
    read_time_tags,
    histogram_photons,
    gate_of_tags,
    histogram_time_tags,
)

__all__ = [
    "planar_to_radial",
    "pixel_rays",
    "ray_norm",
    "has_return",
    "normalise_depth",
    "denormalise_depth",
    "irf_bin_weights",
    "check_photon_args",
    "calibrate",
    "expected_histograms",
    "calibrated_rates",
    "simulate_histograms",
    "EXACT_BELOW",
    "NORMAL_ABOVE",
    "PATHWISE_ESTIMATORS",
    "sample_poisson",
    "poisson_pathwise",
    "NO_RETURN",
    "median_of_bins",
    "default_window",
    "centre_of_mass",
    "maximum_likelihood_depth",
    "gate_depth",
    "to_network_depth",
    "from_network_depth",
    "gate_warnings",
    "TIME_TAG_FORMATS",
    "TimeTags",
    "time_tags_from_cells",
    "read_time_tags",
    "histogram_photons",
    "gate_of_tags",
    "histogram_time_tags",
]
