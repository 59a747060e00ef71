"""Robots: the :class:`Robot` description, the planar 3-link and the Franka Panda (docs/design.md §4.2)."""

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


__all__ = ["FRANKA", "ROBOTS", "THREE_LINK", "Robot", "get"]
