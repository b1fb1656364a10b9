"""The `jaxsr` command: its parser (every subcommand registered, with help and a runner), argument errors of
`jaxsr train`, and `jaxsr simulate` on a tiny case (3 frames) with its user errors. `jaxsr upscale` and
`jaxsr info` are tested in test_upscale.py."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import jaxsr
from jaxsr import cli, io
from jaxsr.io.previews import COLOUR_BAR_HEIGHT

# The subcommands the README documents.
SUBCOMMANDS = {"simulate", "train", "finetune", "upscale", "info", "models"}


@pytest.mark.slow  # 10-18 s: keeps the default suite under 8 minutes on 2 cores
def test_simulate_scene(tmp_path, capsys):
    out = tmp_path / "sim"
    rc = cli.main(["simulate", "--scene", "walkers", "--frames", "3", "--fps", "25", "--snr", "1.3", "--seed", "0",
                   "--output", str(out)])
    assert rc == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["counts_shape"] == [3, 32, 64, 16] and summary["snr"] == 1.3
    h = io.read_histograms(out / "histograms.npz")
    assert h["counts"].shape == (3, 32, 64, 16) and h["depth"].shape == (3, 128, 256)
    assert h["config"]["gate"]["bins"] == 16 and h["metadata"]["kind"] == "walkers"
    com = np.load(out / "com_depth.npy")
    assert com.shape == (3, 32, 64) and 0 <= com.min() and com.max() <= 1
    gt = np.load(out / "gt_depth.npy")
    # The centre-of-mass depth follows the ground truth where there is a return (coarse check, 16 bins).
    gt_lr = np.clip(gt.reshape(3, 32, 4, 64, 4).mean((2, 4)) / 35.0, 0, 1)
    assert np.median(np.abs(com - gt_lr)[gt_lr < 0.9]) < 0.1
    for name in ("preview_gt.png", "preview_com.png", "preview_intensity.png"):
        assert io.read_image(out / name).shape[:2] in {(128, 256), (32, 64)}
    assert io.read_image(out / "preview_strip.png").shape[:2] == (128 + COLOUR_BAR_HEIGHT, 3 * 256 + 4)
    # The reported baseline score is the PSNR of bicubic(centre of mass) against the normalised ground truth.
    from jaxsr import bicubic, normalise_depth, psnr

    want = float(np.mean(psnr(bicubic(com, scale=4), normalise_depth(gt))))
    assert summary["bicubic_psnr_db"] == pytest.approx(want, abs=0.01)
    # A second run refuses to overwrite, then overwrites with --force.
    assert cli.main(["simulate", "--scene", "walkers", "--frames", "3", "--output", str(out)]) == 2
    assert "--force" in capsys.readouterr().err
    assert cli.main(["simulate", "--scene", "walkers", "--frames", "3", "--output", str(out), "--force"]) == 0


def test_simulate_missing_input_is_a_clear_error(tmp_path, capsys):
    assert cli.main(["simulate", str(tmp_path / "nope"), "--output", str(tmp_path / "o")]) == 2
    assert "airsim_rec.txt" in capsys.readouterr().err


@pytest.mark.parametrize("new,old", [
    (["upscale", "rec.npz", "-o", "out.npz", "-k", "histograms", "-m", "tr4", "-f", "-q"],
     ["upscale", "rec.npz", "--output", "out.npz", "--input", "histograms", "--model", "tr4", "--force",
      "--no-progress"]),
    (["simulate", "--scene", "road", "-o", "sim", "-f"], ["simulate", "--kind", "road", "--out", "sim", "--force"]),
    (["simulate", "airsim", "-o", "sim"], ["simulate", "--input", "airsim", "--out", "sim"]),
    (["train", "--tr", "0", "-o", "run", "-f", "-q"], ["train", "--tr", "0", "--out", "run", "--force",
                                                       "--no-progress"]),
    (["finetune", "--sensor", "s.toml", "-m", "tr0", "-o", "run"],
     ["finetune", "--sensor", "s.toml", "--from", "tr0", "--out", "run"]),
])
def test_every_subcommand_spells_the_same_things_the_same_way(new, old):
    """-o/--output, -m/--model, -k/--kind, -f/--force, -q/--quiet; the old spellings give the same arguments, with
    a note for each (printed as a warning line by `main`)."""
    parser = cli.build_parser()
    got_new, got_old = vars(parser.parse_args(new)), vars(parser.parse_args(old))
    notes = got_old.pop("old_spellings", [])
    assert "old_spellings" not in got_new and len(notes) == sum(a in ("--out", "--input", "--kind", "--from")
                                                                for a in old)
    if "old_input" in got_old:  # simulate's AirSim folder: positional now
        got_old["source"], got_old["old_input"] = got_old["old_input"], None
    assert {k: v for k, v in got_old.items() if k not in ("func", "before_jax")} == {
        k: v for k, v in got_new.items() if k not in ("func", "before_jax")}


def test_old_spellings_work_with_a_warning_line_and_the_output_is_required(tmp_path, capsys):
    assert cli.main(["simulate", "--input", str(tmp_path / "nope"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[:2] == ["jaxsr simulate: warning: --input is the old spelling of AIRSIM_DIR and goes in the next "
                       "release", "jaxsr simulate: warning: --out is the old spelling of -o/--output and goes in the "
                       "next release"] and "airsim_rec.txt" in err[-1]
    np.save(tmp_path / "in.npy", np.full((2, 8, 8), 0.5, np.float32))
    assert cli.main(["upscale", str(tmp_path / "in.npy"), "-q"]) == 2
    assert capsys.readouterr().err == "jaxsr upscale: error: the output is required: -o/--output PATH\n"
    assert cli.main(["upscale", str(tmp_path / "in.npy"), "a.npy", "-o", "b.npy"]) == 2
    assert "two outputs" in capsys.readouterr().err


def test_parser_needs_a_command(capsys):
    with pytest.raises(SystemExit) as e:
        cli.main([])
    assert e.value.code == 2 and "required" in capsys.readouterr().err


def _subparsers(parser):
    (action,) = [a for a in parser._actions if a.dest == "command"]
    return action


def test_every_subcommand_has_help_and_its_runner():
    action = _subparsers(cli.build_parser())
    assert set(action.choices) == SUBCOMMANDS
    helps = {a.dest: a.help for a in action._choices_actions}
    modules = {m.__name__.rsplit(".", 1)[-1]: m for m in cli.COMMANDS}
    for name, sub in action.choices.items():
        assert helps.get(name), f"jaxsr {name} has no help string"
        assert sub.get_default("func") is modules[name].run, f"jaxsr {name} does not run jaxsr.cli.{name}.run"


def test_help_lists_every_subcommand(capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(["--help"])
    out = capsys.readouterr().out
    assert e.value.code == 0
    assert all(name in out for name in SUBCOMMANDS), out
    for name in SUBCOMMANDS:
        with pytest.raises(SystemExit) as e:
            cli.main([name, "--help"])
        assert e.value.code == 0 and f"usage: jaxsr {name}" in capsys.readouterr().out


@pytest.mark.parametrize("args,message", [
    (["--tr", "x"], "argument --tr: expected an integer, got 'x'"),
    (["--preset", "nope"], "argument --preset: invalid choice: 'nope'"),
    (["--epochs", "1.5"], "argument --epochs: expected an integer, got '1.5'"),
    (["--tr", "-1"], "argument --tr: expected an integer from 0 to 8, got -1"),
    (["--tr", "9"], "argument --tr: expected an integer from 0 to 8, got 9 (memory and compute grow"),
])
def test_train_bad_arguments_exit_2(tmp_path, capsys, args, message):
    with pytest.raises(SystemExit) as e:
        cli.main(["train", "--output", str(tmp_path / "run"), *args])
    err = capsys.readouterr().err
    assert e.value.code == 2 and message in err
    assert err.count("\n") == 1 and err.startswith("jaxsr train: error: "), err  # one line, no usage block
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("args,message", [
    (["--scale", "3"], "must be divisible by scale 3"),
])
def test_train_bad_values_are_errors_before_any_training(tmp_path, capsys, args, message):
    assert cli.main(["train", "--output", str(tmp_path / "run"), *args]) == 2
    err = capsys.readouterr().err
    assert err.startswith("jaxsr train: error: ") and message in err
    assert not (tmp_path / "run").exists()


def test_runs_as_python_m_jaxsr_cli():
    """`python -m jaxsr.cli` (experiments/studies/startup.py runs the command so) reaches the same parser."""
    root = Path(__file__).resolve().parents[2]
    done = subprocess.run([sys.executable, "-m", "jaxsr.cli", "info", "--help"], cwd=root, capture_output=True,
                          text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("usage: jaxsr info")


@pytest.mark.parametrize("minutes,seconds", [("0", 0.0), ("2.5", 150.0), ("inf", float("inf"))])
def test_train_checkpoint_minutes_reach_fit_as_seconds(tmp_path, monkeypatch, minutes, seconds):
    import jaxsr.training.presets as presets

    got = {}
    monkeypatch.setattr(presets, "fit", lambda *a, **kw: (got.update(kw), (None, []))[1])
    assert cli.main(["train", "--tr", "0", "--output", str(tmp_path / "run"), "--no-progress",
                     "--checkpoint-minutes", minutes]) == 0
    assert got["checkpoint_every_s"] == seconds


def test_train_is_one_library_call_for_every_architecture(tmp_path, monkeypatch):
    import jaxsr.training.presets as presets

    got = []
    monkeypatch.setattr(presets, "fit", lambda cfg, *a, **kw: (got.append(cfg), (None, []))[1])
    assert cli.main(["train", "--arch", "histnet", "--output", str(tmp_path / "h"), "--no-progress"]) == 0
    assert got[-1] == jaxsr.baselines.HistNetConfig()
    jaxsr.training.train(tmp_path / "d", tr=1, temporal="sequence", progress=False)
    assert got[-1] == jaxsr.ModelConfig(tr=1, temporal="sequence")
    with pytest.raises(ValueError, match="sequence form"):
        jaxsr.training.train(tmp_path / "w", tr=1, clip_frames=20)
    with pytest.raises(ValueError, match="no data, init or scale"):
        jaxsr.training.train(tmp_path / "i", arch="iseebetter", init="tr0")


def test_a_terminating_signal_ignored_at_the_start_stays_ignored(monkeypatch):
    """`nohup jaxsr train ... &` ignores SIGHUP; `main` replaced that with its own handler, so the run died with the
    terminal (exit 129). A signal ignored when `main` starts stays ignored; the others are handled, and put back."""
    import signal

    seen = {}
    monkeypatch.setattr(cli, "_run", lambda args, argv: seen.update(
        hup=signal.getsignal(signal.SIGHUP), term=signal.getsignal(signal.SIGTERM)) or 0)
    hup, term = signal.signal(signal.SIGHUP, signal.SIG_IGN), signal.getsignal(signal.SIGTERM)
    try:
        assert cli.main(["info", "tr0"]) == 0
        assert seen["hup"] == signal.SIG_IGN and seen["term"] is cli._raise_terminated
        assert signal.getsignal(signal.SIGHUP) == signal.SIG_IGN and signal.getsignal(signal.SIGTERM) == term
        signal.signal(signal.SIGHUP, signal.SIG_DFL)
        assert cli.main(["info", "tr0"]) == 0
        assert seen["hup"] is cli._raise_terminated and signal.getsignal(signal.SIGHUP) == signal.SIG_DFL
    finally:
        signal.signal(signal.SIGHUP, hup)


@pytest.mark.parametrize("command", ["train", "finetune"])
def test_a_warning_of_train_or_finetune_is_one_line(tmp_path, monkeypatch, capsys, command):
    """`jaxsr train` and `jaxsr finetune` had their own warning printers, which printed a message of several lines
    as it was; `main`'s prints every subcommand's warning as one line."""
    import warnings

    import jaxsr.cli.finetune as finetune_command
    import jaxsr.cli.train as train_command

    def warn(*args, **kwargs):
        warnings.warn("a resumed run\nhas nothing to train")
        return None, []

    monkeypatch.setattr(train_command, "train", warn)
    monkeypatch.setattr(finetune_command, "finetune", warn)
    (tmp_path / "s.toml").write_text("[sensor]\nbins = 16\nbin_width_m = 2.0\nlr_rows = 8\nlr_cols = 8\n"
                                     "irf_sigma_bins = 0.5\n\n[photons]\nsignal_range = [2.0, 8.0]\n"
                                     "snr_range = [5.0, 20.0]\n")
    argv = (["train", "--tr", "0"] if command == "train" else ["finetune", "--sensor", str(tmp_path / "s.toml")])
    assert cli.main([*argv, "--output", str(tmp_path / "run"), "--no-progress"]) == 0
    assert capsys.readouterr().err.splitlines() == [f"jaxsr {command}: warning: a resumed run has nothing to train"]


def test_version_models_and_a_closed_pipe(capsys):
    """`jaxsr --version` names the version; `jaxsr models` lists every bundled model a line each; a reader that
    closes the pipe early ends the command quietly, exit 0."""
    import subprocess
    import sys

    import jaxsr

    with pytest.raises(SystemExit) as stop:
        cli.main(["--version"])
    assert stop.value.code == 0 and capsys.readouterr().out.strip() == f"jaxsr {jaxsr.__version__}"
    assert cli.main(["models"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert any(line.startswith("tr4-ambient ") and "[default for histograms]" in line for line in lines)
    assert any(line.startswith("tr4 ") and "[default for depth]" in line for line in lines)
    assert cli.main(["models", "--json"]) == 0
    assert {r["name"] for r in json.loads(capsys.readouterr().out)} >= {f"tr{k}" for k in range(5)} | {"tr4-ambient"}
    # `true` exits without reading: every write of the command meets a closed pipe
    run = subprocess.run(f"{sys.executable} -m jaxsr.cli info tr4 | true; echo ${{PIPESTATUS[0]}}", shell=True,
                         capture_output=True, text=True, check=False, executable="/bin/bash")
    assert run.stderr == "" and run.stdout.strip() == "0"


def test_info_of_a_bundled_model_is_a_short_summary_and_json_the_whole_card(capsys):
    """`jaxsr info tr4-ambient`: a few lines (what it is for, what it reads, its size and its validation score);
    the training card, lineage included, only in --json."""
    from jaxsr.app.models import BUNDLED_USES

    assert cli.main(["info", "tr4-ambient"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert 5 <= len(lines) <= 7 and all(len(line) < 200 for line in lines), lines
    assert lines[0].startswith("tr4-ambient: bundled weights, ") and lines[0].endswith("tr4-ambient.npz")
    assert lines[1] == f"  use: {BUNDLED_USES['tr4-ambient']}; jaxsr upscale's default for histograms input"
    text = "\n".join(lines)
    assert "TR 4 (window of 9 frames)" in text and "depth, signal, background and ambient" in text
    assert "marks no return" in text and "GFLOP per 32x64 frame" in text and "validation: 24.96 dB PSNR" in text
    assert "earlier_stages" not in text and "lease" not in text
    assert cli.main(["info", "tr4-ambient", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["card"]["earlier_stages"] and info["reads"] == ["depth", "signal", "background", "ambient"]
    assert info["marks_no_return"] is True
