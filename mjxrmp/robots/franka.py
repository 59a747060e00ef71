"""Franka Emika Panda (thesis §6.3, docs/design.md §4.2): kinematics and control points in JAX.

The chain uses the manufacturer's modified (Craig) Denavit–Hartenberg parameters: the frame of
joint ``i`` relative to the previous one is ``RotX(α) · TransX(a) · RotZ(q_i) · TransZ(d)``,
which equals a constant translation ``(a, −sin α · d, cos α · d)`` followed by the rotation
``RotX(α) · RotZ(q_i)``. The flange ("link8") sits 0.107 m along the link-7 z-axis, the hand is
the flange rotated by −π/4 about its z-axis, and the grasp target (the end effector) lies 0.105 m
along the hand's z-axis.

48 collision control points (radii 0.01–0.1 m) are interpolated along 8 segments between named
frames, as in the original Franka configuration; on each segment the points sit at fractions
``i/n``, ``i = 1..n`` (the first endpoint is excluded).

Everything is computed in one forward-kinematics pass with elementwise operations only (rotations
by the constant DH/offset matrices are expanded into column combinations at trace time), and the
control points are interpolated elementwise between them, so the functions stay lean under
repeated ``jax.jvp``/``jax.vmap``.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from mjxrmp.robots.base import Robot

#: Modified DH parameters ``(a, d, alpha)`` of joints 1–7 (m, m, rad).
DH_PARAMS: tuple[tuple[float, float, float], ...] = (
    (0.0, 0.333, 0.0),
    (0.0, 0.0, -math.pi / 2),
    (0.0, 0.316, math.pi / 2),
    (0.0825, 0.0, math.pi / 2),
    (-0.0825, 0.384, -math.pi / 2),
    (0.0, 0.0, math.pi / 2),
    (0.088, 0.0, math.pi / 2),
)
#: Flange ("link8") parameters ``(a, d, alpha)``; no joint.
FLANGE_DH: tuple[float, float, float] = (0.0, 0.107, 0.0)
#: Rotation of the hand about the flange z-axis (rad).
HAND_YAW = -math.pi / 4
#: Distance of the grasp target along the hand z-axis (m).
GRASP_OFFSET = 0.105

#: Extra frames: ``name -> (parent frame, translation in the parent frame)``; each keeps its
#: parent's orientation. Listed in dependency order.
OFFSET_FRAMES: dict[str, tuple[str, tuple[float, float, float]]] = {
    "forearm_end_pt": ("link4", (-0.09, 0.02, 0.0)),
    "forearm_mid_pt": ("forearm_end_pt", (0.0, 0.175, 0.0)),
    "forearm_mid_pt_shifted": ("forearm_mid_pt", (0.0, 0.0, -0.05)),
    "forearm_distal": ("link5", (0.0, 0.1, 0.0)),
    "wrist_end_pt": ("link7", (0.0, 0.0, -0.07)),
    "face_left": ("hand", (0.0, 0.07, 0.04)),
    "face_right": ("hand", (0.0, -0.07, 0.04)),
    "face_back_left": ("hand", (0.0, 0.07, 0.0)),
    "face_back_right": ("hand", (0.0, -0.07, 0.0)),
    "left_finger": ("hand", (0.0, 0.03999065, 0.0584)),
    "right_finger": ("hand", (0.0, -0.03999065, 0.0584)),
    "left_fingertip": ("left_finger", (0.0, 0.0, 0.045)),
    "right_fingertip": ("right_finger", (0.0, 0.0, 0.045)),
    "grasp_target": ("hand", (0.0, 0.0, GRASP_OFFSET)),
}

#: Names of the DH frames (``link0`` is the base, ``link8`` the flange) and the hand.
CHAIN_FRAMES: tuple[str, ...] = (*(f"link{i}" for i in range(9)), "hand")
#: Every frame returned by :func:`link_frames`, in order.
FRAME_NAMES: tuple[str, ...] = (*CHAIN_FRAMES, *OFFSET_FRAMES)

#: Control-point segments ``(start frame, end frame, number of points, radius)``.
CONTROL_POINT_SEGMENTS: tuple[tuple[str, str, int, float], ...] = (
    ("link1", "link3", 10, 0.1),
    ("forearm_end_pt", "forearm_mid_pt", 5, 0.1),
    ("forearm_mid_pt_shifted", "forearm_distal", 5, 0.075),
    ("wrist_end_pt", "link8", 8, 0.05),
    ("face_back_left", "face_back_right", 5, 0.03),
    ("face_left", "face_right", 5, 0.02),
    ("hand", "left_fingertip", 5, 0.01),
    ("hand", "right_fingertip", 5, 0.01),
)
NUM_CONTROL_POINTS = sum(n for _, _, n, _ in CONTROL_POINT_SEGMENTS)
CONTROL_POINT_RADII: tuple[float, ...] = tuple(
    r for _, _, n, r in CONTROL_POINT_SEGMENTS for _ in range(n)
)

#: Default ("ready") configuration of the original implementation (rad).
DEFAULT_Q = (0.0, -0.7854, 0.0, -2.4435, 0.0, 1.6581, 0.75)
#: Position limits of the original implementation's robot model (rad).
Q_LOWER = (-2.9671, -1.8326, -2.9671, -3.1416, -2.9671, -0.0873, -2.9671)
Q_UPPER = (2.9671, 1.8326, 2.9671, 0.0, 2.9671, 3.8223, 2.9671)
#: The manufacturer's (tighter) position limits (rad).
MANUFACTURER_Q_LOWER = (-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973)
MANUFACTURER_Q_UPPER = (2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973)
#: Joint velocity limits (rad/s).
QD_MAX = (2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61)

Frame = tuple[jax.Array, jax.Array]


def _clean(x: float) -> float:
    """Snap values that are zero or ±1 up to rounding (e.g. ``cos(π/2)``) to the exact value."""
    for exact in (0.0, 1.0, -1.0):
        if abs(x - exact) < 1e-12:
            return exact
    return x


def dh_translation(a: float, d: float, alpha: float) -> tuple[float, float, float]:
    """Constant translation ``(a, −sin α · d, cos α · d)`` of a modified-DH transform."""
    return (a, _clean(-math.sin(alpha) * d), _clean(math.cos(alpha) * d))


Columns = tuple[jax.Array, jax.Array, jax.Array]


def _times_vector(cols: Columns, v: tuple[float, float, float]) -> jax.Array:
    """``R @ v`` for a constant vector, as a sum of scaled columns."""
    terms = [v[k] * cols[k] for k in range(3) if v[k] != 0.0]
    if not terms:
        return jnp.zeros_like(cols[0])
    out = terms[0]
    for t in terms[1:]:
        out = out + t
    return out


def _rotate(cols: Columns, axis: int, c: jax.Array | float, s: jax.Array | float) -> Columns:
    """Columns of ``R @ Rot_axis(θ)`` given ``c = cos θ``, ``s = sin θ`` (axis 0 = x, 2 = z).

    Rotations are kept as three column vectors so that the chain is pure elementwise
    arithmetic (no slicing or stacking), which XLA fuses into few kernels.
    """
    i, j = (1, 2) if axis == 0 else (0, 1)
    if isinstance(c, float) and isinstance(s, float):
        if s == 0.0 and c == 1.0:
            return cols
        if c == 0.0:  # ±π/2: a signed column permutation
            ci, cj = s * cols[j], -s * cols[i]
        else:
            ci, cj = c * cols[i] + s * cols[j], c * cols[j] - s * cols[i]
    else:
        ci, cj = c * cols[i] + s * cols[j], c * cols[j] - s * cols[i]
    out = list(cols)
    out[i], out[j] = ci, cj
    return (out[0], out[1], out[2])


def _frame_columns(q: jax.Array) -> dict[str, tuple[Columns, jax.Array]]:
    """Every named frame as ``(rotation columns, position)`` in one forward pass."""
    eye = jnp.eye(3, dtype=q.dtype)
    cols: Columns = (eye[0], eye[1], eye[2])
    p = jnp.zeros(3, dtype=q.dtype)
    frames = {"link0": (cols, p)}
    cos_q, sin_q = jnp.cos(q), jnp.sin(q)
    for i, (a, d, alpha) in enumerate(DH_PARAMS):
        p = p + _times_vector(cols, dh_translation(a, d, alpha))
        cols = _rotate(cols, 0, _clean(math.cos(alpha)), _clean(math.sin(alpha)))
        cols = _rotate(cols, 2, cos_q[i], sin_q[i])
        # Materialise each link frame: otherwise XLA fuses the whole chain into every consumer
        # and recomputes it per output element (3× growth per joint; 3× slower on CPU).
        cols, p = jax.lax.optimization_barrier((cols, p))
        frames[f"link{i + 1}"] = (cols, p)
    p = p + _times_vector(cols, dh_translation(*FLANGE_DH))
    frames["link8"] = (cols, p)
    frames["hand"] = (_rotate(cols, 2, math.cos(HAND_YAW), math.sin(HAND_YAW)), p)
    for name, (parent, offset) in OFFSET_FRAMES.items():
        parent_cols, parent_p = frames[parent]
        frames[name] = (parent_cols, parent_p + _times_vector(parent_cols, offset))
    return frames


def _as_float(q: jax.Array) -> jax.Array:
    q = jnp.asarray(q)
    if not jnp.issubdtype(q.dtype, jnp.floating):
        q = q.astype(jnp.result_type(float))
    return q


def link_frames(q: jax.Array) -> dict[str, Frame]:
    """All named frames ``name -> (R (3, 3), p (3,))`` in the base frame, in one FK pass.

    Names: ``link0`` (base) … ``link7``, ``link8`` (flange), ``hand`` and the offset frames of
    :data:`OFFSET_FRAMES` (forearm/wrist points, hand faces, fingers, fingertips,
    ``grasp_target``). ``R`` maps frame coordinates to base coordinates.
    """
    return {
        name: (jnp.stack(cols, axis=1), p)
        for name, (cols, p) in _frame_columns(_as_float(q)).items()
    }


def _segment_interpolation() -> tuple[tuple[str, ...], np.ndarray, np.ndarray, np.ndarray]:
    """Frames used by the control points, each point's start/end frame index and fraction."""
    names = tuple(dict.fromkeys(n for s, e, _, _ in CONTROL_POINT_SEGMENTS for n in (s, e)))
    starts, ends, fractions = [], [], []
    for start, end, n, _ in CONTROL_POINT_SEGMENTS:
        starts += [names.index(start)] * n
        ends += [names.index(end)] * n
        fractions += list(np.arange(1, n + 1) / n)
    return names, np.array(starts, np.int32), np.array(ends, np.int32), np.array(fractions)


_CP_FRAMES, _CP_START, _CP_END, _CP_FRACTION = _segment_interpolation()


def control_points(q: jax.Array) -> jax.Array:
    """The 48 collision control points in the base frame, shape ``(48, 3)``.

    Ordered by :data:`CONTROL_POINT_SEGMENTS`; radii in :data:`CONTROL_POINT_RADII`. Each point
    is ``start + t·(end − start)`` (elementwise, so it fuses with the kinematics; no matrix
    product, hence no TF32 rounding on GPUs).
    """
    frames = _frame_columns(_as_float(q))
    ends = jnp.stack([frames[n][1] for n in _CP_FRAMES])
    t = jnp.asarray(_CP_FRACTION, ends.dtype)[:, None]
    start = jnp.take(ends, jnp.asarray(_CP_START), axis=0)
    end = jnp.take(ends, jnp.asarray(_CP_END), axis=0)
    return start + t * (end - start)


def end_effector(q: jax.Array) -> jax.Array:
    """Grasp-target position (0.105 m along the hand z-axis), shape ``(3,)``."""
    return _frame_columns(_as_float(q))["grasp_target"][1]


FRANKA = Robot(
    name="franka",
    dof=7,
    workspace_dim=3,
    q_lower=Q_LOWER,
    q_upper=Q_UPPER,
    qd_max=QD_MAX,
    default_q=DEFAULT_Q,
    control_point_radii=CONTROL_POINT_RADII,
    control_points=control_points,
    end_effector=end_effector,
)
