"""A full disk (ENOSPC, as any OSError of the system) while `jaxsr upscale`, `jaxsr simulate` or `jaxsr train`
writes: exit status 1 and one line, `jaxsr CMD: error: no space left on device while writing OUT; nothing was
written (...)`, naming the output (never its hidden temporary), with no traceback and no file or temporary left
behind. The write is made to fail in-process (monkeypatch), after part of the file is written where it can be."""

import errno
import os
from pathlib import Path

import jax
import numpy as np
import pytest

import jaxsr.app.writing as recording
import jaxsr.training.presets as presets
from jaxsr import cli
from jaxsr.config import ModelConfig
from jaxsr.io.checkpoint import save_model
from jaxsr.nn import Model, init_model

TINY = ModelConfig(tr=1, base=8, growth=4, head=16, filter_hidden=16)
FULL = "no space left on device while writing"


@pytest.fixture(scope="module")
def model_path(tmp_path_factory):
    path = tmp_path_factory.mktemp("model") / "tiny.npz"
    save_model(path, Model(*init_model(jax.random.key(0), TINY), TINY), card={"data": "none: random weights"})
    return path


def disk_full(*args, **kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def half_then_full(file, *args, **kwargs):
    """np.save / np.savez(_compressed) on a full disk: some bytes reach the file, then ENOSPC."""
    file.write(b"PK\x03\x04 half an archive")
    disk_full()


def tree(folder):
    """Every path below `folder`, hidden ones included."""
    return sorted(str(p.relative_to(folder)) for p in Path(folder).rglob("*"))


def run_full(argv, capsys):
    """`jaxsr ARGV` in-process: (exit status, the last stderr line), with no traceback on stderr."""
    status = cli.main([*map(str, argv)])
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    return status, err.splitlines()[-1]


def frame_then_full(real):
    """write_depth that writes the first frame, then finds the disk full."""

    def write(path, depth, **kwargs):
        if Path(path).name != "frame_000000.exr":
            disk_full()
        real(path, depth, **kwargs)

    return write


# output, (module, attribute, replacement factory), what is named, what was removed
UPSCALE_CASES = {
    "npz": ("out.npz", (np, "savez_compressed", lambda: half_then_full), "out.npz", "file"),
    "npy": ("out.npy", (os, "posix_fallocate", lambda: disk_full), "out.npy", "file"),  # before the map is written
    "folder of frames": ("out", (recording, "write_depth", lambda: frame_then_full(recording.write_depth)), "out",
                         "folder"),
}


@pytest.mark.parametrize("case", UPSCALE_CASES)
def test_upscale_on_a_full_disk_exits_1_with_one_line_and_leaves_nothing(tmp_path, model_path, monkeypatch,
                                                                         capsys, case):
    output, (module, name, replacement), named, partial = UPSCALE_CASES[case]
    np.save(tmp_path / "in.npy", np.full((3, 32, 64), 0.5, np.float32))
    before = tree(tmp_path)
    monkeypatch.setattr(module, name, replacement())
    monkeypatch.chdir(tmp_path)
    status, line = run_full(["upscale", "in.npy", "-o", output, "--model", model_path, "--no-progress"], capsys)
    assert status == 1
    assert line == f"jaxsr upscale: error: {FULL} {named}; nothing was written (the partial {partial} was removed)"
    assert tree(tmp_path) == before  # no output, no hidden temporary


@pytest.mark.slow  # renders a scene sequence (10 s)
def test_simulate_on_a_full_disk_exits_1_and_leaves_no_folder(tmp_path, monkeypatch, capsys):
    """The first file (histograms.npz, written into the hidden temporary folder) fails: the message names its
    final place, and neither OUT nor the temporary folder is left."""
    monkeypatch.setattr(np, "savez_compressed", half_then_full)
    monkeypatch.chdir(tmp_path)
    status, line = run_full(["simulate", "--scene", "walkers", "--frames", "2", "--output", "sim"], capsys)
    assert status == 1
    want = os.path.join("sim", "histograms.npz")
    assert line == f"jaxsr simulate: error: {FULL} {want}; nothing was written (the partial folder was removed)"
    assert tree(tmp_path) == []


def test_train_on_a_full_disk_exits_1_and_leaves_no_run_folder(tmp_path, monkeypatch, capsys):
    """A checkpoint that cannot be written (here the run's first, through the real writer `save_model`): one
    line, and the new run folder goes too (nothing had been saved in it)."""

    def fit_that_saves(model_cfg, train_cfg, *, out, **kwargs):
        Path(out).mkdir(parents=True, exist_ok=True)
        save_model(Path(out) / "best.npz", Model(*init_model(jax.random.key(0), TINY), TINY))

    monkeypatch.setattr(presets, "fit", fit_that_saves)
    monkeypatch.setattr(np, "savez", half_then_full)
    monkeypatch.chdir(tmp_path)
    status, line = run_full(["train", "--tr", "0", "--output", "run", "--no-progress"], capsys)
    assert status == 1
    want = os.path.join("run", "best.npz")
    assert line == f"jaxsr train: error: {FULL} {want}; nothing was written (the partial file was removed)"
    assert tree(tmp_path) == []


@pytest.mark.slow
def test_a_real_training_run_on_a_full_disk(tmp_path, monkeypatch, capsys):
    """The real loop (1-2 min on two cores): its first save inside the epoch (--checkpoint-minutes 0) fails."""
    monkeypatch.setattr(np, "savez", half_then_full)
    monkeypatch.chdir(tmp_path)
    status, line = run_full(["train", "--tr", "0", "--epochs", "1", "--output", "run", "--no-progress",
                             "--checkpoint-minutes", "0"], capsys)
    assert status == 1 and line.startswith(f"jaxsr train: error: {FULL} {os.path.join('run', 'resume.npz')};")
    assert tree(tmp_path) == []


def test_another_os_error_is_one_line_and_exit_1(tmp_path, model_path, monkeypatch, capsys):
    """Any OSError the system raises (here EIO while the output is written) is one line without "[Errno N]"."""
    np.save(tmp_path / "in.npy", np.full((3, 32, 64), 0.5, np.float32))

    def io_error(file, *args, **kwargs):
        raise OSError(errno.EIO, os.strerror(errno.EIO))

    monkeypatch.setattr(np, "savez_compressed", io_error)
    monkeypatch.chdir(tmp_path)
    status, line = run_full(["upscale", "in.npy", "-o", "out.npz", "--model", model_path, "--no-progress"], capsys)
    assert status == 1
    assert line == ("jaxsr upscale: error: input/output error while writing out.npz; nothing was written (the "
                    "partial file was removed)")
    assert tree(tmp_path) == ["in.npy"]


@pytest.mark.parametrize("error,said", [
    (OSError(errno.EIO, os.strerror(errno.EIO), "in.npy"), f"{os.strerror(errno.EIO)}: in.npy"),
    (OSError("ffmpeg ended:\n  broken pipe"), "ffmpeg ended: broken pipe"),
])
def test_an_os_error_outside_the_writes_is_one_line_too(monkeypatch, capsys, error, said):
    """An OSError raised elsewhere (reading, a helper program): the system's words and the file, one line."""
    import jaxsr.cli.upscale as command

    def fail(*args, **kwargs):
        raise error

    monkeypatch.setattr(command, "upscale", fail)
    assert run_full(["upscale", "in.npy", "-o", "out.npy"], capsys) == (1, f"jaxsr upscale: error: {said}")


# --- a read-only file system: the user's choice of place (exit 2), wherever it is met -------------------------


@pytest.mark.parametrize("where", ["the write, naming no file", "outside the writes"])
def test_a_read_only_file_system_is_exit_2_wherever_it_is_met(tmp_path, model_path, monkeypatch, capsys, where):
    """EROFS was exit 2 only where the error named the output's temporary: through an open file (no name) inside
    the write, or outside the atomic writes, it was exit 1, as a failing disk is."""
    import jaxsr.cli.upscale as command

    np.save(tmp_path / "in.npy", np.full((3, 32, 64), 0.5, np.float32))

    def read_only(*args, **kwargs):
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), *([] if where.startswith("the write") else ["/mnt/x"]))

    monkeypatch.setattr(np, "savez_compressed", read_only)
    if where == "outside the writes":
        monkeypatch.setattr(command, "upscale", read_only)
    monkeypatch.chdir(tmp_path)
    status, line = run_full(["upscale", "in.npy", "-o", "out.npz", "--model", model_path, "--no-progress"], capsys)
    assert status == 2
    assert line == ("jaxsr upscale: error: cannot write out.npz: read-only file system; choose a folder you can "
                    "write to" if where.startswith("the write") else
                    f"jaxsr upscale: error: {os.strerror(errno.EROFS)}: /mnt/x")
    assert tree(tmp_path) == ["in.npy"]


def test_png_frames_on_a_really_full_disk_exit_1_and_leave_nothing(small_tmpfs, model_path, tmp_path, capsys):
    """OpenImageIO's PNG writer reports a failed write in its error text only: 41 empty frames and exit 0 before."""
    np.save(tmp_path / "in.npy", np.random.default_rng(0).uniform(2, 30, (8, 64, 64)).astype(np.float32))
    status = cli.main(["upscale", str(tmp_path / "in.npy"), "-o", str(small_tmpfs / "out"), "--model", str(model_path),
                       "--frame-format", "png", "--units", "m", "--no-progress"])
    err = capsys.readouterr().err
    assert status == 1 and FULL in err and err.count("\n") == 2, err  # the note on the work, then the error
    assert not any(small_tmpfs.iterdir())


def test_a_video_on_a_really_full_disk_is_one_line_naming_it(small_tmpfs, model_path, tmp_path, capsys):
    """ffmpeg's failure on a full disk: one line naming the video, not ffmpeg's lines and a hidden temporary's."""
    np.save(tmp_path / "in.npy", np.random.default_rng(0).uniform(2, 30, (20, 32, 64)).astype(np.float32))
    status = cli.main(["upscale", str(tmp_path / "in.npy"), "-o", str(tmp_path / "out.npy"), "--model", str(model_path),
                       "--units", "m", "--video", str(small_tmpfs / "v.gif"), "--no-progress"])
    err = capsys.readouterr().err
    assert status == 1 and f"{FULL} {small_tmpfs / 'v.gif'}" in err and "partial" in err.splitlines()[-1], err
    assert "ffmpeg" not in err.lower() and not any(small_tmpfs.iterdir()) and not (tmp_path / "out.npy").exists()
