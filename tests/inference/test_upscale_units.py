"""Depth units: `jaxsr upscale` never reads millimetres as metres. Integer arrays (16-bit millimetres,
centimetres) and values that could be kilometres are refused by the guess with a message asking for --units;
--units mm / cm / km convert to metres on the way in and back on the way out; float metres and normalised input
are guessed as before. Only the input's normalisation runs here, no network (a tiny zero-weight model)."""

import json

import jax
import numpy as np
import pytest

from jaxsr import cli, io
from jaxsr.config import ModelConfig
from jaxsr.app import DEPTH_UNITS, Reading, prepare_upscale, to_metres, to_units
from jaxsr.io.checkpoint import model_template, save_model
from jaxsr.nn import Model
from upscale_specs import specs

METRES = np.array([[0.0, 1.234, 5.0, 12.5], [20.0, 34.9, 40.0, np.inf]] * 4, np.float32)  # (8, 4): 0 and inf
MM = np.where(np.isfinite(METRES), np.rint(METRES * 1000), 0).astype(np.uint16)  # 16-bit millimetres, 0 = none
MM[0, 0] = 0  # 0 m in metres is depth 0; in millimetres 0 is no return (as 16-bit depth images store it)


@pytest.fixture(scope="module")
def model_path(tmp_path_factory):
    cfg = ModelConfig(tr=0, base=4, growth=2, head=4, filter_hidden=4)
    params, state = jax.tree_util.tree_map(lambda s: np.zeros(s.shape, s.dtype), model_template(cfg))
    return save_model(tmp_path_factory.mktemp("m") / "tiny.npz", Model(params, state, cfg))


def lr(array, model_path, **options):
    """The network's input `jaxsr upscale` makes of `array` (T, h, w): (T, h, w) normalised depth."""
    job = prepare_upscale(array, **specs(model_path, **options))
    return job, np.stack(list(job.lr_frames()))


@pytest.mark.parametrize("array, words", [
    (np.stack([MM, MM]), ["integers (uint16)", "millimetres", "--units"]),
    (np.full((2, 8, 4), 250, np.int32), ["integers (int32)", "centimetres", "--units"]),
    (np.full((2, 8, 4), 0.02, np.float32), ["could be kilometres", "--units"]),  # 20 m in km
    (np.stack([np.where(np.isfinite(METRES), METRES / 1000, np.inf)] * 2), ["kilometres", "inf", "--units"]),
])
def test_units_that_could_be_misread_are_not_guessed(model_path, array, words):
    for word in words:  # each case asks for --units, naming what it could be
        with pytest.raises(ValueError, match=word.replace("(", r"\(").replace(")", r"\)")):
            prepare_upscale(array, model=model_path)


def test_the_cli_refuses_an_integer_array_in_one_line_and_converts_with_units_mm(tmp_path, model_path, capsys):
    np.save(tmp_path / "in.npy", np.stack([MM, MM]))
    args = ["upscale", str(tmp_path / "in.npy"), "-o", str(tmp_path / "out.npy"), "--model", str(model_path),
            "--no-progress"]
    assert cli.main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("jaxsr upscale: error: ") and "--units" in err
    assert not (tmp_path / "out.npy").exists()
    assert cli.main([*args, "--units", "mm"]) == 0
    assert json.loads(capsys.readouterr().out)["units"] == "mm"
    np.save(tmp_path / "m.npy", np.stack([np.where(MM > 0, MM / 1000, np.inf)] * 2).astype(np.float32))
    assert cli.main(["upscale", str(tmp_path / "m.npy"), "-o", str(tmp_path / "m_out.npy"), "--model", str(model_path),
                     "--no-progress", "--units", "m"]) == 0
    got, want = np.load(tmp_path / "out.npy"), np.load(tmp_path / "m_out.npy")
    assert got.dtype == np.float32 and np.array_equal(np.isinf(got), np.isinf(want))
    np.testing.assert_allclose(got[np.isfinite(got)], 1000 * want[np.isfinite(want)], rtol=1e-6)


@pytest.mark.parametrize("units, factor", [("mm", 1000), ("cm", 100), ("km", 1e-3)])
def test_mm_cm_km_are_metres_scaled(model_path, units, factor):
    metres = np.where(MM > 0, MM / 1000, np.inf).astype(np.float32)  # what MM means, no return as inf
    stored = np.where(np.isfinite(metres), metres * factor, 0 if units != "km" else np.inf)
    stored = np.rint(stored).astype(np.int32) if units == "mm" else stored.astype(np.float32)
    job, got = lr(np.stack([stored] * 2), model_path, units=units)
    _, want = lr(np.stack([metres] * 2), model_path, units="m")
    assert job.units == units
    np.testing.assert_allclose(got, want, atol=1e-6)
    assert np.all(got[:, MM == 0] == 1.0)  # 0 mm: no return, not a wall at the lens
    hr = np.array([[0.1, 0.5, 1.0]], np.float32)
    np.testing.assert_allclose(to_units(hr, units), to_units(hr, "m") * factor, rtol=1e-6)
    np.testing.assert_allclose(to_metres(stored, units)[np.isfinite(metres)], metres[np.isfinite(metres)], rtol=1e-6)


def test_float_metres_and_normalised_are_guessed_as_before(tmp_path, model_path):
    assert lr(np.stack([METRES] * 2), model_path)[0].units == "m"
    assert lr(np.full((2, 8, 4), 5.0, np.float32), model_path)[0].units == "m"
    assert lr(np.full((2, 8, 4), 0.5, np.float32), model_path)[0].units == "normalised"
    near = np.linspace(0.05, 1.0, 32, dtype=np.float32).reshape(8, 4)  # with its sky (1.0)
    assert lr(np.stack([near] * 2), model_path)[0].units == "normalised"
    with pytest.raises(ValueError, match="NaN .* in every pixel, which says nothing of its units"):  # 1.0 or inf?
        lr(np.full((2, 8, 4), np.nan, np.float32), model_path)
    assert lr(np.full((2, 8, 4), np.inf, np.float32), model_path)[0].units == "m"
    (tmp_path / "frames").mkdir()  # 16-bit PNG frames are millimetres by their format: read as metres, no question
    for t in range(2):
        io.write_depth(tmp_path / "frames" / f"f{t}.png", np.where(MM > 0, MM / 1000, np.inf))
    job, got = lr(str(tmp_path / "frames"), model_path)
    assert job.units == "m"
    np.testing.assert_allclose(got, lr(np.stack([np.where(MM > 0, MM / 1000, np.inf)] * 2), model_path, units="m")[1],
                               atol=1e-6)
    with pytest.raises(ValueError, match="units is one of 'm', 'normalised', 'mm', 'cm', 'km'"):
        prepare_upscale(np.full((2, 8, 4), 5.0, np.float32), model=model_path, read=Reading(units="inch"))
    assert DEPTH_UNITS == ("m", "normalised", "mm", "cm", "km")
