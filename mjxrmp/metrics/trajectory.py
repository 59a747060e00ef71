"""Trajectory-comparison metrics for learning from demonstrations (thesis chapters 4–5).

One shared implementation of the metrics docs/design.md §2.3 and §4.6 list for the LASA and
Franka experiments, gathered here under one name (and :func:`all_metrics` for every metric of a
pair at once):

* :mod:`mjxrmp.metrics.pointwise` — RMSE, the thesis' own mean position error (§5.3.2),
  final-point error, and the per-sample distance to a set of demonstrated paths (corridor
  tests such as the Franka "task success");
* :mod:`mjxrmp.metrics.warping` — true dynamic-time-warping (DTW) distance, DTW per
  warping-path step, and the discrete Fréchet distance;
* :mod:`mjxrmp.metrics.area` — swept error area (2-D);
* :mod:`mjxrmp.metrics.resampling` — the shared input checks and normalised-time resampling.

The thesis gives no equations for these metrics; where a choice was needed it is stated in the
function's docstring. Every metric takes two trajectories ``a (T, d)`` and ``b (S, d)`` (rows
are samples in time order, columns are coordinates) and returns a float; all are symmetric in
``(a, b)``, so the argument order (reproduction, demonstration) is a convention. NumPy functions
compute in float64 and return Python floats; the ``*_jax`` functions are pure, ``jax.jit``- and
``jax.vmap``-able versions (float32 unless x64 is enabled). Non-finite values are not rejected
(a diverged rollout gives ``nan``/``inf`` metrics rather than an exception).
"""

from __future__ import annotations

from mjxrmp.metrics.area import swept_error_area, swept_error_area_jax
from mjxrmp.metrics.pointwise import (
    distance_to_paths,
    final_point_error,
    final_point_error_jax,
    mean_error,
    mean_error_jax,
    rmse,
    rmse_jax,
)
from mjxrmp.metrics.resampling import as_float64, check_pair, resample, resample_jax
from mjxrmp.metrics.warping import (
    dtw,
    dtw_jax,
    dtw_normalized,
    dtw_normalized_jax,
    dtw_path,
    frechet,
    frechet_jax,
    warping_table,
)

__all__ = [
    "all_metrics",
    "distance_to_paths",
    "dtw",
    "dtw_jax",
    "dtw_normalized",
    "dtw_normalized_jax",
    "dtw_path",
    "final_point_error",
    "final_point_error_jax",
    "frechet",
    "frechet_jax",
    "mean_error",
    "mean_error_jax",
    "resample",
    "resample_jax",
    "rmse",
    "rmse_jax",
    "swept_error_area",
    "swept_error_area_jax",
]


def all_metrics(a, b) -> dict[str, float]:
    """Every metric of this module for one pair (NumPy): keys ``rmse``, ``mean_error``, ``dtw``,
    ``dtw_normalized``, ``frechet``, ``final_point_error`` and, for 2-D trajectories with at
    least two samples each, ``swept_error_area``."""
    check_pair(a, b)
    a = as_float64(a)
    b = as_float64(b)
    table, steps = warping_table(a, b, "dtw")
    out = {
        "rmse": rmse(a, b),
        "mean_error": mean_error(a, b),
        "dtw": float(table[-1, -1]),
        "dtw_normalized": float(table[-1, -1] / steps[-1, -1]),
        "frechet": frechet(a, b),
        "final_point_error": final_point_error(a, b),
    }
    if a.shape[1] == 2 and min(a.shape[0], b.shape[0]) >= 2:
        out["swept_error_area"] = swept_error_area(a, b)
    return out
