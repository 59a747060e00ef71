"""Issue 27, case 2 (no divergence guard): ``--set learning_rate=1e6 --set max_grad_norm=none``
gave a NaN loss from iteration 2, exit status 0 and a summary saying "improved". Now the PPO run
stops at the first non-finite chunk with :class:`DivergenceError` naming the iteration, seed and
quantity, keeps only finite checkpoints, logs what it computed, and ``scripts/train.py`` exits
with status 3."""

from __future__ import annotations

import os
import subprocess
import sys

import jax
import numpy as np
import pytest

from agents.ppo import PPOConfig
from agents.run.loading import checkpoint_steps, load_run
from agents.run.logs import improvement_summary, read_csv
from agents.run.spec import RunSpec
from agents.run.training import _divergence, run_training
from mjxrmp.divergence import DivergenceError

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

# The issue's overrides on a tiny run: iteration 1 is finite, iteration 2's loss is NaN.
DIVERGING = RunSpec(env="three_link/env3", policy="nn", seeds=(0,), log_every=1,
                    checkpoint_every=1,
                    ppo=PPOConfig(num_envs=4, rollout_length=8, num_minibatches=1,
                                  update_epochs=1, total_iterations=3, episode_length=6,
                                  policy_hidden_sizes=(8,), value_hidden_sizes=(8,),
                                  learning_rate=1e6, max_grad_norm=None))
MESSAGE = (r"^training diverged at iteration 2 \(seed 0\): loss is nan; the last finite "
           r"checkpoint is iteration 1 in .*checkpoints$")


@pytest.fixture(scope="module")
def diverged(tmp_path_factory):
    """The diverging run, trained once; its run directory."""
    out = str(tmp_path_factory.mktemp("diverged"))
    with pytest.raises(DivergenceError, match=MESSAGE):
        run_training(DIVERGING, out, progress=False)
    return out


def test_diverging_run_stops_naming_iteration_seed_and_quantity(diverged):
    """issue case 2: `--set learning_rate=1e6 --set max_grad_norm=none` → a DivergenceError
    at iteration 2 naming the seed, `loss is nan` and the last finite
    checkpoint (the fixture's pytest.raises); nothing after iteration 2 ran."""
    history, seeds = read_csv(os.path.join(diverged, "metrics.csv"))
    assert seeds == (0,) and history["loss"].shape == (1, 2)
    assert np.isfinite(history["loss"][0, 0]) and np.isnan(history["loss"][0, 1])


def test_diverged_run_keeps_only_finite_checkpoints_and_logs(diverged):
    """issue case 2: the non-finite state is never checkpointed (only iteration 1, finite,
    restorable); metrics.csv and the learning curves hold what was logged."""
    assert checkpoint_steps(diverged) == [1]
    loaded = load_run(diverged)
    assert all(np.isfinite(np.asarray(x)).all() for x in jax.tree.leaves(loaded.state.params))
    assert os.path.getsize(os.path.join(diverged, "learning_curves.png")) > 0


def test_nonfinite_parameter_is_named_by_path(diverged):
    """issue case 2, parameters: a chunk whose metrics are finite but whose parameters are not
    (the checkpoint's real parameters, one value set to inf in the second of two stacked seeds)
    is caught, naming the chunk's last iteration, the seed and the parameter's path."""
    params = jax.tree.map(lambda x: np.concatenate([x, x]), load_run(diverged).state.params)
    path, leaf = jax.tree_util.tree_flatten_with_path(params)[0][-1]
    leaf[1].flat[0] = np.inf
    runs = ["seed 0", "seed 7"]
    metrics = {"loss": np.zeros((2, 3)), "mean_reward": np.zeros((2, 3))}
    assert str(_divergence(runs, metrics, params, 4)) == (
        f"training diverged at iteration 7 (seed 7): params{jax.tree_util.keystr(path)} is inf")
    params = jax.tree.map(lambda x: np.nan_to_num(x, posinf=0.0), params)
    assert _divergence(runs, metrics, params, 4) is None


def test_summary_of_a_nonfinite_run_gives_no_verdict(diverged):
    """issue case 2: the summary printed "improved" for a NaN run; now it has no verdict and
    names the first non-finite value."""
    history, _ = read_csv(os.path.join(diverged, "metrics.csv"))
    summary = improvement_summary(history)
    assert "improved" not in summary
    assert summary.endswith("no verdict: the run has non-finite values (loss is nan at "
                            "iteration 2)")


def test_train_script_exits_3_on_divergence(tmp_path):
    """issue case 2 through the command line: `scripts/train.py --set learning_rate=1e6 --set
    max_grad_norm=none` exits with status 3 and a one-line message naming the iteration."""
    out = str(tmp_path / "run")
    # DIVERGING's sizes, episode length included: the script's programs are the fixture's, so
    # one of the two loads them from the session's compile cache instead of compiling them
    sets = ["num_envs=4", "rollout_length=8", "num_minibatches=1", "update_epochs=1",
            "episode_length=6",
            "policy_hidden_sizes=8", "value_hidden_sizes=8", "learning_rate=1e6",
            "max_grad_norm=none"]
    cmd = [sys.executable, os.path.join(ROOT, "scripts", "train.py"), "--env", "three_link/env3",
           "--policy", "nn", "--iterations", "3", "--log-every", "1", "--checkpoint-every", "1",
           "--no-progress", "--out", out, *(a for s in sets for a in ("--set", s))]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=ROOT,
                          env={**os.environ, "JAX_PLATFORMS": "cpu"})
    assert proc.returncode == 3, proc.stderr[-3000:]
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("error: training diverged at iteration 2 (seed 0): "), last
    assert "improved" not in proc.stderr and "Traceback" not in proc.stderr
    assert checkpoint_steps(out) == [1]
