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
