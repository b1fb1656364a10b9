"""The real `jaxsr` command (a subprocess, as a user runs it) on user mistakes: each exits with status 2 and
ONE line on stderr, `jaxsr CMD: error: ...`, saying what was expected, with no traceback and no file or folder
left behind (hidden temporaries and empty output folders included); checks run before the long work. Ctrl-C and
SIGTERM remove what the command had started to write. The cases are a few per kind of failure:
shapes the models were not made for, tracebacks that should be messages, options checked late, a run folder
replaced, interruptions; a hypothesis test throws arbitrary arrays at `jaxsr upscale`.

Each command starts JAX (2-4 s); the long cases are marked slow."""

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import jax
import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, event, example, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from jaxsr import io
from jaxsr.io.checkpoint import save_model
from jaxsr.config import ModelConfig
from jaxsr.nn import Model, init_model

ROOT = Path(__file__).resolve().parents[2]
ENV = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])]))
TINY = ModelConfig(tr=1, base=8, growth=4, head=16, filter_hidden=16)


def jaxsr(cwd, *args, timeout=300):
    """Run `jaxsr ARGS` (this worktree's code) in the folder `cwd`."""
    return subprocess.run([sys.executable, "-m", "jaxsr.cli", *map(str, args)], cwd=cwd, env=ENV,
                          capture_output=True, text=True, timeout=timeout, check=False)


def tree(folder):
    """Every path below `folder`, hidden ones included, with the size of each file."""
    return sorted((str(p.relative_to(folder)), p.stat().st_size if p.is_file() else None)
                  for p in Path(folder).rglob("*"))


def assert_refused(done, command, folder, before, *words):
    """Exit status 2, one line `jaxsr COMMAND: error: ...` holding `words`, and `folder` as it was."""
    lines = done.stderr.splitlines()
    assert done.returncode == 2, done.stderr
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith(f"jaxsr {command}: error: "), done.stderr
    for word in words:
        assert word in lines[0], lines[0]
    assert tree(folder) == before


@pytest.fixture(scope="module")
def model_path(tmp_path_factory):
    path = tmp_path_factory.mktemp("model") / "tiny.npz"
    save_model(path, Model(*init_model(jax.random.key(0), TINY), TINY), card={"data": "none: random weights"})
    return path


def _frames(folder, shape, fmt="png"):
    (folder / "frames").mkdir()
    for t in range(3):
        io.write_depth(folder / "frames" / f"f{t}.{fmt}", np.full(shape, 5.0 + t, np.float32))


def _negative_counts():
    """Two tiny background-subtracted histogram frames (4 x 4 pixels, 16 bins): 3 negative counts in 2 pixels of
    frame 1."""
    counts = np.full((2, 4, 4, 16), 2.0, np.float32)
    counts[1, 0, 1, 3] = -1.5
    counts[1, 2, 2, :2] = -0.5
    return counts


# (setup(folder), arguments, words the message must hold). `MODEL` is replaced by the tiny checkpoint.
CASES = {
    # shapes no network runs on (any h, w >= 4 does), and histograms of other than --bins bins
    "upscale 3x64 array": (lambda p: np.save(p / "in.npy", np.full((3, 3, 64), 0.5, np.float32)),
                           ["upscale", "in.npy", "-o", "out.npy", "--model", "MODEL"], ["3 x 64", "at least 4 x 4"]),
    "upscale folder of 64x3 frames": (lambda p: _frames(p, (64, 3)),
                                      ["upscale", "frames", "-o", "out", "--model", "MODEL"], ["64 x 3", "at least 4 x 4"]),
    "upscale histograms of 8 bins": (lambda p: np.save(p / "in.npy", np.ones((2, 32, 64, 8), np.uint16)),
                                     ["upscale", "in.npy", "-o", "out.npy", "--model", "MODEL", "--bins", "16"],
                                     ["8 bins", "16 bins", "--bins"]),
    "upscale --bin-width without a unit": (lambda p: np.save(p / "in.npy", np.ones((2, 32, 64, 16), np.uint16)),
                                           ["upscale", "in.npy", "-o", "out.npy", "--model", "MODEL", "--bin-width", "3"],
                                           ["--bin-width", "with its unit"]),
    "upscale negative counts": (lambda p: np.save(p / "in.npy", _negative_counts()),
                                ["upscale", "in.npy", "-o", "out.npy", "--model", "MODEL"],
                                ["frame 1", "negative photon counts", "--clip-negative"]),
    "upscale --clip-negative for depth": (lambda p: np.save(p / "in.npy", np.full((3, 32, 64), 0.5, np.float32)),
                                          ["upscale", "in.npy", "-o", "out.npy", "--model", "MODEL", "--clip-negative"],
                                          ["--clip-negative applies to histograms only"]),
    "upscale --bins for depth": (lambda p: np.save(p / "in.npy", np.full((3, 32, 64), 0.5, np.float32)),
                                 ["upscale", "in.npy", "-o", "out.npy", "--model", "MODEL", "--bins", "8"],
                                 ["histograms and time tags only"]),
    "upscale time tags of MATLAB v7.3": (lambda p: (p / "t.mat").write_bytes(b"MATLAB 7.3 MAT-file".ljust(124)
                                                                            + b"\x00\x02IM" + b"\0" * 400),
                                         ["upscale", "t.mat", "-o", "out.npy", "--model", "MODEL", "--kind", "timetags",
                                          "--time-unit", "1ps"], ["v7.3", "-v7"]),
    "upscale time tags outside the gate": (lambda p: np.savez(p / "t.npz", pixel=np.arange(16), time=np.arange(16.0),
                                                              shape=np.array([4, 4])),
                                           ["upscale", "t.npz", "-o", "out.npy", "--model", "MODEL", "--kind", "timetags",
                                            "--time-unit", "1ns", "--gate-start", "2ns", "--bin-width", "1ns"],
                                           ["2 of 16 photons", "outside the gate", "--drop-outside"]),
    # tracebacks that must be messages
    "upscale --model .npy": (lambda p: (np.save(p / "in.npy", np.full((3, 32, 64), 0.5, np.float32)),
                                        np.save(p / "m.npy", np.zeros(3))),
                             ["upscale", "in.npy", "-o", "out.npy", "--model", "m.npy"], [".npy array"]),
    "info .npy": (lambda p: np.save(p / "m.npy", np.zeros(3)), ["info", "m.npy"], [".npy array"]),
    # files that are not what their suffix says: named as such, never "load it unsafely" (numpy's pickle advice)
    "upscale random bytes as .npy": (lambda p: (p / "in.npy").write_bytes(bytes(range(256)) * 4),
                                     ["upscale", "in.npy", "-o", "out.npy", "--model", "MODEL"], ["not an NPY file"]),
    "upscale text as .npy": (lambda p: (p / "in.npy").write_text("depth,1,2\n"),
                             ["upscale", "in.npy", "-o", "out.npy", "--model", "MODEL"], ["not an NPY file"]),
    "upscale --model of random bytes": (lambda p: (np.save(p / "in.npy", np.full((3, 32, 64), 0.5, np.float32)),
                                                   (p / "m.npz").write_bytes(bytes(range(256)))),
                                        ["upscale", "in.npy", "-o", "out.npy", "--model", "m.npz"], ["not an .npz file"]),
    # checked before the set-up (rendering the validation sequences took 20-40 s first)
    "train --init of random bytes": (lambda p: (p / "w.npz").write_bytes(bytes(range(256))),
                                     ["train", "--tr", "0", "--init", "w.npz", "--output", "run"], ["not an .npz file"]),
    "train --data .npy": (lambda p: np.save(p / "d.npy", np.zeros(3)),
                          ["train", "--data", "d.npy", "--output", "run"], ["expected an .npz"]),
    "train --tr 99": (None, ["train", "--tr", "99", "--output", "run"], ["--tr", "from 0 to 8", "memory"]),
    "train --checkpoint-minutes -1": (None, ["train", "--checkpoint-minutes", "-1", "--output", "run"],
                                      ["--checkpoint-minutes", "minutes >= 0"]),
    "simulate --frames 0": (None, ["simulate", "--frames", "0", "--output", "S"], ["--frames", ">= 1"]),
    # options checked before the work
    "upscale --preview exists": (lambda p: (np.save(p / "in.npy", np.full((3, 32, 64), 0.5, np.float32)),
                                            (p / "strip.png").write_bytes(b"keep")),
                                 ["upscale", "in.npy", "-o", "out.npy", "--model", "MODEL", "--preview", "strip.png"],
                                 ["strip.png exists", "--force"]),
    "upscale --min-fps nan": (lambda p: np.save(p / "in.npy", np.full((3, 32, 64), 0.5, np.float32)),
                              ["upscale", "in.npy", "-o", "out.npy", "--model", "auto", "--min-fps", "nan"],
                              ["--min-fps", "finite number > 0"]),
    "upscale --min-fps with a fixed model": (lambda p: np.save(p / "in.npy", np.full((3, 32, 64), 0.5, np.float32)),
                                             ["upscale", "in.npy", "-o", "out.npy", "--model", "MODEL", "--min-fps", "5"],
                                             ["--model auto only"]),
    # a finished run is not replaced without --resume or --force
    "train over a run": (lambda p: ((p / "run").mkdir(), (p / "run" / "metrics.jsonl").write_text("{}\n")),
                         ["train", "--tr", "0", "--epochs", "1", "--output", "run"], ["holds a training run", "--force"]),
}


@pytest.mark.parametrize("name", CASES)
def test_user_mistakes_exit_2_with_one_line_and_leave_nothing(tmp_path, model_path, name):
    setup, args, words = CASES[name]
    if setup:
        setup(tmp_path)
    before = tree(tmp_path)
    done = jaxsr(tmp_path, *(str(model_path) if a == "MODEL" else a for a in args))
    assert_refused(done, args[0], tmp_path, before, *words)


# Arrays of any rank, size, dtype and values, the sensor's (T, 32, 64) and (T, 32, 64, 16) shapes among them
# (any (T, h, w) with h, w >= 4 and (T, h, w, 16) is upscaled; smaller sides and other bin counts refused).
SHAPES = st.one_of(
    st.sampled_from([(2, 32, 64), (32, 64), (1, 32, 64, 16), (2, 31, 64), (2, 32, 64, 8), (0, 32, 64)]),
    hnp.array_shapes(min_dims=0, max_dims=5, min_side=0, max_side=4),
)
DTYPES = st.sampled_from(["<f4", "<f8", "<f2", "<i2", "|u1", "|b1", "<c8", "<U2"])


# No shrinking: each example is a subprocess of seconds; the failing example is printed as found.
@pytest.mark.slow  # 8 subprocesses of arbitrary arrays (25 s); the one-line refusals are the cases above
@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture],
          phases=[Phase.explicit, Phase.generate])
@given(arr=hnp.arrays(DTYPES, SHAPES), units=st.sampled_from([None, "m", "normalised"]))
@example(arr=np.full((2, 31, 64), 0.5, np.float32), units=None)  # any size >= 4 x 4 runs: (2, 124, 256)
@example(arr=np.full((1, 32, 64, 16), 1.5e59), units=None)  # once an overflow warning on stderr
def test_upscale_any_array_is_upscaled_or_refused_cleanly(tmp_path_factory, model_path, arr, units):
    folder = tmp_path_factory.mktemp("any")
    np.save(folder / "in.npy", arr)
    before = tree(folder)
    done = jaxsr(folder, "upscale", "in.npy", "-o", "out.npy", "--model", model_path, "--no-progress",
                 *(["--units", units] if units else []))
    event(f"exit status {done.returncode}")
    assert "Traceback" not in done.stderr, done.stderr
    if done.returncode == 0:
        assert len(done.stderr.splitlines()) == 1, done.stderr  # the "N frames ... model" line, no warnings
        out = np.load(folder / "out.npy")
        lr = arr[None] if arr.ndim == 2 else arr
        assert out.shape == (lr.shape[0], 4 * lr.shape[1], 4 * lr.shape[2])
        assert [n for n, _ in tree(folder)] == sorted(["in.npy", "out.npy"])
    else:
        assert_refused(done, "upscale", folder, before)


@pytest.mark.slow  # 3 commands (15 s); the refusal is a case above, the clipping is tested in test_upscale_api
def test_negative_counts_are_refused_with_the_hint_then_clipped_with_clip_negative(tmp_path, model_path):
    """Background-subtracted histograms: refused by default, naming --clip-negative; with it, clipped
    at 0, the count and the pixels said on a warning line and in the summary, and the output that of the
    histograms clipped beforehand."""
    np.save(tmp_path / "in.npy", _negative_counts())
    before = tree(tmp_path)
    args = ("upscale", "in.npy", "-o", "out.npy", "--model", model_path, "--no-progress")
    assert_refused(jaxsr(tmp_path, *args), "upscale", tmp_path, before, "in.npy: frame 1 holds negative photon "
                   "counts", "pass --clip-negative")
    done = jaxsr(tmp_path, *args, "--clip-negative")
    assert done.returncode == 0, done.stderr
    assert done.stderr.splitlines()[0] == ("jaxsr upscale: warning: 3 negative counts in 2 pixels clipped at 0 "
                                           "(--clip-negative: background-subtracted histograms)"), done.stderr
    assert json.loads(done.stdout)["negative_counts_clipped"] == {"counts": 3, "pixels": 2}
    np.save(tmp_path / "clipped.npy", np.maximum(_negative_counts(), 0))
    assert jaxsr(tmp_path, "upscale", "clipped.npy", "-o", "want.npy", "--model", model_path).returncode == 0
    np.testing.assert_array_equal(np.load(tmp_path / "out.npy"), np.load(tmp_path / "want.npy"))


@pytest.mark.parametrize("error,sig", [("terminated", signal.SIGTERM), ("interrupted", signal.SIGINT)])
def test_an_interruption_python_dropped_is_delivered_again(error, sig):
    """A signal handler's exception raised inside a garbage-collection callback (XLA has one) is dropped by Python
    ("Exception ignored"), and the command went on to exit 0 with its output written: the unraisable hook `main`
    installs sends the signal again; other exceptions go to the previous hook."""
    from types import SimpleNamespace

    from jaxsr.cli import Terminated, _redeliver_dropped_interruptions

    seen, passed = [], []
    hook = _redeliver_dropped_interruptions(passed.append)
    handler = signal.signal(sig, lambda signum, frame: seen.append(signum))
    try:
        hook(SimpleNamespace(exc_value=Terminated(sig) if error == "terminated" else KeyboardInterrupt()))
        for _ in range(100):  # the handler runs at the main thread's next bytecode
            if seen:
                break
            time.sleep(0.01)
    finally:
        signal.signal(sig, handler)
    assert seen == [sig] and not passed
    other = SimpleNamespace(exc_value=ValueError("x"))
    hook(other)
    assert passed == [other]


def _interrupt(tmp_path, model_path, output, sig, frames=2000):
    """Start `jaxsr upscale` on a long recording into `output`, send `sig` while frames are being written, and
    return (the finished process, its stderr, the folder before)."""
    rng = np.random.default_rng(0)
    np.save(tmp_path / "in.npy", rng.uniform(0, 1, (frames, 32, 64)).astype(np.float32))
    before = tree(tmp_path)
    # the signal's default disposition for the child: under `nohup pytest` SIGHUP is inherited as ignored, and jaxsr
    # keeps an ignored SIGHUP ignored (the next test), so the upscale would finish with exit 0 (no preexec_fn: a
    # fork beside JAX's threads can deadlock)
    ignored = signal.getsignal(sig) == signal.SIG_IGN  # never so for SIGKILL, which has no disposition to set
    inherited = signal.signal(sig, signal.SIG_DFL) if ignored else None
    try:
        proc = subprocess.Popen([sys.executable, "-m", "jaxsr.cli", "upscale", "in.npy", "-o", output, "--model",
                                 str(model_path), "--no-progress", "--batch-size", "2"], cwd=tmp_path, env=ENV,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    finally:
        if ignored:
            signal.signal(sig, inherited)
    first = proc.stderr.readline()  # "jaxsr upscale: N frames ...": checks done, the network starts
    assert first.startswith(f"jaxsr upscale: {frames} frames"), first + proc.stderr.read()
    deadline = time.monotonic() + 60
    while not any(n.startswith(".") for n, _ in tree(tmp_path)):  # the temporary output is being written
        assert time.monotonic() < deadline and proc.poll() is None, "no temporary output appeared"
        time.sleep(0.05)
    time.sleep(0.2)
    assert proc.poll() is None, "the upscale ended before it could be interrupted"
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=120)
    return proc, first + err, before


@pytest.mark.parametrize("output,sig", [("out", signal.SIGTERM), ("out.npy", signal.SIGHUP),
                                        pytest.param("out.npy", signal.SIGINT, marks=pytest.mark.slow)])
def test_interrupted_upscale_leaves_nothing(tmp_path, model_path, output, sig):
    """SIGHUP (the terminal closed) left the .npy's hidden temporary (78 MB for this recording): handled as
    SIGTERM is now."""
    proc, err, before = _interrupt(tmp_path, model_path, output, sig)
    if proc.returncode == 0:  # it finished between the last check and the signal (a fast host): once more, longer
        done = tmp_path / output  # its finished output, which the next run would refuse to replace
        shutil.rmtree(done) if done.is_dir() else done.unlink()
        proc, err, before = _interrupt(tmp_path, model_path, output, sig, frames=6000)
    assert proc.returncode == 128 + sig, err
    last = err.splitlines()[-1]
    assert last == ("jaxsr upscale: " + ("interrupted" if sig == signal.SIGINT else f"terminated ({sig.name})")
                    + "; unfinished outputs removed"), err
    assert "Traceback" not in err, err
    assert tree(tmp_path) == before  # no partial folder or file, no hidden temporary


def test_an_upscale_started_with_sighup_ignored_outlives_the_terminal(tmp_path, model_path):
    """`nohup jaxsr ... &` ignores SIGHUP so that the command outlives the terminal; `jaxsr` put its own handler in
    its place and died with the terminal (exit 129). A signal ignored at the start stays ignored."""
    np.save(tmp_path / "in.npy", np.random.default_rng(0).uniform(0, 1, (40, 32, 64)).astype(np.float32))
    command = [sys.executable, "-m", "jaxsr.cli", "upscale", "in.npy", "-o", "out.npy", "--model", str(model_path),
               "--no-progress", "--batch-size", "2"]
    # as nohup does (not with preexec_fn, which forks this process, JAX's threads and all)
    nohup = f"import os, signal, sys; signal.signal(signal.SIGHUP, signal.SIG_IGN); os.execv(sys.executable, {command})"
    proc = subprocess.Popen([sys.executable, "-c", nohup], cwd=tmp_path, env=ENV, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    first = proc.stderr.readline()  # "jaxsr upscale: 40 frames ...": the handlers are in place, the network starts
    assert first.startswith("jaxsr upscale: 40 frames"), first + proc.stderr.read()
    proc.send_signal(signal.SIGHUP)  # the terminal closes
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, first + err
    assert np.load(tmp_path / "out.npy").shape == (40, 128, 256)


def test_the_temporary_a_killed_upscale_left_is_removed_by_the_next_run(tmp_path, model_path):
    """SIGKILL cannot be handled: the hidden temporary stays, named after OUTPUT and the process. The next run on
    that output removes it, saying so in one line, and writes the output."""
    proc, err, before = _interrupt(tmp_path, model_path, "out.npy", signal.SIGKILL)
    assert proc.returncode == -signal.SIGKILL, err
    left = sorted(set(tree(tmp_path)) - set(before))
    assert len(left) == 1 and re.fullmatch(rf"\.out\.[A-Za-z0-9-]+-{proc.pid}\.[a-z0-9_]+\.partial\.npy", left[0][0])
    np.save(tmp_path / "short.npy", np.full((2, 32, 64), 0.5, np.float32))
    done = jaxsr(tmp_path, "upscale", "short.npy", "-o", "out.npy", "--model", model_path, "--no-progress")
    assert done.returncode == 0, done.stderr
    assert (f"jaxsr upscale: warning: removed 1 temporary file of out.npy that a stopped writer left (process "
            f"{proc.pid}, no longer running)") in done.stderr.splitlines(), done.stderr
    assert [n for n, _ in tree(tmp_path)] == ["in.npy", "out.npy", "short.npy"]


@pytest.mark.slow
def test_a_finished_run_is_refused_then_replaced_with_force(tmp_path):
    """A finished run, then the same command with fewer epochs and no --resume."""
    args = ["train", "--tr", "0", "--preset", "cpu", "--no-progress", "--output", "R"]
    assert jaxsr(tmp_path, *args, "--epochs", "1", timeout=1800).returncode == 0
    before = tree(tmp_path)
    best = (tmp_path / "R" / "best.npz").read_bytes()
    assert_refused(jaxsr(tmp_path, *args, "--epochs", "1"), "train", tmp_path, before, "holds a training run")
    assert (tmp_path / "R" / "best.npz").read_bytes() == best
    assert jaxsr(tmp_path, *args, "--epochs", "1", "--seed", "3", "--force", timeout=1800).returncode == 0
    assert (tmp_path / "R" / "best.npz").read_bytes() != best
    assert len((tmp_path / "R" / "metrics.jsonl").read_text().splitlines()) == 1


def test_nan_in_a_metres_array_is_no_return(tmp_path, model_path):
    """NaN in radial metres means no return (docs/sensor-model.md), in arrays as in image frames: upscaled, not
    refused."""
    depth = np.full((2, 32, 64), 8.0, np.float32)
    depth[:, :, 40:] = np.nan
    np.save(tmp_path / "in.npy", depth)
    done = jaxsr(tmp_path, "upscale", "in.npy", "-o", "out.npy", "--model", model_path, "--units", "m")
    assert done.returncode == 0, done.stderr
    assert np.load(tmp_path / "out.npy").shape == (2, 128, 256)


def test_a_value_that_looks_like_a_flag_is_explained(capsys):
    """argparse takes -5m (or -1GB, -1,2) for an option and says only "expected one argument"."""
    from jaxsr import cli

    with pytest.raises(SystemExit) as stop:
        cli.main(["upscale", "in.npy", "-o", "out.npy", "--gate-start", "-5m"])
    assert stop.value.code == 2
    assert "expected one argument (one that begins with '-' is written --gate-start=VALUE)" in capsys.readouterr().err
