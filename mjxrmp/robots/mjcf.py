"""MJCF (MuJoCo XML) models of the robots, generated from the same parameters as the JAX kinematics.

Pure string building — this module does not import MuJoCo. Bodies and hinge joints are placed so
that MuJoCo's forward kinematics equals :mod:`mjxrmp.robots.three_link` and
:mod:`mjxrmp.robots.franka` exactly (docs/design.md §4.2; ``tests/mjxrmp/test_robots.py`` checks it with MJX):

* **3-link:** body ``link{i}`` at height ``LINK_HEIGHTS[i-1]`` with a hinge ``joint{i}`` about z at
  its origin; each link is a capsule of radius 0.025 and length 0.25 along the body x-axis, mass
  1 kg. Sites ``link1``–``link3`` mark the joints and ``end_effector`` the tip.
* **Franka:** one body per modified-DH frame (``link0`` … ``link7``, the flange ``link8``),
  placed by ``pos = (a, −sin α · d, cos α · d)`` and ``quat = RotX(α)``, with a hinge ``joint{i}``
  about the local z-axis limited to ``franka.Q_LOWER``/``Q_UPPER``; the ``hand`` body (flange
  rotated −π/4 about z) and two rigid finger bodies. Every frame of
  :func:`mjxrmp.robots.franka.link_frames` has a ``<site>`` of the same name (in the body it
  belongs to, with that frame's orientation), plus the site ``end_effector`` at the grasp target.

Geoms are primitive (capsules, cylinders, a plane) and never collide: the default class sets
``contype = conaffinity = 0``, which also applies to obstacles an environment adds through
``worldbody_extra``. Joint-space control uses, per joint, a position actuator ``pos_{joint}`` and a
velocity actuator ``vel_{joint}``; ``ctrl = concat(q_target, qd_target)`` (all position actuators
first). The default integrator is ``implicitfast`` so the velocity gains are integrated implicitly.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from mjxrmp.robots import franka, three_link

DEFAULT_TIMESTEP = 1.0 / 240.0

#: Default gains of the 3-link servos: ``kp`` (N·m/rad) and ``kv`` (N·m·s/rad).
THREE_LINK_KP = 100.0
THREE_LINK_KV = 10.0
#: Default gains of the Franka servos: ``kp`` (N·m/rad) and ``kv`` (N·m·s/rad).
FRANKA_KP = 1000.0
FRANKA_KV = 50.0
#: Default rotor inertia added to every Franka joint (kg·m²); keeps the stiff servos stable at
#: ``dt = 1/240`` s.
FRANKA_ARMATURE = 0.1

#: Masses of the Franka bodies (kg), from the original URDF.
FRANKA_MASSES: dict[str, float] = {
    "link0": 2.9,
    "link1": 2.7,
    "link2": 2.73,
    "link3": 2.04,
    "link4": 2.08,
    "link5": 3.0,
    "link6": 1.3,
    "link7": 0.2,
    "hand": 0.81,
    "left_finger": 0.1,
    "right_finger": 0.1,
}
#: Diagonal inertia used by the original URDF for every body (kg·m²).
URDF_DIAG_INERTIA = 0.1
#: Radius of gyration of the default (realistic) inertias: ``I = m · 0.1² · (1, 1, 1)``.
RADIUS_OF_GYRATION = 0.1

_LINK_RADII = (0.06, 0.06, 0.06, 0.06, 0.055, 0.05, 0.045)
#: Centres of mass of the links whose next frame shares their origin (link 1: the shoulder
#: column below joint 2; link 5: the lower forearm). Others sit halfway to the next frame.
_COM_OVERRIDES: dict[str, tuple[float, float, float]] = {
    "link1": (0.0, 0.0, -0.09),
    "link5": (0.0, 0.04, -0.1),
}
_ROBOT_NAMES = ("three_link", "franka")


def _num(x: float) -> str:
    """Shortest exact decimal form of a float (round-trips in float64)."""
    x = float(x)
    if x == 0.0:
        return "0"
    return repr(x)


def _vec(v: Sequence[float]) -> str:
    """Space-separated numbers."""
    return " ".join(_num(x) for x in v)


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


def _header(name: str, timestep: float, integrator: str) -> list[str]:
    return [
        f'<mujoco model="{name}">',
        '  <compiler angle="radian" autolimits="true"/>',
        f'  <option timestep="{_num(timestep)}" integrator="{integrator}"/>',
        "  <default>",
        '    <geom contype="0" conaffinity="0" rgba="0.85 0.85 0.9 1"/>',
        '    <site size="0.01" group="3" rgba="1 0.3 0.3 1"/>',
        "  </default>",
    ]


def _floor() -> str:
    return '    <geom name="floor" type="plane" size="2 2 0.05" rgba="0.4 0.45 0.5 1"/>'


def _actuator_block(
    joints: Sequence[str],
    kp: Sequence[float],
    kv: Sequence[float],
    q_lower: Sequence[float],
    q_upper: Sequence[float],
    qd_max: Sequence[float],
) -> list[str]:
    lines = ["  <actuator>"]
    for j, k, lo, hi in zip(joints, kp, q_lower, q_upper, strict=True):
        rng = (
            f' ctrlrange="{_num(lo)} {_num(hi)}"' if math.isfinite(lo) and math.isfinite(hi) else ""
        )
        lines.append(f'    <position name="pos_{j}" joint="{j}" kp="{_num(k)}"{rng}/>')
    for j, k, v in zip(joints, kv, qd_max, strict=True):
        rng = f' ctrlrange="{_num(-v)} {_num(v)}"' if math.isfinite(v) else ""
        lines.append(f'    <velocity name="vel_{j}" joint="{j}" kv="{_num(k)}"{rng}/>')
    lines.append("  </actuator>")
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
    dof = three_link.NUM_LINKS
    length, radius, mass = three_link.LINK_LENGTH, three_link.CONTROL_POINT_RADIUS, 1.0
    i_axial = 0.5 * mass * radius**2
    i_trans = mass * (3 * radius**2 + length**2) / 12
    joints = joint_names("three_link")
    lines = _header("three_link", timestep, integrator)
    lines.append("  <worldbody>")
    if floor:
        lines.append(_floor())
    base_h = three_link.LINK_HEIGHTS[0]
    lines.append(
        f'    <geom name="base" type="cylinder" fromto="0 0 0 0 0 {_num(base_h)}" size="0.03"'
        ' rgba="0.3 0.3 0.3 1"/>'
    )
    indent = "    "
    prev_h = 0.0
    for i in range(dof):
        h = three_link.LINK_HEIGHTS[i]
        x = 0.0 if i == 0 else length
        lines += [
            f'{indent}<body name="link{i + 1}" pos="{_vec((x, 0.0, h - prev_h))}">',
            f'{indent}  <joint name="{joints[i]}" type="hinge" axis="0 0 1"'
            f' armature="{_num(armature)}" damping="{_num(damping)}"/>',
            f'{indent}  <inertial pos="{_vec((length / 2, 0.0, 0.0))}" mass="{_num(mass)}"'
            f' diaginertia="{_vec((i_axial, i_trans, i_trans))}"/>',
            f'{indent}  <geom name="link{i + 1}" type="capsule"'
            f' fromto="0 0 0 {_num(length)} 0 0" size="{_num(radius)}"/>',
            f'{indent}  <site name="link{i + 1}"/>',
        ]
        if i == dof - 1:
            lines.append(f'{indent}  <site name="end_effector" pos="{_num(length)} 0 0"/>')
        indent += "  "
        prev_h = h
    for _ in range(dof):
        indent = indent[:-2]
        lines.append(f"{indent}</body>")
    if worldbody_extra:
        lines.append(worldbody_extra)
    lines.append("  </worldbody>")
    if actuators:
        kps = _per_joint(kp, dof, "kp")
        kvs = _per_joint(kv, dof, "kv")
        lines += _actuator_block(
            joints,
            kps,
            kvs,
            three_link.THREE_LINK.q_lower,
            three_link.THREE_LINK.q_upper,
            three_link.THREE_LINK.qd_max,
        )
    lines.append("</mujoco>")
    return "\n".join(lines) + "\n"


def _franka_sites() -> dict[str, list[tuple[str, tuple[float, float, float]]]]:
    """Sites per Franka body: ``body -> [(site name, position in the body frame)]``."""
    bodies = {*franka.CHAIN_FRAMES, "left_finger", "right_finger"}
    sites: dict[str, list[tuple[str, tuple[float, float, float]]]] = {b: [] for b in bodies}
    for name in franka.FRAME_NAMES:
        frame, pos = name, (0.0, 0.0, 0.0)
        while frame not in bodies:  # offset frames keep their parent's orientation: add up
            frame, offset = franka.OFFSET_FRAMES[frame]
            pos = tuple(a + b for a, b in zip(pos, offset, strict=True))
        sites[frame].append((name, pos))
    sites["hand"].append(("end_effector", (0.0, 0.0, franka.GRASP_OFFSET)))
    return sites


def franka_mjcf(
    *,
    timestep: float = DEFAULT_TIMESTEP,
    actuators: bool = True,
    kp: float | Sequence[float] = FRANKA_KP,
    kv: float | Sequence[float] = FRANKA_KV,
    armature: float = FRANKA_ARMATURE,
    damping: float = 0.0,
    gravity_compensation: bool = True,
    urdf_inertia: bool = False,
    integrator: str = "implicitfast",
    floor: bool = True,
    worldbody_extra: str = "",
) -> str:
    """MJCF of the Franka Panda (7 hinge joints; the fingers are rigid).

    Args:
        timestep: simulation step (s), 1/240 by default as in the original environments.
        actuators: add a position and a velocity actuator per joint
            (``ctrl = concat(q_target, qd_target)``; ctrl limited to the joint range and ±QD_MAX).
        kp: position gain(s), default 1000 N·m/rad.
        kv: velocity gain(s), default 50 N·m·s/rad.
        armature: rotor inertia per joint (kg·m²), default 0.1.
        damping: passive joint damping (N·m·s/rad).
        gravity_compensation: set ``gravcomp="1"`` on all moving bodies (as the real robot's
            controller does), so the servos need not hold the arm against gravity.
        urdf_inertia: use the original URDF's diagonal inertia 0.1 kg·m² for every body. By
            default each body gets ``m · 0.1² · (1, 1, 1)`` (radius of gyration 0.1 m) instead:
            0.1 kg·m² on the 0.2 kg link 7 or the 0.1 kg fingers is unrealistically large and makes
            the distal joints sluggish.
        integrator: MuJoCo integrator name.
        floor: add a ground plane.
        worldbody_extra: XML inserted at the end of ``<worldbody>`` (obstacles, goal markers).

    Masses are the original URDF's (:data:`FRANKA_MASSES`); centres of mass sit halfway to the
    next frame (link 1 and link 5: on the shoulder column / lower forearm). Joint ranges are
    ``franka.Q_LOWER``/``Q_UPPER``.
    """
    dof = len(franka.DH_PARAMS)
    joints = joint_names("franka")
    sites = _franka_sites()
    grav = ' gravcomp="1"' if gravity_compensation else ""

    def inertial(body: str, com: Sequence[float]) -> str:
        m = FRANKA_MASSES[body]
        diag = URDF_DIAG_INERTIA if urdf_inertia else round(m * RADIUS_OF_GYRATION**2, 12)
        return (
            f'<inertial pos="{_vec(com)}" mass="{_num(m)}"'
            f' diaginertia="{_vec((diag, diag, diag))}"/>'
        )

    def site_lines(body: str, indent: str) -> list[str]:
        out = []
        for name, pos in sites[body]:
            p = f' pos="{_vec(pos)}"' if any(pos) else ""
            out.append(f'{indent}<site name="{name}"{p}/>')
        return out

    dh = [*franka.DH_PARAMS, franka.FLANGE_DH]
    lines = _header("franka", timestep, integrator)
    lines.append("  <worldbody>")
    if floor:
        lines.append(_floor())
    indent = "    "
    # link0: the fixed base.
    lines += [
        f'{indent}<body name="link0">',
        f"{indent}  {inertial('link0', (0.0, 0.0, 0.07))}",
        f'{indent}  <geom name="link0" type="cylinder" fromto="0 0 0 0 0 0.15" size="0.07"/>',
        *site_lines("link0", indent + "  "),
    ]
    for i in range(dof):
        a, d, alpha = dh[i]
        indent += "  "
        pos = franka.dh_translation(a, d, alpha)
        quat = (math.cos(alpha / 2), math.sin(alpha / 2), 0.0, 0.0)
        nxt = franka.dh_translation(*dh[i + 1])
        r = _LINK_RADII[i]
        body = f"link{i + 1}"
        lines += [
            f'{indent}<body name="{body}" pos="{_vec(pos)}" quat="{_vec(quat)}"{grav}>',
            f'{indent}  <joint name="{joints[i]}" type="hinge" axis="0 0 1"'
            f' range="{_num(franka.Q_LOWER[i])} {_num(franka.Q_UPPER[i])}"'
            f' armature="{_num(armature)}" damping="{_num(damping)}"/>',
            f"{indent}  {inertial(body, _COM_OVERRIDES.get(body, tuple(0.5 * x for x in nxt)))}",
            f'{indent}  <geom name="{body}_joint" type="cylinder"'
            f' fromto="0 0 {_num(-r)} 0 0 {_num(r)}" size="{_num(r)}"/>',
        ]
        if any(nxt):
            lines.append(
                f'{indent}  <geom name="{body}" type="capsule" fromto="0 0 0 {_vec(nxt)}"'
                f' size="{_num(r)}"/>'
            )
        if i == 0:  # the shoulder column below joint 2
            lines.append(
                f'{indent}  <geom name="link1_column" type="capsule" fromto="0 0 -0.18 0 0 0"'
                f' size="{_num(r)}"/>'
            )
        lines += site_lines(body, indent + "  ")
    # Flange (no joint, massless), hand and rigid fingers.
    indent += "  "
    yaw = franka.HAND_YAW
    hand_quat = (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))
    lines += [
        f'{indent}<body name="link8" pos="{_vec(franka.dh_translation(*franka.FLANGE_DH))}">',
        *site_lines("link8", indent + "  "),
        f'{indent}  <body name="hand" quat="{_vec(hand_quat)}"{grav}>',
        f"{indent}    {inertial('hand', (0.0, 0.0, 0.03))}",
        f'{indent}    <geom name="hand" type="capsule" fromto="0 -0.08 0.03 0 0.08 0.03"'
        ' size="0.03"/>',
        f'{indent}    <geom name="hand_mount" type="cylinder" fromto="0 0 0 0 0 0.02"'
        ' size="0.04"/>',
        *site_lines("hand", indent + "    "),
    ]
    for side in ("left", "right"):
        body = f"{side}_finger"
        _, offset = franka.OFFSET_FRAMES[body]
        tip = franka.OFFSET_FRAMES[f"{side}_fingertip"][1]
        lines += [
            f'{indent}    <body name="{body}" pos="{_vec(offset)}"{grav}>',
            f"{indent}      {inertial(body, tuple(0.5 * x for x in tip))}",
            f'{indent}      <geom name="{body}" type="capsule" fromto="0 0 0 {_vec(tip)}"'
            ' size="0.01"/>',
            *site_lines(body, indent + "      "),
            f"{indent}    </body>",
        ]
    lines += [f"{indent}  </body>", f"{indent}</body>"]
    for _ in range(dof + 1):
        indent = indent[:-2]
        lines.append(f"{indent}</body>")
    if worldbody_extra:
        lines.append(worldbody_extra)
    lines.append("  </worldbody>")
    if actuators:
        lines += _actuator_block(
            joints,
            _per_joint(kp, dof, "kp"),
            _per_joint(kv, dof, "kv"),
            franka.Q_LOWER,
            franka.Q_UPPER,
            franka.QD_MAX,
        )
    lines.append("</mujoco>")
    return "\n".join(lines) + "\n"


__all__ = [
    "DEFAULT_TIMESTEP",
    "FRANKA_ARMATURE",
    "FRANKA_KP",
    "FRANKA_KV",
    "FRANKA_MASSES",
    "THREE_LINK_KP",
    "THREE_LINK_KV",
    "actuator_names",
    "franka_mjcf",
    "joint_names",
    "site_names",
    "three_link_mjcf",
]
