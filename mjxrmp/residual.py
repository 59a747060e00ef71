"""The residual RMP policy split into what depends on the learned leaf and what does not
(thesis §6.2.2, eqs 3.10 and 3.31; docs/design.md §4.4).

:func:`mjxrmp.policies.residual_rmp_acceleration` replaces the target leaf of a hand-designed
RMP² policy by a learned end-effector RMP and resolves the whole tree. Everything in that tree
but the learned leaf's metric and acceleration is a function of the state alone: the pullback
of every other leaf, the end-effector Jacobian and curvature, and the hand-designed target
RMP the residual is built on. :func:`residual_parts` computes those once per state;
:func:`residual_from_parts` adds the learned leaf and resolves. Since the root is a sum over
leaves (eq 3.31), the two together give the same acceleration up to float rounding, and a
learner that evaluates many parameter values at the same states (PPO's epochs over one
rollout) pays for the hand-designed tree once.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from mjxrmp import policies
from mjxrmp.core import rmp2
from mjxrmp.core.linalg import cholesky, spd_solve
from mjxrmp.core.rmp import RMP
from mjxrmp.geometry import Obstacles
from mjxrmp.leaves.hand_designed import target_rmp
from mjxrmp.robots import get

__all__ = ["ResidualParts", "residual_from_parts", "residual_parts"]


class ResidualParts(NamedTuple):
    """The state-only parts of a residual RMP policy at one configuration (d joints, m
    end-effector dimensions): the root ``(M_fixed (d, d), f_fixed (d,))`` of every leaf but
    the target, the end-effector Jacobian ``J (m, d)`` and curvature ``c = J̇q̇ (m,)``, and the
    hand-designed target RMP as ``L_h = chol(M_h) (m, m)`` and ``a_h = M_h⁻¹ f_h (m,)``."""

    M_fixed: jax.Array
    f_fixed: jax.Array
    J: jax.Array
    c: jax.Array
    L_h: jax.Array
    a_h: jax.Array


def residual_parts(cfg: policies.PolicyConfig, q: jax.Array, qd: jax.Array, goal: jax.Array,
                   obstacles: Obstacles) -> ResidualParts:
    """The :class:`ResidualParts` of the hand-designed policy ``cfg`` (which must have a target
    leaf) at one state."""
    if cfg.target is None:
        raise ValueError("residual_parts needs a PolicyConfig with a target leaf")

    def fixed_map(q_, goal_, obstacles_, cfg_):
        out = policies.task_map(q_, goal_, obstacles_, cfg_)
        del out["target"]
        return out

    root = rmp2.pullback(fixed_map, policies.leaf_rmps, q, qd, goal, obstacles, cfg)
    end_effector = get(cfg.robot).end_effector
    x, xd, c, J = rmp2.task_kinematics(lambda q_: end_effector(q_)[None], q, qd)
    M_h, f_h = target_rmp(x, xd, goal, cfg.target)
    return ResidualParts(root.M, root.f, J[0], c[0], cholesky(M_h[0]),
                         spd_solve(M_h[0], f_h[0]))


def residual_from_parts(parts: ResidualParts, A_r: jax.Array, a_r: jax.Array) -> jax.Array:
    """Joint acceleration of the residual RMP policy: the learned leaf ``M = (A_r + L_h)(A_r +
    L_h)ᵀ``, ``a = a_r + a_h`` pulled back through ``J, c`` and added to the fixed root, then
    resolved (eq 3.10). Equals :func:`mjxrmp.policies.residual_rmp_acceleration` to rounding."""
    B = A_r + parts.L_h
    M = jnp.sum(B[:, None, :] * B[None, :, :], axis=-1)  # B Bᵀ, exact products (no TF32)
    f = jnp.sum(M * (a_r + parts.a_h - parts.c)[None, :], axis=-1)  # M (a − c)
    MJ = jnp.sum(M[:, :, None] * parts.J[None, :, :], axis=1)
    M_root = parts.M_fixed + jnp.sum(parts.J[:, :, None] * MJ[:, None, :], axis=0)
    f_root = parts.f_fixed + jnp.sum(parts.J * f[:, None], axis=0)
    return rmp2.resolve(RMP(M_root, f_root))
