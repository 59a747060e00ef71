"""MJCF text shared by the robot models: number format, document skeleton, servos and names.

Pure string building (no MuJoCo import). Geoms never collide: the default class sets
``contype = conaffinity = 0``, which also applies to obstacles an environment adds through
``worldbody_extra``. Joint-space control uses, per joint, a position actuator ``pos_{joint}``
and a velocity actuator ``vel_{joint}``; ``ctrl = concat(q_target, qd_target)`` (all position
actuators first).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from mjxrmp.robots import franka, three_link

DEFAULT_TIMESTEP = 1.0 / 240.0

_ROBOT_NAMES = ("three_link", "franka")

__all__ = [
    "DEFAULT_TIMESTEP",
    "actuator_names",
    "document",
    "joint_names",
    "num",
    "servos",
    "site_names",
    "vec",
]


def num(x: float) -> str:
    """Shortest exact decimal form of a float (round-trips in float64)."""
    x = float(x)
    if x == 0.0:
        return "0"
    return repr(x)


def vec(v: Sequence[float]) -> str:
    """Space-separated numbers."""
    return " ".join(num(x) for x in v)


def _per_joint(value: float | Sequence[float], dof: int, what: str) -> tuple[float, ...]:
    """Broadcast a scalar or check a per-joint sequence."""
    if isinstance(value, int | float):
        return (float(value),) * dof
    out = tuple(float(v) for v in value)
    if len(out) != dof:
        raise ValueError(f"{what} must be a scalar or have {dof} entries, got {len(out)}")
    return out


def _check_robot(robot_name: str) -> None:
    if robot_name not in _ROBOT_NAMES:
        raise ValueError(f"unknown robot_name={robot_name!r}; valid names are {list(_ROBOT_NAMES)}")


def joint_names(robot_name: str) -> tuple[str, ...]:
    """Hinge joint names of ``robot_name`` in qpos order: ``joint1`` … ``joint{dof}``."""
    _check_robot(robot_name)
    dof = three_link.NUM_LINKS if robot_name == "three_link" else len(franka.DH_PARAMS)
    return tuple(f"joint{i + 1}" for i in range(dof))


def actuator_names(robot_name: str) -> tuple[str, ...]:
    """Actuator names in ctrl order: all ``pos_joint{i}``, then all ``vel_joint{i}``."""
    joints = joint_names(robot_name)
    return (*(f"pos_{j}" for j in joints), *(f"vel_{j}" for j in joints))


def site_names(robot_name: str) -> tuple[str, ...]:
    """Site names of the generated model.

    3-link: ``link1``–``link3`` (joints) and ``end_effector`` (tip). Franka: every name of
    :data:`mjxrmp.robots.franka.FRAME_NAMES` and ``end_effector``.
    """
    _check_robot(robot_name)
    if robot_name == "three_link":
        return (*(f"link{i + 1}" for i in range(three_link.NUM_LINKS)), "end_effector")
    return (*franka.FRAME_NAMES, "end_effector")


def servos(
    joints: Sequence[str],
    kp: float | Sequence[float],
    kv: float | Sequence[float],
    q_lower: Sequence[float],
    q_upper: Sequence[float],
    qd_max: Sequence[float],
) -> list[str]:
    """The ``<actuator>`` block: a position servo (gain ``kp``, ctrl limited to the joint range)
    and a velocity servo (gain ``kv``, ctrl limited to ``±qd_max``) per joint; a scalar gain is
    broadcast to every joint."""
    kp = _per_joint(kp, len(joints), "kp")
    kv = _per_joint(kv, len(joints), "kv")
    lines = ["  <actuator>"]
    for j, k, lo, hi in zip(joints, kp, q_lower, q_upper, strict=True):
        rng = f' ctrlrange="{num(lo)} {num(hi)}"' if math.isfinite(lo) and math.isfinite(hi) else ""
        lines.append(f'    <position name="pos_{j}" joint="{j}" kp="{num(k)}"{rng}/>')
    for j, k, v in zip(joints, kv, qd_max, strict=True):
        rng = f' ctrlrange="{num(-v)} {num(v)}"' if math.isfinite(v) else ""
        lines.append(f'    <velocity name="vel_{j}" joint="{j}" kv="{num(k)}"{rng}/>')
    lines.append("  </actuator>")
    return lines


def document(
    name: str,
    bodies: Sequence[str],
    *,
    timestep: float,
    integrator: str,
    floor: bool,
    worldbody_extra: str,
    actuators: Sequence[str],
) -> str:
    """A complete MJCF document: compiler/option/default header, ``<worldbody>`` with an
    optional ground plane, the robot's ``bodies`` lines and ``worldbody_extra``, then the
    ``actuators`` lines."""
    lines = [
        f'<mujoco model="{name}">',
        '  <compiler angle="radian" autolimits="true"/>',
        f'  <option timestep="{num(timestep)}" integrator="{integrator}"/>',
        "  <default>",
        '    <geom contype="0" conaffinity="0" rgba="0.85 0.85 0.9 1"/>',
        '    <site size="0.01" group="3" rgba="1 0.3 0.3 1"/>',
        "  </default>",
        "  <worldbody>",
    ]
    if floor:
        lines.append('    <geom name="floor" type="plane" size="2 2 0.05" rgba="0.4 0.45 0.5 1"/>')
    lines += bodies
    if worldbody_extra:
        lines.append(worldbody_extra)
    lines += ["  </worldbody>", *actuators, "</mujoco>"]
    return "\n".join(lines) + "\n"
