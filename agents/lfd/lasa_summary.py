"""Summaries of the LASA evaluation (thesis §4.2.2, Figs 4.4 and 4.7; :mod:`agents.lfd.lasa_eval`).

Per shape, :func:`shape_record` collects the trajectory metrics of the reproductions
(:func:`metric_summary` of :func:`mjxrmp.metrics.trajectory.all_metrics`) and of a straight-line
baseline (:func:`straight_line`), the training summary and the convergence check; over shapes,
:func:`summary_table` gives the medians and the acceptance counts, :func:`format_summary` the
printed table (docs/design.md §6). Lengths are in the normalised coordinates of
:mod:`mjxrmp.data.lasa` (goal at the origin).
"""

from __future__ import annotations

import numpy as np

from mjxrmp.metrics.trajectory import all_metrics

__all__ = [
    "ACCEPT_FINAL_ERROR",
    "format_summary",
    "metric_summary",
    "shape_line",
    "shape_record",
    "straight_line",
    "summary_table",
]

#: Acceptance: a rollout from a demonstration start ends within 1 % of the workspace size (the
#: normalised demonstrations span 1 along each axis) of the goal.
ACCEPT_FINAL_ERROR = 0.01


def straight_line(demos: np.ndarray) -> np.ndarray:
    """Uniform-speed straight line from each demonstration's start to the goal (origin), as many
    samples as the demonstration: ``(N, T, 2)``."""
    T = demos.shape[1]
    return demos[:, :1] * (1.0 - np.linspace(0.0, 1.0, T))[None, :, None]


def metric_summary(rollouts: np.ndarray, demos: np.ndarray) -> dict:
    """:func:`mjxrmp.metrics.trajectory.all_metrics` between each rollout ``(N, T, 2)`` and its
    demonstration: ``{"mean": {metric: mean over demonstrations}, "per_demo": {metric: list}}``."""
    per = [all_metrics(r, d) for r, d in zip(rollouts, demos, strict=True)]
    keys = list(per[0])
    return {"mean": {k: float(np.mean([p[k] for p in per])) for k in keys},
            "per_demo": {k: [float(p[k]) for p in per] for k in keys}}


def shape_record(demos: np.ndarray, rollouts: np.ndarray, dt: float, training: dict,
                 demo_final: np.ndarray, demo_monotone: np.ndarray, convergence: dict) -> dict:
    """One shape's entry of ``metrics.json``: the metrics of the ``rollouts (N, T, 2)`` against
    ``demos`` (mean and per demonstration) and of the straight-line baseline, the ``training``
    summary, the converged final errors ``demo_final (N,)`` of the demonstration rollouts and
    whether ``‖ψ‖`` was monotone along each (``demo_monotone (N,)``), and the random-start
    ``convergence`` check."""
    summary = metric_summary(rollouts, demos)
    return {
        "dt": float(dt),
        "metrics": summary["mean"],
        "per_demo": summary["per_demo"],
        "baseline_straight_line": metric_summary(straight_line(demos), demos)["mean"],
        **training,
        "final_error_converged": [float(d) for d in demo_final],
        "max_final_error_converged": float(demo_final.max()),
        "demo_rollouts_monotone": bool(demo_monotone.all()),
        "convergence": convergence,
    }


def shape_line(name: str, rec: dict) -> str:
    """The progress line of one shape's :func:`shape_record`."""
    m, b, c = rec["metrics"], rec["baseline_straight_line"], rec["convergence"]
    return (f"{name:>16s}: RMSE {m['rmse']:.4f} (straight line {b['rmse']:.4f})  "
            f"DTW/len {m['dtw_normalized']:.4f}  Fréchet {m['frechet']:.4f}  "
            f"area {m['swept_error_area']:.4f}  final {m['final_point_error']:.4f}  | "
            f"converged {c['fraction_within_radius']:.0%} (max dist "
            f"{c['max_final_distance']:.4f}, ‖ψ‖ monotone {c['fraction_monotone']:.0%})  "
            f"converged final error {rec['max_final_error_converged']:.2e}"
            f"  min speed {c['min_speed_away_from_goal']:.2e}")


def summary_table(shapes: dict, goal_radius: float) -> dict:
    """Medians over shapes of DTW / path length and swept error area, the worst converged
    final error and check results, and one row per shape (the acceptance numbers)."""
    rows = {n: {"dtw_normalized": r["metrics"]["dtw_normalized"],
                "swept_error_area": r["metrics"]["swept_error_area"],
                "max_final_error_converged": r["max_final_error_converged"],
                "fraction_converged": r["convergence"]["fraction_within_radius"],
                "fraction_monotone": r["convergence"]["fraction_monotone"],
                "max_final_distance": r["convergence"]["max_final_distance"]}
            for n, r in shapes.items()}
    col = lambda k: np.asarray([row[k] for row in rows.values()])  # noqa: E731
    return {
        "median_dtw_normalized": float(np.median(col("dtw_normalized"))),
        "median_swept_error_area": float(np.median(col("swept_error_area"))),
        "max_final_error_converged": float(col("max_final_error_converged").max()),
        "shapes_demo_rollouts_within_1pct": int(np.sum(col("max_final_error_converged")
                                                       < ACCEPT_FINAL_ERROR)),
        "shapes_all_starts_converged": int(np.sum(col("fraction_converged") == 1.0)),
        "shapes_all_monotone": int(np.sum(col("fraction_monotone") == 1.0)),
        "num_shapes": len(rows),
        "goal_radius": goal_radius,
        "per_shape": rows,
    }


def format_summary(summary: dict) -> str:
    """The summary table as text (one line per shape, then the medians)."""
    head = (f"{'shape':>16s}  {'DTW/len':>8s}  {'area':>8s}  {'conv. final':>11s}  "
            f"{'converged':>9s}  {'monotone':>8s}  {'max dist':>9s}")
    lines = [head]
    for n, r in summary["per_shape"].items():
        lines.append(f"{n:>16s}  {r['dtw_normalized']:8.4f}  {r['swept_error_area']:8.4f}  "
                     f"{r['max_final_error_converged']:11.2e}  {r['fraction_converged']:9.0%}  "
                     f"{r['fraction_monotone']:8.0%}  {r['max_final_distance']:9.2e}")
    k = summary["num_shapes"]
    lines.append(f"{'median':>16s}  {summary['median_dtw_normalized']:8.4f}  "
                 f"{summary['median_swept_error_area']:8.4f}  "
                 f"{summary['max_final_error_converged']:11.2e} (max)")
    lines.append(f"demonstration rollouts within 1 % of the goal: "
                 f"{summary['shapes_demo_rollouts_within_1pct']}/{k} shapes; all random starts "
                 f"within {summary['goal_radius']}: {summary['shapes_all_starts_converged']}/{k};"
                 f" ‖ψ‖ monotone on every rollout: {summary['shapes_all_monotone']}/{k}")
    return "\n".join(lines)
