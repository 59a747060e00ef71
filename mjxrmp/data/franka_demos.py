"""Kinesthetic Franka demonstrations: door reaching and drawer closing (thesis §5.2.3).

The data (``/work/shared/data/franka_demos``, MIT licence in that folder; never copied into the
project) has one folder per task, ``door_reaching`` and ``drawer_closing``, each with six plain
text files ``0.txt`` … ``5.txt``. Every row is one sample: ``time`` (s), the 7 joint angles (rad)
and the 2 finger widths (m). Samples arrive at an irregular ~100 Hz.

Checks (:func:`load_task`, after :func:`read_raw`'s format checks): the finger widths (below);
time in seconds, the median interval within :data:`RAW_DT_RANGE` (a file in milliseconds is
refused) and no gap longer than :data:`mjxrmp.data.lasa.MAX_GAP_FACTOR` median intervals; every
joint angle within the robot's limits (:data:`mjxrmp.robots.franka.FRANKA`) up to
:data:`JOINT_LIMIT_TOL` (a file in degrees is refused). Messages name the file, the sample and
the value.

Preprocessing (:func:`load_task`), per demonstration:

1. **Trim** the motionless head and tail: samples before the first one whose configuration moved
   more than ``trim_tol`` (max-abs over joints, rad) from the first sample, and after the last one
   that is still more than ``trim_tol`` from the final sample, are dropped (the recordings start
   and end with seconds of the robot at rest).
2. **Resample** to the fixed step ``dt`` by linear interpolation in time (the first sample is
   kept; the last resampled time is the largest multiple of ``dt`` within the recording).
3. **Velocities** by forward differences ``(q_{t+1} − q_t)/dt``, zero at the last sample (so that
   explicit Euler with the same ``dt`` reproduces the demonstration; the same rule as
   :func:`agents.lfd.flow_training.finite_difference_velocities`, restated here because ``mjxrmp``
   does not import ``agents``).
4. **Control points** (§5.2.3: "3 control points on the hand: one at the centre of the gripper
   and one at each of the tips of the two-fingered gripper"): positions by the forward kinematics
   of :mod:`mjxrmp.robots.franka`, velocities by forward differences of those positions.
   The fingertips are the model's ``left_fingertip`` / ``right_fingertip`` frames, whose lateral
   offset is the fixed open finger width ``0.03999065`` m of the robot model; every sample of
   these recordings reports exactly that width for both fingers (the gripper stayed open), which
   :func:`load_task` checks (``FINGER_WIDTH_TOL``). The centre point is selectable
   (:data:`CENTRE_FRAMES`): ``"hand"`` (default; the hand frame origin between the finger roots)
   or ``"grasp"`` (the grasp target 0.105 m along the hand axis). The grasp target lies 1.6 mm
   from the line through the two fingertips, so with ``"grasp"`` the three points are nearly
   collinear and leave the rotation about that line unobserved; the thesis draws the three
   points as the vertices of a triangle (Figs 5.1, 5.3, 5.4), which ``"hand"`` gives (a 0.10 m
   high, 0.08 m wide isosceles triangle).
5. **Goals** ``g_k``: each control point's position at the demonstration's final pose (§5.2.3:
   the subtask map is ``ψ_k = FK_k − g_k``).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mjxrmp.data.lasa import check_sampling
from mjxrmp.robots import franka

#: Default location of the demonstrations (an argument everywhere; never copied).
DEFAULT_ROOT = "/work/shared/data/franka_demos"
#: The two tasks of §5.2.3.
TASKS = ("door_reaching", "drawer_closing")
#: Columns of a row: time, 7 joint angles, 2 finger widths.
NUM_COLUMNS = 10
#: ``centre`` choice → the frame of :func:`mjxrmp.robots.franka.link_frames` used as the centre
#: control point (module docstring, step 4).
CENTRE_FRAMES = {"hand": "hand", "grasp": "grasp_target"}
#: The fingertip frames (the second and third control points).
FINGERTIP_FRAMES = ("left_fingertip", "right_fingertip")
#: Finger width of the model's fingertip frames (m).
MODEL_FINGER_WIDTH = 0.03999065
#: Largest accepted deviation of a recorded finger width from :data:`MODEL_FINGER_WIDTH` (m).
FINGER_WIDTH_TOL = 1e-3
#: Plausible median interval of the raw samples (s): 2 kHz … 5 Hz (the recordings: ~100 Hz).
RAW_DT_RANGE = (5e-4, 0.2)
#: Largest accepted excursion of a recorded joint angle beyond the robot's limits (rad).
JOINT_LIMIT_TOL = 0.05

__all__ = [
    "CENTRE_FRAMES",
    "DEFAULT_ROOT",
    "TASKS",
    "FrankaDemo",
    "StackedDemos",
    "control_point_names",
    "hand_points",
    "load_task",
    "read_raw",
    "stack",
]


@dataclasses.dataclass(frozen=True)
class FrankaDemo:
    """One preprocessed demonstration (module docstring), ``T`` samples ``dt`` apart.

    ``t (T,)`` times from 0; ``q (T, 7)``, ``qd (T, 7)``; ``fingers (T, 2)``; ``points (T, 3, 3)``
    the control points (centre, left tip, right tip) and ``point_velocities (T, 3, 3)``;
    ``goals (3, 3)`` = ``points[-1]``; ``source`` the file it came from.
    """

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    fingers: np.ndarray
    points: np.ndarray
    point_velocities: np.ndarray
    goals: np.ndarray
    dt: float
    source: str

    @property
    def length(self) -> int:
        """Number of samples ``T``."""
        return int(self.q.shape[0])


class StackedDemos(NamedTuple):
    """Demonstrations of one task padded to a common length ``T`` and stacked (a pytree).

    ``q``, ``qd (N, T, 7)``; ``points``, ``point_velocities (N, T, 3, 3)``; ``goals (N, 3, 3)``;
    ``q_goal (N, 7)`` (final configurations); ``mask (N, T)`` (1 on real samples, 0 on padding:
    the last sample repeated with zero velocity); ``lengths (N,)``.
    """

    q: jax.Array
    qd: jax.Array
    points: jax.Array
    point_velocities: jax.Array
    goals: jax.Array
    q_goal: jax.Array
    mask: jax.Array
    lengths: jax.Array


def control_point_names(centre: str = "hand") -> tuple[str, str, str]:
    """Frame names of the three control points for ``centre`` (module docstring, step 4)."""
    if centre not in CENTRE_FRAMES:
        raise ValueError(f"centre must be one of {sorted(CENTRE_FRAMES)}, got {centre!r}")
    return (CENTRE_FRAMES[centre], *FINGERTIP_FRAMES)


def hand_points(q: jax.Array, centre: str = "hand") -> jax.Array:
    """The three hand control points ``FK_k(q)`` (§5.2.3) of one configuration ``q (7,)``,
    shape ``(3, 3)`` (centre, left fingertip, right fingertip); batch with ``jax.vmap``."""
    names = control_point_names(centre)
    q = jnp.asarray(q)
    if q.shape != (franka.FRANKA.dof,):
        raise ValueError(f"q must have shape (7,), got {q.shape}; batch with jax.vmap")
    frames = franka.link_frames(q)
    return jnp.stack([frames[n][1] for n in names])


@functools.partial(jax.jit, static_argnames="centre")
def _hand_points_of_rows(q: jax.Array, centre: str) -> jax.Array:
    """:func:`hand_points` of every row of ``q`` (one compiled program per recording length,
    reused when a task is loaded again)."""
    return jax.vmap(lambda x: hand_points(x, centre))(q)


def read_raw(path: str | os.PathLike) -> np.ndarray:
    """The raw rows ``(n, 10)`` of one demonstration file (time, 7 joints, 2 finger widths),
    checked: 10 finite columns, at least 2 rows, strictly increasing time."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"demonstration file {path!r} does not exist")
    try:
        rows = np.loadtxt(path, dtype=np.float64, ndmin=2)
    except ValueError as err:
        raise ValueError(f"malformed demonstration file {path!r}: {err}") from None
    if rows.shape[1] != NUM_COLUMNS or rows.shape[0] < 2:
        raise ValueError(f"malformed demonstration file {path!r}: expected >= 2 rows of "
                         f"{NUM_COLUMNS} columns (time, 7 joint angles, 2 finger widths), "
                         f"got shape {rows.shape}")
    if not np.all(np.isfinite(rows)):
        raise ValueError(f"malformed demonstration file {path!r}: non-finite values")
    if not np.all(np.diff(rows[:, 0]) > 0):
        raise ValueError(f"malformed demonstration file {path!r}: time must increase strictly")
    return rows


def _trim(rows: np.ndarray, tol: float) -> np.ndarray:
    q = rows[:, 1:8]
    moved = np.max(np.abs(q - q[0]), axis=1) > tol
    unsettled = np.max(np.abs(q - q[-1]), axis=1) > tol
    if not moved.any() or not unsettled.any():
        return rows
    start = max(int(np.argmax(moved)) - 1, 0)
    stop = min(len(rows) - int(np.argmax(unsettled[::-1])) + 1, len(rows))
    return rows[start:stop]


def _forward_difference(x: np.ndarray, dt: float) -> np.ndarray:
    v = np.zeros_like(x)
    v[:-1] = np.diff(x, axis=0) / dt
    return v


def _preprocess(rows: np.ndarray, dt: float, trim_tol: float | None, centre: str,
                source: str) -> FrankaDemo:
    if trim_tol is not None:
        rows = _trim(rows, trim_tol)
    time = rows[:, 0] - rows[0, 0]
    t = np.arange(math.floor(time[-1] / dt + 1e-9) + 1) * dt
    if t.shape[0] < 2:
        raise ValueError(f"{source}: the recording ({time[-1]:.3f} s) is shorter than dt={dt}")
    cols = np.stack([np.interp(t, time, rows[:, j]) for j in range(1, NUM_COLUMNS)], axis=1)
    q, fingers = cols[:, :7], cols[:, 7:]
    points = np.asarray(_hand_points_of_rows(jnp.asarray(q, jnp.float32), centre), np.float64)
    return FrankaDemo(t=t, q=q, qd=_forward_difference(q, dt), fingers=fingers, points=points,
                      point_velocities=_forward_difference(points, dt), goals=points[-1].copy(),
                      dt=float(dt), source=source)


def load_task(task: str, root: str | os.PathLike = DEFAULT_ROOT, *, dt: float = 0.1,
              trim_tol: float | None = 1e-3, centre: str = "hand") -> list[FrankaDemo]:
    """Load and preprocess every demonstration of ``task`` (module docstring, steps 1–5).

    ``root`` is the data directory (default :data:`DEFAULT_ROOT`); ``dt`` the resampling step
    (s); ``trim_tol`` the motionless-head/tail tolerance (rad; ``None``: no trimming); ``centre``
    the centre control point (:data:`CENTRE_FRAMES`). Files are read in numeric order.
    """
    if task not in TASKS:
        raise ValueError(f"task must be one of {TASKS}, got {task!r}")
    if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a finite number > 0, got {dt!r}")
    if trim_tol is not None and not (math.isfinite(trim_tol) and trim_tol > 0):
        raise ValueError(f"trim_tol must be a finite number > 0 or None, got {trim_tol!r}")
    control_point_names(centre)
    folder = os.path.join(os.fspath(root), task)
    if not os.path.isdir(folder):
        raise FileNotFoundError(f"demonstration directory {folder!r} does not exist (root="
                                f"{os.fspath(root)!r} must contain {list(TASKS)})")
    names = sorted((f for f in os.listdir(folder) if f.endswith(".txt")),
                   key=lambda f: (len(f), f))
    if not names:
        raise FileNotFoundError(f"no demonstration files (*.txt) in {folder!r}")
    demos = []
    for name in names:
        path = os.path.join(folder, name)
        rows = _check_recording(read_raw(path), path)
        demos.append(_preprocess(rows, float(dt), trim_tol, centre, path))
    return demos


def _check_recording(rows: np.ndarray, path: str) -> np.ndarray:
    """The plausibility checks of the module docstring on the raw ``rows`` of file ``path``."""
    widths = rows[:, 8:]
    if np.max(np.abs(widths - MODEL_FINGER_WIDTH)) > FINGER_WIDTH_TOL:
        raise ValueError(f"{path}: finger widths {widths.min():.4f}–{widths.max():.4f} m "
                         f"differ from the model's open width {MODEL_FINGER_WIDTH} m by more "
                         f"than {FINGER_WIDTH_TOL} m; the fingertip control points assume "
                         "an open gripper")
    check_sampling(rows[:, 0], path, dt_range=RAW_DT_RANGE, uniform_rtol=None)
    lower = np.asarray(franka.FRANKA.q_lower) - JOINT_LIMIT_TOL
    upper = np.asarray(franka.FRANKA.q_upper) + JOINT_LIMIT_TOL
    q = rows[:, 1:8]
    outside = (q < lower) | (q > upper)
    if outside.any():
        k, j = (int(i) for i in np.argwhere(outside)[0])
        raise ValueError(f"{path}: joint {j + 1} angle {q[k, j]:.4g} at sample {k} (t = "
                         f"{rows[k, 0]:.6g} s) lies outside the robot's limits "
                         f"[{lower[j]:.4f}, {upper[j]:.4f}] rad (tolerance {JOINT_LIMIT_TOL} "
                         f"included); {int(outside.sum())} such values; angles must be in rad")
    return rows


def stack(demos: Sequence[FrankaDemo]) -> StackedDemos:
    """Pad ``demos`` to the longest length (the last sample repeated, zero velocities, mask 0)
    and stack them into float32 arrays (:class:`StackedDemos`)."""
    if not demos:
        raise ValueError("demos must contain at least one FrankaDemo")
    if len({d.dt for d in demos}) != 1:
        raise ValueError(f"demos must share one dt, got {sorted({d.dt for d in demos})}")
    T = max(d.length for d in demos)

    def pad(x: np.ndarray, zero: bool) -> np.ndarray:
        extra = np.repeat(np.zeros_like(x[-1:]) if zero else x[-1:], T - x.shape[0], axis=0)
        return np.concatenate([x, extra], axis=0)

    f32 = lambda xs: jnp.asarray(np.stack(xs), jnp.float32)  # noqa: E731
    return StackedDemos(
        q=f32([pad(d.q, False) for d in demos]),
        qd=f32([pad(d.qd, True) for d in demos]),
        points=f32([pad(d.points, False) for d in demos]),
        point_velocities=f32([pad(d.point_velocities, True) for d in demos]),
        goals=f32([d.goals for d in demos]),
        q_goal=f32([d.q[-1] for d in demos]),
        mask=f32([np.arange(T) < d.length for d in demos]),
        lengths=jnp.asarray([d.length for d in demos], jnp.int32),
    )
