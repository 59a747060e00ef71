"""Thesis Figs 3.2 and 3.3 (mjxrmp.studies.ch3) with a few integration steps, and one run of
``scripts/reproduce_ch3.py`` as a subprocess."""

from __future__ import annotations

import json
import pathlib
import subprocess
import sys

import numpy as np
import pytest

from mjxrmp.studies import ch3
from mjxrmp.studies.ch3_figures import figures

ROOT = pathlib.Path(__file__).resolve().parents[2]


def test_swap_metrics_definitions():
    goals = np.array([[1.0, 0.0], [-1.0, 0.0]])
    traj = np.stack([np.array([[0.0, 0.0], [0.0, 2.0]]),      # t = 0: far
                     np.array([[0.99, 0.0], [-1.0, 0.02]]),   # t = dt: inside
                     np.array([[1.2, 0.0], [-1.0, 0.0]]),     # t = 2dt: leaves again
                     np.array([[1.0, 0.01], [-1.0, 0.0]])])   # t = 3dt: inside for good
    m = ch3.swap_metrics(traj, goals, tol=0.05, dt=0.5)
    assert m["reached"] and m["time_to_goal"] == pytest.approx(1.5)
    assert m["min_pair_distance"] == pytest.approx(np.hypot(1.99, 0.02))
    never = ch3.swap_metrics(traj[:3], goals, tol=0.05, dt=0.5)
    assert not never["reached"] and never["time_to_goal"] is None


def test_fig3_2_trajectories_are_finite():
    trajs = ch3.run_fig3_2(steps=20)  # the script's --steps 30 gives 20 Fig 3.2 steps too
    assert set(trajs) == set(ch3.CONTROLLERS)
    for tr in trajs.values():
        assert tr.shape == (21, 2) and np.all(np.isfinite(tr))


def test_record_summary_and_figures_from_a_stub_result():
    """The JSON record, console lines and both figures of hand-made runs (no simulation)."""
    goals = np.array([[1.0, 0.0], [-1.0, 0.0]])
    traj = np.stack([-goals, 0.5 * goals, goals])
    metrics = ch3.swap_metrics(traj, goals, tol=0.05)
    res = {"trajectories": {"spiral_clf": traj, "gds": traj}, "goals": goals, "start": -goals,
           "metrics": {"spiral_clf": metrics, "gds": metrics},
           "per_seed": {"spiral_clf": [metrics], "gds": [metrics]},
           "symmetric_start": {"gds": metrics}}
    record = ch3.fig3_3_record(res, steps=2, tol=0.05, seeds=(0,))
    assert record["n_robots"] == 2 and record["horizon_s"] == pytest.approx(2 * ch3.DT)
    assert record["gds"]["symmetric_start"] == metrics
    assert record["spiral_clf"]["symmetric_start"] is None
    assert record["gds"]["mean_time_to_goal"] == pytest.approx(2 * ch3.DT)
    line = np.linspace([2.5, -3.2], ch3.SINGLE_GOAL, 5)
    result = ch3.Ch3Result({c: line for c in ch3.CONTROLLERS}, res, record, 0.05, (0,),
                           (0.0, 0.0))
    text = "\n".join(ch3.summary_lines(result))
    assert "goal error 0.0000" in text and "symmetric" in text
    figs = figures(result)
    assert set(figs) == {"fig3_2.png", "fig3_3.png"}
    assert len(figs["fig3_3.png"].axes) == 3


def test_script_writes_figures_and_json(tmp_path):
    out = subprocess.run(
        [sys.executable, "scripts/reproduce_ch3.py", "--out", str(tmp_path), "--steps", "30",
         "--robots", "4", "--seeds", "1"],
        cwd=ROOT, capture_output=True, text=True, timeout=900, check=True)
    assert "Fig 3.2" in out.stdout and "Fig 3.3" in out.stdout
    for name in ("fig3_2.png", "fig3_3.png", "fig3_3.json"):
        assert (tmp_path / name).stat().st_size > 0
    data = json.loads((tmp_path / "fig3_3.json").read_text())
    for key in ("n_robots", "dt", "steps", "goal_tolerance", "spiral_clf", "gds",
                "spiral_clf_euclidean_alpha", "clf_alpha", "seeds"):
        assert key in data
    assert data["n_robots"] == 4 and data["steps"] == 30
    for variant in ("spiral_clf", "gds"):
        summary = data[variant]
        for key in ("seed0", "time_to_goal_per_seed", "min_pair_distance_per_seed",
                    "symmetric_start"):
            assert key in summary
        seed0 = summary["seed0"]
        assert seed0["finite"]
        assert np.isfinite(seed0["min_pair_distance"]) and seed0["min_pair_distance"] > 0
        assert np.isfinite(seed0["final_max_goal_error"])
        assert "time_to_goal" in seed0 and "reached" in seed0
