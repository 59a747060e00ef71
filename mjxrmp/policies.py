"""Hand-designed RMP² policies for the planar 3-link and the Franka (thesis §6.2–6.3).

A :class:`PolicyConfig` names the robot and holds one parameter dataclass per leaf (``None``
switches a leaf off). It is frozen and hashable (usable as a static argument) and a pytree whose
children are the leaf parameters (so losses can be differentiated with respect to them).

The policy's context is ``(goal, obstacles)``: the goal in the workspace (``(2,)`` or ``(3,)``)
and an :class:`~mjxrmp.geometry.Obstacles` set. Leaf families follow the original order: cspace
target, joint limit, velocity cap, target, collision, damping. The environment clips the
resulting acceleration (±1 by default); the policy does not.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

import jax
import jax.numpy as jnp

from mjxrmp.config import check_choice
from mjxrmp.core import rmp2
from mjxrmp.core.linalg import cholesky, spd_solve
from mjxrmp.core.rmp import RMP
from mjxrmp.geometry import OBSTACLE_SHAPES, Obstacles, point_obstacle_distances
from mjxrmp.leaves.hand_designed import (
    CollisionParams,
    CSpaceTargetParams,
    DampingParams,
    JointLimitParams,
    TargetParams,
    VelocityCapParams,
    collision_rmp,
    cspace_target_rmp,
    damping_rmp,
    joint_limit_rmp,
    target_rmp,
    velocity_cap_rmp,
)
from mjxrmp.robots import Robot, get

Variant = Literal["hand_designed", "residual_base", "residual_rmp"]
VARIANTS = ("hand_designed", "residual_base", "residual_rmp")

_LEAF_FIELDS = ("cspace_target", "joint_limit", "velocity_cap", "target", "collision", "damping")


@dataclasses.dataclass(frozen=True)
class PolicyConfig:
    """Which leaves a hand-designed RMP² policy uses, and their parameters.

    ``joint_limit_buffers`` shrink the joint limits per joint; ``obstacle_shape`` is ``"sphere"``
    (Franka balls) or ``"cylinder"`` (vertical pillars; circles for the planar 3-link).
    """

    robot: str
    cspace_target: CSpaceTargetParams | None = None
    joint_limit: JointLimitParams | None = None
    velocity_cap: VelocityCapParams | None = None
    target: TargetParams | None = None
    collision: CollisionParams | None = None
    damping: DampingParams | None = None
    joint_limit_buffers: tuple[float, ...] = ()
    obstacle_shape: str = "sphere"

    def __post_init__(self) -> None:
        robot = get(self.robot)
        check_choice(self.obstacle_shape, "PolicyConfig.obstacle_shape", OBSTACLE_SHAPES)
        if self.joint_limit is not None and len(self.joint_limit_buffers) != robot.dof:
            raise ValueError(
                f"joint_limit_buffers must have {robot.dof} entries for {self.robot}, "
                f"got {len(self.joint_limit_buffers)}"
            )
        if any(b < 0 for b in self.joint_limit_buffers):
            raise ValueError(f"joint_limit_buffers must be >= 0, got {self.joint_limit_buffers}")
        if all(getattr(self, f) is None for f in _LEAF_FIELDS):
            raise ValueError("PolicyConfig needs at least one leaf RMP")


def _flatten(cfg: PolicyConfig):
    children = tuple(getattr(cfg, f) for f in _LEAF_FIELDS)
    return children, (cfg.robot, cfg.joint_limit_buffers, cfg.obstacle_shape)


def _unflatten(aux, children) -> PolicyConfig:
    cfg = object.__new__(PolicyConfig)
    for name, value in zip(_LEAF_FIELDS, children, strict=True):
        object.__setattr__(cfg, name, value)
    for name, value in zip(("robot", "joint_limit_buffers", "obstacle_shape"), aux, strict=True):
        object.__setattr__(cfg, name, value)
    return cfg


jax.tree_util.register_pytree_node(PolicyConfig, _flatten, _unflatten)


# --------------------------------------------------------------------------------------------
# Presets reproducing the original configurations (docs/design.md §4.1; one documented departure:
# the 3-link collision metric length scale, see three_link_config)
# --------------------------------------------------------------------------------------------


#: Collision-metric length scale ``σ_e`` of every 3-link preset (original: 0.02).
THREE_LINK_METRIC_STD = 0.1


def three_link_config(variant: Variant = "hand_designed") -> PolicyConfig:
    """3-link policy: hand-designed, base policy under a residual network, or residual-RMP base.

    No cspace-target or joint-limit leaves; obstacles are vertical cylinders. Under a residual
    (``residual_base``/``residual_rmp``) the target gains drop to ``k_p 5, k_d 10, b 5``, the
    velocity-cap region to 0.1 and the damping gain to 5. For ``residual_rmp`` the target params
    are the hand-designed part of the learned end-effector RMP.

    **One departure from the original values (every 3-link variant):** the collision leaf's
    metric length scale ``σ_e`` (``CollisionParams.metric_std``) is 0.1 m instead of the original
    0.02 m (docs/design.md §4.1: "collision as Franka"); every other value is the original one.
    Why: the environment clips the commanded joint
    accelerations to ±1 rad/s², so the tip (up to 0.75 m from the base) can brake at only about
    1 m/s². The target attractor drives it at up to ``k_p/k_d ≈ 0.7`` m/s, which needs a
    stopping distance ``v²/2a`` of about 0.05–0.25 m. The collision leaf's priority
    ``w = 1/(s/σ_e + ε_e) ≈ σ_e/s`` only exceeds the target's (≈ 0.5–1, pushing at up to
    ``k_p`` = 50 m/s²) for ``s ≲ σ_e``. With σ_e = 0.02 the leaf takes over 2–3 cm from the
    obstacle, too late for the clipped actuation: the original values gave 98.3 / 96.6 / 93.9 %
    safe episodes on env1 / env2 / env3 (thesis obstacle sampler, 4,096 episodes each).
    With σ_e = 0.1 it takes over at about the braking distance, so all three setups reach
    100 % safe, with the thesis sampler and with the original one. Success also went up, to
    91.8 / 80.8 / 83.5 % from 88.4 / 73.5 / 71.5 % (BENCHMARKS.md; sweep in
    ``results/environments/sweep_hand_designed_collision_h100.jsonl``). Scaling the collision
    damping instead (``σ_d`` 0.04 → 0.15, or ``g_damp`` 50 → 200) works about as well: less
    than 1 pp more success but a lower return. ``σ_e`` was chosen because it acts on the cause
    (priority), not on a deceleration demand that the clip already saturates. The residual
    variants face the same clip: their low target gains (``k_p 5, k_d 10``) keep the *base*
    policies 100 % safe even with σ_e = 0.02 (sweep), but a learned residual drives the arm as
    fast as the hand-designed policy does. With σ_e = 0.02, thesis-scale PPO of
    ``rmp_residual`` on env3 (4 seeds) stayed 100 % safe for 250 iterations and then, as the
    policy sped up, dropped to 98–99 % (569 collisions in 218,573 episodes;
    ``results/ch6/ablation_sigma_e_0.02``); so the residual variants use σ_e = 0.1 as well.
    """
    _check_variant(variant)
    if variant == "hand_designed":
        target = TargetParams(s_max=1.0, boost=20.0)
        cap = VelocityCapParams(max_velocity=1.0, damping_region=0.15)
        damping = DampingParams(damping_gain=30.0)
    else:
        target = TargetParams(k_p=5.0, k_d=10.0, s_max=1.0, boost=5.0)
        cap = VelocityCapParams(max_velocity=1.0, damping_region=0.1)
        damping = DampingParams(damping_gain=5.0)
    return PolicyConfig(
        robot="three_link",
        velocity_cap=cap,
        target=target,
        collision=CollisionParams(metric_std=THREE_LINK_METRIC_STD),
        damping=damping,
        obstacle_shape="cylinder",
    )


FRANKA_JOINT_LIMIT_BUFFERS = (0.01, 0.03, 0.01, 0.01, 0.01, 0.01, 0.01)


def franka_config(variant: Variant = "hand_designed") -> PolicyConfig:
    """Franka policy: hand-designed, base under a residual network, or residual-RMP base.

    Under a residual the cspace target uses ``k_p 1, k_d 2``, the target
    ``k_p .5, k_d .5, s_max .5, s_min .5, b 1`` and the damping gain 1 (docs/design.md §4.1).
    """
    _check_variant(variant)
    if variant == "hand_designed":
        cspace, target, damping = CSpaceTargetParams(), TargetParams(), DampingParams()
    else:
        cspace = CSpaceTargetParams(k_p=1.0, k_d=2.0)
        target = TargetParams(k_p=0.5, k_d=0.5, s_max=0.5, s_min=0.5, boost=1.0)
        damping = DampingParams(damping_gain=1.0)
    return PolicyConfig(
        robot="franka",
        cspace_target=cspace,
        joint_limit=JointLimitParams(),
        velocity_cap=VelocityCapParams(),
        target=target,
        collision=CollisionParams(),
        damping=damping,
        joint_limit_buffers=FRANKA_JOINT_LIMIT_BUFFERS,
        obstacle_shape="sphere",
    )


def default_config(robot: str, variant: Variant = "hand_designed") -> PolicyConfig:
    """The preset for ``robot`` (``"three_link"`` or ``"franka"``) and ``variant``."""
    presets = {"three_link": three_link_config, "franka": franka_config}
    if robot not in presets:
        raise ValueError(f"robot must be one of {sorted(presets)}, got {robot!r}")
    return presets[robot](variant)


def _check_variant(variant: str) -> None:
    if variant not in VARIANTS:
        raise ValueError(f"variant must be one of {VARIANTS}, got {variant!r}")


# --------------------------------------------------------------------------------------------
# Task map and leaves
# --------------------------------------------------------------------------------------------


def _robot(cfg: PolicyConfig) -> Robot:
    return get(cfg.robot)


def task_map(q: jax.Array, goal: jax.Array, obstacles: Obstacles, cfg: PolicyConfig) -> dict:
    """Subtask coordinates of every enabled family (eq 3.7's ``ψ``), as ``(n_k, m_k)`` arrays."""
    del goal
    robot = _robot(cfg)
    out = {}
    if cfg.cspace_target is not None:
        out["cspace_target"] = (q - jnp.asarray(robot.default_q, q.dtype))[None]
    if cfg.joint_limit is not None:
        buf = jnp.asarray(cfg.joint_limit_buffers, q.dtype)
        upper = jnp.asarray(robot.q_upper, q.dtype) - buf
        lower = jnp.asarray(robot.q_lower, q.dtype) + buf
        out["joint_limit"] = jnp.concatenate([upper - q, q - lower])[:, None]
    if cfg.velocity_cap is not None:
        out["velocity_cap"] = q[:, None]
    if cfg.target is not None:
        out["target"] = robot.end_effector(q)[None]
    if cfg.collision is not None:
        radii = jnp.asarray(robot.control_point_radii, q.dtype)
        d = point_obstacle_distances(
            robot.control_points(q), radii, obstacles, cfg.obstacle_shape
        )
        out["collision"] = d.reshape(-1, 1)
    if cfg.damping is not None:
        out["damping"] = q[None]
    return out


def leaf_rmps(
    x: dict, xd: dict, goal: jax.Array, obstacles: Obstacles, cfg: PolicyConfig
) -> dict:
    """The hand-designed leaf RMPs for every family of :func:`task_map`."""
    out = {}
    for name, xk in x.items():
        p = getattr(cfg, name)
        if name == "target":
            out[name] = target_rmp(xk, xd[name], goal, p)
        elif name == "collision":
            rmp = collision_rmp(xk, xd[name], p)
            n_points = xk.shape[0] // obstacles.radius.shape[0]
            mask = jnp.tile(obstacles.active.astype(xk.dtype), n_points)
            out[name] = RMP(rmp.M * mask[:, None, None], rmp.f * mask[:, None])
        else:
            leaf = {
                "cspace_target": cspace_target_rmp,
                "joint_limit": joint_limit_rmp,
                "velocity_cap": velocity_cap_rmp,
                "damping": damping_rmp,
            }[name]
            out[name] = leaf(xk, xd[name], p)
    return out


def _check_context(cfg: PolicyConfig, goal: jax.Array, obstacles: Obstacles) -> None:
    robot = _robot(cfg)
    dim = robot.workspace_dim
    if not isinstance(obstacles, Obstacles):
        raise TypeError(f"obstacles must be mjxrmp.geometry.Obstacles, got {type(obstacles)}")
    if jnp.shape(goal) != (dim,):
        raise ValueError(f"goal must have shape ({dim},) for {cfg.robot}, got {jnp.shape(goal)}")
    if obstacles.center.ndim != 2 or obstacles.center.shape[1] != dim:
        raise ValueError(
            f"obstacles.center must have shape (O, {dim}) for {cfg.robot}, "
            f"got {obstacles.center.shape}"
        )


def root(
    cfg: PolicyConfig, q: jax.Array, qd: jax.Array, goal: jax.Array, obstacles: Obstacles
) -> RMP:
    """Root RMP ``[M, f]`` of the hand-designed policy (eq 3.31), for residual compositions."""
    _check_context(cfg, goal, obstacles)
    return rmp2.pullback(task_map, leaf_rmps, q, qd, goal, obstacles, cfg)


def acceleration(
    cfg: PolicyConfig, q: jax.Array, qd: jax.Array, goal: jax.Array, obstacles: Obstacles,
    debug: bool = False,
) -> jax.Array:
    """Joint acceleration ``q̈`` of the hand-designed RMP² policy (Algorithm 2, eq 3.10)."""
    _check_context(cfg, goal, obstacles)
    return rmp2.acceleration(task_map, leaf_rmps, q, qd, goal, obstacles, cfg, debug=debug)


def residual_rmp_acceleration(
    cfg: PolicyConfig,
    q: jax.Array,
    qd: jax.Array,
    goal: jax.Array,
    obstacles: Obstacles,
    A_r: jax.Array,
    a_r: jax.Array,
) -> jax.Array:
    """RMP² acceleration with the target leaf replaced by a residual end-effector RMP (§6.2.2).

    With the hand-designed target RMP ``(M_h, a_h)`` of ``cfg`` (the ``residual_rmp`` preset's
    hand-designed part), the learned leaf is ``M = (A_r + chol(M_h))(A_r + chol(M_h))ᵀ`` and
    ``a = a_r + a_h``; all other leaves stay hand-designed. ``A_r (m, m)`` and ``a_r (m,)`` are the
    (already squashed) network outputs; ``A_r = 0, a_r = 0`` gives back the hand-designed policy.
    """
    if cfg.target is None:
        raise ValueError("residual_rmp_acceleration needs a PolicyConfig with a target leaf")
    _check_context(cfg, goal, obstacles)
    exact = jax.lax.Precision.HIGHEST

    def task_map_r(q_, goal_, obstacles_, cfg_, A_r_, a_r_):
        del A_r_, a_r_
        return task_map(q_, goal_, obstacles_, cfg_)

    def leaf_fn(x, xd, goal_, obstacles_, cfg_, A_r_, a_r_):
        out = leaf_rmps(x, xd, goal_, obstacles_, cfg_)
        M_h, f_h = out["target"]
        a_h = spd_solve(M_h[0], f_h[0])
        B = A_r_ + cholesky(M_h[0])
        M = jnp.matmul(B, B.T, precision=exact)
        out["target"] = RMP(M[None], jnp.matmul(M, a_r_ + a_h, precision=exact)[None])
        return out

    return rmp2.acceleration(task_map_r, leaf_fn, q, qd, goal, obstacles, cfg, A_r, a_r)
