"""Planar 3-link robot (thesis §6.2, docs/design.md §4.2): kinematics and control points.

Three revolute joints about z, links of 0.25 m (reach 0.75 m), velocity limit 1 rad/s, no
position limits. The links sit at different heights (0.075, 0.15, 0.225 m) so they cannot
collide with each other; the RMPs act in the xy-plane. Five control points per link (radius
0.025) are interpolated along each link, the first endpoint excluded; the end effector is the tip.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from mjxrmp.robots.base import Robot

LINK_LENGTH = 0.25
NUM_LINKS = 3
#: Heights of the three links above the ground in the simulator (m).
LINK_HEIGHTS = (0.075, 0.15, 0.225)
POINTS_PER_LINK = 5
CONTROL_POINT_RADIUS = 0.025
VELOCITY_LIMIT = 1.0


def joint_positions(q: jax.Array) -> jax.Array:
    """Planar positions of the 3 joints and the tip, shape ``(4, 2)`` (base at the origin)."""
    angles = jnp.cumsum(q)
    steps = LINK_LENGTH * jnp.stack([jnp.cos(angles), jnp.sin(angles)], axis=-1)
    zero = jnp.zeros((1, 2), dtype=q.dtype)
    return jnp.concatenate([zero, jnp.cumsum(steps, axis=0)], axis=0)


def control_points(q: jax.Array) -> jax.Array:
    """The 15 control points, shape ``(15, 2)``: 5 per link at fractions 0.2, 0.4, …, 1.0."""
    p = joint_positions(q)
    t = jnp.arange(1, POINTS_PER_LINK + 1, dtype=q.dtype) / POINTS_PER_LINK
    starts, ends = p[:-1], p[1:]
    pts = starts[:, None, :] + t[None, :, None] * (ends - starts)[:, None, :]
    return pts.reshape(NUM_LINKS * POINTS_PER_LINK, 2)


def end_effector(q: jax.Array) -> jax.Array:
    """Tip position, shape ``(2,)``."""
    return joint_positions(q)[-1]


THREE_LINK = Robot(
    name="three_link",
    dof=3,
    workspace_dim=2,
    q_lower=(-math.inf,) * 3,
    q_upper=(math.inf,) * 3,
    qd_max=(VELOCITY_LIMIT,) * 3,
    default_q=(0.0, 0.0, 0.0),
    control_point_radii=(CONTROL_POINT_RADIUS,) * (NUM_LINKS * POINTS_PER_LINK),
    control_points=control_points,
    end_effector=end_effector,
)
