"""Policy classes of thesis §6.2.2 as flax modules for :func:`agents.ppo.train.make_train`.

Every module maps an observation ``(..., obs_size)`` of a reaching environment
(:mod:`envs.reaching`) to ``(mean, log_std)``: a joint-acceleration mean ``(..., dof)`` and a
state-independent log standard deviation ``(dof,)`` initialised at −1 (docs/design.md §4.4). The
mean is not clipped (the environment clips the sampled action).

All RMP² inputs are decoded from the observation (:func:`decode_observation`):
``q = atan2(sin q, cos q)`` (exact for the 3-link, whose kinematics is 2π-periodic and whose
leaves use ``q`` only through the kinematics or not at all, and for the Franka, whose joint
limits lie inside ±π), ``q̇``, ``goal = (g − x) + FK(q)`` and the obstacles from the
``(centre, radius)`` block (``active = radius > 0``; padded obstacles have radius −1).

Kinds (:func:`make_policy`):

* ``"nn"`` — :class:`agents.ppo.networks.GaussianPolicy`: MLP (256, 128) relu (Franka (512, 256)),
  output init scale 0.1, on the observation.
* ``"nn_residual"`` — :class:`NNResidualPolicy`: the same MLP's output plus the acceleration of
  the hand-designed ``residual_base`` RMP² preset. ``nn`` and ``nn_residual`` have the same
  parameters; with the base's weight as per-run data (0 for ``nn``) one program trains both
  (:func:`packed_kind`, :mod:`agents.ppo.hparams`).
* ``"rmp_residual"`` — :class:`RMPResidualPolicy`: a residual RMP on the end-effector space
  inside the policy. MLP (128, 64) elu (Franka (256, 128)), output init scale 0.01, over
  ``[x, ẋ, g, {o_i}]`` gives ``A_r = √5·tanh(·)`` (m × m) and ``a_r = tanh(·)`` (m); with the
  hand-designed target RMP ``(M_h, a_h)`` of the ``residual_rmp`` preset the learned leaf is
  ``M = (A_r + chol(M_h))(A_r + chol(M_h))ᵀ``, ``a = a_r + a_h``. It replaces the target leaf;
  the other leaves are hand-designed; RMP² resolves them into the mean (differentiable in the
  network parameters).
* ``"rmp_residual_env"`` — RMP² inside the environment (:class:`envs.wrappers.RMPInEnv`):
  the environment's action is the raw residual RMP ``(A_r, a_r)`` (squashed there), the policy
  a :class:`agents.ppo.networks.GaussianPolicy` with the ``rmp_residual`` network sizes on the
  ``residual_rmp`` observation (the default one plus goal, end-effector position and velocity).
  :func:`make_env_and_policy` builds the pair.
* ``"hand_designed"`` — :class:`HandDesignedPolicy`: the ``hand_designed`` preset's
  acceleration; the only parameter is the log-std (a non-learning baseline).

Every module's ``__call__(obs, norm=None)`` accepts running observation statistics
(:mod:`agents.ppo.normalization`); only MLPs that read the observation normalise it, RMP² always
decodes the raw observation. The modules with a hand-designed part also have
``precompute(obs)``, its parameter-free part, and accept it back as ``__call__(obs, norm,
features)``: PPO's update computes it once per rollout state instead of once per epoch
(docs/design.md §5.7).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp
from brax.envs.base import Env

import envs
from agents.ppo.networks import MLP, GaussianPolicy
from agents.ppo.normalization import RunningStats, normalize
from envs.wrappers import RMPInEnv
from mjxrmp import policies as rmp_policies
from mjxrmp.geometry import Obstacles
from mjxrmp.residual import ResidualParts, residual_from_parts, residual_parts
from mjxrmp.robots import get

KINDS = ("nn", "nn_residual", "rmp_residual", "rmp_residual_env", "hand_designed")

#: Default MLP hidden sizes per (kind family, robot) (thesis §6.2.2, §6.3; docs/design.md §4.4).
_NN_HIDDEN = {"three_link": (256, 128), "franka": (512, 256)}
_RMP_HIDDEN = {"three_link": (128, 64), "franka": (256, 128)}


@dataclasses.dataclass(frozen=True)
class ObservationSpec:
    """Static description of a reaching observation: robot, obstacle count and named slices.

    ``layout`` is a tuple of ``(name, start, stop)`` (hashable, unlike ``slice``).
    """

    robot: str
    num_obstacles: int
    layout: tuple[tuple[str, int, int], ...]

    @classmethod
    def from_env(cls, env: Env) -> ObservationSpec:
        """The spec of a reaching environment (possibly wrapped)."""
        base = getattr(env, "unwrapped", env)
        layout = tuple((k, s.start, s.stop) for k, s in base.observation_layout().items())
        return cls(str(base.robot_name), int(base.num_obstacles), layout)

    @property
    def size(self) -> int:
        """Length of one observation."""
        return max(stop for _, _, stop in self.layout)

    def part(self, obs: jax.Array, name: str) -> jax.Array:
        """The slice ``name`` of ``obs`` (last axis); ``KeyError`` for an unknown name."""
        for k, start, stop in self.layout:
            if k == name:
                return obs[..., start:stop]
        raise KeyError(name)


def _decode_one(spec: ObservationSpec, obs: jax.Array):
    robot = get(spec.robot)
    dim = robot.workspace_dim
    q = jnp.arctan2(spec.part(obs, "sin_q"), spec.part(obs, "cos_q"))
    qd = spec.part(obs, "qd")
    goal = spec.part(obs, "goal_minus_x") + robot.end_effector(q)
    block = spec.part(obs, "obstacles").reshape(spec.num_obstacles, dim + 1)
    radius = block[:, dim]
    obstacles = Obstacles(block[:, :dim], radius, (radius > 0).astype(obs.dtype))
    return q, qd, goal, obstacles


def _over_batch(fn, *args):
    """Apply the single-sample ``fn`` to pytrees whose leading dims are batch dims.

    The first argument (an array) fixes the batch shape: all but its last axis.
    """
    lead = args[0].shape[:-1]
    flat = jax.tree.map(lambda a: a.reshape((-1, *a.shape[len(lead):])), args)
    out = jax.vmap(fn)(*flat)
    return jax.tree.map(lambda x: x.reshape((*lead, *x.shape[1:])), out)


def decode_observation(spec_or_env: ObservationSpec | Env, obs: jax.Array
                       ) -> tuple[jax.Array, jax.Array, jax.Array, Obstacles]:
    """``(q, q̇, goal, obstacles)`` recovered from an observation with any leading batch shape.

    ``spec_or_env`` is an :class:`ObservationSpec` or a reaching environment (possibly wrapped).
    """
    spec = (spec_or_env if isinstance(spec_or_env, ObservationSpec)
            else ObservationSpec.from_env(spec_or_env))
    obs = jnp.asarray(obs)
    if obs.shape[-1] != spec.size:
        raise ValueError(f"observation must have last axis {spec.size}, got {obs.shape}")
    if obs.ndim == 1:
        return _decode_one(spec, obs)
    return _over_batch(lambda o: _decode_one(spec, o), obs)


def residual_features(spec: ObservationSpec, obs: jax.Array
                      ) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array, Obstacles]:
    """``(net_input, q, q̇, goal, obstacles)`` of :class:`RMPResidualPolicy` for one observation;
    ``net_input = [x, ẋ, g, {o_i}]`` with ``x = FK(q)``, ``ẋ = J q̇`` (by ``jvp``) and ``o_i`` the
    observation's (centre, radius) block."""
    robot = get(spec.robot)
    q, qd, goal, obstacles = _decode_one(spec, obs)
    x, xd = jax.jvp(robot.end_effector, (q,), (qd,))
    net_in = jnp.concatenate([x, xd, goal, spec.part(obs, "obstacles")])
    return net_in, q, qd, goal, obstacles


def hand_designed_mean(spec: ObservationSpec, cfg: rmp_policies.PolicyConfig,
                       obs: jax.Array) -> jax.Array:
    """Joint acceleration of the hand-designed RMP² policy ``cfg`` (eq 3.12 resolved over the
    leaves of the preset) at the state decoded from ``obs`` (``(O,)`` or any batch)."""

    def one(o):
        q, qd, goal, obstacles = _decode_one(spec, o)
        return rmp_policies.acceleration(cfg, q, qd, goal, obstacles)

    return one(obs) if obs.ndim == 1 else _over_batch(one, obs)


class HandDesignedPolicy(nn.Module):
    """Mean = hand-designed RMP² acceleration of ``rmp_config``; only ``log_std`` is learnable."""

    spec: ObservationSpec
    rmp_config: rmp_policies.PolicyConfig
    log_std_init: float = -1.0

    def precompute(self, obs: jax.Array) -> jax.Array:
        """The mean at ``obs`` (it has no parameters), computed once per state by PPO."""
        return hand_designed_mean(self.spec, self.rmp_config, obs)

    @nn.compact
    def __call__(self, obs: jax.Array, norm: RunningStats | None = None,
                 features: jax.Array | None = None) -> tuple[jax.Array, jax.Array]:
        del norm  # nothing learned reads the observation
        dof = get(self.spec.robot).dof
        log_std = self.param("log_std", nn.initializers.constant(self.log_std_init), (dof,))
        return self.precompute(obs) if features is None else features, log_std


class NNResidualPolicy(nn.Module):
    """Mean = MLP(obs) + hand-designed RMP² acceleration of ``rmp_config`` (times a packed
    sweep's ``base_weight``, passed in through ``features``)."""

    #: its precomputed part is the added base: a run's ``base_weight`` may scale it
    weighted_base = True

    spec: ObservationSpec
    rmp_config: rmp_policies.PolicyConfig
    hidden_sizes: Sequence[int] = (256, 128)
    activation: str = "relu"
    out_scale: float = 0.1
    log_std_init: float = -1.0

    def precompute(self, obs: jax.Array) -> jax.Array:
        """The hand-designed acceleration at ``obs`` (parameter-free), computed once per state
        by PPO."""
        return hand_designed_mean(self.spec, self.rmp_config, obs)

    @nn.compact
    def __call__(self, obs: jax.Array, norm: RunningStats | None = None,
                 features: jax.Array | None = None) -> tuple[jax.Array, jax.Array]:
        dof = get(self.spec.robot).dof
        residual = MLP(tuple(self.hidden_sizes), dof, self.activation, self.out_scale,
                       name="mean")(normalize(norm, obs))
        log_std = self.param("log_std", nn.initializers.constant(self.log_std_init), (dof,))
        base = self.precompute(obs) if features is None else features
        return residual + base, log_std


class RMPResidualPolicy(nn.Module):
    """Residual end-effector RMP inside the policy, resolved by RMP² (see the module doc).

    The network (submodule ``"residual"``) outputs ``m·m + m`` raw values: ``A_r`` row-major,
    then ``a_r``.
    """

    spec: ObservationSpec
    rmp_config: rmp_policies.PolicyConfig
    hidden_sizes: Sequence[int] = (128, 64)
    activation: str = "elu"
    out_scale: float = 0.01
    metric_scale: float = math.sqrt(5.0)
    log_std_init: float = -1.0

    def precompute(self, obs: jax.Array) -> tuple[jax.Array, ResidualParts]:
        """``(net_input, parts)`` at observations of any batch shape: the network's input
        ``[x, ẋ, g, {o_i}]`` and the parameter-free :class:`mjxrmp.residual.ResidualParts` of
        the RMP² tree. Computed once per state, they let :meth:`__call__` evaluate many
        parameter values (PPO's epochs) without the hand-designed tree."""
        cfg = self.rmp_config

        def one(o):
            net_in, q, qd, goal, obstacles = residual_features(self.spec, o)
            return net_in, residual_parts(cfg, q, qd, goal, obstacles)

        return one(obs) if obs.ndim == 1 else _over_batch(one, obs)

    @nn.compact
    def __call__(self, obs: jax.Array, norm: RunningStats | None = None,
                 features: tuple[jax.Array, ResidualParts] | None = None
                 ) -> tuple[jax.Array, jax.Array]:
        del norm  # the network reads physical features [x, ẋ, g, {o_i}], not the observation
        robot = get(self.spec.robot)
        m, dof = robot.workspace_dim, robot.dof
        net_in, parts = self.precompute(obs) if features is None else features
        raw = MLP(tuple(self.hidden_sizes), m * m + m, self.activation, self.out_scale,
                  name="residual")(net_in)
        A_r = self.metric_scale * jnp.tanh(raw[..., : m * m]).reshape((*raw.shape[:-1], m, m))
        a_r = jnp.tanh(raw[..., m * m:])
        if raw.ndim == 1:
            mean = residual_from_parts(parts, A_r, a_r)
        else:
            mean = _over_batch(lambda a, p, A: residual_from_parts(p, A, a), a_r, parts, A_r)
        log_std = self.param("log_std", nn.initializers.constant(self.log_std_init), (dof,))
        return mean, log_std


#: The kinds that share one network, by the weight of the hand-designed base added to its
#: output: ``nn`` is :class:`NNResidualPolicy` with weight 0 (the same parameters as
#: :class:`agents.ppo.networks.GaussianPolicy`).
BASE_WEIGHT = {"nn": 0.0, "nn_residual": 1.0}


def packed_kind(kinds: Sequence[str]) -> str:
    """The policy kind one program trains all of ``kinds`` with: the kind itself when there is
    one, ``nn_residual`` for ``nn`` and ``nn_residual`` (each run's ``base_weight`` from
    :data:`BASE_WEIGHT`). An error names kinds that differ in network structure."""
    kinds = tuple(kinds)
    unknown = sorted(set(kinds) - set(KINDS))
    if unknown or not kinds:
        raise ValueError(f"policy kinds must be among {KINDS}, got {kinds!r}")
    if len(set(kinds)) == 1:
        return kinds[0]
    if not set(kinds) <= set(BASE_WEIGHT):
        raise ValueError(f"policy kinds {sorted(set(kinds))} differ in network structure and "
                         f"cannot share a program; only {sorted(BASE_WEIGHT)} can (the same "
                         f"network, the hand-designed base added or not)")
    return "nn_residual"


def policy_groups(kinds: Sequence[str]) -> list[tuple[str, ...]]:
    """``kinds`` grouped into what one program can train (:func:`packed_kind`), in order of
    first appearance."""
    shared = tuple(k for k in kinds if k in BASE_WEIGHT)
    return [shared if kind in BASE_WEIGHT else (kind,)
            for kind in kinds if kind not in BASE_WEIGHT or kind == shared[0]]


def make_policy(kind: str, env, **overrides) -> nn.Module:
    """The ``kind`` policy (one of :data:`KINDS`) for reaching environment ``env``.

    ``overrides`` replace module fields: ``hidden_sizes``, ``activation``, ``out_scale``,
    ``log_std_init`` (and ``metric_scale`` for ``rmp_residual``); ``rmp_config`` replaces the
    hand-designed preset (defaults: ``residual_base`` for ``nn_residual``, ``residual_rmp`` for
    ``rmp_residual``, ``hand_designed`` for ``hand_designed``).
    """
    if kind not in KINDS:
        raise ValueError(f"unknown policy kind={kind!r}; valid kinds are {KINDS}")
    spec = ObservationSpec.from_env(env)
    robot = get(spec.robot)
    if spec.robot not in _NN_HIDDEN:
        raise ValueError(f"make_policy supports robots {sorted(_NN_HIDDEN)}, got {spec.robot!r}")
    if (kind == "rmp_residual_env") != isinstance(env, RMPInEnv):
        raise ValueError(
            f"policy kind={kind!r} " + ("needs" if kind == "rmp_residual_env" else "cannot use")
            + " an environment wrapped in envs.RMPInEnv; build both with make_env_and_policy")
    if kind == "rmp_residual_env":
        fields = dict(hidden_sizes=_RMP_HIDDEN[spec.robot], activation="elu", out_scale=0.01,
                      log_std_init=-1.0)
        fields.update(overrides)
        fields["hidden_sizes"] = tuple(fields["hidden_sizes"])
        return GaussianPolicy(int(env.action_size), **fields)
    if kind == "nn":
        fields = dict(hidden_sizes=_NN_HIDDEN[spec.robot], activation="relu", out_scale=0.1,
                      log_std_init=-1.0)
        fields.update(overrides)
        fields["hidden_sizes"] = tuple(fields["hidden_sizes"])
        return GaussianPolicy(robot.dof, **fields)
    variant = {"nn_residual": "residual_base", "rmp_residual": "residual_rmp",
               "hand_designed": "hand_designed"}[kind]
    fields = dict(spec=spec, rmp_config=rmp_policies.default_config(spec.robot, variant))
    if kind == "nn_residual":
        fields.update(hidden_sizes=_NN_HIDDEN[spec.robot], activation="relu", out_scale=0.1)
        cls = NNResidualPolicy
    elif kind == "rmp_residual":
        fields.update(hidden_sizes=_RMP_HIDDEN[spec.robot], activation="elu", out_scale=0.01)
        cls = RMPResidualPolicy
    else:
        cls = HandDesignedPolicy
    fields["log_std_init"] = -1.0
    fields.update(overrides)
    if "hidden_sizes" in fields:
        fields["hidden_sizes"] = tuple(fields["hidden_sizes"])
    return cls(**fields)


def make_env_and_policy(env_name: str, kind: str, env_kwargs: dict | None = None,
                        **overrides) -> tuple[Env, nn.Module]:
    """``(env, policy)`` for training policy ``kind`` on the environment called ``env_name``.

    For ``rmp_residual_env`` the environment is ``envs.make(env_name, rmp_in_env=True,
    **env_kwargs)`` (RMP² inside the environment); otherwise ``envs.make(env_name, **env_kwargs)``.
    ``overrides`` go to :func:`make_policy`. Unknown names raise ``ValueError`` listing the valid
    ones.
    """
    if kind not in KINDS:
        raise ValueError(f"unknown policy kind={kind!r}; valid kinds are {KINDS}")
    env = envs.make(env_name, rmp_in_env=kind == "rmp_residual_env", **dict(env_kwargs or {}))
    return env, make_policy(kind, env, **overrides)


__all__ = [
    "BASE_WEIGHT",
    "KINDS",
    "HandDesignedPolicy",
    "NNResidualPolicy",
    "ObservationSpec",
    "RMPResidualPolicy",
    "decode_observation",
    "hand_designed_mean",
    "make_env_and_policy",
    "make_policy",
    "packed_kind",
    "policy_groups",
    "residual_features",
]
