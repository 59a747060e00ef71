"""Smoke test of scripts/reproduce_ch3.py (Figs 3.2 and 3.3) with a few integration steps."""

from __future__ import annotations

import importlib.util
import json
import pathlib

import numpy as np
import pytest

import mjxrmp  # noqa: F401  (XLA flags first)

SCRIPT = pathlib.Path(__file__).resolve().parents[2] / "scripts" / "reproduce_ch3.py"


@pytest.fixture(scope="module")
def ch3():
    spec = importlib.util.spec_from_file_location("reproduce_ch3", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_swap_metrics_definitions(ch3):
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


def test_main_writes_figures_and_json(ch3, tmp_path):
    record = ch3.main(["--out", str(tmp_path), "--steps", "30", "--robots", "4", "--seeds", "1"])
    for name in ("fig3_2.png", "fig3_3.png", "fig3_3.json"):
        assert (tmp_path / name).stat().st_size > 0
    data = json.loads((tmp_path / "fig3_3.json").read_text())
    assert data == json.loads(json.dumps(record))
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


def test_fig3_2_trajectories_are_finite(ch3):
    trajs = ch3.run_fig3_2(steps=20)  # same shapes as main(--steps 30): reuses the compiles
    assert set(trajs) == set(ch3.CONTROLLERS)
    for tr in trajs.values():
        assert tr.shape == (21, 2) and np.all(np.isfinite(tr))
