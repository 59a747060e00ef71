"""The chapter-6 study (agents/run/ch6.py): the plot stage on synthetic run directories (summary
numbers against hand-computed values, the figures and tables it writes, a clear error when
there is nothing to plot) and the train stage's packing of setups that share a model and policy
kinds that share a network."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from agents.run.ch6 import (
    ENVS,
    POLICIES,
    packed_cells,
    packed_groups,
    plot_all,
    run_dir,
    summary_row,
    train_all,
)
from agents.run.loading import load_run
from agents.run.logs import write_csv

SEEDS, ITERS = (0, 1), 40


def _history(reward: float) -> dict[str, np.ndarray]:
    """Constant return ``reward`` (seed 1 at ``reward + 2``), 50 episodes per iteration, all
    safe except iteration 10 of seed 0 (half of its 50 episodes collided)."""
    shape = (len(SEEDS), ITERS)
    ret = np.full(shape, reward)
    ret[1] += 2.0
    safe = np.ones(shape)
    safe[0, 10] = 0.5
    return {"mean_episode_return": ret, "safe_fraction": safe, "episodes": np.full(shape, 50.0),
            "mean_reward": ret / 100, "success_fraction": np.zeros(shape)}


def test_summary_row_by_hand():
    r = summary_row("three_link/env3", "nn", _history(10.0))
    assert (r["seeds"], r["iterations"], r["episodes"]) == (2, ITERS, 2 * ITERS * 50)
    assert r["final_reward"] == pytest.approx(11.0) and r["final_reward_std"] == pytest.approx(1)
    assert r["collisions"] == 25
    assert r["min_safe_pct_per_iteration_any_seed"] == pytest.approx(50.0)
    # the 100-episode window holds iterations 10 and 9 of seed 0: (25 + 50) / 100 safe
    assert r["min_safe_pct_100ep_any_seed"] == pytest.approx(75.0)
    assert r["min_safe_pct_100ep"] == pytest.approx(87.5)
    assert r["mean_safe_pct"] == pytest.approx(100 * (1 - 0.5 / (2 * ITERS)))


def test_plot_stage_writes_figures_and_tables(tmp_path):
    runs, figures = str(tmp_path / "runs"), str(tmp_path / "figures")
    for (env, policy), reward in {("three_link/env3", "nn"): 10.0,
                                  ("three_link/env3", "rmp_residual"): 40.0,
                                  ("franka", "nn_residual"): 5.0}.items():
        out = run_dir(runs, env, policy)
        os.makedirs(out)
        write_csv(os.path.join(out, "metrics.csv"), _history(reward), SEEDS, 64)
    summary = plot_all(runs, figures, smooth=100)
    for name in ("fig6_2.png", "fig6_3.png", "fig6_4.png", "ch6_summary.csv"):
        assert os.path.getsize(os.path.join(figures, name)) > 0, name
    with open(os.path.join(figures, "ch6_summary.json")) as f:
        assert json.load(f) == summary
    assert [(r["env"], r["policy"]) for r in summary["rows"]] == [
        ("franka", "nn_residual"), ("three_link/env3", "nn"), ("three_link/env3", "rmp_residual")]
    assert summary["env3_rmp_residual_over_nn"] == pytest.approx(41.0 / 11.0)
    with pytest.raises(FileNotFoundError, match=r"no runs with metrics\.csv"):
        plot_all(str(tmp_path / "empty"), figures, smooth=100)


def test_train_stage_packs_setups_and_kinds_that_share_a_program(tmp_path, capsys):
    """The three 3-link setups × nn and nn_residual train in one program into their usual run
    directories; their speed records split the program's wall time; a repeated stage skips the
    finished runs."""
    three = ("three_link/env1", "three_link/env2", "three_link/env3")
    assert packed_groups(ENVS) == [three, ("franka",)]
    cells = packed_cells(ENVS, POLICIES)
    assert len(cells) == 4 and cells[0] == [(e, k) for e in three for k in ("nn", "nn_residual")]
    assert cells[1] == [(e, "rmp_residual") for e in three]
    assert cells[2:] == [[("franka", "nn"), ("franka", "nn_residual")],
                         [("franka", "rmp_residual")]]
    runs = str(tmp_path / "runs")
    settings = dict(envs=three, policies=("nn", "nn_residual"),
                    seeds=(0, 3),
                    preset_name="cpu", iterations=2, log_every=2, checkpoint_every=2,
                    progress=False, profile=False, num_envs=8, rollout_length=16,
                    num_minibatches=2, update_epochs=2)
    train_all(runs, **settings)
    records, names = [], []
    for env, kind in cells[0]:
        out = run_dir(runs, env, kind)
        run = load_run(out)
        assert (run.spec.env, run.spec.policy) == (env, kind) and run.iteration == 2
        assert run.state.iteration.shape == (2,)
        with open(os.path.join(out, "speed.json")) as f:
            records.append(json.load(f))
        names.append(os.path.basename(out))
    assert all(r["packed_with"] == names for r in records)
    program_wall = records[0]["segments"][-1]["program_wall_s"]
    assert sum(r["wall_s"] for r in records) == pytest.approx(program_wall)
    assert os.path.exists(os.path.join(runs, "sweep_" + "+".join(names), "sweep.json"))
    capsys.readouterr()
    train_all(runs, **settings)
    assert capsys.readouterr().err.count("finished (2 iterations), skipped") == 6
