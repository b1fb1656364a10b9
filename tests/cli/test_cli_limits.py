"""`jaxsr upscale` and `jaxsr simulate` at the limits of memory and of their output paths,
in-process. Each refusal is one line `jaxsr CMD: error: ...` saying what was expected, exit status 2, before the
work and with nothing written; a result the format cannot hold exactly comes with a warning line that counts it.
Memory budgets are given (--max-memory) so that the machine's RAM does not decide the outcome."""

import errno
import json
import os
import tempfile
from pathlib import Path

import jax
import numpy as np
import pytest

from jaxsr import cli
from jaxsr.config import ModelConfig
from jaxsr.io.checkpoint import save_model
from jaxsr.nn import Model, init_model

TINY = ModelConfig(tr=1, base=8, growth=4, head=16, filter_hidden=16)


@pytest.fixture(scope="module")
def model_path(tmp_path_factory):
    path = tmp_path_factory.mktemp("model") / "tiny.npz"
    save_model(path, Model(*init_model(jax.random.key(0), TINY), TINY), card={"data": "none: random weights"})
    return path


def tree(folder):
    """Every path below `folder`, hidden ones included."""
    return sorted(str(p.relative_to(folder)) for p in Path(folder).rglob("*"))


def run(argv, capsys):
    """`jaxsr ARGV` in-process: (exit status, stdout, the stderr lines), with no traceback."""
    status = cli.main([*map(str, argv)])
    out, err = capsys.readouterr()
    assert "Traceback" not in err, err
    return status, out, err.splitlines()


def refused(argv, capsys, folder, *words):
    """Exit status 2, one stderr line `jaxsr CMD: error: ...` holding `words`, `folder` as it was."""
    before = tree(folder)
    status, _, lines = run(argv, capsys)
    assert status == 2 and len(lines) == 1, lines
    assert lines[0].startswith(f"jaxsr {argv[0]}: error: "), lines
    for word in words:
        assert word in lines[0], lines[0]
    assert tree(folder) == before
    return lines[0]


@pytest.fixture
def depth(tmp_path, monkeypatch):
    """in.npy: 3 frames of normalised depth, 32 x 64; the working folder is tmp_path."""
    np.save(tmp_path / "in.npy", np.random.default_rng(0).uniform(0.1, 0.9, (3, 32, 64)).astype(np.float32))
    monkeypatch.chdir(tmp_path)
    return tmp_path


# --- memory: estimated before it is allocated ---------------------------------------------------------------


def test_a_huge_frame_is_refused_with_its_memory_estimate_before_the_work(tmp_path, model_path, capsys,
                                                                         monkeypatch):
    """One 4097 x 4097 frame took 7 GB and more with no word up front; now the estimate, and --max-memory: from
    the frame's size alone (its result held, at least), or, with a budget that holds that, of the whole work."""
    np.save(tmp_path / "big.npy", np.full((1, 4097, 4097), 0.5, np.float32))
    monkeypatch.chdir(tmp_path)
    line = refused(["upscale", "big.npy", "-o", "out.npz", "--model", model_path, "--max-memory", "3GB"], capsys,
                   tmp_path, "upscaling 1 frame of 4097 x 4097 to 16388 x 16388 needs at least about ",
                   "more than the 3.0 GB allowed by --max-memory", "or more (max_memory=) to try anyway")
    least = float(line.split("needs at least about ")[1].split(" GB")[0])
    assert 4 < least < 8  # the input frame, the result and the HR frames of a batch of one: 4.8 GB
    line = refused(["upscale", "big.npy", "-o", "out.npz", "--model", model_path, "--max-memory", f"{least + 0.1}GB"],
                   capsys, tmp_path, "upscaling 1 frame of 4097 x 4097 to 16388 x 16388 needs about ",
                   "allowed by --max-memory", "to try anyway")
    need = float(line.split("needs about ")[1].split(" GB")[0])
    assert least < need < 8  # measured: 7 GB with the bundled TR4, whose features take more than the tiny model's


def test_a_huge_batch_runs_as_the_recording_and_is_refused_beyond_the_budget(depth, model_path, capsys):
    """--batch-size 1000000 allocated 8 GB for 3 frames (every batch padded to its size): a batch is at most the
    recording, the same output; and a batch the budget cannot hold is refused, naming --batch-size."""
    assert run(["upscale", "in.npy", "-o", "one.npy", "--model", model_path, "--batch-size", "1", "--no-progress"],
               capsys)[0] == 0
    assert run(["upscale", "in.npy", "-o", "huge.npy", "--model", model_path, "--batch-size", "1000000", "--no-progress",
                "--max-memory", "2GB"], capsys)[0] == 0
    np.testing.assert_allclose(np.load(depth / "huge.npy"), np.load(depth / "one.npy"), atol=1e-6)
    np.save(depth / "long.npy", np.full((400, 32, 64), 0.5, np.float32))
    refused(["upscale", "long.npy", "-o", "out.npz", "--model", model_path, "--batch-size", "1000000", "--max-memory",
             "1GB"], capsys, depth, "upscaling 400 frames of 32 x 64 to 128 x 256 needs about",
            "give a smaller --batch-size (now 400) or an .npy or folder OUTPUT (written frame by frame, not held)")


def test_an_npz_input_reads_only_its_recording_and_checks_its_size_first(tmp_path, model_path, capsys, monkeypatch):
    """An .npz's unused arrays were decompressed whole (3 GB for 8 frames of counts beside their HR depth): only
    the recording's array (and the metadata) is read, once its size passes the budget."""
    counts = np.random.default_rng(0).poisson(2.0, (2, 32, 64, 16)).astype(np.uint16)
    np.savez_compressed(tmp_path / "h.npz", counts=counts, depth=np.zeros((2, 512, 1024), np.float32),
                        extra=np.zeros((64, 1024, 1024), np.uint8), metadata=np.array('{"fps": 10}'))
    read = []
    real = np.lib.npyio.NpzFile.__getitem__
    monkeypatch.setattr(np.lib.npyio.NpzFile, "__getitem__",
                        lambda self, key: read.append((Path(self.zip.filename).name, key)) or real(self, key))
    monkeypatch.chdir(tmp_path)
    status, out, _ = run(["upscale", "h.npz", "-o", "out.npy", "--model", model_path, "--no-progress"], capsys)
    assert status == 0 and json.loads(out)["shape"] == [2, 128, 256]
    assert {key for name, key in read if name == "h.npz"} == {"counts", "metadata"}, read
    refused(["upscale", "h.npz", "-o", "out2.npy", "--model", model_path, "--max-memory", "100kB"], capsys, tmp_path,
            "h.npz: its array 'counts' needs about 131 kB of memory, more than the 100 kB allowed by --max-memory")


def test_time_tags_of_many_bins_or_frames_are_refused_with_the_estimate(tmp_path, model_path, capsys, monkeypatch):
    """--bins 100000 was killed for memory after a minute, a frame index of 1e7 a traceback."""
    np.savez(tmp_path / "t.npz", pixel=np.arange(2048), time=np.full(2048, 5000.0) + np.arange(2048),
             frame=np.zeros(2048, np.int64), shape=np.array([32, 64]), time_unit_s=1e-12)
    frame = np.zeros(2048, np.int64)
    frame[-1] = 10**7
    np.savez(tmp_path / "far.npz", pixel=np.arange(2048), time=5000.0 + np.arange(2048), frame=frame,
             shape=np.array([32, 64]), time_unit_s=1e-12)
    monkeypatch.chdir(tmp_path)
    tags = ["--kind", "timetags", "--model", model_path]
    refused(["upscale", "t.npz", "-o", "out.npy", *tags, "--bins", "100000", "--max-memory", "1GB"], capsys, tmp_path,
            "t.npz: histogramming 1 frame of 32 x 64 pixels x 100000 bins needs about 1.6 GB", "give fewer --bins")
    refused(["upscale", "far.npz", "-o", "out.npy", *tags], capsys, tmp_path,
            "far.npz: histogramming 10000001 frames (frame indices up to 10000000)", "check the frame indices")


def test_max_memory_is_a_size_with_its_unit(depth, model_path, capsys):
    with pytest.raises(SystemExit) as caught:  # argparse's one line
        cli.main(["upscale", "in.npy", "-o", "out.npy", "--model", str(model_path), "--max-memory", "16"])
    assert caught.value.code == 2
    assert "argument --max-memory: expected a size > 0 with its unit" in capsys.readouterr().err
    refused(["simulate", "--frames", "100000", "--output", "sim", "--max-memory", "8GB"], capsys, depth,
            "simulating 100000 frames needs about 1500.7 GB of memory, more than the 8.0 GB allowed",
            "simulate the recording in parts")
    (depth / "airsim").mkdir()  # an AirSim recording is counted by its rows before its images are read
    (depth / "airsim" / "airsim_rec.txt").write_text("TimeStamp\tImageFile\n" + "0\tx.pfm\n" * 1000)
    refused(["simulate", "airsim", "--output", "sim", "--max-memory", "10GB"], capsys, depth,
            "simulating 1000 frames needs about 15.7 GB of memory")


# --- time tags: what the photons say about the gate and the unit --------------------------------------------


def test_time_tag_warnings_are_lines_and_a_negative_gate_start_is_refused(tmp_path, model_path, capsys,
                                                                         monkeypatch):
    """Photons dropped outside the gate are counted; times read in a unit 1000x too small fall inside a sliver
    of the gate: a warning names the unit that fits. A gate before the laser pulse gave negative metres."""
    times = np.random.default_rng(1).uniform(5005, 6195, 2048)
    times[:5] = 1e8
    np.savez(tmp_path / "t.npz", pixel=np.arange(2048), time=times, shape=np.array([32, 64]))
    monkeypatch.chdir(tmp_path)
    gate = ["--kind", "timetags", "--model", model_path, "--no-progress", "--bin-width", "1ns", "--gate-start", "0ns"]
    status, _, lines = run(["upscale", "t.npz", "-o", "out.npy", *gate, "--time-unit", "1fs", "--drop-outside"], capsys)
    assert status == 0
    assert lines[0] == "jaxsr upscale: warning: t.npz: 5 of 2048 photons outside the gate dropped (--drop-outside)"
    assert lines[1].startswith("jaxsr upscale: warning: t.npz: the photons fall inside 0.01% of the gate; is the "
                               "time unit right? with --time-unit 1ps (not 1fs) 100% of them would fall inside"), lines
    refused(["upscale", "t.npz", "-o", "out2.npy", "--kind", "timetags", "--model", model_path, "--time-unit", "1ps",
             "--bin-width", "1ns", "--gate-start=-2ns"], capsys, tmp_path,
            "gate_start (--gate-start): expected a range >= 0 from the laser pulse, got -0.299792 m")


# --- output paths ------------------------------------------------------------------------------------------


def test_a_folder_that_cannot_be_written_into_is_refused_before_the_work(depth, model_path, capsys, monkeypatch):
    """A read-only output folder was an OSError traceback. Root writes anywhere, so os.access (which reports a
    read-only file system to root too) is made to refuse."""
    monkeypatch.setattr(os, "access", lambda path, mode: os.path.abspath(path) != str(depth))
    refused(["upscale", "in.npy", "-o", "out.npy", "--model", model_path], capsys, depth,
            f"cannot write out.npy: {depth} is not writable; choose a folder you can write to")
    refused(["upscale", "in.npy", "-o", "frames", "--model", model_path], capsys, depth,
            f"cannot write frames: {depth} is not writable")


@pytest.mark.parametrize("output,factory", [("out.npz", "mkstemp"), ("frames", "mkdtemp")])
def test_a_read_only_file_system_found_at_the_write_is_exit_2_and_leaves_nothing(depth, model_path, capsys,
                                                                                  monkeypatch, output, factory):
    """EROFS where the output's temporary is created, after the work: one line naming the output, exit 2."""

    def read_only(*args, dir=None, **kwargs):
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), os.path.join(dir, ".x"))

    monkeypatch.setattr(tempfile, factory, read_only)
    before = tree(depth)
    status, _, lines = run(["upscale", "in.npy", "-o", output, "--model", model_path, "--no-progress"], capsys)
    assert status == 2 and len(lines) == 2, lines  # what is read with which model, then the error
    assert lines[-1] == (f"jaxsr upscale: error: cannot write {output}: read-only file system; choose a folder you "
                         "can write to")
    assert tree(depth) == before


def test_a_symbolic_link_as_output_is_refused_up_front(depth, model_path, capsys):
    """A link to a folder failed after the run (the final rename cannot replace it); a link to nothing looked like
    another writer's output."""
    (depth / "real").mkdir()
    os.symlink(depth / "real", depth / "frames")
    os.symlink(depth / "nowhere.npy", depth / "out.npy")
    refused(["upscale", "in.npy", "-o", "frames", "--model", model_path], capsys, depth,
            f"frames is a symbolic link (to {depth / 'real'}); OUTPUT is moved into place by a rename")
    refused(["upscale", "in.npy", "-o", "out.npy", "--model", model_path, "--force"], capsys, depth,
            "out.npy is a symbolic link", "give the path it points to")


def test_frame_format_applies_to_a_folder_and_a_folder_is_metres(depth, model_path, capsys):
    """--frame-format with an .npy output was silently ignored; the summary of a folder of frames said the
    input's units (normalised) while the frames are metres."""
    refused(["upscale", "in.npy", "-o", "out.npy", "--model", model_path, "--frame-format", "png"], capsys, depth,
            "--frame-format) applies to a folder OUTPUT (one file per frame), not out.npy")
    status, out, lines = run(["upscale", "in.npy", "-o", "frames", "--model", model_path, "--no-progress"], capsys)
    assert status == 0 and "input units normalised" in lines[-1]
    summary = json.loads(out)
    assert summary["units"] == "m" and summary["input_units"] == "normalised"
    assert sorted(p.name for p in (depth / "frames").iterdir()) == [f"frame_00000{t}.exr" for t in range(3)]


def test_png_frames_beyond_65_m_are_refused_or_counted(tmp_path, model_path, capsys, monkeypatch):
    """16-bit PNG holds 1 mm .. 65.535 m, and deeper depth was clipped silently: a range that starts beyond is
    refused up front, and pixels beyond are counted in a warning that names the formats that hold them."""
    counts = np.zeros((2, 32, 64, 16), np.float32)
    counts[..., 9] = 20.0  # a return in bin 9 of 16
    np.save(tmp_path / "h.npy", counts)
    monkeypatch.chdir(tmp_path)
    args = ["upscale", "h.npy", "-o", "frames", "--model", model_path, "--frame-format", "png", "--no-progress"]
    refused([*args, "--gate-start", "70m", "--bin-width", "2m"], capsys, tmp_path,
            "16-bit PNG frames hold depth up to 65.535 m, and this recording's range starts at 70 m",
            "choose --frame-format exr, pfm or tif")
    status, _, lines = run([*args, "--gate-start", "50m", "--bin-width", "2m"], capsys)  # returns at about 69 m
    assert status == 0
    pixels = int(lines[-1].split("warning: ")[1].split(" pixel")[0])
    assert 0 < pixels <= 2 * 128 * 256
    assert lines[-1] == (f"jaxsr upscale: warning: {pixels} pixels beyond 65.535 m written as 65.535 m (16-bit PNG's "
                         "largest depth); --frame-format exr, pfm or tif store them")


def test_a_result_too_large_to_hold_is_refused_before_any_frame_is_read(tmp_path, model_path, capsys, monkeypatch):
    """A 13 GB recording into an .npz was refused for memory only after a 53 s pass over its frames: its result
    held whole is sized from the recording's shape, and refused before one frame is read (`upscale`, and the
    command on a memory-mapped .npy). The same frames into an .npy (written frame by frame) still run."""
    from jaxsr.app import Recording, upscale
    from jaxsr.app.memory import result_memory

    def unread():
        raise AssertionError("a frame was read")

    frames, shape = 2000, (64, 64)
    long = Recording("depth", frames, shape, unread, "long")
    need = result_memory(long, 4, in_memory=True, looks=False)
    assert need > frames * 4 * 256 * 256  # the result, at least
    with pytest.raises(ValueError, match=r"upscaling 2000 frames of 64 x 64 to 256 x 256 needs at least about "
                                         r"1\.0 GB of memory, more than the 900 MB allowed by --max-memory .*an \.npy "
                                         r"or folder OUTPUT"):
        upscale(long, tmp_path / "out.npz", model=str(model_path), max_memory="900MB")
    with pytest.raises(ValueError, match="needs at least about"):
        upscale(long, None, model=str(model_path), max_memory="900MB")
    with pytest.raises(AssertionError, match="a frame was read"):  # written frame by frame: within the budget
        upscale(long, tmp_path / "out.npy", model=str(model_path), max_memory="900MB")

    np.lib.format.open_memmap(tmp_path / "long.npy", "w+", np.float32, (frames, *shape))[:] = 0.5
    monkeypatch.setattr(Recording, "__iter__", lambda self: unread())
    monkeypatch.chdir(tmp_path)
    refused(["upscale", "long.npy", "-o", "out.npz", "--model", model_path, "--max-memory", "900MB"], capsys, tmp_path,
            "upscaling 2000 frames of 64 x 64 to 256 x 256 needs at least about")


def test_the_least_memory_of_a_result_is_below_the_estimate_of_its_work(depth, model_path):
    """`result_memory` (from the sizes, before anything is read) never exceeds `upscale_memory` (of the whole job,
    once the model is chosen), whatever is held: a recording it refuses would be refused later anyway."""
    from jaxsr.app import prepare_upscale, upscale_memory
    from jaxsr.app.memory import result_memory

    job = prepare_upscale(depth / "in.npy", model=str(model_path))
    for in_memory in (False, True):
        for looks in (False, True):
            least = result_memory(job.recording, 4, in_memory=in_memory, looks=looks)
            assert least <= upscale_memory(job, batch_size=1, in_memory=in_memory, looks=looks)
