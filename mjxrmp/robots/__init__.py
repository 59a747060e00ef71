"""Robots (docs/design.md §4.2): kinematic descriptions and their MuJoCo models.

* :mod:`~mjxrmp.robots.base` — :class:`Robot`, the kinematic facts and pure-JAX kinematics;
* :mod:`~mjxrmp.robots.three_link` — the planar 3-link robot (thesis §6.2);
* :mod:`~mjxrmp.robots.franka` — the Franka Panda (thesis §6.3);
* :mod:`~mjxrmp.robots.mjcf` — MJCF models of both, generated from the same parameters.
"""

from __future__ import annotations

from mjxrmp.robots.base import Robot
from mjxrmp.robots.franka import FRANKA
from mjxrmp.robots.three_link import THREE_LINK

#: Registered robots by name.
ROBOTS: dict[str, Robot] = {THREE_LINK.name: THREE_LINK, FRANKA.name: FRANKA}


def get(name: str) -> Robot:
    """The robot called ``name`` (``"three_link"`` or ``"franka"``).

    Raises:
        ValueError: if ``name`` is not a registered robot.
    """
    try:
        return ROBOTS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown robot name={name!r}; valid names are {sorted(ROBOTS)}") from None


__all__ = ["FRANKA", "ROBOTS", "THREE_LINK", "Robot", "base", "franka", "get", "mjcf", "three_link"]
