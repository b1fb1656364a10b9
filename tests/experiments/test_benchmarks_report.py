"""experiments/studies/benchmarks_report.py --json: a pytest-benchmark report recorded on another machine is rendered
with that machine and date, never into the CPU report's file by default."""

import json
import sys

import pytest

import benchmarks_report  # experiments/studies (pytest's pythonpath)

RECORDED = {
    "datetime": "2026-11-24T07:47:13",
    "machine_info": {"cpu": {"brand_raw": "Some Xeon"}, "python_version": "3.12.3"},
    "benchmarks": [{"fullname": "benchmarks/bench_inference.py::test_super_resolve[4-8]",
                    "stats": {"mean": 0.0113, "stddev": 0.0016},
                    "extra_info": {"items_per_s": 1412.2, "gflops_per_s": 40202.4, "device": "1 x cuda:0"}}],
}


def test_a_recorded_report_names_its_machine_and_date(tmp_path, monkeypatch):
    source, out = tmp_path / "bench.json", tmp_path / "gpu.md"
    source.write_text(json.dumps(RECORDED))
    monkeypatch.setattr(sys, "argv", ["benchmarks_report.py", "--json", str(source), "--out", str(out),
                                      "--machine", "one H100", "--recorded-with", "pytest benchmarks"])
    benchmarks_report.main()
    text = out.read_text()
    assert "- machine: one H100; JAX devices 1 x cuda:0; Python 3.12.3" in text and "- date: 2026-11-24" in text
    assert "- recorded with: `pytest benchmarks`" in text
    assert "| `bench_inference.py::test_super_resolve[4-8]` | 11.3 | 1.6 | 1412.2 | 40202 |" in text


def test_the_share_of_the_matmul_ceiling_is_a_column_where_recorded():
    shared = {"fullname": "benchmarks/bench_inference.py::test_precision_from_histograms[4-sequence-32-bfloat16]",
              "stats": {"mean": 2.0, "stddev": 0.1},
              "extra_info": {"items_per_s": 16.0, "gflops_per_s": 147.2, "share_of_matmul_peak": 0.31}}
    text = benchmarks_report.table([*RECORDED["benchmarks"], shared])
    assert "| benchmark | mean ms / call | std ms | items / s | GFLOP/s | of ceiling |" in text
    assert "test_precision_from_histograms[4-sequence-32-bfloat16]` | 2000.0 | 100.0 | 16.0 | 147 | 31 % |" in text
    assert "test_super_resolve[4-8]` | 11.3 | 1.6 | 1412.2 | 40202 |  |" in text


@pytest.mark.parametrize("argv", [["--json", "bench.json"], ["--json", "bench.json", "--out", "x.md", "tr4"],
                                  ["--machine", "one H100"]])
def test_mismatched_options_are_refused(argv, monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", ["benchmarks_report.py", *argv])
    with pytest.raises(SystemExit):
        benchmarks_report.main()
    assert "--json" in capsys.readouterr().err
