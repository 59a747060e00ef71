"""MJCF (MuJoCo XML) models of the robots, generated from the same parameters as the JAX kinematics.

Pure string building — no module here imports MuJoCo. Bodies and hinge joints are placed so
that MuJoCo's forward kinematics equals :mod:`mjxrmp.robots.three_link` and
:mod:`mjxrmp.robots.franka` exactly (docs/design.md §4.2; ``tests/mjxrmp/test_robots.py``
checks it with MJX). Geoms are primitive (capsules, cylinders, a plane) and never collide. The
default integrator is ``implicitfast`` so the velocity gains are integrated implicitly.

* :mod:`~mjxrmp.robots.mjcf.common` — number format, document skeleton, servos, joint/site names;
* :mod:`~mjxrmp.robots.mjcf.three_link` — :func:`three_link_mjcf`;
* :mod:`~mjxrmp.robots.mjcf.franka` — :func:`franka_mjcf`.
"""

from __future__ import annotations

from mjxrmp.robots.mjcf.common import DEFAULT_TIMESTEP, actuator_names, joint_names, site_names
from mjxrmp.robots.mjcf.franka import (
    FRANKA_ARMATURE,
    FRANKA_KP,
    FRANKA_KV,
    FRANKA_MASSES,
    franka_mjcf,
)
from mjxrmp.robots.mjcf.three_link import THREE_LINK_KP, THREE_LINK_KV, three_link_mjcf

__all__ = [
    "DEFAULT_TIMESTEP",
    "FRANKA_ARMATURE",
    "FRANKA_KP",
    "FRANKA_KV",
    "FRANKA_MASSES",
    "THREE_LINK_KP",
    "THREE_LINK_KV",
    "actuator_names",
    "common",
    "franka",
    "franka_mjcf",
    "joint_names",
    "site_names",
    "three_link",
    "three_link_mjcf",
]
