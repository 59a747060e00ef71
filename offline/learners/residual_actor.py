"""The offline learners' actor classes: a plain tanh-Gaussian MLP, or the chapter-6 NN-RESIDUAL
structure (thesis §6.2.2) as a tanh-Gaussian.

Every offline learner (ATAC, PSPI, MAHALO, RP, AP, UDS, Oracle, BC, BCO, IQL, CQL) has an
``actor`` setting, one of :data:`ACTORS`:

* ``"mlp"`` (default) — :class:`offline.learners.tanh_gaussian.TanhGaussianPolicy`: ``a = tanh(u)``,
  ``u ~ N(μ(s), σ(s)²)`` with ``(μ, log σ)`` from a 3×256 MLP (docs/design.md §4.5).
* ``"nn_residual"`` — :class:`ResidualTanhGaussianPolicy`: the same MLP's mean is added, before
  the squashing, to the pre-tanh image of a hand-designed RMP² policy,

      u ~ N(μ(s) + b(s), σ(s)²),   b(s) = atanh(clip(a_h(s) / a_max, −c, c)),  c = 0.999,

  where ``a_h(s)`` is the joint acceleration (eq 3.12) of the ``residual_base`` preset — the
  base that NN-RESIDUAL adds its network to in chapter 6 (target gains ``k_p 5, k_d 10``;
  :func:`mjxrmp.policies.default_config`) — evaluated at the state decoded from the observation
  (:func:`agents.ppo.policies.decode_observation`), and ``a_max`` the dataset's action limit. With a
  zero network mean the actor's deterministic action ``a_max·tanh(μ + b)`` is the base policy's
  (clipped to the action limit, as the environment clips it); ``b`` does not depend on the
  parameters, so the log-probabilities are those of a tanh-Gaussian with a shifted mean and the
  change of variables of :mod:`offline.learners.tanh_gaussian` holds unchanged. The clip ``c`` keeps
  ``|b| ≤ atanh(0.999) ≈ 3.8`` for saturated base actions.

Why: a plain MLP cannot imitate the RMP² expert precisely enough near obstacles (measured in our
chapter-7 tables), the failure chapter 6 shows for plain-MLP PPO; the residual structure keeps
the RMP² policy's collision avoidance and lets the data correct the rest.

The base reads the **raw** observation, so ``"nn_residual"`` cannot be combined with
``normalize_observations`` (the learners refuse it: :func:`check_actor`).

**Precomputed bases.** ``b(s)`` does not depend on the parameters, so the learners evaluate it
once per dataset transition when they are built (:func:`dataset_bases`, for the observations and
next observations they sample) and pass the rows of each minibatch to the actor
(:func:`apply_actor`; :func:`offline.data.dataset.sample_with` draws them with the minibatch). Each
gradient step then skips the RMP² evaluations of its minibatch: on the 7-DoF Franka with its
collision spheres that made a PSPI step 2.6× slower than with the plain MLP actor (2-core CPU).
Evaluation in the environment computes ``b`` from the observation as before.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp

from agents.ppo.policies import ObservationSpec, hand_designed_mean
from mjxrmp import policies as rmp_policies
from offline.data.rollouts import make_env
from offline.learners.tanh_gaussian import TanhGaussian, TanhGaussianPolicy

#: Actor classes of the offline learners (module docstring).
ACTORS = ("mlp", "nn_residual")
#: The hand-designed preset under the ``"nn_residual"`` actor (chapter 6's NN-RESIDUAL base).
BASE_VARIANT = "residual_base"
#: Largest ``|a_h / a_max|`` mapped through ``atanh`` (``|b| ≤ atanh(0.999) ≈ 3.8``).
BASE_CLIP = 0.999


def check_actor(actor: Any, normalize_observations: bool = False) -> str:
    """``actor`` if it names one of :data:`ACTORS`; raises ``ValueError`` otherwise, or when
    ``"nn_residual"`` is combined with ``normalize_observations`` (its base reads raw states)."""
    if actor not in ACTORS:
        raise ValueError(f"actor must be one of {list(ACTORS)}, got {actor!r}")
    if actor == "nn_residual" and normalize_observations:
        raise ValueError("actor='nn_residual' decodes the raw observation for its RMP² base; it "
                         "cannot be combined with normalize_observations=True")
    return actor


def base_pre_tanh(spec: ObservationSpec, rmp_config: rmp_policies.PolicyConfig,
                  action_limit: float, obs: jax.Array) -> jax.Array:
    """``b(s) = atanh(clip(a_h(s)/a_max, −c, c))`` (module docstring) for observations ``obs``
    of any batch shape; no gradient flows through it."""
    a_h = hand_designed_mean(spec, rmp_config, obs)
    b = jnp.arctanh(jnp.clip(a_h / action_limit, -BASE_CLIP, BASE_CLIP))
    return jax.lax.stop_gradient(b.astype(obs.dtype))


class ResidualTanhGaussianPolicy(nn.Module):
    """``u ~ N(μ(s) + b(s), σ(s)²)``, ``a = tanh(u)`` (module docstring): the MLP
    ``residual`` (a :class:`TanhGaussianPolicy`, its own submodule) gives ``(μ, log σ)``, the
    RMP² base ``b``."""

    residual: TanhGaussianPolicy
    spec: ObservationSpec
    rmp_config: rmp_policies.PolicyConfig
    action_limit: float

    @property
    def action_size(self) -> int:
        """Size of the action (that of the residual MLP)."""
        return self.residual.action_size

    def __call__(self, obs: jax.Array, base: jax.Array | None = None) -> TanhGaussian:
        """The distribution at ``obs``; ``base``: ``b(obs)`` when precomputed
        (:func:`dataset_bases`), otherwise evaluated here."""
        dist = self.residual(obs)
        if base is None:
            base = base_pre_tanh(self.spec, self.rmp_config, self.action_limit, obs)
        return TanhGaussian(dist.mean + base, dist.log_std)


class ActorBases(NamedTuple):
    """``b(s)`` (module docstring) of every transition's observation and next observation,
    ``(N, A)`` each; ``None`` where not needed or for an actor without an RMP² base."""

    observations: jax.Array | None = None
    next_observations: jax.Array | None = None


#: No precomputed bases: every actor call evaluates its own (what :func:`dataset_bases` gives
#: an actor without an RMP² base).
NO_BASES = ActorBases()

#: Observations per batch when :func:`dataset_bases` evaluates the RMP² base.
BASE_CHUNK = 4096


def dataset_bases(actor: nn.Module, observations: jax.Array,
                  next_observations: jax.Array | None = None) -> ActorBases:
    """``b(s)`` of ``actor``'s RMP² base at every row of ``observations`` and (if given)
    ``next_observations`` — evaluated once, in batches of :data:`BASE_CHUNK`; empty
    :class:`ActorBases` for an actor without a base (the plain MLP)."""
    if not isinstance(actor, ResidualTanhGaussianPolicy):
        return NO_BASES

    @jax.jit
    def of(obs: jax.Array) -> jax.Array:
        row = lambda o: base_pre_tanh(actor.spec, actor.rmp_config, actor.action_limit, o)  # noqa: E731
        return jax.lax.map(row, obs, batch_size=BASE_CHUNK)

    return ActorBases(of(jnp.asarray(observations)),
                      None if next_observations is None else of(jnp.asarray(next_observations)))


def apply_actor(actor: nn.Module, params: Any, obs: jax.Array,
                base: jax.Array | None = None) -> TanhGaussian:
    """``actor``'s distribution at ``obs`` with its RMP² base ``b(obs)`` from ``base`` (the
    matching rows of :func:`dataset_bases`) when given; the same as ``actor.apply(params, obs)``
    up to float rounding."""
    return actor.apply(params, obs) if base is None else actor.apply(params, obs, base)


def make_actor(actor: str, metadata: Mapping[str, Any], action_size: int,
               hidden_sizes: Sequence[int], activation: str = "relu") -> nn.Module:
    """The actor module of kind ``actor`` (:data:`ACTORS`) for a dataset with ``metadata`` and
    ``action_size`` actions. ``"nn_residual"`` needs the environment the data came from
    (``metadata["env"]``, ``["env_kwargs"]``, ``["action_limit"]``: recorded by
    :mod:`offline.data.collect`) and an RMP² preset for its robot."""
    check_actor(actor)
    mlp = TanhGaussianPolicy(action_size, tuple(hidden_sizes), activation)
    if actor == "mlp":
        return mlp
    missing = [k for k in ("env", "action_limit") if k not in metadata]
    if missing:
        raise ValueError(f"actor='nn_residual' needs the dataset's environment; its metadata "
                         f"lacks {missing} (collect it with offline.data.collect)")
    env = make_env(metadata["env"], metadata.get("env_kwargs"))
    spec = ObservationSpec.from_env(env)
    dof = env.unwrapped.robot.dof
    if action_size != dof:
        raise ValueError(f"actor='nn_residual' needs joint-acceleration actions ({dof} for "
                         f"{metadata['env']}), got action_size={action_size}")
    cfg = rmp_policies.default_config(spec.robot, BASE_VARIANT)
    return ResidualTanhGaussianPolicy(mlp, spec, cfg, float(metadata["action_limit"]))


__all__ = [
    "ACTORS",
    "BASE_CHUNK",
    "BASE_CLIP",
    "BASE_VARIANT",
    "NO_BASES",
    "ActorBases",
    "ResidualTanhGaussianPolicy",
    "apply_actor",
    "base_pre_tanh",
    "check_actor",
    "dataset_bases",
    "make_actor",
]
