"""The accelerator driver of the paper preset (experiments/paper/train_paper.py): one child process per run with an
equal share of device memory, failures named, the child's run argument checked; a resumed run continues (slow:
it trains a tiny stand-in of the preset on the CPU)."""

import dataclasses
import json
from pathlib import Path

import pytest

import train_paper  # experiments/paper (pytest's pythonpath)
from jaxsr.config import PRESETS


class _FakeProcess:
    def __init__(self, args, env, fail):
        self.args, self.env, self.code = args, env, 1 if fail else 0
        self.done = self.terminated = False

    def wait(self):
        if self.code == "interrupt":  # the parent is stopped while waiting for this child
            raise KeyboardInterrupt
        self.done = True
        return self.code

    def poll(self):
        return self.code if self.done else None

    def terminate(self):
        self.terminated = True


def _launches(monkeypatch, fail=()):
    launched = []

    def popen(args, env):
        launched.append(_FakeProcess(args, env, args[args.index("--one") + 1] in fail))
        return launched[-1]

    monkeypatch.setattr(train_paper.subprocess, "Popen", popen)
    return launched


def test_one_process_per_run_each_with_an_equal_share_of_memory(monkeypatch, tmp_path):
    launched = _launches(monkeypatch)
    train_paper.main(["--epochs", "3", "--seeds", "1", "0", "0", "--tr", "1", "0", "--runs", str(tmp_path)])
    assert {p.env["XLA_PYTHON_CLIENT_MEM_FRACTION"] for p in launched} == {"0.225"}
    # each child, run as launched, trains its own run: (root, seed, tr, epochs)
    trained = []
    monkeypatch.setattr(train_paper, "train_one", lambda *a: trained.append(a))
    for p in launched:
        assert p.args[1] == train_paper.__file__
        train_paper.main(p.args[2:])
    assert trained == [(tmp_path, s, tr, 3) for s in (0, 1) for tr in (0, 1)]


def test_failed_runs_are_named(monkeypatch, tmp_path):
    _launches(monkeypatch, fail={"s0/tr4"})
    with pytest.raises(SystemExit, match="s0/tr4") as err:
        train_paper.train_all(tmp_path, [(0, 0), (0, 4)], epochs=1)
    assert "s0/tr0" not in str(err.value)


@pytest.mark.parametrize("args, says", [(["--seeds", "3"], "s3/tr0"), (["--seeds", "3", "--tr", "4"], "s3/tr4"),
                                        (["--epochs", "0"], "--epochs must be >= 1")])
def test_runs_the_report_cannot_read_and_empty_budgets_are_refused(args, says, monkeypatch, capsys):
    launched = _launches(monkeypatch)
    with pytest.raises(SystemExit):
        train_paper.main(args)
    assert says in capsys.readouterr().err and not launched


@pytest.mark.parametrize("one", ["0/4", "s0/tr5", "s0-tr1", "s/tr1"])
def test_a_malformed_run_argument_is_refused(one, capsys):
    with pytest.raises(SystemExit):
        train_paper.main(["--one", one, "--epochs", "1"])
    assert "expected s<seed>/tr<0-4>" in capsys.readouterr().err


@pytest.mark.slow
def test_a_run_resumes_to_more_epochs(monkeypatch, tmp_path):
    tiny = dataclasses.replace(PRESETS["paper"], examples_per_epoch=4, patch=(16, 32), val_frames=2)
    monkeypatch.setitem(train_paper.PRESETS, "paper", tiny)
    train_paper.train_one(tmp_path, 0, 0, epochs=1)
    train_paper.train_one(tmp_path, 0, 0, epochs=2)
    records = [json.loads(line) for line in (tmp_path / "s0" / "tr0" / "metrics.jsonl").read_text().splitlines()]
    assert [r["epoch"] for r in records] == [1, 2] and records[-1]["step"] == 2


def test_children_are_stopped_with_their_parent(monkeypatch, tmp_path):
    launched = _launches(monkeypatch)
    original = train_paper.subprocess.Popen

    def popen(args, env):
        p = original(args, env)
        if args[args.index("--one") + 1] == "s0/tr1":
            p.code = "interrupt"
        return p

    monkeypatch.setattr(train_paper.subprocess, "Popen", popen)
    with pytest.raises(KeyboardInterrupt):
        train_paper.train_all(tmp_path, [(0, 0), (0, 1), (0, 2)], epochs=1)
    assert [p.terminated for p in launched] == [False, True, True]


@pytest.mark.parametrize("mode, target", [("--score", "score"), ("--report", "report"), ("--keep", "keep")])
def test_score_and_report_read_the_kept_runs_and_keep_writes_them(mode, target, monkeypatch):
    called = []
    monkeypatch.setattr(train_paper, target, lambda root, *a, **k: called.append((root, *a)) or ["s0/tr0"])
    train_paper.main([mode])
    assert called[0][0] == (Path("runs/paper") if mode == "--keep" else train_paper.KEPT)
    if mode == "--keep":
        assert called[0][1] == train_paper.KEPT
    assert (Path(__file__).resolve().parents[2] / train_paper.KEPT / "s0" / "tr4" / "best.npz").exists()
