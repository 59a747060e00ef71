"""Checkpoint loading and evaluation (agents/run/{loading,evaluation,eval_report}.py,
scripts/eval.py): a restored run equals the state training returned, the sweep over checkpoints ×
seeds × episodes in one compiled call equals evaluating each parameter set separately, setups a
policy cannot read are refused, the report holds the GIF of the best checkpoint's evaluated
episode, the CLI writes its JSON report, and an exported checkpoint acts as its mean policy."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import subprocess
import sys

import jax
import numpy as np
import pytest
from jax import export as jax_export
from script_main import load_script

import mjxrmp  # noqa: F401  (XLA flags first)
from agents.ppo import PPOConfig
from agents.run import checkpoint
from agents.run.eval_report import evaluate_runs, format_table, summarize_sweep
from agents.run.evaluation import STATS, group_checkpoints, run_sweep, setup_env
from agents.run.export import export_run
from agents.run.loading import (
    checkpoint_steps,
    deterministic_policy,
    env_policy,
    load_run,
    make_env,
    mean_action_fn,
    policy_params,
    spec_from_json,
)
from agents.run.spec import RunSpec
from agents.run.training import run_training
from envs.evaluate import make_rollout

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

# As tests/agents/test_training.py: 3-link env1 with the nn policy (the cheapest reaching task to
# compile), 2 seeds, checkpoints at iterations 2 and 4.
SPEC = RunSpec(env="three_link/env1", policy="nn", seeds=(0, 1),
               ppo=PPOConfig(num_envs=4, rollout_length=8, num_minibatches=2, update_epochs=2,
                             total_iterations=4, policy_hidden_sizes=(8,),
                             value_hidden_sizes=(8,), episode_length=10,
                             normalize_observations=True),
               log_every=2, checkpoint_every=2)
EPISODES, HORIZON = 3, 25


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    out = str(tmp_path_factory.mktemp("run"))
    return run_training(SPEC, out, progress=False), out


@pytest.fixture(scope="module")
def sweep(trained):
    _, out = trained
    checkpoints = [load_run(out, step) for step in (2, 4)]
    return run_sweep(checkpoints, num_episodes=EPISODES, eval_seed=3, horizon=HORIZON)


def test_load_run_round_trip(trained, tmp_path):
    result, out = trained
    assert spec_from_json(SPEC.to_json()) == SPEC
    assert checkpoint_steps(out) == [2, 4]
    run = load_run(out)
    assert (run.step, run.iteration, run.spec, run.seeds) == (4, 4, SPEC, (0, 1))
    for a, b in zip(jax.tree.leaves(run.state), jax.tree.leaves(result.state), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert int(load_run(out, step=2).state.iteration[0]) == 2

    # the deterministic policy is the module's mean with that seed's observation statistics
    apply_fn, params = deterministic_policy(run, seed_index=1)
    obs = jax.random.normal(jax.random.PRNGKey(0), (5, make_env(SPEC.env, "nn").observation_size))
    seed1 = jax.tree.map(lambda x: x[1], result.state)
    want = result.trainer.policy.apply(seed1.params["policy"], obs, seed1.obs_stats)[0]
    np.testing.assert_array_equal(np.asarray(apply_fn(params, obs)), np.asarray(want))
    with pytest.raises(IndexError, match="seed_index"):
        policy_params(run, 2)

    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_run(str(tmp_path / "nothing"))
    with pytest.raises(FileNotFoundError, match=r"run\.json"):
        load_run(str(tmp_path))
    with pytest.raises(FileNotFoundError, match=r"available steps are \[2, 4\]"):
        load_run(out, step=3)
    copy = str(tmp_path / "copy")
    shutil.copytree(out, copy)
    with open(os.path.join(copy, "run.json")) as f:
        d = json.load(f)
    d["seeds"] = [0, 1, 2]
    with open(os.path.join(copy, "run.json"), "w") as f:
        json.dump(d, f)
    with pytest.raises(checkpoint.IncompatibleCheckpointError, match="seeds"):
        load_run(copy)
    d["ppo"]["learning_rat"] = 1.0
    with open(os.path.join(copy, "run.json"), "w") as f:
        json.dump(d, f)
    with pytest.raises(ValueError, match="learning_rat"):
        load_run(copy)


def test_sweep_shapes_and_finite(sweep):
    assert sweep.setups == ("three_link/env1",)
    assert sweep.members == [(0, 0), (0, 1), (1, 0), (1, 1)]
    assert [c.step for c in sweep.checkpoints] == [2, 4]
    assert sweep.horizons == {"three_link/env1": HORIZON}
    eps = sweep.episodes["three_link/env1"]
    assert set(eps) == set(STATS)
    for k, v in eps.items():
        assert v.shape == (4, EPISODES), k
        assert np.all(np.isfinite(v)), k
    np.testing.assert_array_equal(eps["length"], HORIZON)  # nothing collided in 25 steps
    rows = summarize_sweep(sweep)
    assert [(r["step"], r["setup"]) for r in rows] == [(2, "three_link/env1"),
                                                      (4, "three_link/env1")]
    for r in rows:
        assert len(r["per_seed"]["mean_return"]) == 2
        for k in ("mean_return", "success_pct", "safe_pct", "mean_final_goal_distance"):
            assert np.isfinite(r[k]) and np.isfinite(r[k + "_std"]), k
        np.testing.assert_allclose(r["mean_return"], np.mean(r["per_seed"]["mean_return"]))
    assert sweep.compile_seconds > 0 and sweep.run_seconds > 0
    assert "three_link/env1" in format_table(rows)


def test_sweep_equals_separate_evaluations(sweep):
    """One compiled call over the (checkpoint, seed) stack == one rollout per parameter set."""
    env = make_env(SPEC.env, SPEC.policy)
    apply_fn = mean_action_fn(sweep.checkpoints[0])

    @jax.jit
    def single(params, key):
        return make_rollout(env, EPISODES, HORIZON, policy=env_policy(apply_fn, params))(key)

    eps = sweep.episodes["three_link/env1"]
    for m, (ci, si) in enumerate(sweep.members):
        out = single(policy_params(sweep.checkpoints[ci], si), jax.random.PRNGKey(3))
        for k in STATS:
            np.testing.assert_allclose(eps[k][m], np.asarray(out[k]), rtol=1e-5, atol=1e-6,
                                       err_msg=f"member {m} {k}")
    # the two checkpoints are different policies: their returns differ
    assert not np.allclose(eps["return"][0], eps["return"][2], rtol=0, atol=0)


def test_mismatched_setup_is_refused(sweep):
    run = sweep.checkpoints[1]
    assert setup_env(run, "three_link/env3").observation_size == 26  # the setups share a model
    with pytest.raises(ValueError, match=r"observation size 26\).*observation size 45"):
        run_sweep([run], ["franka"], num_episodes=2, horizon=2)
    with pytest.raises(ValueError, match="valid setups"):
        setup_env(run, "point2d")
    # checkpoints of another environment/policy kind form their own group
    other = dataclasses.replace(run, spec=dataclasses.replace(run.spec, env="three_link/env2"))
    assert len(group_checkpoints([run, other, sweep.checkpoints[0]])) == 2
    with pytest.raises(ValueError, match="one compiled call"):
        run_sweep([run, other], num_episodes=2, horizon=2)


def test_report_with_gif_of_the_best_episode(trained, tmp_path):
    """:func:`evaluate_runs`: rows per checkpoint, one group, the GIF replays episode 0 of the
    best row's best seed (the same episode as evaluated); unreadable setups, missing
    checkpoints and missing run directories raise clear errors. (The sizes of the ``sweep``
    fixture: the same program, compiled once.)"""
    _, out = trained
    gif = str(tmp_path / "best.gif")
    report = evaluate_runs([out], ["all"], num_episodes=EPISODES, horizon=HORIZON,
                           per_episode=True, gif=gif)
    assert [(r["iteration"], len(r["seeds"]), r["episodes"]) for r in report["rows"]] == \
        [(2, 2, EPISODES), (4, 2, EPISODES)]
    assert len(report["groups"]) == 1 and report["groups"][0]["members"] == 4
    assert report["compile_seconds"] > 0 and report["run_seconds"] > 0
    json.dumps(report, allow_nan=False)
    best, shown = report["best"], report["gif"]
    assert os.path.getsize(gif) > 0 and shown["path"] == gif
    assert (shown["step"], shown["seed"]) == (best["step"], best["best_seed"])
    row = next(r for r in report["rows"] if r["step"] == best["step"])
    evaluated = row["per_episode"]["return"][row["seeds"].index(shown["seed"])][0]
    np.testing.assert_allclose(shown["return"], evaluated, rtol=1e-4, atol=1e-7)

    with pytest.raises(ValueError, match=r"observation size 26\).*observation size 45"):
        evaluate_runs([out], setups=["franka"], num_episodes=2)
    with pytest.raises(FileNotFoundError, match=r"available: \[2, 4\]"):
        evaluate_runs([out], ["3"])
    with pytest.raises(FileNotFoundError, match="does not exist"):
        evaluate_runs([str(tmp_path / "missing")])


def test_cli_writes_json(trained, tmp_path, capsys):
    """``scripts/eval.py`` end to end (a subprocess): the table, the JSON report; exit status 2
    with the error for a missing run directory (its ``main``, in this process)."""
    _, out = trained
    path = str(tmp_path / "eval.json")
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    script = os.path.join(ROOT, "scripts", "eval.py")
    proc = subprocess.run([sys.executable, script, out, "--episodes", "2", "--horizon", "5",
                           "--json", path], capture_output=True, text=True, env=env, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "return (± std)" in proc.stdout and "three_link/env1" in proc.stdout
    with open(path) as f:
        report = json.load(f)
    assert [r["iteration"] for r in report["rows"]] == [4] and report["gif"] is None
    # the missing run directory through the script's main in this process (no new interpreter)
    assert load_script("eval.py").main([str(tmp_path / "missing")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_export_checkpoint_matches_deterministic_policy(trained, tmp_path):
    """:func:`agents.run.export.export_run` of a checkpoint bakes the trained parameters and the
    observation statistics in: the deserialised export acts as the checkpoint's mean policy."""
    _, out = trained
    path = tmp_path / "p.jaxexport"
    manifest = export_run(path, out, train_seed_index=1, platforms=("cpu",))
    loaded = load_run(out)
    apply_fn, params = deterministic_policy(loaded, 1)
    assert params.norm is not None  # normalize_observations=True in SPEC
    obs = np.asarray(jax.random.normal(jax.random.PRNGKey(5), (7, 26)), np.float32)
    expected = np.asarray(jax.jit(apply_fn)(params, obs))
    exported = jax_export.deserialize(bytearray(path.read_bytes()))
    np.testing.assert_allclose(np.asarray(exported.call(obs)), expected, rtol=1e-5, atol=1e-6)
    assert manifest == json.loads(path.with_suffix(".json").read_text())
    assert manifest["metadata"]["iteration"] == 4 and manifest["metadata"]["seed"] == 1
    assert manifest["metadata"]["source"] == "checkpoint"
    with pytest.raises(ValueError, match="env_name and kind"):
        export_run(tmp_path / "q.jaxexport")
