"""What a recording's photons say, and the photon rules of `jaxsr upscale` that follow from it: the frame SNR and
signal photons per pixel (`photon_levels`), the ambient-only test's rate where `PhotonRules.ambient_alpha` is
"auto" (`auto_ambient_alpha`), the keep rule's, and the warnings where a model meets photon levels it was not
trained on.
"""

from __future__ import annotations

import itertools
from typing import NamedTuple

import numpy as np

from ..config import TRAINED_RANGE_M, Gate, Sensor
from ..sensor.peaks import frame_levels
from .specs import PhotonRules, is_auto

__all__ = ["HEAD_FRAMES", "AUTO_KEEP_RETURNS", "AUTO_AMBIENT_ALPHA", "AUTO_AMBIENT_MIN_SNR",
           "AUTO_AMBIENT_MIN_SIGNAL_SNR", "AUTO_AMBIENT_MIN_FRAMES", "FEW_PHOTONS", "AMBIENT_FRAMES", "PhotonLevels",
           "photon_levels", "auto_ambient_alpha", "PhotonDecision", "decide_photon_rules", "few_photons_warnings",
           "snr_warnings", "rule_warnings"]

HEAD_FRAMES = 64  # frames model="auto" measures the motion on, and the frame SNR is estimated from
# ambient_alpha="auto" (the default for histograms and time tags): the ambient-only test at this false-alarm rate
# where the recording's estimated frame SNR is at least AUTO_AMBIENT_MIN_SNR, or its signal photons per pixel and
# frame times that SNR (signal^2 / ambient photons: how far one pixel's return stands out of its ambient light) at
# least AUTO_AMBIENT_MIN_SIGNAL_SNR (experiments/results/upscale_defaults.md)
AUTO_AMBIENT_ALPHA = 1e-3
AUTO_AMBIENT_MIN_SNR = 1.0
AUTO_AMBIENT_MIN_SIGNAL_SNR = 5.0
# frames the SNR is read from before "auto" trusts it: fewer read high at a few photons (at SNR 0.8 and 3 photons,
# 0.91-0.99 from 16 frames, 1.09-1.29 from 8, 3.2-4.0 from one), and the rule was measured on 64
AUTO_AMBIENT_MIN_FRAMES = 16
# below this many estimated signal photons per LR pixel and frame, a model reading depth alone is told that the
# photon model may serve better (experiments/results/upscale_defaults.md: +5.8 dB on the simulated test scenes
# there, but not on every real recording, so it stays a hint)
FEW_PHOTONS = 3.0
# keep_returns="auto": for a model with a no-return head on histograms and time tags, the confidence's no return kept
# only where the photons pass for ambient light alone at this rate (`jaxsr.inference.iter_quiet`; before the
# confidence and the pools: the head's, with the pixel's own photons). On the real tower recording that turned
# tr4-ambient's head alone (+2.4 to -10.4 dB against bicubic on a dim building at 1-8 photons) into +3.5 to +4.7 dB,
# for 0.1-0.5 dB in simulation at 100-1000 photons (the sky at the edges of sky regions shown as depth)
AUTO_KEEP_RETURNS = 1e-3
AMBIENT_FRAMES = 9  # frames the no-return tests of `ambient_alpha` and `keep_returns` sum (`iter_ambient_only`'s)


# `snr_warnings` speaks beyond this factor outside the trained SNRs: `frame_snr` reads up to 1.5-3x high from a few
# frames of few bins (noise in the peak's window) and low for moving scenes, so the edge itself is no evidence
SNR_WARNING_MARGIN = 2.0


class PhotonLevels(NamedTuple):
    """What a recording's photons say about it (`photon_levels`): its frame SNR (`jaxsr.sensor.frame_snr`) and
    its signal photons per LR pixel with a return and frame (`jaxsr.sensor.signal_photons`); NaN where no
    return is seen."""

    snr: float
    signal: float


def photon_levels(counts, bins: int) -> PhotonLevels:
    """The `PhotonLevels` of a recording's first HEAD_FRAMES frames of (h, w, bins) counts (any iterable of
    frames), summed frame by frame: one frame's memory, not HEAD_FRAMES'."""
    head, frames = None, 0
    for frame in itertools.islice(counts, HEAD_FRAMES):
        head = np.asarray(frame, np.float32) if head is None else head + frame
        frames += 1
    # of the sum: one frame's worth of signal
    snr, signal = frame_levels(head, Sensor(gate=Gate.spanning(TRAINED_RANGE_M, bins)))
    return PhotonLevels(snr, signal / frames)


def auto_ambient_alpha(snr: float, signal: float = float("nan"), *, min_snr: float = AUTO_AMBIENT_MIN_SNR,
                       min_signal_snr: float = AUTO_AMBIENT_MIN_SIGNAL_SNR) -> float | None:
    """The false-alarm rate `ambient_alpha="auto"` picks for a recording whose frame SNR and signal photons per
    LR pixel and frame (`photon_levels`) are `snr` and `signal`: AUTO_AMBIENT_ALPHA where the SNR is at least
    AUTO_AMBIENT_MIN_SNR or signal x SNR (signal^2 / ambient photons) at least AUTO_AMBIENT_MIN_SIGNAL_SNR; None
    (no test) elsewhere and where no return is seen (NaN). Below both, the summed photons of a faint return no
    longer stand out from the ambient light, and the test cost the paper's TR4 PSNR on the test scenes; from
    either up it cost at most 0.33 dB there, and gained up to 0.8 dB on sky at many photons and low SNR
    (experiments/results/upscale_defaults.md). min_snr, min_signal_snr: the two thresholds (the study that
    chose them scores others)."""
    tested = snr >= min_snr or signal * snr >= min_signal_snr  # NaN compares False
    return AUTO_AMBIENT_ALPHA if tested else None


def _ambient_choice(setting, levels: PhotonLevels | None, marks_no_return: bool,
                    frames: int) -> tuple[float | None, str]:
    """`ambient_alpha` as set (None, a rate) or, for "auto", `auto_ambient_alpha` of the recording's levels;
    and the words that say why, for the model's name ("" where set). "auto" is off where the rule was not measured
    to hold: background-subtracted counts (`levels` None: their ambient light is gone), a model with a no-return
    head (it marks no return itself, and the test cost tr4-photons 4.9 dB at worst), fewer than
    AUTO_AMBIENT_MIN_FRAMES frames (the SNR reads high)."""
    if not is_auto(setting):
        return setting, ""
    if levels is None:
        return None, " (ambient test off: background-subtracted counts)"
    if marks_no_return:
        return None, " (ambient test off: the model marks no return itself)"
    if frames < AUTO_AMBIENT_MIN_FRAMES:
        return None, (f" (ambient test off: {frames} frames, too few to read the SNR; --ambient-alpha 0.001 "
                      "sets it)")
    if np.isnan(levels.snr):
        return None, " (ambient test off: no return seen)"
    shown = ("no ambient light seen" if np.isinf(levels.snr) else
             f"frame SNR about {levels.snr:.2g}, {levels.signal:.3g} signal photons per pixel and frame")
    alpha = auto_ambient_alpha(levels.snr, levels.signal)
    if alpha is None:
        return None, (f" (ambient test off: {shown}, SNR below {AUTO_AMBIENT_MIN_SNR:g} and signal x SNR below "
                      f"{AUTO_AMBIENT_MIN_SIGNAL_SNR:g})")
    return alpha, f"; auto: {shown}"


def few_photons_warnings(signal: float, frames: int) -> tuple[str, ...]:
    """A hint where a model reading depth alone gets a recording of fewer than FEW_PHOTONS signal photons per
    pixel and frame (`photon_levels`), where the paper's models fall below bicubic."""
    if not signal < FEW_PHOTONS:  # NaN (no return seen): nothing to say
        return ()
    return ((f"about {signal:.2g} signal photons per pixel and frame (first {frames} frames): below "
             f"{FEW_PHOTONS:g} a model reading depth alone falls behind; tr4-ambient, the default model of "
             "histograms and time tags (--model default), also reads the photons behind each depth (check a frame, "
             "--preview; docs/results/real-photons.md)"),)


def snr_warnings(trained: tuple[float, float], snr: float, frames: int, no_return_logit=None) -> tuple[str, ...]:
    """A warning where the recording's frame SNR (`photon_levels`) lies well outside (SNR_WARNING_MARGIN) the SNRs
    a model with a no-return head was trained on: its threshold is then a guess; with a threshold given
    (`no_return_logit`), the SNR alone is said."""
    lo, hi = trained
    if np.isnan(snr) or lo / SNR_WARNING_MARGIN <= snr <= hi * SNR_WARNING_MARGIN:  # NaN: no return seen, nothing to say
        return ()
    shown = "no ambient light seen" if snr == float("inf") else f"about {snr:.3g}"
    if no_return_logit is not None:
        advice = f"its no-return threshold is set to {float(no_return_logit):g}: check a frame (--preview)"
    elif snr > hi:
        advice = ("with little ambient light its no-return head may mark dim returns as no return; a higher "
                  "--no-return-logit (such as 2) keeps them and shows more sky as depth")
    else:
        advice = ("with this much ambient light it may show sky as depth; a lower --no-return-logit marks more "
                  "pixels as no return")
    return ((f"the recording's frame SNR (signal / ambient photons, first {frames} frames) is {shown}, well "
             f"outside the {lo:g}-{hi:g} this model was trained on: {advice} (docs/network.md, choosing the "
             "threshold)"),)




class PhotonDecision(NamedTuple):
    """The photon rules as they apply to one recording and model (`decide_photon_rules`): the ambient-only test's
    false-alarm rate (None: off) and the words that say why (for the model's name; "" where set), the keep
    rule's rate (None: off) and whether the confidence's probability decides no return (`by_probability`; with
    neither, the model's head decides alone, or there is no head)."""

    ambient_alpha: float | None
    ambient_why: str
    keep_returns: float | None
    by_probability: bool = False


def decide_photon_rules(rules: PhotonRules, levels: PhotonLevels | None, *, marks_no_return: bool,
                        frames: int) -> PhotonDecision:
    """`rules` for a recording of `frames` frames whose photons say `levels` (None: background-subtracted counts,
    whose ambient light is gone) and a model that marks no return itself or not: "auto" ambient as
    `_ambient_choice`; "auto" keep: for a head, no return where the confidence's P(return) is below the threshold
    (`by_probability`: `jaxsr.inference.confidence`, the head's logit and each pixel's photons over 9 frames) and
    the pixel's own photons over 9 frames, and the quiet pixels' pooled around it (`QUIET_POOLS`), pass for
    ambient light alone at AUTO_KEEP_RETURNS, unless the counts are background-subtracted (the head alone) or an
    ambient rate decides no return instead; a keep rate: the head's no return kept only where those photons pass
    for ambient light alone at it."""
    alpha, why = _ambient_choice(rules.ambient_alpha, levels, marks_no_return, frames)
    keep = rules.keep_returns
    if is_auto(keep):  # the confidence decides, where the photons do not show a return
        on = marks_no_return and levels is not None and alpha is None
        return PhotonDecision(alpha, why, AUTO_KEEP_RETURNS if on else None, on)
    return PhotonDecision(alpha, why, keep)


def rule_warnings(rules: PhotonRules, *, clip_negative: bool) -> tuple[str, ...]:
    """Warnings on rates given for background-subtracted counts: both tests assume raw counts."""
    if not clip_negative:
        return ()
    return tuple(f"{flag} on background-subtracted counts: {whose} test assumes raw counts, whose ambient light it "
                 "looks for, and was measured on those only"
                 for flag, whose, value in (("--ambient-alpha", "the", rules.ambient_alpha),
                                            ("--keep-returns", "its", rules.keep_returns))
                 if value is not None and not is_auto(value))
