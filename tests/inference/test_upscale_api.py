"""`jaxsr.upscale`, the library call behind `jaxsr upscale`: the same options give the same output, and bad
input raises the documented exception with the command's message, leaving nothing written."""

import json
from types import SimpleNamespace

import jax
import numpy as np
import pytest

import jaxsr
from jaxsr import cli, io
from jaxsr.config import Gate, Sensor
from jaxsr.app import PhotonRules, Reading, UpscaleResult, Writing, prepare_upscale, upscale, write_upscaled
from jaxsr.io.checkpoint import load_model
from upscale_specs import specs

SENSOR = Sensor()


@pytest.fixture(scope="module")
def metres():
    """Three LR frames of radial depth in metres, with some no-return pixels."""
    rng = np.random.default_rng(0)
    d = rng.uniform(2.0, 30.0, (3, 32, 64)).astype(np.float32)
    d[:, :4] = np.inf
    return d


def command(*args, capsys):
    """`jaxsr upscale ARGS` in-process: (exit status, the JSON summary or None, stderr)."""
    status = cli.main(["upscale", str(args[0]), "-o", *map(str, args[1:]), "--no-progress"])
    captured = capsys.readouterr()
    return status, (json.loads(captured.out) if status == 0 else None), captured.err


def test_the_top_level_name_is_the_library_call():
    assert jaxsr.upscale is upscale and "upscale" in jaxsr.__all__
    assert len(jaxsr.__all__) <= 62  # 60, and the Sensor's parts Optics and Pulse beside Gate and DepthScale


def test_npy_output_equals_the_command_and_in_memory(tmp_path, model_path, metres, capsys):
    np.save(tmp_path / "in.npy", metres)
    result = upscale(tmp_path / "in.npy", tmp_path / "api.npy", model=model_path, read=Reading(units="m"))
    status, summary, err = command(tmp_path / "in.npy", tmp_path / "cli.npy", "--model", model_path, "--units", "m",
                                   capsys=capsys)
    assert status == 0
    np.testing.assert_array_equal(np.load(tmp_path / "api.npy"), np.load(tmp_path / "cli.npy"))
    assert isinstance(result, UpscaleResult)
    assert result.output == tmp_path / "api.npy" and result.depth is None
    assert (result.frames, result.shape, result.kind, result.units) == (3, (3, 128, 256), "depth", "m")
    assert result.model == str(model_path) and result.gate is None and result.warnings == ()
    assert dict(result.summary(), output=None) == dict(summary, output=None)
    assert err.startswith("jaxsr upscale: " + result.notes[-1])
    # no output: the same frames in memory; a NumPy array or an opened job give them too
    kept = upscale(tmp_path / "in.npy", None, model=model_path, read=Reading(units="m"))
    assert kept.output is None
    np.testing.assert_array_equal(kept.depth, np.load(tmp_path / "cli.npy"))
    np.testing.assert_array_equal(upscale(metres, None, model=load_model(model_path)).depth, kept.depth)
    job = prepare_upscale(tmp_path / "in.npy", model=model_path)
    assert job.units == "m" and job.frames == 3 and job.hr_shape == (128, 256)
    # another batch size: the same frames up to float32 rounding (XLA may sum in another order)
    np.testing.assert_allclose(np.stack(list(job.iter_frames(batch_size=2))), kept.depth, rtol=1e-6)


def test_histograms_to_npz_with_a_gate_and_preview_equal_the_command(tmp_path, model_path, capsys):
    counts = np.asarray(jax.random.poisson(jax.random.key(1), 1.5, (3, 32, 64, 8)))
    io.write_histograms(tmp_path / "h.npz", counts, sensor=Sensor(gate=Gate.spanning(35.0, 8)))
    result = upscale(tmp_path / "h.npz", tmp_path / "api.npz", model=model_path, read=Reading(bins=8, bin_width="25ns", gate_start=10.0), write=Writing(preview=tmp_path / "api.png"), batch_size=2)
    status, summary, err = command(tmp_path / "h.npz", tmp_path / "cli.npz", "--model", model_path, "--bins", "8",
                                   "--bin-width", "25ns", "--gate-start", "10m", "--preview", tmp_path / "cli.png",
                                   "--batch-size", "2", capsys=capsys)
    assert status == 0
    api, cli_out = io.read_sequence(tmp_path / "api.npz"), io.read_sequence(tmp_path / "cli.npz")
    np.testing.assert_array_equal(api["depth"], cli_out["depth"])
    assert api["metadata"]["units"] == cli_out["metadata"]["units"] == "m"
    assert api["metadata"]["model"] == cli_out["metadata"]["model"]
    np.testing.assert_array_equal(io.read_image(tmp_path / "api.png"), io.read_image(tmp_path / "cli.png"))
    assert result.gate.bins == 8 and result.gate.start == 10.0 and result.preview == tmp_path / "api.png"
    assert summary["preview"] == str(tmp_path / "cli.png")
    assert dict(result.summary(), output=None, preview=None) == dict(summary, output=None, preview=None)
    for note in result.notes[:-1]:  # the gate's warnings, printed by the command as they are
        assert f"jaxsr upscale: {note}" in err


def test_folder_output_equals_the_command(tmp_path, model_path, metres, capsys):
    np.save(tmp_path / "in.npy", metres)
    upscale(tmp_path / "in.npy", tmp_path / "api", model=model_path, write=Writing(frame_format="pfm"))
    assert command(tmp_path / "in.npy", tmp_path / "cli", "--model", model_path, "--frame-format", "pfm",
                   capsys=capsys)[0] == 0
    names = sorted(f.name for f in (tmp_path / "api").iterdir())
    assert names == sorted(f.name for f in (tmp_path / "cli").iterdir()) == [f"frame_{t:06d}.pfm" for t in range(3)]
    for name in names:
        np.testing.assert_array_equal(io.read_depth(tmp_path / "api" / name), io.read_depth(tmp_path / "cli" / name))


@pytest.mark.parametrize("make,options,error,message", [
    (lambda p: None, {}, FileNotFoundError, "no such file"),
    (lambda p: np.save(p / "in.npy", np.zeros(5)), {}, ValueError, "expected depth"),
    (lambda p: np.save(p / "in.npy", np.full((2, 32, 64), 5.0)), {"units": "normalised"}, ValueError,
     r"outside \[0, 1\]"),
    (lambda p: np.save(p / "in.npy", np.full((2, 32, 64), 0.5)), {"bins": 8}, ValueError, "histograms and time tags"),
    (lambda p: np.save(p / "in.npy", np.full((2, 32, 64), 0.5)), {"min_fps": 5.0}, ValueError, "--model auto only"),
    (lambda p: np.save(p / "in.npy", np.full((2, 32, 64), 0.5)), {"time_unit": "1ps"}, ValueError,
     "applies to time tags only"),
    (lambda p: np.save(p / "in.npy", np.ones((2, 32, 64, 8))), {"bins": 16}, ValueError, "8 bins"),
    (lambda p: (np.save(p / "in.npy", np.full((2, 32, 64), 0.5)), (p / "out.npy").write_bytes(b"keep")), {},
     FileExistsError, "--force"),
    (lambda p: np.save(p / "in.npy", np.full((2, 32, 64), 0.5)), {"preview": "strip.jpg"}, ValueError, "a .png"),
])
def test_bad_input_raises_the_commands_error(tmp_path, model_path, capsys, make, options, error, message):
    make(tmp_path)
    before = sorted(p.name for p in tmp_path.iterdir())
    with pytest.raises(error, match=message):
        upscale(tmp_path / "in.npy", tmp_path / "out.npy", **specs(model_path, **options))
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # nothing written, nothing replaced
    # the command says the same, as one line, exit status 2
    args = [f"--{k.replace('_', '-')}={v}" for k, v in options.items()]
    status, _, err = command(tmp_path / "in.npy", tmp_path / "out.npy", "--model", model_path, *args, capsys=capsys)
    assert status == 2 and err.startswith("jaxsr upscale: error: ") and len(err.strip().splitlines()) == 1


def background_subtracted():
    """Histograms (3, 32, 64, 16) with their background subtracted, as some published data sets are: photon counts
    less a background of 1.5 per bin, so that many counts are negative."""
    counts = np.asarray(jax.random.poisson(jax.random.key(2), 1.5, (3, 32, 64, SENSOR.bins)), np.float32)
    counts[:, 10:14, 20:30, 5] += 20.0  # a return
    return counts - 1.5


def test_clip_negative_clips_background_subtracted_histograms_and_says_how_many(model_path):
    """Refused by default (the message names the option); clipped at 0 with clip_negative, the result that of the
    histograms clipped beforehand, and the negative counts and the pixels holding them said in a warning, the
    result and the summary."""
    counts = background_subtracted()
    n, pixels = int((counts < 0).sum()), int((counts < 0).any(-1).sum())
    with pytest.raises(ValueError, match=r"array: frame 0 holds negative photon counts.*--clip-negative, "
                       r"clip_negative=True"):
        upscale(counts, None, model=model_path)
    result = upscale(counts, None, model=model_path, read=Reading(clip_negative=True))
    # (the ambient-only test is off for clipped counts: their ambient light was subtracted)
    clipped = upscale(np.maximum(counts, 0), None, model=model_path, photons=PhotonRules(ambient_alpha=None))
    np.testing.assert_array_equal(result.depth, clipped.depth)
    assert result.negative_counts == (n, pixels) and 0 < pixels < n
    assert result.summary()["negative_counts_clipped"] == {"counts": n, "pixels": pixels}
    assert result.warnings[-1] == (f"{n} negative counts in {pixels} pixels clipped at 0 (--clip-negative: "
                                   "background-subtracted histograms)")
    assert f"warning: {result.warnings[-1]}" in result.notes
    # nothing to clip: (0, 0), and no warning; without the option, no such field
    job = prepare_upscale(np.maximum(counts, 0), model=model_path, read=Reading(clip_negative=True))
    assert job.negative_counts == (0, 0) and not any("negative" in w for w in job.warnings)
    assert prepare_upscale(np.maximum(counts, 0), model=model_path).negative_counts is None


@pytest.mark.parametrize("case", ["NaN count", "depth", "time tags"])
def test_clip_negative_clips_nothing_else(tmp_path, model_path, case):
    """Non-finite counts stay refused with clip_negative; depth and time tags (whose counts are never negative)
    refuse the option."""
    if case == "NaN count":
        counts = background_subtracted()
        counts[1, 0, 0, 0] = np.nan
        source, options, message = counts, {}, "frame 1 holds non-finite"
    elif case == "depth":
        source, options, message = np.full((2, 32, 64), 0.5, np.float32), {}, "histograms only"
    else:
        np.savez(tmp_path / "t.npz", pixel=np.arange(16), time=np.arange(16.0), shape=np.array([4, 4]))
        source, options, message = tmp_path / "t.npz", {"kind": "timetags", "time_unit": "1ns"}, "never negative"
    with pytest.raises(ValueError, match=message):
        upscale(source, None, model=model_path, read=Reading(clip_negative=True, **options))


def test_write_upscaled_checks_its_output(tmp_path, model_path, metres):
    job = prepare_upscale(metres, model=model_path)
    (tmp_path / "out.npz").write_bytes(b"keep")
    with pytest.raises(FileExistsError, match="--force"):
        write_upscaled(job, tmp_path / "out.npz")
    with pytest.raises(ValueError, match="frame_format"):
        write_upscaled(job, tmp_path / "frames", write=Writing(frame_format="jpg"))
    assert (tmp_path / "out.npz").read_bytes() == b"keep" and not (tmp_path / "frames").exists()


@pytest.mark.slow  # renders a scene sequence twice (15 s)
def test_simulate_recording_equals_the_command(tmp_path, capsys):
    """`jaxsr.simulate_recording`, the library call behind `jaxsr simulate`: the same files and summary."""
    result = jaxsr.simulate_recording(tmp_path / "api", kind="walkers", frames=2, seed=3)
    assert cli.main(["simulate", "--scene", "walkers", "--frames", "2", "--seed", "3", "--output",
                     str(tmp_path / "cli")]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert dict(result.summary(), out=None) == dict(summary, out=None)
    assert result.counts.shape == (2, 32, 64, 16) and result.depth.shape == (2, 128, 256)
    for name in ("com_depth.npy", "gt_depth.npy"):
        np.testing.assert_array_equal(np.load(tmp_path / "api" / name), np.load(tmp_path / "cli" / name))
    np.testing.assert_array_equal(io.read_histograms(tmp_path / "api" / "histograms.npz")["counts"],
                                  io.read_histograms(tmp_path / "cli" / "histograms.npz")["counts"])
    with pytest.raises(FileExistsError, match="--force"):
        jaxsr.simulate_recording(tmp_path / "api", kind="walkers", frames=2)
    with pytest.raises(ValueError, match="--camera"):
        jaxsr.simulate_recording(None, camera="flying")
    with pytest.raises(ValueError, match=r"simulate_recording: snr must be a scalar .* shape \(2,\)"):
        jaxsr.simulate_recording(None, snr=np.array([1.0, 2.0]))


def test_simulate_clip_refuses_an_array_snr():
    """`harness.scoring.simulate_clip` takes one SNR for the clip (a TypeError before)."""
    from harness.scoring import simulate_clip

    record = SimpleNamespace(name="x", depth=np.full((2, 128, 256), 8.0, np.float32),
                             intensity=np.full((2, 128, 256), 0.5, np.float32), fps=25.0, snr=1.3)
    with pytest.raises(ValueError, match=r"simulate_clip: snr must be a scalar .* shape \(2,\)"):
        simulate_clip(jax.random.key(0), record, snr=np.array([1.0, 2.0]))
