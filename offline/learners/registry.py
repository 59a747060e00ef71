"""The learner registry: learner name → builder of its :class:`~offline.learners.base.Trainer` on
a PLfO scenario's data or a plain dataset, at a run :class:`Budget` (thesis §7.4, Table 7.3;
docs/design.md §2.4 and §4.5). :func:`offline.experiment.run.build` dispatches through
:data:`BUILDERS`.

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
rate of 5e-7 (docs/design.md §4.5). :func:`atac_config` shortens it to ``steps`` with the warm
start at the same 10 % (``Budget.warmstart``; the 7-DoF Franka needs more) and every rate as
published (``Budget.actor_rate="published"``, the default): the slow actor then moves
``steps / 1e6`` as far as in a full run, on critics trained as long as it moves.
``actor_rate="scaled"`` multiplies the actor rate by ``1e6 / steps`` instead, so that the
product (how far the actor can move) is unchanged — the rule of our first tables. Measured
against the published rate on the 3-link (20 k steps, NN-RESIDUAL actor), the scaled rate drives
the actor by critics trained 50× less than in a full run and lost 20–30 points (Oracle 51 vs 73,
MAHALO 45 vs 72 at β 16). BC, BCO, the inverse model and RP's reward regression get ``steps``
steps too.

**Observation standardisation.** ``Budget.normalize_observations`` (default off) turns on every
learner's ``normalize_observations``: all networks see states standardised with the statistics
of ``D_A`` (the dynamics data given to the builder;
:class:`offline.learners.base.ObservationNormalizer`) — also AP's ATAC on the labelled ``D_R``,
ATAC on the shared transitions, BC of the reward episodes and the inverse-dynamics model that
labels ``D_R``. ``act`` takes raw observations.

**Actor.** ``Budget.actor`` (default ``"mlp"``) is every learner's actor class
(:mod:`offline.learners.residual_actor`): ``"nn_residual"`` adds the actor's MLP to the pre-tanh
image of the chapter-6 NN-RESIDUAL base RMP² policy. The critics, value and reward networks and
the inverse-dynamics model stay MLPs.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import jax
import numpy as np

from mjxrmp.config import (
    check_bool,
    check_choice,
    check_fraction,
    check_int,
    check_sizes,
)
from mjxrmp.divergence import guard_finite_series, guard_finite_tree
from offline.data import dataset as odata
from offline.data import scenarios
from offline.learners import atac, bc, cql, iql, mahalo, plfo_baselines
from offline.learners.base import ObservationNormalizer, Trainer
from offline.learners.inverse_dynamics import (
    InverseDynamicsConfig,
    label_actions,
    make_inverse_dynamics,
)
from offline.learners.residual_actor import check_actor

#: Learners of the chapter-7 table, in its column order (thesis Table 7.3, without SMODICE).
TABLE_LEARNERS = ("MAHALO", "RP", "AP", "UDS", "ATAC", "BCO", "BC", "Oracle")
#: Learners with ATAC's Bellman weight β (``init(key, beta)`` takes it traced: vmap over β).
BETA_LEARNERS = ("MAHALO", "RP", "AP", "UDS", "ATAC", "Oracle", "PSPI")
#: Learners that need action-labelled reward data (a reward dataset overlapping ``D_A``).
NEEDS_SHARED = ("UDS", "ATAC")
#: Learners that train on a plain dataset with its own rewards (no scenario).
PLAIN_LEARNERS = ("Oracle", "PSPI", "IQL", "CQL", "BC")
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
#: Scenarios whose reward data has actions (BC clones its episodes there).
_ACTION_LABELLED = ("IL", "RL-expert", "RL-sample")


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
        n = type(self).__name__
        object.__setattr__(self, "hidden", check_sizes(self.hidden, f"{n}.hidden"))
        check_int(self.steps, f"{n}.steps", minimum=10)
        check_int(self.batch, f"{n}.batch")
        check_int(self.inverse_seed, f"{n}.inverse_seed", minimum=0)
        check_bool(self.normalize_observations, f"{n}.normalize_observations")
        check_actor(self.actor, self.normalize_observations)
        check_fraction(self.warmstart, f"{n}.warmstart", allow_zero=True)
        check_choice(self.actor_rate, f"{n}.actor_rate", ACTOR_RATES)


def atac_config(budget: Budget, **overrides: Any) -> atac.ATACConfig:
    """ATAC's settings shortened to ``budget.steps`` (module docstring: warm start
    ``budget.warmstart`` of the steps, 10 % by default, the published actor rate, or that rate
    × ``1e6 / steps`` for ``budget.actor_rate == "scaled"``)."""
    scale = REFERENCE_STEPS / budget.steps if budget.actor_rate == "scaled" else 1.0
    kw = dict(hidden_sizes=budget.hidden, batch_size=budget.batch, num_steps=budget.steps,
              warmstart_steps=int(budget.steps * budget.warmstart + 1e-9),
              actor_lr=REFERENCE_ACTOR_LR * scale,
              normalize_observations=budget.normalize_observations, actor=budget.actor)
    kw.update(overrides)
    return atac.ATACConfig(**kw)


def inverse_config(budget: Budget) -> InverseDynamicsConfig:
    """The inverse-dynamics model of AP and BCO at ``budget``."""
    return InverseDynamicsConfig(hidden_sizes=budget.hidden, batch_size=budget.batch,
                                 num_steps=budget.steps,
                                 normalize_observations=budget.normalize_observations)


def reward_net_config(budget: Budget, scenario: str | None) -> mahalo.RewardNetConfig:
    """The reward network of MAHALO and RP at ``budget`` (max-reward labels in ILfO and IL,
    thesis §7.4)."""
    return mahalo.RewardNetConfig(hidden_sizes=budget.hidden, batch_size=budget.batch,
                                  max_reward_label=scenario in ("ILfO", "IL"))


def bc_config(budget: Budget) -> bc.BCConfig:
    """BC at ``budget`` (cloning all of its data)."""
    return bc.BCConfig(num_steps=budget.steps, **_network(budget))


def _network(budget: Budget) -> dict[str, Any]:
    """The network settings every non-ATAC learner takes from ``budget``."""
    return dict(hidden_sizes=budget.hidden, batch_size=budget.batch,
                normalize_observations=budget.normalize_observations, actor=budget.actor)


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
    statistics when ``budget.normalize_observations``) — AP's dataset. A model whose loss or
    parameters turn non-finite raises :class:`mjxrmp.divergence.DivergenceError`."""
    trainer = make_inverse_dynamics(dynamics, inverse_config(budget))
    state, metrics = jax.jit(trainer.train)(jax.random.PRNGKey(budget.inverse_seed))
    what = "AP's inverse-dynamics model"
    guard_finite_series({k: np.asarray(v)[None] for k, v in metrics.items()}, what,
                        unit="gradient step")
    guard_finite_tree(state.params, what, trainer.num_steps, unit="gradient step")
    labelled = label_actions(trainer.model(state), reward_data)
    return jax.tree.map(np.asarray, labelled)


def _statistics_of(dynamics: odata.Dataset, budget: Budget) -> ObservationNormalizer | None:
    """``D_A``'s normalizer for a learner trained on data derived from it (AP, ATAC); None
    when the budget does not standardise."""
    return ObservationNormalizer.fit(dynamics) if budget.normalize_observations else None


def _plain(dynamics: odata.Dataset) -> odata.Dataset:
    """``dynamics`` with its rewards marked visible (PSPI, IQL and CQL read them)."""
    return dynamics.replace(metadata=dynamics.metadata.updated(rewards_visible=True))


#: ``builder(dynamics, reward_data, budget, scenario) -> Trainer``.
Builder = Callable[[odata.Dataset, Any, Budget, Any], Trainer]


def _mahalo(dynamics, reward_data, budget, scenario) -> Trainer:
    config = mahalo.MAHALOConfig(atac=atac_config(budget, beta=10.0),
                                 reward=reward_net_config(budget, scenario))
    return mahalo.make_train(dynamics, config, reward_data=reward_data)


def _rp(dynamics, reward_data, budget, scenario) -> Trainer:
    config = plfo_baselines.RPConfig(atac=atac_config(budget),
                                     reward=reward_net_config(budget, scenario),
                                     reward_steps=budget.steps)
    return plfo_baselines.make_train_rp(dynamics, config, reward_data=reward_data)


def _ap(dynamics, reward_data, budget, scenario) -> Trainer:
    return atac.make_train(inverse_labelled(dynamics, reward_data, budget), atac_config(budget),
                           normalizer=_statistics_of(dynamics, budget))


def _uds(dynamics, reward_data, budget, scenario) -> Trainer:
    return plfo_baselines.make_train_uds(
        dynamics, plfo_baselines.UDSConfig(atac=atac_config(budget)), reward_data=reward_data)


def _atac(dynamics, reward_data, budget, scenario) -> Trainer:
    return atac.make_train(labelled_transitions(dynamics, reward_data), atac_config(budget),
                           normalizer=_statistics_of(dynamics, budget))


def _bco(dynamics, reward_data, budget, scenario) -> Trainer:
    config = bc.BCOConfig(bc=bc_config(budget), inverse=inverse_config(budget))
    return bc.make_train(dynamics, config, reward_data=reward_data)


def _bc(dynamics, reward_data, budget, scenario) -> Trainer:
    if scenario in _ACTION_LABELLED:
        return bc.make_train(dynamics, dataclasses.replace(bc_config(budget),
                                                           data="reward_episodes"),
                             reward_data=reward_data)
    return bc.make_train(dynamics, bc_config(budget))


def _oracle(dynamics, reward_data, budget, scenario) -> Trainer:
    return plfo_baselines.make_train_oracle(dynamics, atac_config(budget))


def _pspi(dynamics, reward_data, budget, scenario) -> Trainer:
    return atac.make_train(_plain(dynamics), atac_config(budget, pessimism="absolute"))


def _iql(dynamics, reward_data, budget, scenario) -> Trainer:
    return iql.make_train(_plain(dynamics), iql.IQLConfig(num_steps=budget.steps,
                                                          **_network(budget)))


def _cql(dynamics, reward_data, budget, scenario) -> Trainer:
    return cql.make_train(_plain(dynamics), cql.CQLConfig(num_steps=budget.steps,
                                                          **_network(budget)))


#: Learner name → builder ``(dynamics, reward_data, budget, scenario) -> Trainer`` (the data
#: each reads: module docstring). Callers check :func:`offline.experiment.run.applicable` first.
BUILDERS: dict[str, Builder] = {
    "MAHALO": _mahalo, "RP": _rp, "AP": _ap, "UDS": _uds, "ATAC": _atac, "BCO": _bco,
    "BC": _bc, "Oracle": _oracle, "PSPI": _pspi, "IQL": _iql, "CQL": _cql,
}
#: Every learner of the registry: the table's, then PSPI, IQL and CQL.
LEARNERS = tuple(BUILDERS)


__all__ = [
    "ACTOR_RATES",
    "BETA_LEARNERS",
    "BUILDERS",
    "DEFAULT_WARMSTART",
    "DYNAMICS_ONLY",
    "LEARNERS",
    "NEEDS_SHARED",
    "PLAIN_LEARNERS",
    "REFERENCE_ACTOR_LR",
    "REFERENCE_STEPS",
    "TABLE_LEARNERS",
    "Budget",
    "Builder",
    "atac_config",
    "bc_config",
    "inverse_config",
    "inverse_labelled",
    "labelled_transitions",
    "reward_net_config",
]
