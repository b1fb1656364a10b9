"""experiments/paper/converge_session.py: the packed train state within what a slot may bring back, and a tiny
session on the CPU that a second one, on fresh run folders, resumes from what the first packed (its compilation
cache hit)."""

import json
import subprocess
import sys

import numpy as np
import pytest

import converge_session as session  # experiments/paper (pytest's pythonpath)


def _state_file(tmp_path):
    """A train state file shaped as `fit` writes one: weights, Adam's moments, counters and metadata."""
    rng = np.random.default_rng(0)
    arrays = {"params/blocks/0/w": rng.normal(size=(3, 4)).astype(np.float32),
              "best/params/blocks/0/w": rng.normal(size=(3, 4)).astype(np.float32),
              "best/state/bn/mean": rng.normal(size=4).astype(np.float32),
              "opt/mu/blocks/0/w": rng.normal(size=(3, 4)).astype(np.float32),
              "opt/nu/blocks/0/w": (1e-9 * rng.random((3, 4))).astype(np.float32),
              "opt/count": np.asarray(7, np.int32), "key": np.asarray([1, 2], np.uint32),
              "__metadata__": np.array(json.dumps({"run": {"step": 7}}))}
    path = tmp_path / "last.npz"
    np.savez(path, **arrays)
    return path, arrays


def test_packed_state_keeps_weights_to_float16_and_the_second_moment_to_bfloat16(tmp_path):
    path, arrays = _state_file(tmp_path)
    back = session.unpack_state(session.pack_state(path))
    assert set(back) == set(arrays)
    for k in ("params/blocks/0/w", "best/params/blocks/0/w"):
        np.testing.assert_allclose(back[k], arrays[k], rtol=1e-3)
    np.testing.assert_allclose(back["opt/nu/blocks/0/w"], arrays["opt/nu/blocks/0/w"], rtol=1e-2)
    assert not back["opt/mu/blocks/0/w"].any()  # the first moment restarts at zero
    for k in ("opt/count", "key", "best/state/bn/mean"):
        np.testing.assert_array_equal(back[k], arrays[k])
    assert back["params/blocks/0/w"].dtype == np.float32


@pytest.mark.slow  # two sessions of a tiny TR0 on the CPU: about 6 minutes on 2 busy cores
def test_a_session_resumes_on_fresh_folders_from_what_the_first_packed(tmp_path):
    def run(name, *extra):
        cmd = [sys.executable, session.__file__, "--out", str(tmp_path / name),
               "--runs", str(tmp_path / f"runs-{name}"), "--quick", "--tr", "0", "--batch", "2",
               "--checkpoint-s", "5", *extra]
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
        assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
        return proc.stdout

    run("a", "--minutes", "3.5", "--epochs", "2")
    parts = sorted((tmp_path / "a").glob("state.tar.*"))
    assert parts and all(p.stat().st_size <= session.PART_BYTES for p in parts)
    assert len(list((tmp_path / "a").iterdir())) <= 8  # what may come back from the device
    first = [json.loads(s) for s in (tmp_path / "runs-a" / "tr0" / "metrics.jsonl").read_text().splitlines()]
    cache = {p.name for p in (tmp_path / "runs-a" / "xla").iterdir()}
    assert len(first) == 2 and any(name.startswith("jit_step_fn") for name in cache)
    out = run("b", "--minutes", "2.5", "--epochs", "4", "--state", str(tmp_path / "a"))
    assert "restored {0:" in out
    second = [json.loads(s) for s in (tmp_path / "runs-b" / "tr0" / "metrics.jsonl").read_text().splitlines()]
    assert len(second) == 4 and second[:2] == first  # continued, its log kept
    # the second session found the train step compiled: its cache holds the first's entries and no other step
    again = {p.name for p in (tmp_path / "runs-b" / "xla").iterdir()}
    assert again >= cache and not any(name.startswith("jit_step_fn") for name in again - cache)
