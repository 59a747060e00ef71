"""The robot description shared by policies, environments and the MJCF generator."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import jax


@dataclasses.dataclass(frozen=True)
class Robot:
    """Kinematic facts of a robot and its pure-JAX forward kinematics (docs/design.md §4.2).

    ``control_points(q) -> (n_cp, dim)`` and ``end_effector(q) -> (dim,)`` are pure functions
    of a single configuration ``q (dof,)``; batch them with ``jax.vmap``. ``dim`` is the
    workspace dimension the RMPs act in (2 for the planar 3-link, 3 for the Franka). Joints
    without position limits carry ``±inf``.
    """

    name: str
    dof: int
    workspace_dim: int
    q_lower: tuple[float, ...]
    q_upper: tuple[float, ...]
    qd_max: tuple[float, ...]
    default_q: tuple[float, ...]
    control_point_radii: tuple[float, ...]
    control_points: Callable[[jax.Array], jax.Array]
    end_effector: Callable[[jax.Array], jax.Array]

    @property
    def num_control_points(self) -> int:
        """Number of collision control points on the robot."""
        return len(self.control_point_radii)
