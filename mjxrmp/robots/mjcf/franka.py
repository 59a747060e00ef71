"""MJCF of the Franka Panda (thesis §6.3, docs/design.md §4.2; the fingers are rigid).

One body per modified-DH frame (``link0`` … ``link7``, the flange ``link8``), placed by
``pos = (a, −sin α · d, cos α · d)`` and ``quat = RotX(α)``, with a hinge ``joint{i}`` about the
local z-axis limited to ``franka.Q_LOWER``/``Q_UPPER``; the ``hand`` body (flange rotated −π/4
about z) and two rigid finger bodies. Every frame of :func:`mjxrmp.robots.franka.link_frames`
has a ``<site>`` of the same name (in the body it belongs to, with that frame's orientation),
plus the site ``end_effector`` at the grasp target, so MuJoCo's forward kinematics equals
:mod:`mjxrmp.robots.franka` exactly.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

from mjxrmp.robots import franka
from mjxrmp.robots.mjcf.common import DEFAULT_TIMESTEP, document, joint_names, num, servos, vec

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

__all__ = [
    "FRANKA_ARMATURE",
    "FRANKA_KP",
    "FRANKA_KV",
    "FRANKA_MASSES",
    "RADIUS_OF_GYRATION",
    "URDF_DIAG_INERTIA",
    "franka_mjcf",
]


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


@dataclasses.dataclass(frozen=True)
class _BodyWriter:
    """Writes the Franka bodies with one set of options (see :func:`franka_mjcf`)."""

    armature: float
    damping: float
    gravity_compensation: bool
    urdf_inertia: bool
    sites: dict = dataclasses.field(default_factory=_franka_sites)

    @property
    def grav(self) -> str:
        return ' gravcomp="1"' if self.gravity_compensation else ""

    def inertial(self, body: str, com: Sequence[float]) -> str:
        m = FRANKA_MASSES[body]
        diag = URDF_DIAG_INERTIA if self.urdf_inertia else round(m * RADIUS_OF_GYRATION**2, 12)
        return f'<inertial pos="{vec(com)}" mass="{num(m)}" diaginertia="{vec((diag,) * 3)}"/>'

    def site_lines(self, body: str, indent: str) -> list[str]:
        out = []
        for name, pos in self.sites[body]:
            p = f' pos="{vec(pos)}"' if any(pos) else ""
            out.append(f'{indent}<site name="{name}"{p}/>')
        return out

    def base(self, indent: str) -> list[str]:
        """``link0``, the fixed base (opened, closed by :meth:`all`)."""
        return [
            f'{indent}<body name="link0">',
            f"{indent}  {self.inertial('link0', (0.0, 0.0, 0.07))}",
            f'{indent}  <geom name="link0" type="cylinder" fromto="0 0 0 0 0 0.15" size="0.07"/>',
            *self.site_lines("link0", indent + "  "),
        ]

    def link(self, i: int, indent: str) -> list[str]:
        """Moving link ``i + 1`` (opened): DH placement, limited hinge, inertia, geoms, sites."""
        dh = [*franka.DH_PARAMS, franka.FLANGE_DH]
        a, d, alpha = dh[i]
        quat = (math.cos(alpha / 2), math.sin(alpha / 2), 0.0, 0.0)
        nxt = franka.dh_translation(*dh[i + 1])
        r, body = _LINK_RADII[i], f"link{i + 1}"
        com = _COM_OVERRIDES.get(body, tuple(0.5 * x for x in nxt))
        lines = [
            f'{indent}<body name="{body}" pos="{vec(franka.dh_translation(a, d, alpha))}"'
            f' quat="{vec(quat)}"{self.grav}>',
            f'{indent}  <joint name="{joint_names("franka")[i]}" type="hinge" axis="0 0 1"'
            f' range="{num(franka.Q_LOWER[i])} {num(franka.Q_UPPER[i])}"'
            f' armature="{num(self.armature)}" damping="{num(self.damping)}"/>',
            f"{indent}  {self.inertial(body, com)}",
            f'{indent}  <geom name="{body}_joint" type="cylinder"'
            f' fromto="0 0 {num(-r)} 0 0 {num(r)}" size="{num(r)}"/>',
        ]
        if any(nxt):
            lines.append(f'{indent}  <geom name="{body}" type="capsule" fromto="0 0 0 {vec(nxt)}"'
                         f' size="{num(r)}"/>')
        if i == 0:  # the shoulder column below joint 2
            lines.append(f'{indent}  <geom name="link1_column" type="capsule"'
                         f' fromto="0 0 -0.18 0 0 0" size="{num(r)}"/>')
        return lines + self.site_lines(body, indent + "  ")

    def finger(self, side: str, indent: str) -> list[str]:
        """A rigid finger body (closed)."""
        body = f"{side}_finger"
        _, offset = franka.OFFSET_FRAMES[body]
        tip = franka.OFFSET_FRAMES[f"{side}_fingertip"][1]
        return [
            f'{indent}<body name="{body}" pos="{vec(offset)}"{self.grav}>',
            f"{indent}  {self.inertial(body, tuple(0.5 * x for x in tip))}",
            f'{indent}  <geom name="{body}" type="capsule" fromto="0 0 0 {vec(tip)}"'
            ' size="0.01"/>',
            *self.site_lines(body, indent + "  "),
            f"{indent}</body>",
        ]

    def flange_and_hand(self, indent: str) -> list[str]:
        """The flange ``link8`` (no joint, massless) holding the hand and fingers (closed)."""
        yaw = franka.HAND_YAW
        hand_quat = (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))
        return [
            f'{indent}<body name="link8" pos="{vec(franka.dh_translation(*franka.FLANGE_DH))}">',
            *self.site_lines("link8", indent + "  "),
            f'{indent}  <body name="hand" quat="{vec(hand_quat)}"{self.grav}>',
            f"{indent}    {self.inertial('hand', (0.0, 0.0, 0.03))}",
            f'{indent}    <geom name="hand" type="capsule" fromto="0 -0.08 0.03 0 0.08 0.03"'
            ' size="0.03"/>',
            f'{indent}    <geom name="hand_mount" type="cylinder" fromto="0 0 0 0 0 0.02"'
            ' size="0.04"/>',
            *self.site_lines("hand", indent + "    "),
            *self.finger("left", indent + "    "),
            *self.finger("right", indent + "    "),
            f"{indent}  </body>",
            f"{indent}</body>",
        ]

    def all(self) -> list[str]:
        """Every body: the base, the 7 links nested in it, the flange and the hand."""
        dof = len(franka.DH_PARAMS)
        indent = "    "
        lines = self.base(indent)
        for i in range(dof):
            indent += "  "
            lines += self.link(i, indent)
        lines += self.flange_and_hand(indent + "  ")
        for _ in range(dof + 1):
            lines.append(f"{indent}</body>")
            indent = indent[:-2]
        return lines


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
    bodies = _BodyWriter(armature, damping, gravity_compensation, urdf_inertia).all()
    servo_lines = (
        servos(joint_names("franka"), kp, kv, franka.Q_LOWER, franka.Q_UPPER, franka.QD_MAX)
        if actuators else []
    )
    return document("franka", bodies, timestep=timestep, integrator=integrator, floor=floor,
                    worldbody_extra=worldbody_extra, actuators=servo_lines)
