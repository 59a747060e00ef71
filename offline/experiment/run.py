"""Learner × scenario × dataset experiments (thesis §7.4, Table 7.3): one place that knows which
learner reads which data, shared by ``scripts/train_offline.py`` and ``scripts/reproduce_ch7.py``.

**Learners** (:data:`LEARNERS`) and the data each one trains on in a PLfO scenario
``(D_A, D_R)`` (:func:`offline.data.scenarios.make`):

==========  ==============================================================================
MAHALO      ``D_A`` and ``D_R``: Algorithm 3 (:mod:`offline.learners.mahalo`)
RP          reward network fitted on ``D_R``, frozen, labels ``D_A``; ATAC
AP          inverse-dynamics model fitted on ``D_A`` labels ``D_R``'s missing actions; ATAC on
            the labelled ``D_R`` only (§7.4 "runs ATAC on the reward dataset"). The inverse
            model is trained once per cell (key ``inverse_seed``) and shared by the seeds.
UDS         ATAC on ``D_A``, shared transitions keep their labels, the rest ``r_min``
            (IL, RL-expert, RL-sample only)
ATAC        ATAC on the data with both actions and rewards — ``D_A``'s transitions that are in
            ``D_R`` with ``D_R``'s rewards (Table 7.3's "ATAC†"; IL, RL-expert, RL-sample only)
BCO         inverse-dynamics labels for ``D_R``, then BC (:mod:`offline.learners.bc`)
BC          BC of ``D_R``'s episodes where they have actions (IL, RL-expert, RL-sample),
            otherwise of all of ``D_A``
Oracle      ATAC with the true rewards of all of ``D_A`` (privileged)
PSPI, IQL,  on a plain dataset with its own rewards (no scenario): ``learner(dataset)``; in a
CQL        scenario they behave as Oracle does (true rewards of ``D_A``)
==========  ==============================================================================

**Budgets.** ATAC's published schedule is 1 M steps with a 100 k-step BC warm start and an actor
rate of 5e-7 (docs/design.md §4.5). :func:`atac_config` shortens it to ``steps`` with the warm start
at the same 10 % (``Budget.warmstart``; the 7-DoF Franka needs more, BENCHMARKS) and every rate as
published (``Budget.actor_rate="published"``, the default):
the slow actor then moves ``steps / 1e6`` as far as in a full run, on critics trained as long
as it moves. ``actor_rate="scaled"`` multiplies the actor rate by ``1e6 / steps`` instead, so
that the product (how far the actor can move) is unchanged — the rule of our first tables. It
was the default until measured against the published rate on the 3-link (20 k steps, NN-RESIDUAL
actor, BENCHMARKS "Chapter 7 with the published actor rate"): the scaled rate drives the actor by
critics trained 50× less than in a full run and lost 20–30 points (Oracle 51 vs 73, MAHALO 45 vs
72 at β 16). BC, BCO, the inverse model and RP's reward regression get ``steps`` steps too.

**Observation standardisation.** ``Budget.normalize_observations`` (default off) turns on every
learner's ``normalize_observations``: all networks see states standardised with the statistics
of ``D_A`` (the dynamics data given to :func:`build`;
:class:`offline.learners.base.ObservationNormalizer`) — also AP's ATAC on the labelled ``D_R``, ATAC
on the shared transitions, BC of the reward episodes and the inverse-dynamics model that labels
``D_R``. ``act`` takes raw observations.

**Actor.** ``Budget.actor`` (default ``"mlp"``) is every learner's actor class
(:mod:`offline.learners.residual_actor`): ``"nn_residual"`` adds the actor's MLP to the pre-tanh image of
the chapter-6 NN-RESIDUAL base RMP² policy. The critics, value and reward networks and the
inverse-dynamics model stay MLPs.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

import jax
import numpy as np

from offline.data import dataset as odata
from offline.data import scenarios
from offline.learners import atac, bc, cql, iql, mahalo, plfo_baselines
from offline.learners.base import ObservationNormalizer, Trainer, check_bool
from offline.learners.inverse_dynamics import (
    InverseDynamicsConfig,
    label_actions,
    make_inverse_dynamics,
)
from offline.learners.residual_actor import check_actor

#: Learners of the chapter-7 table, in its column order (thesis Table 7.3, without SMODICE).
TABLE_LEARNERS = ("MAHALO", "RP", "AP", "UDS", "ATAC", "BCO", "BC", "Oracle")
#: Every learner this module builds.
LEARNERS = (*TABLE_LEARNERS, "PSPI", "IQL", "CQL")
#: Learners with ATAC's Bellman weight β (``init(key, beta)`` takes it traced: vmap over β).
BETA_LEARNERS = ("MAHALO", "RP", "AP", "UDS", "ATAC", "Oracle", "PSPI")
#: Learners that need action-labelled reward data (a reward dataset overlapping ``D_A``).
NEEDS_SHARED = ("UDS", "ATAC")
#: Learners whose run reads only the dynamics data (with its true rewards): one run serves every
#: scenario of :func:`offline.data.scenarios.same_dynamics`.
DYNAMICS_ONLY = ("Oracle",)
#: ATAC's published length and actor rate (docs/design.md §4.5).
REFERENCE_STEPS = 1_000_000
REFERENCE_ACTOR_LR = 5e-7
#: Fraction of the steps in ATAC's BC warm start (published: 100 k of 1 M).
DEFAULT_WARMSTART = 0.1
#: How :func:`atac_config` sets the actor rate of a shortened run (module docstring).
ACTOR_RATES = ("scaled", "published")


@dataclasses.dataclass(frozen=True)
class Budget:
    """Size of one training run: ``steps`` gradient steps, MLP ``hidden`` sizes, ``batch``;
    whether every learner standardises its observations, every learner's actor class, the
    fraction ``warmstart`` of ATAC's steps spent in BC warm start and ATAC's actor rate rule
    (module docstring)."""

    steps: int = REFERENCE_STEPS
    hidden: tuple[int, ...] = (256, 256, 256)
    batch: int = 256
    inverse_seed: int = 12345
    normalize_observations: bool = False
    actor: str = "mlp"
    actor_rate: str = "published"
    warmstart: float = DEFAULT_WARMSTART

    def __post_init__(self) -> None:
        object.__setattr__(self, "hidden", tuple(self.hidden))
        if not (isinstance(self.steps, int) and self.steps >= 10):
            raise ValueError(f"steps must be an integer >= 10, got {self.steps!r}")
        if not self.hidden or any(not isinstance(h, int) or h < 1 for h in self.hidden):
            raise ValueError(f"hidden must be positive integers, got {self.hidden!r}")
        if not (isinstance(self.batch, int) and self.batch >= 1):
            raise ValueError(f"batch must be a positive integer, got {self.batch!r}")
        check_bool(self.normalize_observations, "normalize_observations")
        check_actor(self.actor, self.normalize_observations)
        if not (isinstance(self.warmstart, int | float) and 0 <= self.warmstart < 1):
            raise ValueError(f"warmstart must be a fraction of the steps in [0, 1), got "
                             f"{self.warmstart!r}")
        if self.actor_rate not in ACTOR_RATES:
            raise ValueError(f"actor_rate must be one of {list(ACTOR_RATES)}, got "
                             f"{self.actor_rate!r}")


def atac_config(budget: Budget, **overrides: Any) -> atac.ATACConfig:
    """ATAC's settings shortened to ``budget.steps`` (module docstring: warm start
    ``budget.warmstart`` of the steps, 10 % by default, the
    published actor rate, or that rate × ``1e6 / steps`` for ``budget.actor_rate ==
    "scaled"``)."""
    scale = REFERENCE_STEPS / budget.steps if budget.actor_rate == "scaled" else 1.0
    kw = dict(hidden_sizes=budget.hidden, batch_size=budget.batch, num_steps=budget.steps,
              warmstart_steps=int(budget.steps * budget.warmstart + 1e-9),
              actor_lr=REFERENCE_ACTOR_LR * scale,
              normalize_observations=budget.normalize_observations, actor=budget.actor)
    kw.update(overrides)
    return atac.ATACConfig(**kw)


def applicable(learner: str, scenario: str | None) -> bool:
    """Whether ``learner`` has data to train on in ``scenario`` (None: a plain dataset)."""
    if learner not in LEARNERS:
        raise ValueError(f"unknown learner={learner!r}; valid names are {list(LEARNERS)}")
    if scenario is None:
        return learner in ("Oracle", "PSPI", "IQL", "CQL", "BC")
    if scenario not in scenarios.SCENARIOS:
        raise ValueError(f"unknown scenario={scenario!r}; valid scenarios are "
                         f"{list(scenarios.SCENARIOS)}")
    return not (learner in NEEDS_SHARED and scenario in ("ILfO", "RLfO"))


def labelled_transitions(dynamics: odata.Dataset, reward_data: scenarios.RewardData
                         ) -> odata.Dataset:
    """The transitions that have both actions and rewards: ``D_A``'s episodes that are in
    ``D_R``, with ``D_R``'s rewards (host-side; raises when they share none)."""
    shared = bc.reward_episodes(dynamics, reward_data)
    out = plfo_baselines.uds_relabel(shared, reward_data, min_reward=0.0)
    if out.metadata["uds"]["labelled"] != out.size:
        raise ValueError(f"only {out.metadata['uds']['labelled']} of the {out.size} transitions "
                         f"of the shared episodes are in the reward data")
    return out


def inverse_labelled(dynamics: odata.Dataset, reward_data: scenarios.RewardData,
                     budget: Budget) -> odata.Dataset:
    """``D_R`` with actions predicted by an inverse-dynamics model fitted on ``D_A``
    (``budget.steps`` steps, key ``budget.inverse_seed``, states standardised with ``D_A``'s
    statistics when ``budget.normalize_observations``) — AP's dataset."""
    trainer = make_inverse_dynamics(dynamics, inverse_config(budget))
    state, _ = jax.jit(trainer.train)(jax.random.PRNGKey(budget.inverse_seed))
    labelled = label_actions(trainer.model(state), reward_data)
    return jax.tree.map(np.asarray, labelled)


def inverse_config(budget: Budget) -> InverseDynamicsConfig:
    """The inverse-dynamics model of AP and BCO at ``budget``."""
    return InverseDynamicsConfig(hidden_sizes=budget.hidden, batch_size=budget.batch,
                                 num_steps=budget.steps,
                                 normalize_observations=budget.normalize_observations)


def _statistics_of(dynamics: odata.Dataset, budget: Budget) -> ObservationNormalizer | None:
    """``D_A``'s normalizer for a learner trained on data derived from it (AP, ATAC); None
    when the budget does not standardise."""
    return ObservationNormalizer.fit(dynamics) if budget.normalize_observations else None


def build(learner: str, dynamics: odata.Dataset, reward_data: scenarios.RewardData | None,
          budget: Budget, scenario: str | None = None) -> Trainer:
    """The :class:`~offline.learners.base.Trainer` of ``learner`` on a scenario's data (module
    docstring), or on a plain dataset when ``reward_data`` is None."""
    if not applicable(learner, scenario):
        raise ValueError(f"{learner} has no data to train on in scenario {scenario!r}: it needs "
                         f"reward data with actions (IL, RL-expert, RL-sample)")
    if (reward_data is None) != (scenario is None):
        raise ValueError("pass reward_data exactly when a scenario is named")
    cfg = atac_config(budget)
    net = dict(hidden_sizes=budget.hidden, batch_size=budget.batch,
               normalize_observations=budget.normalize_observations, actor=budget.actor)
    if learner == "MAHALO":
        return mahalo.make_train(dynamics, mahalo.MAHALOConfig(
            atac=atac_config(budget, beta=10.0),
            reward=mahalo.RewardNetConfig(hidden_sizes=budget.hidden, batch_size=budget.batch,
                                          max_reward_label=scenario in ("ILfO", "IL"))),
            reward_data=reward_data)
    if learner == "RP":
        return plfo_baselines.make_train_rp(dynamics, plfo_baselines.RPConfig(
            atac=cfg, reward=mahalo.RewardNetConfig(
                hidden_sizes=budget.hidden, batch_size=budget.batch,
                max_reward_label=scenario in ("ILfO", "IL")),
            reward_steps=budget.steps), reward_data=reward_data)
    if learner == "AP":
        return atac.make_train(inverse_labelled(dynamics, reward_data, budget), cfg,
                               normalizer=_statistics_of(dynamics, budget))
    if learner == "UDS":
        return plfo_baselines.make_train_uds(dynamics, plfo_baselines.UDSConfig(atac=cfg),
                                             reward_data=reward_data)
    if learner == "ATAC":
        return atac.make_train(labelled_transitions(dynamics, reward_data), cfg,
                               normalizer=_statistics_of(dynamics, budget))
    bc_cfg = bc.BCConfig(num_steps=budget.steps, **net)
    if learner == "BCO":
        return bc.make_train(dynamics, bc.BCOConfig(bc=bc_cfg, inverse=inverse_config(budget)),
                             reward_data=reward_data)
    if learner == "BC":
        if scenario in ("IL", "RL-expert", "RL-sample"):
            return bc.make_train(dynamics, dataclasses.replace(bc_cfg, data="reward_episodes"),
                                 reward_data=reward_data)
        return bc.make_train(dynamics, bc_cfg)
    if learner == "Oracle":
        return plfo_baselines.make_train_oracle(dynamics, cfg)
    plain = dynamics.replace(metadata=dynamics.metadata.updated(rewards_visible=True))
    if learner == "PSPI":
        return atac.make_train(plain, atac_config(budget, pessimism="absolute"))
    if learner == "IQL":
        return iql.make_train(plain, iql.IQLConfig(num_steps=budget.steps, **net))
    return cql.make_train(plain, cql.CQLConfig(num_steps=budget.steps, **net))


def train_chunked(trainer: Trainer, keys: jax.Array, chunk: int,
                  on_chunk: Callable[[Any, dict, int], None] | None = None,
                  state: Any = None, start: int = 0) -> tuple[Any, dict[str, np.ndarray]]:
    """Train the seeds ``keys`` (vmapped) for ``trainer.num_steps`` steps in compiled chunks
    of ``chunk`` steps (the last one shorter), from ``state`` at step ``start`` (default: a fresh
    ``init``). After each chunk ``on_chunk(state, chunk_metrics, steps_done)`` is called (progress,
    logging, checkpoints). Returns the final state and the per-chunk means of every metric,
    shape ``(chunks, seeds)``."""
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
    every leaf, e.g. ``(rewards, keys)`` of :func:`offline.survival.sweep.reward_seed_keys`), each at
    its β from ``betas`` (one per run; ``None``: the config's β) — one program trains the whole
    grid."""
    if betas is None:
        return jax.jit(jax.vmap(trainer.init))(keys)
    runs = jax.tree.leaves(keys)[0].shape[0]
    if len(betas) != runs:
        raise ValueError(f"betas has {len(betas)} entries for {runs} runs")
    return jax.jit(jax.vmap(trainer.init))(keys, jax.numpy.asarray(betas, jax.numpy.float32))


__all__ = [
    "ACTOR_RATES",
    "BETA_LEARNERS",
    "DEFAULT_WARMSTART",
    "DYNAMICS_ONLY",
    "LEARNERS",
    "NEEDS_SHARED",
    "TABLE_LEARNERS",
    "Budget",
    "applicable",
    "atac_config",
    "build",
    "init_runs",
    "inverse_config",
    "inverse_labelled",
    "labelled_transitions",
    "seed_beta_runs",
    "seed_keys",
    "train_chunked",
]
