"""jaxsr: video super-resolution of single-photon (SPAD) lidar depth, in pure functional JAX.

The public API is re-exported here; see README.md and DESIGN.md for the pipeline.
"""

__version__ = "0.1.0"

from .baselines import bicubic as bicubic
from .baselines import lanczos as lanczos
from .config import DEFAULT_MEAN_SIGNAL as DEFAULT_MEAN_SIGNAL
from .config import SensorConfig as SensorConfig
from .metrics import TemporalCoherence as TemporalCoherence
from .metrics import psnr as psnr
from .metrics import ssim as ssim
from .metrics import ssim_global as ssim_global
from .metrics import temporal_coherence as temporal_coherence
from .peaks import centre_of_mass as centre_of_mass
from .peaks import maximum_likelihood_depth as maximum_likelihood_depth
from .poisson import sample_poisson as sample_poisson
from .sensor import calibrate as calibrate
from .sensor import expected_histograms as expected_histograms
from .sensor import normalise_depth as normalise_depth
from .sensor import planar_to_radial as planar_to_radial
from .sensor import simulate_histograms as simulate_histograms
