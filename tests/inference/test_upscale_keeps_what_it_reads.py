"""`jaxsr upscale` never writes over what it reads, --force or not: the input (a file, a folder or pattern of
frames) and the reference stay as they were; and a folder written with --force holds this run's frames only."""

import numpy as np
import pytest

from jaxsr import cli, io


def command(*args):
    return cli.main(["upscale", str(args[0]), "-o", *map(str, args[1:]), "--no-progress"])


@pytest.fixture
def depth(tmp_path):
    """3 LR frames of metres in rec.npy."""
    frames = np.full((3, 8, 8), 12.0, np.float32)
    np.save(tmp_path / "rec.npy", frames)
    return tmp_path / "rec.npy"


@pytest.mark.parametrize("extra", [[], ["--force"]])
def test_the_input_is_not_its_own_output(depth, model_path, capsys, extra):
    before = depth.read_bytes()
    assert command(depth, depth, "--model", model_path, *extra) == 2
    assert depth.read_bytes() == before
    if extra:  # without --force the file's existence is said first
        assert "OUTPUT is the input itself" in capsys.readouterr().err


@pytest.mark.parametrize("how", ["folder", "pattern"])
def test_a_folder_of_frames_is_not_written_into(tmp_path, model_path, capsys, how):
    frames = tmp_path / "frames"
    frames.mkdir()
    for t in range(3):
        io.write_depth(frames / f"frame_{t:06d}.pfm", np.full((8, 8), 10.0 + t, np.float32))
    before = {f.name: f.read_bytes() for f in frames.iterdir()}
    source = frames if how == "folder" else f"{frames}/frame_*.pfm"
    assert command(source, frames, "--model", model_path, "--force", "--frame-format", "pfm") == 2
    assert "the input itself (or its folder of frames)" in capsys.readouterr().err
    assert {f.name: f.read_bytes() for f in frames.iterdir()} == before


def test_a_preview_is_not_written_over_an_input_frame(tmp_path, model_path, capsys):
    frames = tmp_path / "frames"
    frames.mkdir()
    for t in range(2):
        io.write_depth(frames / f"frame_{t:06d}.png", np.full((8, 8), 10.0, np.float32))
    before = (frames / "frame_000000.png").read_bytes()
    assert command(frames, tmp_path / "o.npy", "--model", model_path, "--preview", frames / "frame_000000.png",
                   "--force") == 2
    assert "the preview is the input itself" in capsys.readouterr().err
    assert (frames / "frame_000000.png").read_bytes() == before and not (tmp_path / "o.npy").exists()


def test_the_reference_is_not_overwritten_by_the_output(depth, tmp_path, model_path, capsys):
    reference = tmp_path / "ref.npy"
    np.save(reference, np.full((3, 32, 32), 12.0, np.float32))
    before = reference.read_bytes()
    assert command(depth, reference, "--model", model_path, "--video", tmp_path / "v.gif", "--reference", reference,
                   "--force") == 2
    assert "OUTPUT is the reference itself" in capsys.readouterr().err
    assert reference.read_bytes() == before and not (tmp_path / "v.gif").exists()


def test_a_folder_written_with_force_holds_this_runs_frames_only(tmp_path, model_path):
    long = tmp_path / "long.npy"
    np.save(long, np.full((5, 8, 8), 12.0, np.float32))
    short = tmp_path / "short.npy"
    np.save(short, np.full((2, 8, 8), 20.0, np.float32))
    out, clouds = tmp_path / "out", tmp_path / "clouds"
    assert command(long, out, "--model", model_path, "--points", clouds) == 0
    (out / "notes.txt").write_text("mine")  # not a frame: kept
    assert command(short, out, "--model", model_path, "--force", "--frame-format", "pfm", "--points", clouds) == 0
    assert sorted(f.name for f in out.iterdir()) == ["frame_000000.pfm", "frame_000001.pfm", "notes.txt"]
    assert sorted(f.name for f in clouds.iterdir()) == ["frame_000000.ply", "frame_000001.ply"]
    np.testing.assert_allclose(io.read_depth(out / "frame_000001.pfm"), 20.0, atol=5.0)


@pytest.mark.parametrize("eps", [-1.0, float("nan"), 0.0, "x"])
def test_a_config_that_computes_nothing_is_refused_when_loaded(tmp_path, eps, capsys):
    """A checkpoint whose batch norm eps is <= 0, NaN or text is refused by `jaxsr info` and `upscale` in one
    line, not loaded as a model that writes every pixel as no return."""
    import json

    from jaxsr.config import ModelConfig
    from jaxsr.io.checkpoint import save_model
    from jaxsr.nn import Model, init_model
    import jax

    cfg = ModelConfig(tr=0, base=4, growth=2, head=4, filter_hidden=4)
    path = save_model(tmp_path / "m.npz", Model(*init_model(jax.random.key(0), cfg), cfg))
    arrays = dict(np.load(path))  # the same file with its config's bn_eps replaced
    meta = json.loads(str(arrays["__metadata__"]))
    meta["config"]["bn_eps"] = eps
    arrays["__metadata__"] = np.array(json.dumps(meta))
    np.savez(path, **arrays)
    assert cli.main(["info", str(path)]) == 2
    assert "bn_eps must be a number in (0, 1)" in capsys.readouterr().err
    np.save(tmp_path / "in.npy", np.full((2, 8, 8), 10.0, np.float32))
    assert command(tmp_path / "in.npy", tmp_path / "out.npy", "--model", path) == 2
    assert not (tmp_path / "out.npy").exists()


def test_nan_output_is_refused_not_written_as_no_return(tmp_path, model_path):
    """Weights that turn finite input into NaN (here the residual branch's bias): refused with nothing written."""
    import dataclasses

    import jax.numpy as jnp

    from jaxsr.app import upscale
    from jaxsr.io.checkpoint import load_model

    model = load_model(model_path)
    params = dict(model.params, residual=dict(model.params["residual"]))
    conv2 = dict(params["residual"]["conv2"], b=jnp.full_like(params["residual"]["conv2"]["b"], jnp.nan))
    params["residual"]["conv2"] = conv2
    broken = dataclasses.replace(model, params=params)
    with pytest.raises(ValueError, match="its output holds NaN in frame 0"):
        upscale(np.full((2, 8, 8), 10.0, np.float32), tmp_path / "out.npy", model=broken)
    assert not (tmp_path / "out.npy").exists()


@pytest.mark.parametrize("make, options, message", [
    (lambda: np.full((2, 8, 8), 9000.0, np.float32), {}, "could be millimetres or centimetres stored as floats"),
    (lambda: [[0.5]], {}, "got list (np.asarray makes an array of a list)"),
    (lambda: np.full((2, 8, 8), 0.5 + 0j), {}, "complex values are not depth nor counts"),
    (lambda: np.ones((2, 8, 8, 16)), {"span": 1e300}, "span (--span): expected 0.001 to 1e+06 m"),
    (lambda: np.ones((2, 8, 8, 16)), {"span": 1e-300}, "span (--span): expected 0.001 to 1e+06 m"),
    (lambda: np.ones((2, 8, 8, 16)), {"bins": 16.5}, "bins (--bins): expected an integer >= 2"),
    (lambda: np.ones((2, 8, 8)), {"fps": 1e9, "video": "v.gif"}, "fps (--fps): expected frames per second from 0.1 to 1000"),
    (lambda: np.ones((2, 8, 8)), {"fov_deg": 40.0}, "--fov applies to --points only"),
])
def test_bad_input_ends_in_one_clear_error(tmp_path, model_path, make, options, message):
    from jaxsr.app import upscale
    from upscale_specs import specs

    with pytest.raises((ValueError, TypeError)) as e:
        upscale(make(), None, **specs(model_path, **options))
    assert message in str(e.value)


def test_a_recording_whose_frame_rate_no_video_can_show_is_refused_before_the_work(tmp_path, model_path):
    io.write_sequence(tmp_path / "rec.npz", np.full((2, 8, 8), 12.0, np.float32), fps=1e-9)
    assert command(tmp_path / "rec.npz", tmp_path / "o.npy", "--model", model_path, "--video", tmp_path / "v.gif") == 2
    assert not (tmp_path / "o.npy").exists() and not (tmp_path / "v.gif").exists()


def test_bins_are_read_from_the_histograms(model_path):
    """32 bins without --bins: the gate has 32 bins over the trained 35 m (not 70 m of 16-bin widths), not a
    refusal asking for --bins; an array given as input never makes an output named "array" its own input."""
    from jaxsr.app import prepare_upscale

    counts = np.asarray(np.random.default_rng(0).poisson(1.0, (2, 8, 8, 32)), np.float32)
    job = prepare_upscale(counts, model=model_path)
    assert job.gate.bins == 32 and float(job.gate.bins * job.gate.bin_width) == pytest.approx(35.0)
    assert job.input_path is None


def test_a_sky_band_of_depth_input_stays_no_return_inside(model_path):
    """Depth input with a band of inf (no return) 3 LR rows high: the band's inner row comes out as no return
    whatever the network reads there (a pixel whose 8 neighbours hold no return too); rows with returns are the
    network's own."""
    from jaxsr.app import Reading, upscale
    from jaxsr.app.job import no_return_interior

    frames = np.full((3, 8, 12), 12.0, np.float32)
    frames[:, :3] = np.inf
    out = upscale(frames, None, model=model_path, read=Reading(units="m")).depth
    assert np.all(np.isinf(out[:, :8]))  # LR rows 0-1: their HR rows (the border row is edge-replicated)
    flags = no_return_interior(np.where(np.isinf(frames[0]), 1.0, 0.3))
    assert flags[:2].all() and not flags[2:].any()


def test_write_upscaled_takes_what_is_written_once(tmp_path, model_path):
    """Checked Outputs hold their Writing: a second one beside them is refused, not silently dropped."""
    from jaxsr.app import Writing, check_outputs, prepare_upscale, write_upscaled

    job = prepare_upscale(np.full((2, 8, 8), 12.0, np.float32), model=model_path)
    with pytest.raises(ValueError, match="not both"):
        write_upscaled(job, check_outputs(tmp_path / "o.npy"), Writing(video=tmp_path / "v.gif"))
    assert not (tmp_path / "o.npy").exists()


def test_a_recording_whose_metadata_header_lies_plays_at_the_default_rate(tmp_path, model_path, capsys):
    """An .npz recording whose metadata entry claims 10^12 characters: its frame rate for --video was NumPy's
    "Unable to allocate" traceback; the metadata is passed over as unusable (no frame rate from the file), and the
    video plays at the default rate."""
    import io as bytes_io
    import zipfile

    io.write_sequence(tmp_path / "rec.npz", np.full((2, 8, 8), 12.0, np.float32), fps=10)
    with zipfile.ZipFile(tmp_path / "rec.npz") as z:
        entries = {n: z.read(n) for n in z.namelist()}
    lie = bytes_io.BytesIO()
    np.lib.format.write_array_header_1_0(lie, {"descr": "<U1", "fortran_order": False, "shape": (10**12,)})
    entries["metadata.npy"] = lie.getvalue() + b"\0" * 16
    with zipfile.ZipFile(tmp_path / "rec.npz", "w") as z:
        for n, data in entries.items():
            z.writestr(n, data)
    assert command(tmp_path / "rec.npz", tmp_path / "o.npy", "--model", model_path, "--video", tmp_path / "v.gif") == 0
    assert "Traceback" not in capsys.readouterr().err
    from PIL import Image

    with Image.open(tmp_path / "v.gif") as gif:
        assert gif.info["duration"] == 40  # ms: 25 frames/s, not the 10 the unreadable metadata held
