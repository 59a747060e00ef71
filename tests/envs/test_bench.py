"""Smoke test of scripts/bench.py (the benchmark itself is a script, not a timed test)."""

from __future__ import annotations

import json

from scripts import bench


def test_quick_bench_writes_complete_json(tmp_path, capsys):
    path = tmp_path / "bench.json"
    result = bench.main(["--quick", "--robots", "three_link", "--latency-calls", "20",
                         "--envs", "three_link/env3", "--json", str(path)])
    printed = capsys.readouterr().out
    assert "evals/s" in printed and "three_link" in printed

    data = json.loads(path.read_text())
    assert data == json.loads(json.dumps(result))
    for key in ("platform", "device_kind", "jax", "dtype"):
        assert data["device"][key]
    assert data["device"]["dtype"] == "float32"

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


def test_offline_full_run_in_chunks_reports_progress(tmp_path):
    """``bench_offline --full-chunk``: the chunked whole run writes its progress to the JSON
    after each chunk and ends with the same fields as the one-program run; ``--no-rate``
    skips the rate rows."""
    from scripts import bench_offline

    path = tmp_path / "b.json"
    out = bench_offline.main(["--learners", "bc", "--seeds", "1", "--chunk", "20",
                              "--full-steps", "60", "--full-seeds", "2", "--full-chunk", "20",
                              "--scale", "1", "--no-rate", "--json", str(path)])
    row = json.loads(path.read_text())["rows"][0]
    assert "rates" not in row
    assert row["full_progress"]["steps_done"] == 60 and row["full_progress"]["seeds"] == 2
    full = out["rows"][0]["full"]
    assert full["chunk"] == 20 and full["steps"] == 60 and full["metrics_finite"]
    assert 0 < full["compile_s"] < full["wall_s"]
