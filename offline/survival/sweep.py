"""The chapter-8 sweep (thesis §8.4.1; docs/design.md §2.4): one compiled program trains a learner
on **several data rewards × several seeds** of one dataset.

The wrong-reward variants of a dataset (:func:`offline.survival.rewards.variant`) differ only in
their ``rewards`` array, so a learner's trainer (:func:`offline.experiment.run.build`, which closes
over the dataset) can be built *inside* a traced function of the rewards:
:func:`reward_batched` returns a :class:`~offline.learners.base.Trainer` whose ``init`` takes
``(rewards, key)`` and whose state carries the rewards row, so
``offline.experiment.run.train_chunked(trainer, reward_seed_keys(rows, seeds), chunk)`` vmaps over
``len(rows) × len(seeds)`` runs. Each run is the run of ``build(learner,
dataset.replace(rewards=row), None, budget)`` from ``PRNGKey(seed)`` (the same computation,
batched; a test checks this in floating point).
"""

from __future__ import annotations

import zlib
from collections.abc import Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from offline.data import dataset as odata
from offline.experiment import run as experiment
from offline.learners.base import Trainer, actor_params
from offline.learners.registry import Budget
from offline.survival import rewards as survival

#: Learners whose data reward matters (trained once per reward variant); BC reads no reward.
REWARD_LEARNERS = ("ATAC", "PSPI", "IQL", "CQL")
#: On a plain dataset, :func:`offline.experiment.run.build`'s "Oracle" is ATAC on the dataset's
#: own rewards (:func:`offline.learners.plfo_baselines.make_train_oracle`) — here those are the
#: (possibly wrong) data rewards, so that is the chapter-8 "ATAC".
_BUILD_NAME = {"ATAC": "Oracle"}


def build_plain(learner: str, dataset: odata.Dataset, budget: Budget) -> Trainer:
    """The trainer of ``learner`` (:data:`REWARD_LEARNERS` or ``"BC"``) on a plain dataset
    with its own rewards (:func:`offline.experiment.run.build` without a scenario)."""
    if learner not in (*REWARD_LEARNERS, "BC"):
        raise ValueError(f"learner must be one of {[*REWARD_LEARNERS, 'BC']}, got {learner!r}")
    return experiment.build(_BUILD_NAME.get(learner, learner), dataset, None, budget)


class RewardBatchedState(NamedTuple):
    """The state of one run of :func:`reward_batched`: its data rewards and the learner's
    own state."""

    rewards: jax.Array
    inner: Any


def reward_key(seed: int, dataset_name: str) -> jax.Array:
    """The key of a dataset's ``"random"`` rewards: ``fold_in(PRNGKey(seed), crc32(name))``
    (the convention of :func:`offline.survival.rewards.variant_grid`)."""
    return jax.random.fold_in(jax.random.PRNGKey(int(seed)),
                              zlib.crc32(dataset_name.encode()) & 0x7FFFFFFF)


def reward_rows(dataset: odata.Dataset, rewards: Sequence[str], terminals: str,
                key: jax.Array) -> tuple[odata.Dataset, np.ndarray]:
    """``(base, rows)``: the dataset with terminal handling ``terminals`` and its true rewards
    (:func:`offline.survival.rewards.variant` ``"original"``), and the float32 data rewards of each
    variant in ``rewards`` (thesis §8.4.1; ``"random"`` drawn with ``key``), shape
    ``(len(rewards), N)``."""
    if not rewards:
        raise ValueError("rewards must name at least one reward variant")
    base = survival.variant(dataset, "original", terminals)
    rows = [np.asarray(survival.variant(dataset, r, terminals, key).rewards, np.float32)
            for r in rewards]
    return base, np.stack(rows)


def reward_batched(learner: str, dataset: odata.Dataset, budget: Budget) -> Trainer:
    """``learner`` (one of :data:`REWARD_LEARNERS`) on ``dataset`` with the data rewards given
    per run (module docstring): ``init((rewards (N,), key), beta=None)``,
    ``run(state, n)`` and ``act`` as for :func:`offline.experiment.run.build`."""
    if learner not in REWARD_LEARNERS:
        raise ValueError(f"learner must be one of {list(REWARD_LEARNERS)}, got {learner!r}")
    concrete = build_plain(learner, dataset, budget)

    def inner(rewards: jax.Array) -> Trainer:
        # Built inside the traced init/run: what depends only on the (concrete) dataset — its
        # preparation, the NN-RESIDUAL actor's precomputed RMP² bases — is evaluated when
        # traced, not staged into the program and recomputed on every call.
        with jax.ensure_compile_time_eval():
            return build_plain(learner, dataset.replace(rewards=rewards), budget)

    def init(arg: tuple[jax.Array, jax.Array], beta: Any = None) -> RewardBatchedState:
        rewards, key = arg
        return RewardBatchedState(rewards, inner(rewards).init(key, beta))

    def run(state: RewardBatchedState, n: int) -> tuple[RewardBatchedState, dict]:
        new, metrics = inner(state.rewards).run(state.inner, n)
        return RewardBatchedState(state.rewards, new), metrics

    return Trainer(init, run, concrete.act, concrete.num_steps)


def reward_seed_keys(rows: np.ndarray, seeds: Sequence[int]) -> tuple[jax.Array, jax.Array]:
    """The vmapped ``init`` argument of :func:`reward_batched`: every (reward row, seed) pair,
    reward-major — ``(rows repeated, PRNGKey(seed) tiled)``, leading size
    ``len(rows) · len(seeds)``."""
    rows = jnp.asarray(rows, jnp.float32)
    keys = experiment.seed_keys(seeds)
    v, s = rows.shape[0], keys.shape[0]
    return jnp.repeat(rows, s, axis=0), jnp.tile(keys, (v, 1))


def run_actor_params(state: Any) -> Any:
    """The actor parameters of a (possibly reward-batched) learner state."""
    return actor_params(state.inner if isinstance(state, RewardBatchedState) else state)


__all__ = [
    "REWARD_LEARNERS",
    "RewardBatchedState",
    "build_plain",
    "reward_batched",
    "reward_key",
    "reward_rows",
    "reward_seed_keys",
    "run_actor_params",
]
