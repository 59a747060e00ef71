"""The Franka comparison of the chapter-5 strategies (agents/lfd/franka_scenario.py,
franka_folds.py, franka_eval.py, seeds.py; scripts/lfd_franka.py and lfd_franka_seeds.py end to
end): the scenario's starts, obstacle and corridor by hand, the seed summary by hand, and one
quick run of the whole comparison.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from script_main import load_script

import mjxrmp  # noqa: F401  (XLA flags first)
from agents.lfd.config import StrategyConfig
from agents.lfd.franka_eval import compare_strategies, table_lines
from agents.lfd.franka_scenario import (
    FrankaEvalConfig,
    clear_starts,
    clearance,
    corridor_excursions,
    kept_restarts,
    perturbed_starts,
)
from agents.lfd.seeds import load_runs, summarise
from agents.lfd.skills import load_skill
from mjxrmp.data import franka_demos as fd

ROOT = Path(__file__).resolve().parents[3]
needs_data = pytest.mark.skipif(not os.path.isdir(fd.DEFAULT_ROOT),
                                reason="Franka demonstrations not available")


def _script(name: str, *args: str) -> subprocess.CompletedProcess:
    run = subprocess.run([sys.executable, str(ROOT / "scripts" / name), *args], cwd=ROOT,
                         capture_output=True, text=True, timeout=900)
    assert run.returncode == 0, run.stderr[-3000:]
    return run


@needs_data
def test_script_quick_runs_end_to_end(tmp_path):
    """``scripts/lfd_franka.py --quick``'s ``main`` in this process (so that the second seed
    below reuses its compiled training program, under the script's matrix precision), then
    ``scripts/lfd_franka_seeds.py`` as a subprocess."""
    script = load_script("lfd_franka.py")
    script.main(["--quick", "--out", str(tmp_path), "--figures", str(tmp_path),
                 "--save-skills", str(tmp_path / "skills")])
    m = json.loads((tmp_path / "metrics.json").read_text())
    saved = sorted((tmp_path / "skills" / "drawer_closing" / "joint").iterdir())
    folds = m["tasks"]["drawer_closing"]["joint"]["folds"]
    assert [p.name for p in saved] == sorted(f"fold_{f['held_out']}" for f in folds)
    skill = load_skill(saved[0])
    assert skill.kind == "franka" and skill.description["strategy"] == "joint"
    joint = m["tasks"]["drawer_closing"]["joint"]
    assert np.isfinite(joint["mean_position_error"]) and 0 <= joint["success_rate"] <= 1
    assert len(joint["folds"][0]["mean_position_error_per_point"]) == 3
    assert joint["obstacle_rollouts"] == 2 and 0 <= joint["colliding_rollouts"] <= 2
    assert (joint["colliding_rollouts"] == 0) == (joint["min_clearance_obstacle"] > 0)
    assert joint["joint_limit_violations"] == 0
    kept = kept_restarts(np.array([f["restart_errors"] for f in joint["folds"]]), 0.02)
    assert [f["restart"] for f in joint["folds"]] == kept.tolist()
    for fold in joint["folds"]:   # the corridor test only removes successes; excursions >= 0
        assert 0 <= fold["task_success"] <= fold["success"]
        assert len(fold["corridor_excursions"]) == 1 and fold["corridor_excursions"][0] >= 0
    assert (tmp_path / "table.csv").read_text().startswith("task,strategy,")
    for name in ("lfd_franka_drawer_closing.png", "lfd_franka_errors.png"):
        assert (tmp_path / name).stat().st_size > 1000
    settings = m["settings"]
    assert settings["preset"] == "tiny" and settings["restarts"] == 3 and settings["quick"]

    # A second seed through the package function with the script's --quick settings, and the
    # paired summary over both (scripts/lfd_franka_seeds.py).
    fields = {f.name for f in dataclasses.fields(FrankaEvalConfig)}
    config = FrankaEvalConfig(**{k: v for k, v in settings.items() if k in fields} | {"seed": 1})
    lines = []
    with jax.default_matmul_precision(settings["matmul_precision"]):  # as the script runs it
        result = compare_strategies(config, lines.append)
    assert any(line.strip().startswith("joint") for line in lines)
    assert table_lines(result.rows)[1].startswith("drawer_closing   joint")
    j1 = result.metrics["drawer_closing"]["joint"]
    assert len(result.reproductions["drawer_closing"]["joint"]) == 2 == len(j1["folds"])
    other = tmp_path / "seed1"
    other.mkdir()
    (other / "metrics.json").write_text(json.dumps(
        {"settings": {**settings, "seed": 1, "out": str(other)}, "tasks": result.metrics}))
    _script("lfd_franka_seeds.py", str(tmp_path), str(other), "--out", str(tmp_path / "sum"))
    summary = json.loads((tmp_path / "sum" / "seeds.json").read_text())
    e = summary["tasks"]["drawer_closing"]["strategies"]["joint"]
    values = [joint["mean_position_error"], j1["mean_position_error"]]
    assert summary["seeds"] == [0, 1] and e["mean_position_error"]["per_seed"] == values
    np.testing.assert_allclose(e["mean_position_error"]["mean"], np.mean(values))
    assert e["pooled_success"] == [sum(f["success"] for r in (joint, j1) for f in r["folds"]), 4]
    assert e["pooled_colliding"][1] == 4
    for name in ("seeds.json", "seeds.png"):
        assert (tmp_path / "sum" / name).stat().st_size > 100


def test_eval_config_validation_and_presets():
    """Invalid settings are refused naming the field; the presets are the StrategyConfig ones
    with the iteration overrides applied."""
    with pytest.raises(ValueError, match=r"FrankaEvalConfig\.dt must be a finite number > 0"):
        FrankaEvalConfig(dt=0.0)
    with pytest.raises(ValueError, match=r"FrankaEvalConfig\.obstacle_clearance"):
        FrankaEvalConfig(obstacle_clearance=0.05, free_margin=0.05)
    with pytest.raises(ValueError, match=r"FrankaEvalConfig\.strategies must be one of"):
        FrankaEvalConfig(strategies=["bc"])
    with pytest.raises(ValueError, match=r"FrankaEvalConfig\.restarts"):
        FrankaEvalConfig(restarts=0)
    assert FrankaEvalConfig(tasks=["door_reaching"]).tasks == ("door_reaching",)
    cfg = FrankaEvalConfig(preset="cpu", metric_iterations=0).strategy_config("independent")
    assert cfg == StrategyConfig.cpu("independent", metric_iterations=0)
    assert FrankaEvalConfig(preset="thesis").strategy_config("joint") == StrategyConfig()
    assert StrategyConfig.preset("reference", "cspace") == StrategyConfig.reference("cspace")


def test_corridor_excursion_by_hand():
    """A rollout that starts 3 cm off the demonstrated corridor and then runs along it has
    excursion 0; one that moves 10 cm farther away mid-way has 0.10; the worst point counts."""
    t = np.linspace(0.0, 1.0, 21)
    line = np.stack([t, np.zeros_like(t), np.zeros_like(t)], axis=1)           # along x
    side = np.array([0.0, 0.1, 0.0])
    demo = np.stack([line, line + side, line + 2 * side], axis=1)            # (21, 3, 3)
    along = demo + np.array([0.0, 0.0, 0.03]) * (t[::-1, None, None] > 0.9)  # starts 3 cm above
    bump = demo.copy()
    bump[10, 2] += np.array([0.0, 0.0, 0.10])                               # one point lifted
    np.testing.assert_allclose(corridor_excursions(np.stack([along, bump]), [demo]),
                               [0.0, 0.10], atol=1e-12)


def test_kept_restart_is_the_first_within_the_radius_else_the_closest():
    """Fold 0: restarts 1 and 2 are within 2 cm, restart 1 is kept although 2 is closer; fold 1:
    none is within, the closest (restart 2) is kept; fold 2: restart 0 passes and is kept."""
    misses = np.array([[0.30, 0.015, 0.001], [0.30, 0.50, 0.25], [0.01, 0.001, 0.002]])
    np.testing.assert_array_equal(kept_restarts(misses, 0.02), [1, 2, 0])
    np.testing.assert_array_equal(kept_restarts(misses[:, :1], 0.02), [0, 0, 0])


@needs_data
def test_obstacle_starts_inside_the_margin_are_redrawn():
    """A cylinder on the hand of start 0 puts that start inside it: only that start is replaced,
    by one that keeps the margin; an impossible margin is refused."""
    demo = fd.load_task("drawer_closing", dt=0.5)[0]
    starts = perturbed_starts(jax.random.PRNGKey(3), demo.q[0], 6, 0.1)
    hand = np.asarray(fd.hand_points(jnp.asarray(starts[0])))[0]
    center = np.array([hand[0], hand[1], 0.0])
    before = clearance(starts, center[:2], 0.05)
    assert before[0] < 0
    out = clear_starts(jax.random.PRNGKey(4), demo.q[0], starts, 0.1, center, 0.05, 0.02)
    after = clearance(out, center[:2], 0.05)
    assert np.all(after >= 0.02)
    keep = before >= 0.02
    np.testing.assert_array_equal(out[keep], starts[keep])
    assert not np.allclose(out[0], starts[0])
    with pytest.raises(RuntimeError, match="no start"):
        clear_starts(jax.random.PRNGKey(4), demo.q[0], starts, 0.1, center, 0.05, 5.0,
                     max_rounds=3)


def _run_dir(path, seed, errors, successes, **settings):
    """A metrics.json of two strategies on one task with the given per-strategy values."""
    folds = lambda n: [{"success": n, "task_success": n, "corridor_excursions": [0.0] * 10}]  # noqa: E731
    tasks = {"door_reaching": {s: {
        "mean_position_error": errors[s], "success_rate": successes[s] / 10,
        "task_success_rate": successes[s] / 10, "success_rate_obstacle": 1.0,
        "success_rate_no_posture": 1.0, "colliding_rollouts": 0, "obstacle_rollouts": 10,
        "min_clearance_obstacle": 0.01, "joint_limit_violations": 0,
        "folds": folds(successes[s])} for s in errors}}
    path.mkdir()
    (path / "metrics.json").write_text(json.dumps(
        {"settings": {"seed": seed, "preset": "cpu", **settings}, "tasks": tasks}))
    return str(path)


def test_seed_summary_pairs_by_seed_by_hand(tmp_path):
    """Errors joint 0.1/0.2 against independent 0.3/0.3: difference −0.2/−0.1, mean −0.15,
    standard error std([−0.2, −0.1], ddof=1)/√2 = 0.05, joint better in both seeds; successes
    9/6 against 8/8 are pooled to 15/20 and 16/20, joint better in one seed."""
    a = _run_dir(tmp_path / "a", 1, {"joint": 0.1, "independent": 0.3}, {"joint": 9,
                                                                          "independent": 8})
    b = _run_dir(tmp_path / "b", 2, {"joint": 0.2, "independent": 0.3}, {"joint": 6,
                                                                          "independent": 8})
    out = summarise(load_runs([a, b]))["tasks"]["door_reaching"]
    c = out["comparisons"]["independent"]
    np.testing.assert_allclose(c["mean_position_error"]["mean_difference"], -0.15)
    np.testing.assert_allclose(c["mean_position_error"]["se"], 0.05)
    assert c["mean_position_error"]["reference_better"] == 2
    assert c["success_rate"]["reference_better"] == 1
    assert out["strategies"]["joint"]["pooled_success"] == [15, 20]
    assert out["strategies"]["independent"]["pooled_success"] == [16, 20]


def test_seed_summary_refuses_runs_that_differ_in_more_than_the_seed(tmp_path):
    e, n = {"joint": 0.1, "independent": 0.2}, {"joint": 5, "independent": 5}
    a = _run_dir(tmp_path / "a", 1, e, n, perturbation=0.1)
    b = _run_dir(tmp_path / "b", 2, e, n, perturbation=0.3)
    same = _run_dir(tmp_path / "c", 1, e, n, perturbation=0.1)
    with pytest.raises(ValueError, match="setting 'perturbation'"):
        load_runs([a, b])
    with pytest.raises(ValueError, match="its own seed"):
        load_runs([a, same])
    with pytest.raises(ValueError, match="at least 2 runs"):
        load_runs([a])
    with pytest.raises(FileNotFoundError, match=r"no metrics\.json"):
        load_runs([a, str(tmp_path)])
    ok = _run_dir(tmp_path / "d", 2, e, n, perturbation=0.1)
    with pytest.raises(ValueError, match="reference: strategy 'cspace'"):
        summarise(load_runs([a, ok]), reference="cspace")
