"""`jaxsr upscale` on every input format and on bad input, no overwrite without --force, and `jaxsr info`."""

import json

import jax
import numpy as np
import pytest

from jaxsr import cli, io
from jaxsr.config import Sensor
from jaxsr.inference import super_resolve
from jaxsr.sensor.peaks import centre_of_mass
from jaxsr.sensor.forward import normalise_depth
from jaxsr.io.previews import COLOUR_BAR_HEIGHT

SENSOR = Sensor()


@pytest.fixture(scope="module")
def metres():
    """Four LR frames of radial depth in metres, with some no-return pixels."""
    rng = np.random.default_rng(0)
    d = rng.uniform(2.0, 30.0, (4, 32, 64)).astype(np.float32)
    d[:, :4] = np.inf
    return d


def upscale(*args):
    return cli.main(["upscale", str(args[0]), "-o", *map(str, args[1:]), "--no-progress"])


def expected(model_path, lr):
    """The network's output, and no return inside regions of no return, as `jaxsr upscale` gives depth frames."""
    from jaxsr.app.job import no_return_interior
    from jaxsr.inference import no_return_where
    from jaxsr.io.checkpoint import load_model

    hr = np.clip(super_resolve(load_model(model_path), lr), 0, 1)
    return np.stack([no_return_where(f, no_return_interior(lo)) for f, lo in zip(hr, np.asarray(lr))])


def to_metres(n):
    """Clipped normalised output -> metres: 1.0 is no return (docs/sensor-model.md), anything below is n * d_max."""
    return np.where(n >= 1.0, np.inf, n * float(SENSOR.d_max))


def test_npy_normalised_in_and_out(tmp_path, model_path, metres):
    lr = np.asarray(normalise_depth(metres))
    np.save(tmp_path / "in.npy", lr)
    assert upscale(tmp_path / "in.npy", tmp_path / "out.npy", "--model", model_path) == 0
    out = np.load(tmp_path / "out.npy")
    assert out.shape == (4, 128, 256)
    np.testing.assert_allclose(out, expected(model_path, lr), atol=1e-6)


def test_histograms_npz_to_metres_npz_with_preview(tmp_path, model_path):
    counts = np.asarray(jax.random.poisson(jax.random.key(1), 1.5, (3, 32, 64, SENSOR.bins)))
    io.write_histograms(tmp_path / "h.npz", counts, sensor=SENSOR)
    assert upscale(tmp_path / "h.npz", tmp_path / "out.npz", "--model", model_path,
                   "--preview", tmp_path / "strip.png") == 0
    seq = io.read_sequence(tmp_path / "out.npz")
    assert seq["metadata"]["units"] == "m" and seq["depth"].shape == (3, 128, 256)
    want = to_metres(expected(model_path, np.asarray(centre_of_mass(counts.astype(np.float32), SENSOR))))
    np.testing.assert_allclose(seq["depth"], want, rtol=1e-5)
    assert io.read_image(tmp_path / "strip.png").shape == (128 + COLOUR_BAR_HEIGHT, 2 * 256 + 2, 3)


@pytest.mark.parametrize("fmt", ["exr", "pfm", "tif", "png"])
def test_folder_of_frames_to_folder(tmp_path, model_path, metres, fmt):
    src = tmp_path / "frames"
    src.mkdir()
    for t, d in enumerate(metres):
        io.write_depth(src / f"f{t:03d}.{fmt}", d)
    assert upscale(src, tmp_path / "out", "--model", model_path, "--frame-format", "exr") == 0
    files = sorted((tmp_path / "out").iterdir())
    assert [f.name for f in files] == [f"frame_{t:06d}.exr" for t in range(4)]
    lr = np.stack([io.read_depth(f) for f in sorted(src.iterdir())])
    want = to_metres(expected(model_path, np.asarray(normalise_depth(lr))))
    np.testing.assert_allclose(np.stack([io.read_depth(f) for f in files]), want, rtol=1e-5)


def test_glob_pattern(tmp_path, model_path, metres):
    for t, d in enumerate(metres):
        io.write_depth(tmp_path / f"a_{t}.pfm", d)
    io.write_depth(tmp_path / "b_0.pfm", metres[0])  # not matched
    assert upscale(tmp_path / "a_*.pfm", tmp_path / "o.npy", "--model", model_path, "--units", "m") == 0
    assert np.load(tmp_path / "o.npy").shape == (4, 128, 256)


def test_no_overwrite_without_force(tmp_path, model_path, metres, capsys):
    np.save(tmp_path / "in.npy", metres)
    (tmp_path / "out.npy").write_bytes(b"keep me")
    assert upscale(tmp_path / "in.npy", tmp_path / "out.npy", "--model", model_path) == 2
    assert "--force" in capsys.readouterr().err
    assert (tmp_path / "out.npy").read_bytes() == b"keep me"
    (tmp_path / "dir").mkdir()
    (tmp_path / "dir" / "x.txt").write_text("keep")
    assert upscale(tmp_path / "in.npy", tmp_path / "dir", "--model", model_path) == 2
    assert upscale(tmp_path / "in.npy", tmp_path / "out.npy", "--model", model_path, "--force") == 0
    assert np.load(tmp_path / "out.npy").shape == (4, 128, 256)


@pytest.mark.parametrize("make,args,message", [
    (lambda p: None, [], "no such file"),
    (lambda p: np.save(p / "in.npy", np.zeros(5)), [], "expected depth"),
    (lambda p: np.save(p / "in.npy", np.full((2, 32, 64), -0.5)), ["--units", "normalised"], "--units m"),
    (lambda p: np.save(p / "in.npy", np.full((2, 32, 64), 5.0)), ["--units", "normalised"], "outside \\[0, 1\\]"),
    (lambda p: np.save(p / "in.npy", np.zeros((2, 32, 64, 8))), ["--bins", "16"], "8 bins"),
    (lambda p: (p / "in.npy").write_bytes(b"\x93NUMPY garbage"), [], "cannot read"),
])
def test_bad_input_is_a_clear_error(tmp_path, model_path, capsys, make, args, message):
    make(tmp_path)
    assert upscale(tmp_path / "in.npy", tmp_path / "out.npy", "--model", model_path, *args) == 2
    err = capsys.readouterr().err
    assert "jaxsr upscale: error" in err
    assert __import__("re").search(message, err), err
    assert not (tmp_path / "out.npy").exists()



@pytest.mark.parametrize("kind,units", [("m", []), ("m", ["--units", "m"]), ("normalised", []),
                                        ("normalised", ["--units", "normalised"])])
def test_nan_is_no_return_in_either_unit(tmp_path, model_path, metres, kind, units):
    """NaN depth is "no return" (docs/sensor-model.md), in metres (like inf) and normalised (like 1.0), with the
    units given or guessed: the output equals that of the same recording with the no-return code."""
    coded = metres if kind == "m" else np.asarray(normalise_depth(metres))  # rows :4 are no return
    holes = coded.copy()
    holes[:, :4] = np.nan
    for name, data in (("coded", coded), ("holes", holes)):
        np.save(tmp_path / f"{name}.npy", data)
        assert upscale(tmp_path / f"{name}.npy", tmp_path / f"{name}_out.npy", "--model", model_path, *units) == 0
    np.testing.assert_array_equal(np.load(tmp_path / "holes_out.npy"), np.load(tmp_path / "coded_out.npy"))


def test_empty_folder_and_bad_output(tmp_path, model_path, capsys):
    (tmp_path / "empty").mkdir()
    assert upscale(tmp_path / "empty", tmp_path / "o.npy", "--model", model_path) == 2
    assert "no depth frames" in capsys.readouterr().err
    np.save(tmp_path / "in.npy", np.zeros((2, 32, 64)))
    assert upscale(tmp_path / "in.npy", tmp_path / "o.txt", "--model", model_path) == 2
    assert "OUTPUT is an .npy" in capsys.readouterr().err
    assert upscale(tmp_path / "in.npy", tmp_path / "o.npy", "--model", tmp_path / "missing.npz") == 2
    assert "no checkpoint" in capsys.readouterr().err


def test_info(model_path, capsys):
    assert cli.main(["info", str(model_path)]) == 0
    text = capsys.readouterr().out
    assert "TR 1" in text and "parameters" in text and f"jaxsr info {model_path} --json" in text
    assert cli.main(["info", str(model_path), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["config"]["tr"] == 1 and info["frames_per_window"] == 3 and info["gflops_per_frame"] > 0
    assert info["card"]["data"] == "none: random weights for tests" and info["reads"] == ["depth"]


def test_auto_model_uses_choose_tr_and_the_bundled_weights(tmp_path, capsys):
    """--model auto: the TR that `choose_tr` picks from the recording, run with that TR's bundled weights."""
    from jaxsr.inference.adaptive import choose_tr
    from jaxsr.io.checkpoint import load_model

    # a near wall sweeping 3 LR px per frame across a far background: fast motion
    lr = np.full((6, 32, 64), 0.8, np.float32)
    for t in range(6):
        lr[t, 8:24, 3 * t + 4 : 3 * t + 16] = 0.2
    np.save(tmp_path / "in.npy", lr)
    choice = choose_tr(lr)
    assert upscale(tmp_path / "in.npy", tmp_path / "out.npy", "--model", "auto") == 0
    assert f"model tr{choice.tr} (auto: " in capsys.readouterr().err
    np.testing.assert_allclose(np.load(tmp_path / "out.npy"),
                               np.clip(super_resolve(load_model(f"tr{choice.tr}"), lr), 0, 1), atol=1e-6)
    # a budget no model meets: the fastest one, and the reason says so
    assert upscale(tmp_path / "in.npy", tmp_path / "out2.npy", "--model", "auto", "--min-fps", "1e6") == 0
    assert "model tr0 (auto: " in capsys.readouterr().err
