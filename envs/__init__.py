"""MJX reaching environments with the brax ``Env`` API (thesis §6.2–6.3, docs/design.md §2.2).

Build environments with :func:`make` (names in :mod:`envs.registry`; importing this package
registers them with brax too). For training use :func:`envs.wrappers.wrap` (its auto-reset
re-samples goal and obstacles).

* :mod:`envs.registry` — :func:`make`, :data:`ENVIRONMENTS`, :data:`BRAX_NAMES`, brax registration;
* :mod:`envs.base` — action checks, reward, episode bookkeeping shared by every environment;
* :mod:`envs.reaching` — :class:`ReachEnv`, the MJX reaching machinery (PD control, geometry,
  observation, reset/step);
* :mod:`envs.three_link` — :class:`ThreeLinkReach` (planar 3-link, setups env1–env3);
* :mod:`envs.franka` — :class:`FrankaReach` (Franka Panda, ball obstacles);
* :mod:`envs.point2d` — :class:`PointRobot2D` (pure-JAX double integrator);
* :mod:`envs.samplers` — region samplers and bounded rejection;
* :mod:`envs.physics` — which MuJoCo pipeline stages the environments run (constraints off);
* :mod:`envs.wrappers` — the re-sampling auto-reset, :func:`wrap`, :class:`RMPInEnv`;
* :mod:`envs.evaluate` — frozen-episode rollouts and summaries of a policy;
* :mod:`envs.render` — animated GIFs of a rollout (needs matplotlib, ``pip install -e ".[plots]"``);
* :mod:`envs.gymnasium` — Gymnasium 1.x ``Env`` and ``VectorEnv`` adapters (needs gymnasium,
  ``pip install -e ".[gymnasium]"``; import it as ``envs.gymnasium``).
"""

from __future__ import annotations

from envs.franka import FrankaReach
from envs.point2d import PointRobot2D, PointState
from envs.reaching import ReachEnv
from envs.registry import BRAX_NAMES, ENVIRONMENTS, make, register_brax
from envs.three_link import ThreeLinkReach
from envs.wrappers import AutoResetWrapper, RMPInEnv, wrap

register_brax()

__all__ = [
    "BRAX_NAMES",
    "ENVIRONMENTS",
    "AutoResetWrapper",
    "FrankaReach",
    "PointRobot2D",
    "PointState",
    "RMPInEnv",
    "ReachEnv",
    "ThreeLinkReach",
    "base",
    "evaluate",
    "franka",
    "gymnasium",
    "make",
    "physics",
    "point2d",
    "reaching",
    "register_brax",
    "registry",
    "render",
    "samplers",
    "three_link",
    "wrap",
    "wrappers",
]
