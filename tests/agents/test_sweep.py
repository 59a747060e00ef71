"""Packed sweeps (agents.run.sweep): one program trains a grid of hyper-parameters, setups that
share a model and policy kinds that share a network × seeds, and each point equals its separate
run up to float32 rounding; a resumed sweep equals the uninterrupted one; every point's
directory is an ordinary run directory."""

from __future__ import annotations

import csv
import dataclasses

import jax
import numpy as np
import pytest
from script_main import load_script

from agents.ppo.hparams import SWEEPABLE, resolve
from agents.run.loading import load_run
from agents.run.spec import RunSpec, preset
from agents.run.sweep import run_sweep
from agents.run.sweep_spec import SweepSpec, parse_grid
from agents.run.training import run_training

#: Every sweepable name is set away from its default (so each is data in the sweep); two points
#: differ in the learning rate. 3-link env1: the cheapest reaching task to compile.
GRID = (("learning_rate", (3e-4, 1e-3)), ("ent_coef", (0.01,)), ("clip_eps", (0.15,)),
        ("vf_coef", (0.7,)), ("gamma", (0.97,)), ("gae_lambda", (0.9,)))
BASE = RunSpec(env="three_link/env1", policy="nn", seeds=(0, 3),
               ppo=preset("cpu", num_envs=8, rollout_length=16, num_minibatches=2,
                          update_epochs=2, total_iterations=4),
               log_every=2, checkpoint_every=2)


@pytest.fixture(scope="module")
def sweep_dir(tmp_path_factory):
    out = str(tmp_path_factory.mktemp("sweep"))
    result = run_sweep(SweepSpec(BASE, GRID), out, progress=False)
    return out, result


def _params(state):
    return [np.asarray(x) for x in jax.tree.leaves(state.params)]


def _separate_run_matches(spec: RunSpec, out: str, result, rows: slice):
    """Train ``spec`` alone into ``out``; its parameters and metrics equal the sweep result's
    ``rows`` to float32 rounding. The separate run's result."""
    alone = run_training(spec, out, progress=False)
    for a, b in zip(_params(alone.state), _params(result.state), strict=True):
        np.testing.assert_allclose(b[rows], a, rtol=2e-4, atol=2e-6)
    for k in ("mean_reward", "loss", "approx_kl"):
        np.testing.assert_allclose(result.history[k][rows], alone.history[k],
                                   rtol=2e-3, atol=1e-6)
    return alone


def test_grid_names_every_sweepable_value():
    assert {name for name, _ in GRID} == set(SWEEPABLE)
    names = [name for name, _ in SweepSpec(BASE, GRID).points()]
    assert len(names) == 2 and names[0].startswith("learning_rate=0.0003,ent_coef=0.01")


def test_each_point_equals_its_separate_run(sweep_dir, tmp_path):
    """acceptance 1: the sweep's rows of its second point (point-major, then seed: rows 2–3)
    against the separate run of that point's spec (its values as constants), to float32
    rounding. One point is enough: every value is data in the sweep's one program, and the
    second point's rows also check the layout."""
    _, result = sweep_dir
    _, spec = SweepSpec(BASE, GRID).points()[1]
    _separate_run_matches(spec, str(tmp_path / "p1"), result, slice(2, 4))
    # the two learning rates really differ: the points' parameters are not the same
    p = _params(result.state)
    assert max(np.abs(x[0] - x[2]).max() for x in p) > 1e-5


def test_resumed_sweep_equals_the_uninterrupted_one(sweep_dir, tmp_path):
    _, full = sweep_dir
    half = dataclasses.replace(BASE, ppo=dataclasses.replace(BASE.ppo, total_iterations=2))
    out = str(tmp_path / "resumed")
    run_sweep(SweepSpec(half, GRID), out, progress=False)
    resumed = run_sweep(SweepSpec(BASE, GRID), out, resume=True, progress=False)
    for a, b in zip(_params(full.state), _params(resumed.state), strict=True):
        np.testing.assert_array_equal(a, b)
    for k, v in full.history.items():
        np.testing.assert_array_equal(resumed.history[k], v)


def test_points_are_ordinary_run_directories(sweep_dir):
    out, result = sweep_dir
    with open(f"{out}/sweep.csv") as f:
        rows = list(csv.DictReader(f))
    assert [float(r["learning_rate"]) for r in rows] == [3e-4, 1e-3]
    assert all(np.isfinite(float(r["mean_reward"])) for r in rows)
    assert {"mean_episode_return", "safe_fraction", "success_fraction"} <= set(rows[0])
    for i, (name, spec) in enumerate(SweepSpec(BASE, GRID).points()):
        run = load_run(f"{out}/{name}")
        assert run.spec == spec and run.state.hparams is None
        for a, b in zip(_params(run.state), _params(result.state), strict=True):
            np.testing.assert_array_equal(a, b[2 * i:2 * i + 2])


def test_bad_grids_are_refused():
    with pytest.raises(ValueError, match="num_envs"):
        SweepSpec(BASE, (("num_envs", (8.0, 16.0)),))
    with pytest.raises(ValueError, match="distinct"):
        SweepSpec(BASE, (("learning_rate", (1e-3, 1e-3)),))
    with pytest.raises(ValueError, match="clip_eps"):
        SweepSpec(BASE, (("clip_eps", (0.0,)),))
    with pytest.raises(ValueError, match="--grid 'gamma'"):
        parse_grid(["gamma"])
    with pytest.raises(ValueError, match="unknown names"):
        resolve(BASE.ppo, {"lr": 1.0})
    with pytest.raises(FileNotFoundError):
        run_sweep(SweepSpec(BASE, GRID), "/nonexistent/sweep", resume=True)


#: Two setups that share a model (env2 and env3 differ only in the goal region) × two policy
#: kinds that share a network (nn: the hand-designed base added with weight 0) in one program.
SETUPS = SweepSpec(dataclasses.replace(BASE, env="three_link/env2"),
                   envs=("three_link/env2", "three_link/env3"), policies=("nn", "nn_residual"))


@pytest.fixture(scope="module")
def setups_dir(tmp_path_factory):
    out = str(tmp_path_factory.mktemp("setups"))
    return out, run_sweep(SETUPS, out, progress=False)


def test_each_setup_and_policy_equals_its_separate_run(setups_dir, tmp_path):
    """acceptance 1 for setups and policy kinds as data: env2 × nn and env3 × nn_residual rows
    of one program against the two separate runs (each with its own environment and policy
    module), to float32 rounding."""
    out, result = setups_dir
    points = SETUPS.points()
    assert [name for name, _ in points] == [
        f"env=three_link-{e},policy={k}" for e in ("env2", "env3") for k in ("nn", "nn_residual")]
    assert SETUPS.program_spec().policy == "nn_residual"
    np.testing.assert_array_equal(result.state.hparams["base_weight"], [0, 0, 1, 1, 0, 0, 1, 1])
    for i in (0, 3):
        name, spec = points[i]
        rows = slice(2 * i, 2 * i + 2)
        alone = _separate_run_matches(spec, str(tmp_path / f"s{i}"), result, rows)
        np.testing.assert_allclose(np.asarray(result.state.env_state.info["goal"])[rows],
                                   np.asarray(alone.state.env_state.info["goal"]), atol=1e-6)
        assert load_run(f"{out}/{name}").spec == spec
    with open(f"{out}/sweep.csv") as f:
        table = list(csv.DictReader(f))
    assert [(r["env"], r["policy"]) for r in table] == [(s.env, s.policy) for _, s in points]
    # the setups really differ: env2's goals keep to its narrower annulus, env3's do not
    goal_r = np.linalg.norm(np.asarray(result.state.env_state.info["goal"]), axis=-1)
    assert goal_r[:4].max() <= 0.475 + 1e-5 and goal_r[:4].min() >= 0.275 - 1e-5
    assert goal_r[4:].max() > 0.475 or goal_r[4:].min() < 0.275
    # so do the kinds: env2's nn and nn_residual rows start alike (same seeds, same network
    # initialisation) and end apart (the base changes the actions)
    p = _params(result.state)
    assert max(np.abs(x[0] - x[2]).max() for x in p) > 1e-5


def test_resumed_setups_sweep_equals_the_uninterrupted_one(setups_dir, tmp_path):
    _, full = setups_dir
    half = dataclasses.replace(SETUPS.base, ppo=dataclasses.replace(BASE.ppo, total_iterations=2))
    out = str(tmp_path / "resumed")
    run_sweep(dataclasses.replace(SETUPS, base=half), out, progress=False)
    resumed = run_sweep(SETUPS, out, resume=True, progress=False)
    for a, b in zip(jax.tree.leaves(full.state), jax.tree.leaves(resumed.state), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_setups_and_policies_that_differ_in_their_model_are_refused(tmp_path):
    with pytest.raises(ValueError, match="two or more distinct"):
        SweepSpec(BASE, envs=("three_link/env2",))
    with pytest.raises(ValueError, match="a grid or two or more envs or policies"):
        SweepSpec(BASE)
    with pytest.raises(ValueError, match=r"\['nn', 'rmp_residual'\] differ in network structure"):
        SweepSpec(BASE, policies=("nn", "rmp_residual"))
    with pytest.raises(ValueError, match="two or more distinct policy kinds"):
        SweepSpec(BASE, policies=("nn", "nn"))
    with pytest.raises(SystemExit) as refused:  # the command line names the kinds (exit 2)
        load_script("train.py").main(["--policy", "nn", "rmp_residual", "--out",
                                      str(tmp_path / "kinds"), "--no-progress"])
    assert refused.value.code == 2 and not (tmp_path / "kinds").exists()
    mixed = SweepSpec(BASE, envs=("three_link/env2", "franka"))
    with pytest.raises(ValueError, match=r"'franka' does not differ .* only in its scene"):
        run_sweep(mixed, str(tmp_path / "mixed"), progress=False)
    assert not (tmp_path / "mixed" / "sweep.json").exists()
    # the command line: several --env setups are a sweep, refused the same way (exit 2)
    code = load_script("train.py").main(["--env", "three_link/env2", "franka",
                                         "--out", str(tmp_path / "cli"), "--no-progress"])
    assert code == 2 and not (tmp_path / "cli" / "sweep.json").exists()
