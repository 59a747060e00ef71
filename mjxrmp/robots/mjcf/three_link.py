"""MJCF of the planar 3-link robot (thesis §6.2, docs/design.md §4.2).

Body ``link{i}`` sits at height ``LINK_HEIGHTS[i-1]`` with a hinge ``joint{i}`` about z at its
origin; each link is a capsule of radius 0.025 and length 0.25 along the body x-axis, mass
1 kg. Sites ``link1``–``link3`` mark the joints and ``end_effector`` the tip, so MuJoCo's
forward kinematics equals :mod:`mjxrmp.robots.three_link` exactly.
"""

from __future__ import annotations

from collections.abc import Sequence

from mjxrmp.robots import three_link
from mjxrmp.robots.mjcf.common import DEFAULT_TIMESTEP, document, joint_names, num, servos, vec

#: Default gains of the 3-link servos: ``kp`` (N·m/rad) and ``kv`` (N·m·s/rad).
THREE_LINK_KP = 100.0
THREE_LINK_KV = 10.0

__all__ = ["THREE_LINK_KP", "THREE_LINK_KV", "three_link_mjcf"]


def _bodies(armature: float, damping: float) -> list[str]:
    """The base column and the nested link bodies (joint, inertia, capsule, sites)."""
    dof = three_link.NUM_LINKS
    length, radius, mass = three_link.LINK_LENGTH, three_link.CONTROL_POINT_RADIUS, 1.0
    i_axial = 0.5 * mass * radius**2
    i_trans = mass * (3 * radius**2 + length**2) / 12
    joints = joint_names("three_link")
    lines = [
        f'    <geom name="base" type="cylinder" fromto="0 0 0 0 0 '
        f'{num(three_link.LINK_HEIGHTS[0])}" size="0.03" rgba="0.3 0.3 0.3 1"/>'
    ]
    indent = "    "
    prev_h = 0.0
    for i in range(dof):
        h = three_link.LINK_HEIGHTS[i]
        x = 0.0 if i == 0 else length
        lines += [
            f'{indent}<body name="link{i + 1}" pos="{vec((x, 0.0, h - prev_h))}">',
            f'{indent}  <joint name="{joints[i]}" type="hinge" axis="0 0 1"'
            f' armature="{num(armature)}" damping="{num(damping)}"/>',
            f'{indent}  <inertial pos="{vec((length / 2, 0.0, 0.0))}" mass="{num(mass)}"'
            f' diaginertia="{vec((i_axial, i_trans, i_trans))}"/>',
            f'{indent}  <geom name="link{i + 1}" type="capsule"'
            f' fromto="0 0 0 {num(length)} 0 0" size="{num(radius)}"/>',
            f'{indent}  <site name="link{i + 1}"/>',
        ]
        if i == dof - 1:
            lines.append(f'{indent}  <site name="end_effector" pos="{num(length)} 0 0"/>')
        indent += "  "
        prev_h = h
    for _ in range(dof):
        indent = indent[:-2]
        lines.append(f"{indent}</body>")
    return lines


def three_link_mjcf(
    *,
    timestep: float = DEFAULT_TIMESTEP,
    actuators: bool = True,
    kp: float | Sequence[float] = THREE_LINK_KP,
    kv: float | Sequence[float] = THREE_LINK_KV,
    armature: float = 0.0,
    damping: float = 0.0,
    integrator: str = "implicitfast",
    floor: bool = True,
    worldbody_extra: str = "",
) -> str:
    """MJCF of the planar 3-link robot.

    Args:
        timestep: simulation step (s), 1/240 by default as in the original environments.
        actuators: add a position and a velocity actuator per joint
            (``ctrl = concat(q_target, qd_target)``; velocity ctrl limited to ±1 rad/s).
        kp: position gain(s), default 100 N·m/rad.
        kv: velocity gain(s), default 10 N·m·s/rad.
        armature: rotor inertia per joint (kg·m²).
        damping: passive joint damping (N·m·s/rad).
        integrator: MuJoCo integrator name.
        floor: add a ground plane.
        worldbody_extra: XML inserted at the end of ``<worldbody>`` (obstacles, goal markers).

    Each link is a 1 kg capsule (radius 0.025 m, length 0.25 m) with the inertia of a solid
    cylinder about its centre. Gravity acts along −z and exerts no torque on the z hinges.
    """
    robot = three_link.THREE_LINK
    servo_lines = (
        servos(joint_names("three_link"), kp, kv, robot.q_lower, robot.q_upper, robot.qd_max)
        if actuators else []
    )
    return document("three_link", _bodies(armature, damping), timestep=timestep,
                    integrator=integrator, floor=floor, worldbody_extra=worldbody_extra,
                    actuators=servo_lines)
