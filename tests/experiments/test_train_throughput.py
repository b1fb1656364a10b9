"""experiments/studies/train_throughput.py: its table from recorded lines (a failed configuration included), the
network's training FLOPs, and one configuration's worker end to end on CPU at a tiny batch (slow: a compilation)."""

import json

import pytest

import train_throughput  # experiments/studies (pytest's pythonpath)
from jaxsr.config import ModelConfig
from jaxsr.nn import flops_per_frame


def test_report_rows_and_failures(tmp_path):
    lines = [
        {"config": "ceilings", "device": "cpu", "backend": "cpu", "jax": "0", "size": 64,
         "float32": {"tflops": 0.1, "rel_error": 3e-7}, "default": {"tflops": 0.1, "rel_error": 3e-7},
         "bfloat16": {"tflops": 0.2, "rel_error": 2e-3}},
        {"config": "4-16-default", "tr": 4, "batch": 16, "precision": "default", "compile_s": 10.0, "flops": 1.0,
         "step_s": 0.5, "step_s_spread": [0.5, 0.5], "steps": 5, "loss": 0.001, "frames_per_s": 32.0},
        {"config": "0-64-bfloat16", "error": "not compiled within 100 s"},
    ]
    path = tmp_path / "throughput.jsonl"
    path.write_text("".join(json.dumps(r) + "\n" for r in lines))
    table = train_throughput.report(path)
    assert "| 4 | 16 | default | 10 | 500.00 | 32 |" in table
    assert "not compiled within 100 s" in table
    assert "| bfloat16 | 0 | 2.0e-03 |" in table
    rate = 3 * flops_per_frame(ModelConfig(tr=4)) * 32 / 1e12
    assert f"| {rate:.1f} | 0.0010 |" in table


@pytest.mark.slow
def test_worker_times_one_configuration(tmp_path):
    sync, results = tmp_path / "sync", tmp_path / "out.jsonl"
    sync.mkdir()
    (sync / "go-0-1-bfloat16").touch()  # its turn at once
    train_throughput.worker("0,1,bfloat16", sync, results)
    (record,) = [json.loads(s) for s in results.read_text().splitlines()]
    assert "error" not in record, record
    assert record["step_s"] > 0 and record["frames_per_s"] == pytest.approx(1 / record["step_s"])
    assert (sync / "done-0-1-bfloat16").exists()
