"""Executing the learned Franka policies with hand-specified leaves (thesis §5.2.3, §5.3.2).

:func:`policy_velocity` and :func:`rollout` evaluate the policy (*) of :mod:`agents.lfd.policy`
(eq 5.1) by :func:`mjxrmp.core.rmp2.pullback_velocity` (Jacobians by forward-mode autodiff through
FK and the flows; for ``"two_step"`` the leaves of :func:`agents.lfd.two_step.leaf_rmps`),
optionally with hand-specified leaves added "at execution time" (§5.2.3), the same for every
strategy (:class:`agents.lfd.config.ExecutionParams`): a velocity-form joint-limit RMP (a
barrier metric growing like ``1/s²`` within ``ℓ`` of a buffered limit and a repelling velocity), a
configuration-space posture default leaf (§5.3.2), and the hand-designed collision leaves of
:mod:`mjxrmp.policies`. Those are acceleration-form leaves ``(M_h(x, ẋ), f_h = M_h a_h(x, ẋ))``;
in the velocity form each contributes its metric at the current leaf velocity ``ẋ = J q̇_prev``
(the previous command) and the desired velocity ``h·a_h(x, 0)`` — one integration step ``h`` of
its damping-free (repulsive) acceleration: ``p_h = M_h(x, ẋ)·h·a_h(x, 0)``. The damping terms of
those leaves are not needed in a first-order system (velocities do not accumulate), and their
stiffness would make an explicit step unstable. (The lifted acceleration-form joint-limit leaf
used before was too weak at a 0.05 s step: its metric ``0.1/(s/0.01 + 0.001)`` is ~0.01 at
0.1 rad from a limit, negligible against the learned and default leaves, and 73 of 126 door
rollouts of the joint strategy left the limits.) Rollouts integrate
``q ← q + h·clip(q̇, ±q̇_max)`` in one ``lax.scan`` (``ExecutionParams.substeps`` Euler steps
of ``h = dt/substeps`` per control step ``dt``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp

from agents.lfd import two_step
from agents.lfd.config import DOF, ExecutionParams, StrategyConfig
from agents.lfd.policy import StrategyResult, latent_leaves, resolve_velocity
from agents.lfd.samples import task_coordinates
from mjxrmp import policies
from mjxrmp.config import check_float, check_int
from mjxrmp.core import rmp2
from mjxrmp.core.rmp import RMP
from mjxrmp.geometry import Obstacles
from mjxrmp.leaves.hand_designed import CollisionParams
from mjxrmp.robots import franka

__all__ = [
    "Execution",
    "execution_config",
    "joint_limit_distances",
    "joint_limit_leaf",
    "policy_velocity",
    "rollout",
]


class Execution(NamedTuple):
    """Execution-time context of :func:`policy_velocity`: the ``obstacles``, the previous command
    ``qd_prev (7,)`` and step ``h`` (for the lifted collision leaves), the posture ``q_posture
    (7,)`` and its weight ``posture_weight`` (a scalar, may be traced: it overrides
    ``params.posture_weight``), the leaf parameters ``params`` and the collision leaves'
    ``hand_config``."""

    obstacles: Obstacles
    qd_prev: jax.Array
    h: float
    q_posture: jax.Array
    posture_weight: jax.Array | float
    params: ExecutionParams
    hand_config: policies.PolicyConfig


def execution_config(obstacle_shape: str = "cylinder") -> policies.PolicyConfig:
    """The hand-designed acceleration-form leaves lifted at execution time (§5.2.3): the Franka
    collision RMP with its default parameters (docs/design.md §4.1). Joint limits are the
    velocity-form leaf of :class:`agents.lfd.config.ExecutionParams` instead."""
    return policies.PolicyConfig(robot="franka", collision=CollisionParams(),
                                 obstacle_shape=obstacle_shape)


def joint_limit_leaf(s: jax.Array, p: ExecutionParams) -> RMP:
    """The velocity-form joint-limit RMP of :class:`ExecutionParams` on distances ``s (n, 1)``:
    ``(m(s), m(s)·ṡ_d(s))`` as a family of 1-D natural-form pairs."""
    s = jnp.maximum(s, 0.0)
    act = jax.nn.relu(1.0 - s / p.joint_limit_length)
    m = p.joint_limit_scale * (act / (s / p.joint_limit_length + p.joint_limit_eps)) ** 2
    return RMP(m[..., None], m * p.joint_limit_speed * act)


def joint_limit_distances(q: jax.Array) -> jax.Array:
    """``s = [q_u − b − q, q − q_l − b] (14, 1)``: distances to the buffered Franka limits."""
    buf = jnp.asarray(policies.FRANKA_JOINT_LIMIT_BUFFERS, q.dtype)
    upper = jnp.asarray(franka.Q_UPPER, q.dtype) - buf
    lower = jnp.asarray(franka.Q_LOWER, q.dtype) + buf
    return jnp.concatenate([upper - q, q - lower])[:, None]


def _lifted(rmp_moving: RMP, rmp_still: RMP, h: float) -> RMP:
    """Velocity-form pair ``(M(x, ẋ), M(x, ẋ)·h·a(x, 0))`` of a family of 1-D acceleration leaves
    (module docstring); ``a(x, 0) = f/M`` of the leaf at rest (``0`` where that metric
    vanishes)."""
    M, _ = rmp_moving
    M0, f0 = rmp_still
    if M.shape[-1] != 1:
        raise ValueError(f"hand-designed execution leaves must be 1-D families (n, 1), got "
                         f"M of shape {M.shape}")
    m0 = M0[..., 0]
    a0 = jnp.where(m0 > 0, f0 / jnp.where(m0 > 0, m0, 1.0), 0.0)
    return RMP(M, h * M[..., 0] * a0)


def _learned(config: StrategyConfig, result: StrategyResult, goals: jax.Array,
             q_goal: jax.Array) -> tuple[Callable[[jax.Array], jax.Array],
                                         Callable[[jax.Array], RMP]]:
    """The learned leaves' task map ``q ↦ y`` and their natural-form RMPs at ``y``: the flows'
    latent coordinates with ``(G_k(y_k), −γ y_k)`` (:mod:`agents.lfd.policy`), or for
    ``"two_step"`` the task coordinates with :func:`agents.lfd.two_step.leaf_rmps`."""
    s, k = config.strategy, config.point
    if s == "two_step":
        return (lambda q_: task_coordinates(s, k, q_, goals, q_goal),
                lambda y: two_step.leaf_rmps(config, result, y))

    def learned_map(q_):
        x = task_coordinates(s, k, q_, goals, q_goal)
        return latent_leaves(config, result.params, result.constants, x)[0]

    def learned_leaf(y):
        G = jax.vmap(lambda mp, yk: config.metric.apply({"params": mp}, yk))(
            result.params["metric"], y)
        return RMP(G, -config.latent_gain * y)

    return learned_map, learned_leaf


def policy_velocity(config: StrategyConfig, result: StrategyResult, q: jax.Array,
                    goals: jax.Array, q_goal: jax.Array, execution: Execution | None = None
                    ) -> jax.Array:
    """The learned policy (*) of :mod:`agents.lfd.policy` (eq 5.1) at one configuration
    ``q (7,)`` through :func:`mjxrmp.core.rmp2.pullback_velocity`; ``goals (3, 3)`` control-point
    goals, ``q_goal (7,)``.

    ``execution`` (:class:`Execution`) adds the execution-time leaves: the velocity-form
    joint-limit and posture leaves of :class:`agents.lfd.config.ExecutionParams` and the
    hand-designed collision leaves of ``execution.hand_config`` in their velocity-form lift
    (module docstring) at the previous command. Without it this equals
    :func:`agents.lfd.policy.training_velocity` on the same sample.
    """
    s, k = config.strategy, config.point
    learned_map, learned_leaf = _learned(config, result, goals, q_goal)

    def default_leaf(x, w, gain):
        eye = jnp.broadcast_to(jnp.eye(x.shape[-1], dtype=x.dtype), (*x.shape, x.shape[-1]))
        return RMP(w * eye, -w * gain * x)

    def base_map(q_):
        return {"learned": learned_map(q_),
                "default": task_coordinates(s, k, q_, goals, q_goal)}

    def base_leaves(x):
        return {"learned": learned_leaf(x["learned"]),
                "default": default_leaf(x["default"], config.default_weight,
                                        config.default_gain)}

    if execution is None:
        root = rmp2.pullback_velocity(base_map, base_leaves, q)
        return resolve_velocity(root.M, root.f, config.regularization)

    ex = execution
    cfg, p = ex.hand_config, ex.params
    dummy_goal = jnp.zeros((3,), q.dtype)
    hand_map = lambda q_: policies.task_map(q_, dummy_goal, ex.obstacles, cfg)  # noqa: E731
    _, xd_hand = jax.jvp(hand_map, (q,), (ex.qd_prev,))

    def full_map(q_):
        return {**base_map(q_), "hand": hand_map(q_), "joint_limit": joint_limit_distances(q_),
                "posture": (q_ - ex.q_posture)[None]}

    def leaf_fn(x):
        moving = policies.leaf_rmps(x["hand"], xd_hand, dummy_goal, ex.obstacles, cfg)
        still = policies.leaf_rmps(x["hand"], jax.tree.map(jnp.zeros_like, xd_hand),
                                   dummy_goal, ex.obstacles, cfg)
        return {**base_leaves(x),
                "hand": {n: _lifted(moving[n], still[n], ex.h) for n in moving},
                "joint_limit": joint_limit_leaf(x["joint_limit"], p),
                "posture": default_leaf(x["posture"], ex.posture_weight, p.posture_gain)}

    root = rmp2.pullback_velocity(full_map, leaf_fn, q)
    return resolve_velocity(root.M, root.f, config.regularization)


def rollout(config: StrategyConfig, result: StrategyResult, q0: jax.Array, goals: jax.Array,
            q_goal: jax.Array, num_steps: int, dt: float,
            obstacles: Obstacles | None = None,
            hand_config: policies.PolicyConfig | None = None,
            params: ExecutionParams | None = None,
            q_posture: jax.Array | None = None,
            posture_weight: jax.Array | float | None = None) -> tuple[jax.Array, jax.Array]:
    """Integrate the policy from ``q0 (7,)`` for ``num_steps`` control steps of ``dt``, each by
    ``params.substeps`` Euler steps ``q ← q + (dt/substeps)·clip(q̇, ±q̇_max)``, in one
    ``lax.scan``. With ``obstacles`` the execution-time leaves are added (:class:`Execution`:
    ``params`` default :class:`ExecutionParams`, ``hand_config`` default
    :func:`execution_config`, ``q_posture`` default ``q_goal``, ``posture_weight`` (may be
    traced, e.g. ``vmap``-ped) default ``params.posture_weight``); without, the learned policy
    alone. Returns ``(qs (num_steps + 1, 7), qds (num_steps, 7))``, ``qds`` the mean command
    over each control step."""
    check_int(num_steps, "num_steps (static)")
    check_float(dt, "dt")
    q0 = rmp2.check_configuration("q0", q0, DOF)
    qd_max = jnp.asarray(franka.QD_MAX, q0.dtype)
    cfg = execution_config() if hand_config is None else hand_config
    p = ExecutionParams() if params is None else params
    h = dt / p.substeps
    q_p = q_goal if q_posture is None else q_posture
    w_p = p.posture_weight if posture_weight is None else posture_weight

    def sub(carry, _):
        q, qd_prev = carry
        ex = None if obstacles is None else Execution(obstacles, qd_prev, h, q_p, w_p, p, cfg)
        qd = jnp.clip(policy_velocity(config, result, q, goals, q_goal, ex), -qd_max, qd_max)
        return (q + h * qd, qd), qd

    def step(carry, _):
        carry, qds = jax.lax.scan(sub, carry, None, length=p.substeps)
        return carry, (carry[0], jnp.mean(qds, axis=0))

    _, (qs, qds) = jax.lax.scan(step, (q0, jnp.zeros_like(q0)), None, length=int(num_steps))
    return jnp.concatenate([q0[None], qs], axis=0), qds
