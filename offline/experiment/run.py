"""Learner × scenario × dataset runs (thesis §7.4, Table 7.3; docs/design.md §2.4): which learner
has data in which scenario (:func:`applicable`), its trainer (:func:`build`, through the registry
:data:`offline.learners.registry.BUILDERS`, whose docstring says which data each learner reads and
how a :class:`~offline.learners.registry.Budget` shortens the published schedules), and the
vmapped, chunked training of several seeds (and β values) in one compiled program.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import jax
import numpy as np

from mjxrmp.divergence import guard_finite_series, guard_finite_tree
from offline.data import dataset as odata
from offline.data import scenarios
from offline.learners.base import Trainer
from offline.learners.registry import (
    BUILDERS,
    LEARNERS,
    NEEDS_SHARED,
    PLAIN_LEARNERS,
    Budget,
)


def applicable(learner: str, scenario: str | None) -> bool:
    """Whether ``learner`` has data to train on in ``scenario`` (None: a plain dataset)."""
    if learner not in LEARNERS:
        raise ValueError(f"unknown learner={learner!r}; valid names are {list(LEARNERS)}")
    if scenario is None:
        return learner in PLAIN_LEARNERS
    if scenario not in scenarios.SCENARIOS:
        raise ValueError(f"unknown scenario={scenario!r}; valid scenarios are "
                         f"{list(scenarios.SCENARIOS)}")
    return not (learner in NEEDS_SHARED and scenario in ("ILfO", "RLfO"))


def build(learner: str, dynamics: odata.Dataset, reward_data: scenarios.RewardData | None,
          budget: Budget, scenario: str | None = None) -> Trainer:
    """The :class:`~offline.learners.base.Trainer` of ``learner`` on a scenario's data
    (:data:`offline.learners.registry.BUILDERS`), or on a plain dataset when ``reward_data`` is
    None."""
    if not applicable(learner, scenario):
        raise ValueError(f"{learner} has no data to train on in scenario {scenario!r}: it needs "
                         f"reward data with actions (IL, RL-expert, RL-sample)")
    if (reward_data is None) != (scenario is None):
        raise ValueError("pass reward_data exactly when a scenario is named")
    return BUILDERS[learner](dynamics, reward_data, budget, scenario)


def train_chunked(trainer: Trainer, keys: jax.Array, chunk: int,
                  on_chunk: Callable[[Any, dict, int], None] | None = None,
                  state: Any = None, start: int = 0, *, name: str = "offline learner",
                  runs: Sequence[str] | None = None) -> tuple[Any, dict[str, np.ndarray]]:
    """Train the seeds ``keys`` (vmapped) for ``trainer.num_steps`` steps in compiled chunks
    of ``chunk`` steps (the last one shorter), from ``state`` at step ``start`` (default: a fresh
    ``init``). After each chunk ``on_chunk(state, chunk_metrics, steps_done)`` is called (progress,
    logging, checkpoints). Returns the final state and the per-chunk means of every metric,
    shape ``(chunks, seeds)``.

    **Divergence guard** (docs/design.md §5.5): after each chunk, before ``on_chunk``, a non-finite
    metric or state leaf (parameters, targets, optimiser moments) raises
    :class:`mjxrmp.divergence.DivergenceError` naming ``name``, the gradient step (the first
    non-finite metric's, else the chunk's last), the run (``runs[i]``, default ``run <i>``) and
    the quantity (the metric, or the leaf's path such as ``state.params['critic']…``); so no
    non-finite state reaches ``on_chunk`` (its checkpoints and logs keep the last finite
    chunk)."""
    if not (isinstance(chunk, int) and chunk >= 1):
        raise ValueError(f"chunk must be a positive integer, got {chunk!r}")
    if state is None:
        state = init_runs(trainer, keys, None)
    run = jax.jit(jax.vmap(trainer.run, in_axes=(0, None)), static_argnums=1)
    history: dict[str, list] = {}
    done = start
    while done < trainer.num_steps:
        n = min(chunk, trainer.num_steps - done)
        state, metrics = run(state, n)
        done += n
        means = {k: np.asarray(jax.numpy.mean(v, axis=1)) for k, v in metrics.items()}
        if not all(np.isfinite(v).all() for v in means.values()):
            guard_finite_series(metrics, name, start=done - n, unit="gradient step", runs=runs)
        guard_finite_tree(state, name, done, unit="gradient step", runs=runs, prefix="state",
                          batched=True)
        for k, v in means.items():
            history.setdefault(k, []).append(v)
        if on_chunk is not None:
            on_chunk(state, means, done)
    return state, {k: np.stack(v) for k, v in history.items()}


def seed_keys(seeds: Sequence[int]) -> jax.Array:
    """One PRNG key per seed (``PRNGKey(seed)``), stacked for ``vmap``."""
    return jax.numpy.stack([jax.random.PRNGKey(int(s)) for s in seeds])


def seed_beta_runs(seeds: Sequence[int], betas: Sequence[float] | None
                   ) -> tuple[list[int], list[float] | None]:
    """The runs of a seeds × β grid, seed-major: ``(run_seeds, run_betas)``; without ``betas``
    one run per seed and ``None`` (every run at its config's β)."""
    if betas is None:
        return list(seeds), None
    return [s for s in seeds for _ in betas], [float(b) for _ in seeds for b in betas]


def init_runs(trainer: Trainer, keys: Any, betas: Sequence[float] | None) -> Any:
    """The vmapped initial state of the runs ``keys`` (one per run along the leading axis of
    every leaf, e.g. ``(rewards, keys)`` of :func:`offline.survival.sweep.reward_seed_keys`), each
    at its β from ``betas`` (one per run; ``None``: the config's β) — one program trains the whole
    grid."""
    if betas is None:
        return jax.jit(jax.vmap(trainer.init))(keys)
    runs = jax.tree.leaves(keys)[0].shape[0]
    if len(betas) != runs:
        raise ValueError(f"betas has {len(betas)} entries for {runs} runs")
    return jax.jit(jax.vmap(trainer.init))(keys, jax.numpy.asarray(betas, jax.numpy.float32))


__all__ = [
    "applicable",
    "build",
    "init_runs",
    "seed_beta_runs",
    "seed_keys",
    "train_chunked",
]
