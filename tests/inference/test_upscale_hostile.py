"""Cases a hostile user found in `jaxsr upscale` and the host functions: pictures placed inside a folder OUTPUT,
a model whose output is no depth, colour flags with nothing to colour, first frames that say nothing of their
units, arrays of Python objects, gates beyond float32 metres, and arrays that hold no numbers given to the
library. Each ends in one line before the work, with nothing written."""

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest

import jaxsr
from jaxsr import cli, io


def command(recording, output, *args):
    return cli.main(["upscale", str(recording), "-o", str(output), *map(str, args), "-q"])


@pytest.fixture
def depth(tmp_path):
    """3 LR frames of metres in rec.npy."""
    np.save(tmp_path / "rec.npy", np.full((3, 8, 8), 12.0, np.float32))
    return tmp_path / "rec.npy"


@pytest.mark.parametrize("what, flags", [
    ("the preview", ["--preview", "out/p.png"]),                       # failed after the work, p.png left behind
    ("the preview", ["--preview", "out/frame_000099.png", "--force"]),  # deleted as an earlier run's frame
    ("the video", ["--video", "out/v.gif"]),
    ("the point clouds", ["--points", "out/clouds"]),
    ("the point clouds", ["--points", "out/all.ply"]),
])
def test_pictures_inside_a_folder_output_are_refused_before_the_work(tmp_path, depth, model_path, capsys, monkeypatch,
                                                                      what, flags):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "out").mkdir()
    if "--force" in flags:
        (tmp_path / "out" / "notes.txt").write_text("mine")
    before = sorted(f.name for f in (tmp_path / "out").iterdir())
    assert command(depth, "out", "-m", model_path, *flags) == 2
    assert f"{what} lies inside the folder OUTPUT out" in capsys.readouterr().err
    assert sorted(f.name for f in (tmp_path / "out").iterdir()) == before


def _with_residual_bias(model_path, value):
    """The test model with its last residual bias set to `value`: finite input gives output of about `value`."""
    model = jaxsr.load_model(model_path)
    params = dict(model.params, residual=dict(model.params["residual"]))
    conv2 = params["residual"]["conv2"]
    params["residual"]["conv2"] = dict(conv2, b=jnp.full_like(conv2["b"], value))
    return dataclasses.replace(model, params=params)


@pytest.mark.parametrize("bias, message", [(1e4, "more than a whole depth span outside the gate in 100%"),
                                           (-1e4, "more than a whole depth span outside the gate in 100%"),
                                           (np.inf, "its output holds inf in frame 0")])
def test_output_that_is_no_depth_is_refused_not_written_as_no_return(tmp_path, model_path, bias, message):
    """Finite weights can compute output far outside the gate (1e4 spans: every pixel no return, or 0 m) or inf;
    both are refused like NaN, with nothing written."""
    from jaxsr.app import upscale

    with pytest.raises(ValueError, match=message):
        upscale(np.full((2, 8, 8), 10.0, np.float32), tmp_path / "out.npy", model=_with_residual_bias(model_path, bias))
    assert not (tmp_path / "out.npy").exists()


@pytest.mark.parametrize("bias", [np.inf, np.nan])
def test_the_library_refuses_output_that_is_not_finite(model_path, bias):
    """`jaxsr.super_resolve` of a model whose output is NaN or inf raised nothing and returned it (read as no
    return by anyone who clips it); the command refused it already."""
    with pytest.raises(ValueError, match="super_resolve: the model's output holds NaN or inf in frame 0"):
        jaxsr.super_resolve(_with_residual_bias(model_path, bias), np.full((2, 8, 8), 0.5, np.float32))


@pytest.mark.parametrize("flags, message", [
    (["--vmin", "3"], "--vmin applies to --preview, --video and --points only"),
    (["--vmax", "9", "--cmap", "jet"], "--vmax, --cmap apply to --preview, --video and --points only"),
    (["--points-colour", "none"], "--points-colour applies to --points only"),
])
def test_colour_flags_without_a_picture_are_refused(tmp_path, depth, model_path, capsys, flags, message):
    assert command(depth, tmp_path / "o.npy", "-m", model_path, *flags) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "o.npy").exists()


def test_colour_flags_with_a_picture_still_work(tmp_path, depth, model_path):
    from jaxsr.app import Writing

    assert Writing().cmap == "turbo" and Writing(preview="p.png", cmap="jet").cmap == "jet"
    assert command(depth, tmp_path / "o.npy", "-m", model_path, "--preview", tmp_path / "p.png", "--vmin", "3",
                   "--cmap", "viridis") == 0


@pytest.mark.parametrize("first, message", [
    (np.nan, "the first frame is NaN (no return) in every pixel"),  # was read as normalised: 1.0 m everywhere
    (-12.0, "negative in every pixel"),                              # was every pixel no return, exit 0
])
def test_a_first_frame_that_says_nothing_of_its_units_asks_for_them(tmp_path, model_path, capsys, first, message):
    np.save(tmp_path / "rec.npy", np.full((3, 8, 8), first, np.float32))
    assert command(tmp_path / "rec.npy", tmp_path / "o.npy", "-m", model_path) == 2
    err = capsys.readouterr().err
    assert message in err and "pass --units" in err
    assert not (tmp_path / "o.npy").exists()


def test_an_npy_of_python_objects_is_said_to_be_one(tmp_path, model_path, capsys):
    np.save(tmp_path / "rec.npy", np.full((3, 8, 8), 12.0).astype(object), allow_pickle=True)
    assert command(tmp_path / "rec.npy", tmp_path / "o.npy", "-m", model_path) == 2
    err = capsys.readouterr().err
    assert "it holds Python objects" in err and "damaged" not in err


def test_a_gate_beyond_float32_metres_is_refused(tmp_path, model_path, capsys):
    """At 10^10 m float32 metres step by 1 km: every pixel would be written as the gate's start."""
    np.save(tmp_path / "c.npy", np.random.default_rng(0).poisson(2.0, (3, 8, 8, 16)).astype(np.float32))
    assert command(tmp_path / "c.npy", tmp_path / "o.npy", "-m", model_path, "--gate-start", "1e10m") == 2
    assert "float32 metres (the output's) step by 1.02e+03 m, more than a bin" in capsys.readouterr().err
    assert not (tmp_path / "o.npy").exists()
    from jaxsr.config import DepthScale, Gate
    from jaxsr.sensor import gate_warnings

    gate_warnings(Gate(16, 2.1875, 200e3), DepthScale(200e3, 35.0))  # 200 km (1.6 cm steps) stays allowed


@pytest.mark.parametrize("make, message", [
    (lambda lr: lr > 0.5, "holds bool values"),
    (lambda lr: lr.astype(object), "holds object values"),
    (lambda lr: lr.astype(str), "holds <U32 values"),                # NumPy parses the text as numbers
    (lambda lr: np.ma.masked_greater(lr, 0.5), "is a masked array, whose mask would be dropped"),
])
def test_the_library_refuses_arrays_that_hold_no_numbers(model_path, make, message):
    model = jaxsr.load_model(model_path)
    lr = np.random.default_rng(0).uniform(0.1, 0.9, (2, 8, 8)).astype(np.float32)
    with pytest.raises(ValueError, match=f"super_resolve: the LR sequence {message}"):
        jaxsr.super_resolve(model, make(lr))
    with pytest.raises(ValueError, match=f"Stream.push: frame 0 {message}"):
        jaxsr.Stream(model).push(make(lr)[0])
    counts = np.ones((2, 8, 8, 16), np.float32)
    with pytest.raises(ValueError, match=f"super_resolve_histograms: the counts {message}"):
        jaxsr.super_resolve_histograms(model, make(counts))


def test_a_stream_names_itself(model_path):
    with pytest.raises(ValueError, match=r"Stream.push: frame 0 has shape \(3, 8, 8\)"):
        jaxsr.Stream(jaxsr.load_model(model_path)).push(np.zeros((3, 8, 8), np.float32))


def test_io_still_reads_numbers(tmp_path):
    np.save(tmp_path / "a.npy", np.arange(6, dtype=np.float32))
    np.testing.assert_array_equal(io.formats.load_npy(tmp_path / "a.npy"), np.arange(6))


def test_the_summary_names_the_preview_as_it_names_the_video(tmp_path, depth, model_path, capsys):
    import json

    assert command(depth, tmp_path / "o.npy", "-m", model_path, "--preview", tmp_path / "p.png") == 0
    assert json.loads(capsys.readouterr().out)["preview"] == str(tmp_path / "p.png")


def test_a_time_tag_table_without_photons_says_so(tmp_path, model_path, capsys):
    np.savez(tmp_path / "t.npz", pixel=np.zeros(0, np.int64), time=np.zeros(0), shape=np.array([8, 8]))
    assert command(tmp_path / "t.npz", tmp_path / "o.npy", "-m", model_path, "-k", "timetags",
                   "--time-unit", "1ps") == 2
    assert "t.npz: holds no photons" in capsys.readouterr().err


@pytest.mark.parametrize("target_exists, flags", [(False, []), (True, ["--force"])])
def test_a_preview_that_is_a_symbolic_link_is_refused_before_the_work(tmp_path, depth, model_path, capsys,
                                                                       target_exists, flags):
    """A dangling link passed as a new file and failed after the work ("created by another writer", the output
    lost); with --force the link was replaced by the picture. Refused like OUTPUT, the video and the points."""
    if target_exists:
        (tmp_path / "real.png").write_text("mine")
    (tmp_path / "p.png").symlink_to(tmp_path / "real.png")
    assert command(depth, tmp_path / "o.npy", "-m", model_path, "--preview", tmp_path / "p.png", *flags) == 2
    assert "p.png is a symbolic link" in capsys.readouterr().err
    assert (tmp_path / "p.png").is_symlink() and not (tmp_path / "o.npy").exists()
