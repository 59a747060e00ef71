"""Divergence guards of the offline learners (issue 27, case 2 for the offline trainers;
mjxrmp.divergence, offline.experiment.run.train_chunked, offline.experiment.single.train).

Real learners at tiny sizes diverge by construction: rewards of 1e30 (finite data, so the dataset
checks accept them, whose squared Bellman errors overflow float32) or a critic learning rate of
1e6. Each run stops with a ``DivergenceError`` naming the learner, the gradient step, the seed
and the quantity; checkpoints and ``metrics.csv`` end at the last finite chunk and no
``result.json`` is written.
"""

from __future__ import annotations

import argparse

import jax
import numpy as np
import pytest
from offline_bandit import make_bandit

import mjxrmp  # noqa: F401  (XLA flags first)
from agents.run import checkpoint
from mjxrmp.divergence import DivergenceError, guard_finite_series, guard_finite_tree
from offline.data import dataset as odata
from offline.data.rollouts import make_env
from offline.experiment import single
from offline.experiment.programs import train_program
from offline.experiment.run import seed_keys
from offline.learners import atac, iql

ENV = "three_link/env3"


def _huge_rewards(data: odata.Dataset) -> odata.Dataset:
    """``data`` with every reward 1e30 (finite) and its rewards visible (IQL reads them)."""
    return data.replace(rewards=np.full_like(data.rewards, 1e30),
                        metadata=data.metadata.updated(rewards_visible=True))


def test_atac_diverges_at_step_one_and_writes_no_checkpoint(tmp_path):
    """issue case 2 (offline): ATAC on rewards of 1e30 → ``ATAC diverged at gradient step 1
    (seed 3): bellman is inf``; the checkpoint folder stays empty."""
    config = atac.ATACConfig(hidden_sizes=(8,), batch_size=8, num_steps=3, warmstart_steps=0)
    trainer = atac.make_train(_huge_rewards(make_bandit()), config)
    ckpt = tmp_path / "checkpoints"
    with pytest.raises(DivergenceError,
                       match=r"^ATAC diverged at gradient step 1 \(seed 3\): bellman is inf$"):
        train_program(trainer, seed_keys([3, 4]), 1, None, ckpt, {"learner": "ATAC"},
                      name="ATAC", runs=["seed 3", "seed 4"])
    assert checkpoint.latest_step(ckpt) is None


def test_iql_huge_learning_rate_keeps_the_last_finite_checkpoint(tmp_path):
    """issue case 2 (offline): IQL with a critic learning rate of 1e6 → its loss turns
    non-finite after the first step; the error names the step, the newest checkpoint is the
    step before it and holds finite parameters."""
    config = iql.IQLConfig(hidden_sizes=(8, 8, 8), batch_size=8, num_steps=5, critic_lr=1e6,
                           value_lr=1e6)
    data = make_bandit()
    trainer = iql.make_train(data.replace(metadata=data.metadata.updated(rewards_visible=True)),
                             config)
    ckpt = tmp_path / "checkpoints"
    chunks: list[int] = []
    with pytest.raises(DivergenceError, match=r"^IQL diverged at gradient step \d \(seed 0\): "
                                              r"\w+ is (nan|inf|-inf)$") as info:
        train_program(trainer, seed_keys([0]), 1, lambda st, means, done: chunks.append(done),
                      ckpt, {"learner": "IQL"}, name="IQL", runs=["seed 0"])
    step = info.value.step
    assert step >= 2 and chunks == list(range(1, step))
    assert checkpoint.latest_step(ckpt) == step - 1
    template = jax.eval_shape(jax.vmap(trainer.init), seed_keys([0]))
    state, _ = checkpoint.restore(ckpt, template, expected={"learner": "IQL"})
    guard_finite_tree(state.params, "IQL", step - 1, batched=True)  # finite: does not raise


def _train_args(tmp_path, dataset) -> argparse.Namespace:
    """``scripts/train_offline.py``'s parsed options (:data:`single.OPTIONS`) for a tiny IQL
    run on ``dataset``."""
    parser = argparse.ArgumentParser()
    for option in single.OPTIONS:
        parser.add_argument(*option.flags, **option.spec)
    return single.check_args(parser.parse_args([
        "--learner", "IQL", "--dataset", str(dataset), "--steps", "10", "--chunk", "5",
        "--hidden", "8", "--batch", "8", "--seeds", "0", "1", "--out", str(tmp_path / "run"),
        "--no-progress"]))


def test_train_offline_run_stops_without_result(tmp_path):
    """issue case 2 (offline, ``scripts/train_offline.py``'s run): a dataset of ``ENV`` with
    rewards of 1e30 → ``DivergenceError`` naming IQL, step 1 and seed 0; no ``result.json``,
    ``metrics.csv`` or checkpoint is written."""
    env = make_env(ENV)
    rng = np.random.default_rng(0)
    n, o, a = 64, int(env.observation_size), int(env.action_size)
    ends = np.arange(n) % 8 == 7
    data = odata.create(
        rng.normal(size=(n, o)).astype(np.float32),
        rng.uniform(-env.action_limit, env.action_limit, (n, a)).astype(np.float32),
        np.full(n, 1e30, np.float32), rng.normal(size=(n, o)).astype(np.float32),
        np.zeros(n, bool), ends, np.arange(n) // 8,
        {"env": ENV, "action_limit": float(env.action_limit)})
    odata.save(data, tmp_path / "huge.npz")
    args = _train_args(tmp_path, tmp_path / "huge.npz")
    with pytest.raises(DivergenceError,
                       match=r"^IQL diverged at gradient step 1 \(seed 0\): \w+ is inf$"):
        single.train(args)
    out = tmp_path / "run"
    assert not (out / "result.json").exists() and not (out / "metrics.csv").exists()
    assert checkpoint.latest_step(out / "checkpoints") is None


def test_guards_name_the_first_non_finite_value():
    """The shared guards (mjxrmp.divergence): the earliest step over runs and quantities, the
    parameter's path and run; finite values pass."""
    series = {"actor_loss": np.array([[1.0, 2.0, np.nan], [1.0, 1.0, 1.0]]),
              "critic_loss": np.array([[1.0, 1.0, 1.0], [1.0, np.inf, 1.0]])}
    with pytest.raises(DivergenceError, match=r"^X diverged at gradient step 12 \(seed 9\): "
                                              r"critic_loss is inf$"):
        guard_finite_series(series, "X", start=10, unit="gradient step",
                            runs=["seed 8", "seed 9"])
    guard_finite_series({"loss": np.ones((2, 3))}, "X")
    tree = {"actor": {"w": np.ones((2, 3)), "b": np.array([[0.0], [-np.inf]])},
            "step": np.array([1, 2])}
    with pytest.raises(DivergenceError,
                       match=r"^X diverged at step 5 \(run 1\): params\['actor'\]\['b'\] is -inf$"):
        guard_finite_tree(tree, "X", 5, batched=True)
    guard_finite_tree({"w": np.ones(3), "key": jax.random.PRNGKey(0)}, "X", 5)
