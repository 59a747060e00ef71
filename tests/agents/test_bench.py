"""Benchmarks (agents/bench/, offline/experiment/bench.py; the benchmark itself is not a timed
test): the quick ``scripts/bench.py`` run end to end (its ``main``) writes a complete JSON, the
summary and table of synthetic rows, and the offline benchmark's chunked whole run reports its
progress."""

from __future__ import annotations

import json

import jax
import pytest
from script_main import load_script

from agents.bench.run import fill_defaults, run_benchmark
from agents.bench.table import fmt_rate, fmt_time, format_summary, format_table, summarise
from offline.experiment.bench import run_benchmark as run_offline_benchmark


def test_quick_bench_writes_complete_json(tmp_path, capsys):
    """``scripts/bench.py --quick`` through its ``main`` in this process (the argument parsing,
    the run, the printed table and the JSON it writes)."""
    path = tmp_path / "bench.json"
    async_dispatch = jax.config.values["jax_cpu_enable_async_dispatch"]  # the bench turns it off
    try:
        load_script("bench.py").main(["--quick", "--robots", "three_link", "--latency-calls",
                                      "20", "--envs", "three_link/env3", "--json", str(path)])
    finally:  # the tests that follow in this process dispatch as before
        jax.config.update("jax_cpu_enable_async_dispatch", async_dispatch)
    stdout = capsys.readouterr().out
    assert "evals/s" in stdout and "three_link" in stdout

    data = json.loads(path.read_text())
    for key in ("platform", "device_kind", "jax", "dtype"):
        assert data["device"][key]
    assert data["device"]["dtype"] == "float32"
    assert data["settings"]["batches"] == [1, 16] and data["settings"]["repeats"] == 2

    rows = data["rows"]
    seen = {(r["impl"], r["mode"], r["batch"]) for r in rows}
    assert seen == {("rmp2", "single", 1), ("rmp2", "batched", 1), ("rmp2", "batched", 16),
                    ("naive", "single", 1), ("naive", "batched", 1), ("naive", "batched", 16),
                    ("random", "env", 4), ("rmp2", "env", 4)}
    for r in rows:
        assert "error" not in r, r
        assert r["robot"] == ("three_link/env3" if r["mode"] == "env" else "three_link")
        for k in ("evals_per_s", "time_per_call_s", "compile_s"):
            assert r[k] > 0, (k, r)
        assert r["finite_fraction"] == 1.0
        assert r["calls_per_repeat"] >= 1 and r["repeats"] >= 1

    s = data["summary"]["three_link"]
    assert s["rmp2_best_batch"] in (1, 16)
    assert s["ratio_batch"] == 16 and s["rmp2_over_naive"] > 0
    assert s["rmp2_latency_us"] > 0 and s["naive_latency_us"] > 0
    e = data["summary"]["env three_link/env3"]
    assert e["rmp2_best_steps_per_s"] > 0 and e["random_best_steps_per_s"] > 0
    assert [p["robot"] for p in data["precision"]] == ["three_link"]


def test_defaults_summary_and_table():
    """Quick sizes fill only what was not given; the summary picks the best batch, the latency
    and the RMP²/naive ratio at the largest common batch; errors show in the table."""
    args = {"quick": True, "full": False, "batches": None, "envs": ["none"], "env_batches": None,
            "env_steps": None, "naive_batches": [0, 16], "repeats": 3, "latency_calls": None,
            "min_repeat_s": None}
    s = fill_defaults(args)
    assert (s["batches"], s["envs"], s["env_batches"], s["naive_batches"]) == (
        [1, 16], [], [4], [16])
    assert (s["repeats"], s["latency_calls"], s["min_repeat_s"], s["env_steps"]) == (
        3, 50, 0.01, 5)

    def row(impl, mode, batch, rate):
        return {"robot": "franka", "impl": impl, "mode": mode, "batch": batch,
                "evals_per_s": rate, "time_per_call_s": batch / rate, "compile_s": 1.5,
                "calls_per_repeat": 10, "repeats": 2}

    rows = [row("rmp2", "single", 1, 1e4), row("rmp2", "batched", 64, 4e6),
            row("rmp2", "batched", 256, 2e6), row("naive", "batched", 64, 1e6),
            {"robot": "franka", "impl": "naive", "mode": "batched", "batch": 256,
             "error": "XlaRuntimeError: out of memory", "evals_per_s": None}]
    summary = summarise(rows)["franka"]
    assert summary["rmp2_best_batch"] == 64 and summary["ratio_batch"] == 64
    assert summary["rmp2_over_naive"] == 4.0 and summary["rmp2_latency_us"] == 100.0
    assert "RMP²/naive at batch 64 = 4.0×" in format_summary({"franka": summary})
    table = format_table(rows)
    assert "ERROR" in table and "4.00e6/s" in table
    assert (fmt_rate(2.31e7), fmt_rate(None), fmt_time(2.5e-5), fmt_time(0.5)) == (
        "2.31e7/s", "-", "25.0 µs", "500.00 ms")


def test_offline_full_run_in_chunks_reports_progress(tmp_path):
    """The offline benchmark's chunked whole run writes its progress to the JSON after each
    chunk and ends with the same fields as the one-program run; ``rates=False`` skips the rate
    rows."""
    path = tmp_path / "b.json"
    out = run_offline_benchmark(["bc"], path, "test", seeds=[1], chunk=20, full_steps=60,
                                full_seeds=2, full_chunk=20, rates=False, scale=1)
    written = json.loads(path.read_text())
    assert written["command"].endswith("test") and written["versions"]["jax"] == jax.__version__
    assert "xla_flags" in written
    row = written["rows"][0]
    assert "rates" not in row
    assert row["full_progress"]["steps_done"] == 60 and row["full_progress"]["seeds"] == 2
    full = out["rows"][0]["full"]
    assert full["chunk"] == 20 and full["steps"] == 60 and full["metrics_finite"]
    assert 0 < full["compile_s"] < full["wall_s"]


def test_offline_rows_need_the_measure_passed_in(tmp_path):
    """agents cannot import offline (docs/design.md §1): the caller passes the offline measure."""
    with pytest.raises(ValueError, match="no offline_measure"):
        run_benchmark({"offline": ["atac"]}, "test", tmp_path)
