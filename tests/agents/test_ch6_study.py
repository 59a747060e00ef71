"""The chapter-6 study record (agents/run/ch6_study.py) on synthetic run directories of the full
grid: the main table, headline, deviations and GPU wall time against hand-computed values, the
hand-designed baseline in the table and the figures."""

from __future__ import annotations

import json
import os

import pytest
from test_ch6 import SEEDS, _history

from agents.run.ch6 import ENVS, POLICIES, plot_all, run_dir
from agents.run.ch6_study import (
    BASELINES,
    deviations,
    grid_wall_s,
    load_baselines,
    main_table,
    write_ch6_study,
)
from agents.run.logs import write_csv
from mjxrmp.results.summary import load_summary

REWARD = {"nn": 10.0, "nn_residual": 35.0, "rmp_residual": 40.0}


@pytest.fixture(scope="module")
def grid(tmp_path_factory):
    """Every (setup, class) run with a two-launch speed.json (100 s + 20 s each), plus a
    baseline file for env3."""
    root = tmp_path_factory.mktemp("ch6")
    runs, figures = str(root / "runs"), str(root / "figures")
    for env in ENVS:
        for policy in POLICIES:
            out = run_dir(runs, env, policy)
            os.makedirs(out)
            write_csv(os.path.join(out, "metrics.csv"), _history(REWARD[policy]), SEEDS, 64)
            segments = [{"wall_s": 100.0, "versions": {"jax": "x"}}, {"wall_s": 20.0}]
            # Franka's nn and nn_residual trained packed in one program
            packed = ({"packed_with": ["franka_nn", "franka_nn_residual"]}
                      if env == "franka" and policy != "rmp_residual" else {})
            with open(os.path.join(out, "speed.json"), "w") as f:
                json.dump({"wall_s": 120.0, "device": "GPU", "date": "2026-01-01",
                           "segments": segments, **packed}, f)
    base = {"three_link/env3": {"mean_return": 25.0, "safe_pct": 100.0, "episodes": 64,
                                "record": {"command": "c", "device": "cpu", "versions": {},
                                           "date": "2026-01-02"}}}
    with open(os.path.join(runs, BASELINES), "w") as f:
        json.dump(base, f)
    summary = plot_all(runs, figures, 100, load_baselines(runs))
    write_ch6_study(figures, runs, summary)
    return runs, figures, summary


def test_study_record_from_the_grid(grid):
    runs, figures, _ = grid
    study = load_summary(os.path.join(figures, "summary.json"))
    assert grid_wall_s(runs) == pytest.approx(12 * 120.0)
    assert len(study["runs"]) == 14  # 12 trained runs, the whole grid and the env3 baseline
    assert study["runs"]["grid"]["device"] == "GPU"
    rec = study["runs"]["three_link-env3_rmp_residual"]
    assert (rec["device"], rec["date"]) == ("GPU", "2026-01-01")
    assert "--envs three_link/env3 --policies rmp_residual" in rec["command"]
    assert "--envs franka --policies nn nn_residual " in study["runs"]["franka_nn"]["command"]
    cells = {row["cells"][0]: row["cells"][2] for row in study["headline"]["rows"]}
    # RMP-RESIDUAL 41 (seeds 40 and 42) over NN 11 (10 and 12)
    assert cells["env3 final reward, RMP-RESIDUAL vs NN"] == "41.0 ± 1.0 vs 11.0 ± 1.0, 3.7×"
    assert any(v == "24.0 min" for v in cells.values())
    cited = {row["cells"][0]: row["run"] for row in study["headline"]["rows"]}
    # a row comparing cells of different programs cites the whole grid's command
    assert cited["env3 final reward, RMP-RESIDUAL vs NN"] == "grid"
    assert cited["env3 final reward, NN-RESIDUAL"] == "three_link-env3_nn_residual"
    assert not any("30-minute target" in d for d in study["deviations"])
    by = {(r["env"], r["policy"]): r for r in grid[2]["rows"]}
    assert ("The grid takes 35.0 min of GPU time (NVIDIA H200), above the 30-minute target."
            in deviations(by, 35 * 60.0, ["NVIDIA H200"]))
    assert any("NN-RESIDUAL learns nearly as fast" in d for d in study["deviations"])
    assert any("RMP-RESIDUAL collides on the Franka in 25 of" in d for d in study["deviations"])
    assert any("RMP-RESIDUAL ends above NN-RESIDUAL (41.0 vs 36.0)" in d
               for d in study["deviations"])
    for name in ("fig6_2.png", "fig6_3.png", "fig6_4.png", "table.csv"):
        assert os.path.getsize(os.path.join(figures, name)) > 0, name


def test_main_table_has_the_baseline_first_and_wall_times(grid):
    runs, _, summary = grid
    columns, rows = main_table(summary["rows"], load_baselines(runs), runs)
    env3 = [r for r in rows if r[0] == "env3"]
    assert env3[0][:2] == ["env3", "HAND-DESIGNED (fixed)"] and env3[0][3] == "25.0"
    assert [r[1] for r in env3[1:]] == ["NN", "NN-RESIDUAL", "RMP-RESIDUAL"]
    assert all(r[-1] == "120" for r in env3[1:])
    assert len(rows) == len(ENVS) * len(POLICIES) + 1 and len(columns) == len(rows[0])
