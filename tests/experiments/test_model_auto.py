"""The model table of `--model auto` (experiments/studies/model_auto.py): each cell's mean PSNR and the standard
error of each model's lead over the default across the cell's clips, which `choose_photon_model` reads."""

import numpy as np

import model_auto  # experiments/studies (pytest's pythonpath)
from jaxsr.app.models import DEFAULT_MODELS


def _clips(leads: dict, motion: dict, repeats: int = 3) -> list:
    """Calibration clips: per class, level and repeat, the default at 30 dB and each model at 30 + its lead + the
    repeat's offset (the spread across clips)."""
    default = DEFAULT_MODELS["histograms"]
    out = []
    for rep in range(repeats):
        for cls in model_auto.CLASSES:
            for photons in (3.0, 14.0):
                scores = {default: 30.0, **{m: 30.0 + lead + spread * (rep - 1) for m, (lead, spread) in leads.items()}}
                out.append({"split": "calibration", "class": cls, "photons": photons, "signal": photons,
                            "motion": motion[cls], "scores": scores})
    return out


def test_the_table_holds_each_leads_standard_error_and_the_default():
    motion = {"static camera": 0.0, "moving, 25 fps": 0.9, "moving, 10 fps": 0.0}
    leads = {"tr4": (0.5, 1.0), "tr0-ambient": (0.5, 0.05)}  # the same mean lead, spread apart 1 dB and 0.05 dB
    models = (DEFAULT_MODELS["histograms"], *leads)
    table = model_auto.build_table(_clips(leads, motion), models)
    assert table["default"] == DEFAULT_MODELS["histograms"] and table["clips"] == 3
    assert table["classes"] == ["static camera + moving, 10 fps", "moving, 25 fps"]
    # the pooled column holds 6 clips (two classes), the other 3: leads -1, 0, +1 (x spread) around 0.5
    for j, n in enumerate((6, 3)):
        for m, (lead, spread) in leads.items():
            assert np.isclose(table["psnr"][m][0][j], 30.0 + lead)
            offsets = np.repeat([-1.0, 0.0, 1.0], n // 3) * spread
            assert np.isclose(table["lead_se"][m][0][j], np.std(offsets, ddof=1) / np.sqrt(n))
    assert table["lead_se"][DEFAULT_MODELS["histograms"]][0][0] == 0.0


def test_one_clip_a_cell_establishes_no_lead():
    motion = {"static camera": 0.0, "moving, 25 fps": 0.9, "moving, 10 fps": 0.0}
    table = model_auto.build_table(_clips({"tr4": (3.0, 0.0)}, motion, repeats=1),
                                   (DEFAULT_MODELS["histograms"], "tr4"))
    assert table["clips"] == 1 and np.isinf(table["lead_se"]["tr4"][0][1])
