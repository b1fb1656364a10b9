"""What a network reads per LR pixel, built from photon histograms (`ModelConfig.inputs`).

"depth" is the centre-of-mass depth (normalised, 1.0 = no return), the only input of the paper's networks.
"signal" and "background" are the photons behind it (`jaxsr.sensor.peak_evidence`): the counts in the peak
above the background, and the ambient photons of the whole gate, each encoded as log(1 + photons) /
log(1 + PHOTON_SCALE), so that 1 to 1000 photons span [0.1, 1] evenly in ratio and a network sees the same
range at every light level. With them a network can tell "no return" (little signal against the background)
from a surface in mid-gate, which the centre of mass alone cannot. "ambient" is the ambient photons again, from
the mean of the bins outside the peak (`jaxsr.sensor.ambient_photons`): the median that "background" takes is 0
in most pixels at a few photons whatever the ambient light, so only this channel tells SNR 1 from SNR 50 there.
"""

from __future__ import annotations

import jax.numpy as jnp

from ..config import MODEL_INPUTS, Sensor
from ..sensor.gates import gate_to_network
from ..sensor.peaks import ambient_photons, centre_of_mass, peak_evidence

__all__ = ["PHOTON_SCALE", "encode_photons", "network_inputs"]

PHOTON_SCALE = 1000.0  # photons per LR pixel at which an encoded channel reaches 1


def encode_photons(photons):
    """Photon counts (>= 0) -> log(1 + photons) / log(1 + PHOTON_SCALE): 0 -> 0, 1000 -> 1, finite for any
    finite count and monotone, with gradient 1 / ((1 + photons) log 1001) bounded by 0.145."""
    return jnp.log1p(jnp.maximum(photons, 0.0)) / jnp.log1p(PHOTON_SCALE)


def network_inputs(counts, sensor: Sensor = Sensor(), inputs=("depth",)):
    """The network's input from histograms: (..., K) counts -> (..., ) depth for inputs ("depth",), else
    (..., len(inputs)) channels in the order of `inputs` (depth first). The depth is the centre of mass on the
    sensor's depth scale (`jaxsr.sensor.gates.gate_to_network`: the gate's start at `sensor.depth.offset` metres
    and so on; for the paper's sensor, `centre_of_mass` itself). Counts as `centre_of_mass` takes them (finite,
    >= 0; traced, an unusable histogram is no return with signal and background 0). jit/vmap-able."""
    inputs = tuple(inputs)
    if not inputs or inputs[0] != "depth" or not set(inputs) <= set(MODEL_INPUTS):
        raise ValueError(f"network_inputs: inputs must be 'depth' then names of {MODEL_INPUTS}, got {inputs}")
    depth = gate_to_network(centre_of_mass(counts, sensor), sensor)
    if inputs == ("depth",):
        return depth
    signal, background = peak_evidence(counts, sensor)
    channel = {"depth": depth, "signal": encode_photons(signal), "background": encode_photons(background)}
    if "ambient" in inputs:
        channel["ambient"] = encode_photons(ambient_photons(counts, sensor))
    return jnp.stack([channel[name] for name in inputs], axis=-1).astype(depth.dtype)
