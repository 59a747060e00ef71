"""The environment registry: :func:`make`, :data:`ENVIRONMENTS` and brax registration.

Names for :func:`make` and, in brackets, for ``brax.envs.get_environment`` (registered when the
``envs`` package is imported):

* ``three_link/env1`` (``three_link_env1``), ``three_link/env2`` (``three_link_env2``),
  ``three_link/env3`` (``three_link_env3``) — :class:`envs.three_link.ThreeLinkReach`;
* ``franka`` (``franka_reach``) — :class:`envs.franka.FrankaReach`;
* ``point2d`` (``point_robot_2d``) — :class:`envs.point2d.PointRobot2D`.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import brax.envs

from envs.franka import FrankaReach
from envs.point2d import PointRobot2D
from envs.three_link import ThreeLinkReach
from envs.wrappers import RMPInEnv

ENVIRONMENTS: dict[str, Callable[..., brax.envs.Env]] = {
    "three_link/env1": functools.partial(ThreeLinkReach, "env1"),
    "three_link/env2": functools.partial(ThreeLinkReach, "env2"),
    "three_link/env3": functools.partial(ThreeLinkReach, "env3"),
    "franka": FrankaReach,
    "point2d": PointRobot2D,
}
#: brax registry names (valid identifiers) → :data:`ENVIRONMENTS` names.
BRAX_NAMES: dict[str, str] = {
    "three_link_env1": "three_link/env1",
    "three_link_env2": "three_link/env2",
    "three_link_env3": "three_link/env3",
    "franka_reach": "franka",
    "point_robot_2d": "point2d",
}

__all__ = ["BRAX_NAMES", "ENVIRONMENTS", "make", "register_brax"]


def make(name: str, *, rmp_in_env: bool = False, **kwargs) -> brax.envs.Env:
    """Build the environment called ``name`` (see the module docstring).

    Keyword arguments are passed to the constructor, e.g.
    ``make("three_link/env3", obstacle_sampler="original", observation="residual_rmp")``.
    With ``rmp_in_env=True`` the environment is wrapped in :class:`RMPInEnv` (RMP² inside the
    environment, thesis §6.1.1: the action is a residual RMP), observing ``"residual_rmp"``
    unless ``observation`` is given.
    """
    if name in BRAX_NAMES:
        name = BRAX_NAMES[name]
    if name not in ENVIRONMENTS:
        raise ValueError(
            f"unknown environment name={name!r}; valid names are {sorted(ENVIRONMENTS)}"
        )
    if rmp_in_env:
        kwargs.setdefault("observation", "residual_rmp")
        return RMPInEnv(ENVIRONMENTS[name](**kwargs))
    return ENVIRONMENTS[name](**kwargs)


def register_brax() -> None:
    """Register every environment with ``brax.envs.register_environment`` (idempotent)."""
    for brax_name, name in BRAX_NAMES.items():
        brax.envs.register_environment(brax_name, functools.partial(make, name))
