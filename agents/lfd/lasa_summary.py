"""Summaries of the LASA evaluation (thesis §4.2.2, Figs 4.4 and 4.7; :mod:`agents.lfd.lasa_eval`).

Per shape, :func:`shape_record` collects the trajectory metrics of the reproductions
(:func:`metric_summary` of :func:`mjxrmp.metrics.trajectory.all_metrics`) and of a straight-line
baseline (:func:`straight_line`), the arrival check, the training summary and the convergence
check; over shapes, :func:`summary_table` gives the medians and the acceptance counts,
:func:`format_summary` the printed table (docs/design.md §6). Lengths are in the normalised
coordinates of :mod:`mjxrmp.data.lasa` (goal at the origin).

**Timing.** A demonstration of ``T`` samples lasts ``D = (T − 1)·dt``. The stored reproductions
run :func:`horizon_steps` ``= ⌈1.2·(T − 1)⌉`` steps of ``dt`` (``⌈1.2·(T − 1)⌉ + 1`` samples,
the last at time ``≥ 1.2·D``). The trajectory metrics compare their first ``T`` samples with the
demonstration: ``rmse`` is the **time-indexed** error (:func:`time_indexed_rmse`: the two at equal
times ``t·dt``), beside the time-free DTW distance and swept area. The **arrival check** asks
that every reproduction lie within 1 % of the workspace of the goal (:data:`ACCEPT_FINAL_ERROR`)
at its last stored sample, i.e. by ``1.2·D``.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from mjxrmp.config import check_int
from mjxrmp.metrics.trajectory import all_metrics, rmse
from mjxrmp.results.summary import load_summary, run_record, write_summary, write_text

__all__ = [
    "ACCEPT_FINAL_ERROR",
    "ARRIVAL_HORIZON",
    "STUDY",
    "arrival_times",
    "deviations",
    "format_summary",
    "headline_cells",
    "horizon_steps",
    "metric_summary",
    "shape_line",
    "shape_record",
    "shapes_table",
    "straight_line",
    "summary_table",
    "time_indexed_rmse",
    "write_study",
]

#: Acceptance: a rollout from a demonstration start ends within 1 % of the workspace size (the
#: normalised demonstrations span 1 along each axis) of the goal.
ACCEPT_FINAL_ERROR = 0.01
#: The study's identity in ``results/lfd_lasa/summary.json`` (:func:`write_study`).
STUDY = {"study": "lfd_lasa", "title": "Learning from demonstrations: LASA, 30 shapes",
         "report": "docs/reports/lfd_lasa.md"}
#: The arrival check's horizon and the stored rollouts' length, in demonstration durations.
ARRIVAL_HORIZON = 1.2


def horizon_steps(num_samples: int) -> int:
    """Steps of the stored reproductions of a demonstration of ``num_samples`` samples:
    ``⌈1.2·(T − 1)⌉`` (module docstring, "Timing"; 281 for LASA's ``T = 235``)."""
    check_int(num_samples, "num_samples", 2)
    return math.ceil(round(ARRIVAL_HORIZON * (num_samples - 1), 9))


def time_indexed_rmse(rollout: np.ndarray, demo: np.ndarray) -> float:
    """``√(mean_{t<T} ‖r_t − d_t‖²)``: the reproduction ``rollout (K, d)`` against the
    demonstration ``demo (T, d)`` at equal times ``t·dt`` (the rollout's first ``T`` samples,
    ``K ≥ T``; :func:`mjxrmp.metrics.trajectory.rmse` without resampling)."""
    rollout, demo = np.asarray(rollout), np.asarray(demo)
    if rollout.ndim != 2 or demo.ndim != 2 or rollout.shape[0] < demo.shape[0] \
            or rollout.shape[1] != demo.shape[1]:
        raise ValueError(f"rollout (K, d) must hold at least the demonstration's T samples "
                         f"(T, d); got rollout {rollout.shape}, demo {demo.shape}")
    return rmse(rollout[:demo.shape[0]], demo)


def arrival_times(rollouts: np.ndarray, num_samples: int,
                  radius: float = ACCEPT_FINAL_ERROR) -> np.ndarray:
    """The time from which each rollout ``(..., K, 2)`` (goal at the origin, one sample per
    ``dt``) stays within ``radius`` of the goal, in durations ``(T − 1)·dt`` of a demonstration
    of ``num_samples`` samples: ``(...)``; ``inf`` where its last sample (or any NaN) lies
    outside."""
    dist = np.linalg.norm(np.asarray(rollouts, np.float64), axis=-1)
    outside = ~(dist < radius)                                        # NaN counts as outside
    K = dist.shape[-1]
    last_out = np.where(outside.any(-1), K - 1 - np.argmax(outside[..., ::-1], axis=-1), -1)
    return np.where(last_out == K - 1, np.inf, (last_out + 1) / (num_samples - 1))


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
                 demo_final: np.ndarray, demo_monotone: np.ndarray, convergence: dict,
                 arrival: np.ndarray) -> dict:
    """One shape's entry of ``metrics.json``: the metrics of the first ``T`` samples of the
    ``rollouts (N, K, 2)`` (``K ≥ T``; ``rmse`` time-indexed, module docstring) against
    ``demos (N, T, 2)`` (mean and per demonstration) and of the straight-line baseline, the
    arrival check (distance to the goal at the rollouts' last sample, the :func:`horizon_steps`
    horizon, and ``arrival (N,)``, :func:`arrival_times` of the converged rollouts), the
    ``training`` summary, the converged final errors ``demo_final (N,)`` of the demonstration
    rollouts and whether ``‖ψ‖`` was monotone along each (``demo_monotone (N,)``), and the
    random-start ``convergence`` check."""
    T = demos.shape[1]
    summary = metric_summary(np.asarray(rollouts)[:, :T], demos)
    at_horizon = np.linalg.norm(np.asarray(rollouts, np.float64)[:, -1], axis=-1)
    at_horizon = np.where(np.isfinite(at_horizon), at_horizon, np.inf)
    return {
        "dt": float(dt),
        "metrics": summary["mean"],
        "per_demo": summary["per_demo"],
        "baseline_straight_line": metric_summary(straight_line(demos), demos)["mean"],
        "arrival": {"steps": int(rollouts.shape[1] - 1),
                    "distance_at_horizon": [float(d) for d in at_horizon],
                    "within_1pct_at_horizon": int(np.sum(at_horizon < ACCEPT_FINAL_ERROR)),
                    "arrival_time_over_duration": [float(t) for t in arrival]},
        **training,
        "final_error_converged": [float(d) for d in demo_final],
        "max_final_error_converged": float(demo_final.max()),
        "demo_rollouts_monotone": bool(demo_monotone.all()),
        "convergence": convergence,
    }


def shape_line(name: str, rec: dict) -> str:
    """The progress line of one shape's :func:`shape_record`."""
    m, b, c, a = rec["metrics"], rec["baseline_straight_line"], rec["convergence"], rec["arrival"]
    return (f"{name:>16s}: RMSE(t) {m['rmse']:.4f} (straight line {b['rmse']:.4f})  "
            f"DTW/len {m['dtw_normalized']:.4f}  Fréchet {m['frechet']:.4f}  "
            f"area {m['swept_error_area']:.4f}  at {ARRIVAL_HORIZON}·D: "
            f"{a['within_1pct_at_horizon']}/{len(a['distance_at_horizon'])} within 1 % (max "
            f"{max(a['distance_at_horizon']):.4f}; arrival ≤ "
            f"{max(a['arrival_time_over_duration']):.2f}·D)  | "
            f"converged {c['fraction_within_radius']:.0%} (max dist "
            f"{c['max_final_distance']:.4f}, ‖ψ‖ monotone {c['fraction_monotone']:.0%})  "
            f"converged final error {rec['max_final_error_converged']:.2e}"
            f"  min speed {c['min_speed_away_from_goal']:.2e}")


def summary_table(shapes: dict, goal_radius: float) -> dict:
    """Medians over shapes of DTW / path length, swept error area and time-indexed RMSE, the
    arrival counts at ``1.2·D``, the worst converged final error and check results, and one
    row per shape (the acceptance numbers)."""
    rows = {n: {"dtw_normalized": r["metrics"]["dtw_normalized"],
                "swept_error_area": r["metrics"]["swept_error_area"],
                "rmse": r["metrics"]["rmse"],
                "arrived": r["arrival"]["within_1pct_at_horizon"],
                "starts": len(r["arrival"]["distance_at_horizon"]),
                "max_distance_at_horizon": max(r["arrival"]["distance_at_horizon"]),
                "max_arrival_time": max(r["arrival"]["arrival_time_over_duration"]),
                "max_final_error_converged": r["max_final_error_converged"],
                "fraction_converged": r["convergence"]["fraction_within_radius"],
                "fraction_monotone": r["convergence"]["fraction_monotone"],
                "max_final_distance": r["convergence"]["max_final_distance"]}
            for n, r in shapes.items()}
    col = lambda k: np.asarray([row[k] for row in rows.values()])  # noqa: E731
    return {
        "median_dtw_normalized": float(np.median(col("dtw_normalized"))),
        "median_swept_error_area": float(np.median(col("swept_error_area"))),
        "median_rmse": float(np.median(col("rmse"))),
        "demo_starts_arrived": int(col("arrived").sum()),
        "demo_starts": int(col("starts").sum()),
        "shapes_all_arrived": int(np.sum(col("arrived") == col("starts"))),
        "arrival_horizon": ARRIVAL_HORIZON,
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
    head = (f"{'shape':>16s}  {'DTW/len':>8s}  {'area':>8s}  {'RMSE(t)':>8s}  "
            f"{'at 1.2·D':>8s}  {'dist 1.2·D':>10s}  {'conv. final':>11s}  "
            f"{'converged':>9s}  {'monotone':>8s}  {'max dist':>9s}")
    lines = [head]
    for n, r in summary["per_shape"].items():
        lines.append(f"{n:>16s}  {r['dtw_normalized']:8.4f}  {r['swept_error_area']:8.4f}  "
                     f"{r['rmse']:8.4f}  {r['arrived']:>4d}/{r['starts']:<3d}  "
                     f"{r['max_distance_at_horizon']:10.4f}  "
                     f"{r['max_final_error_converged']:11.2e}  {r['fraction_converged']:9.0%}  "
                     f"{r['fraction_monotone']:8.0%}  {r['max_final_distance']:9.2e}")
    k = summary["num_shapes"]
    lines.append(f"{'median':>16s}  {summary['median_dtw_normalized']:8.4f}  "
                 f"{summary['median_swept_error_area']:8.4f}  {summary['median_rmse']:8.4f}")
    lines.append(f"demonstration starts within 1 % of the goal at {ARRIVAL_HORIZON} × the "
                 f"demonstration's duration: {summary['demo_starts_arrived']}/"
                 f"{summary['demo_starts']} ({summary['shapes_all_arrived']}/{k} shapes with "
                 f"all); converged (max final error "
                 f"{summary['max_final_error_converged']:.2e}) within 1 %: "
                 f"{summary['shapes_demo_rollouts_within_1pct']}/{k} shapes")
    lines.append(f"all random starts within {summary['goal_radius']}: "
                 f"{summary['shapes_all_starts_converged']}/{k}; ‖ψ‖ monotone on every "
                 f"rollout: {summary['shapes_all_monotone']}/{k}")
    return "\n".join(lines)


def _spread(rows: dict, key: str) -> str:
    """``"<best shape> <value> … <worst shape> <value>"`` of one per-shape column."""
    lo = min(rows, key=lambda n: rows[n][key])
    hi = max(rows, key=lambda n: rows[n][key])
    return f"{lo} {rows[lo][key]:.4f} … {hi} {rows[hi][key]:.4f}"


def headline_cells(record: dict) -> list[list[str]]:
    """The study's headline rows ``[quantity, thesis or peer figure, ours]`` of one
    :func:`agents.lfd.lasa_eval.evaluate_shapes` record (``results/lfd_lasa/summary.json``)."""
    s, rows = record["summary"], record["summary"]["per_shape"]
    k, check = s["num_shapes"], record["convergence_check"]
    return [
        [f"demonstration starts within 1 % of the goal at {ARRIVAL_HORIZON} × the "
         f"demonstration's duration", "reproductions reach the goals (Fig 4.4)",
         f"{s['demo_starts_arrived']} / {s['demo_starts']} ({s['shapes_all_arrived']} / {k} "
         f"shapes with all)"],
        ["shapes whose demonstration rollouts end within 1 % of the goal, run to convergence",
         "all trajectories converge (Fig 4.4)", f"{s['shapes_demo_rollouts_within_1pct']} / {k}"],
        [f"shapes where {check['starts']} random starts all reach the goal "
         f"({check['goal_radius']}), run {check['steps']} steps ({check['steps_rule']})",
         "origin globally asymptotically stable (§4.2.1)",
         f"{s['shapes_all_starts_converged']} / {k} (largest final distance "
         f"{max(r['max_final_distance'] for r in rows.values()):.0e})"],
        ["shapes with ‖ψ(x)‖ non-increasing on every rollout", "single stationary point "
         "(Fig 4.7)", f"{s['shapes_all_monotone']} / {k}"],
        ["median over shapes of DTW distance / length", "reproductions closely match "
         "(qualitative)", f"{s['median_dtw_normalized']:.4f} ({_spread(rows, 'dtw_normalized')})"],
        ["median over shapes of swept error area", "—",
         f"{s['median_swept_error_area']:.4f} ({_spread(rows, 'swept_error_area')})"],
        ["median over shapes of the RMSE against the demonstration at equal times", "—",
         f"{s['median_rmse']:.4f} ({_spread(rows, 'rmse')})"],
        [f"training, {k} shapes × {record['config']['iterations']:,} iterations vmapped", "—",
         f"{record['train_seconds']:.0f} s"],
    ]


def shapes_table(record: dict) -> tuple[list[str], list[list[str]]]:
    """The report's per-shape table (columns, rows) of one record."""
    columns = ["shape", "DTW / length", "swept area", "RMSE at equal times",
               f"starts within 1 % at {ARRIVAL_HORIZON}·D", "latest arrival (D)",
               "random starts converged", "‖ψ‖ monotone"]
    rows = [[n, f"{r['dtw_normalized']:.4f}", f"{r['swept_error_area']:.4f}", f"{r['rmse']:.4f}",
             f"{r['arrived']} / {r['starts']}", f"{r['max_arrival_time']:.2f}",
             f"{r['fraction_converged']:.0%}".replace("%", " %"),
             f"{100 * r['fraction_monotone']:.1f} %"]
            for n, r in record["summary"]["per_shape"].items()]
    return columns, rows


def deviations(record: dict) -> list[str]:
    """The study's differences from the thesis, one sentence each, from one record."""
    s, cfg = record["summary"], record["config"]
    out = []
    off = [n for n, r in s["per_shape"].items() if r["fraction_monotone"] < 1.0]
    if off:
        out.append(f"‖ψ‖ rose beyond the rounding tolerance along some random-start rollouts of "
                   f"{', '.join(off)} during the {record['convergence_check']['steps']}-step "
                   f"check; the other {s['num_shapes'] - len(off)} shapes are monotone "
                   f"everywhere.")
    if cfg["time_weight"] > 0:
        out.append(f"The learned speed is also fitted to the demonstrations' timing (arrival-"
                   f"time loss, weight {cfg['time_weight']:g}, {cfg['time_anchors']} anchors "
                   f"per demonstration; agents/lfd/flow_field.py): the thesis fits velocities "
                   f"only.")
    if cfg["latent_potential"] != "norm":
        out.append(f"Latent potential {cfg['latent_potential']!r} (length "
                   f"{cfg['potential_length']:g}) instead of the original's smoothed norm; the "
                   f"thesis' example is the quadratic (§4.3.1).")
    out.append("Matrix products run at full float32 precision: with the GPU's default TF32 the "
               "flow's inverse is only about 1e-3 exact and the decrease of ‖ψ‖ held on 2 of 30 "
               "shapes.")
    out.append("Training rules not stated in the thesis (gradient clip 0.1, early stop after 250 "
               "iterations without improvement) follow the LASA reference code.")
    return out


def write_study(out_dir: str | os.PathLike, record: dict, command: str,
                figures: Sequence[str] = (), run: str = "all_shapes",
                keep: Sequence[str] = ("cpu_epoch",)) -> Path:
    """Write the study ``out_dir/summary.json`` and ``table.csv`` (docs/design.md §6) from one
    record: the headline (:func:`headline_cells`), the per-shape table ``shapes``
    (:func:`shapes_table`) and the :func:`deviations`, under the run name ``run`` with
    :func:`mjxrmp.results.summary.run_record` of ``command``. The runs named in ``keep`` of an
    existing ``summary.json`` (the CPU epoch timing) keep their records and headline rows; any
    other earlier run is replaced."""
    path = Path(out_dir) / "summary.json"
    old = load_summary(path) if path.exists() else {"runs": {}, "headline": {"rows": []}}
    runs = {n: r for n, r in old["runs"].items() if n in keep and n != run}
    kept = [r for r in old["headline"]["rows"] if r["run"] in runs]
    runs[run] = run_record(command)
    columns, rows = shapes_table(record)
    headline = [{"run": run, "cells": c} for c in headline_cells(record)] + kept
    summary = {**STUDY, "runs": runs,
               "headline": {"columns": ["quantity", "thesis or peer figure", "ours"],
                            "rows": headline},
               "tables": {"shapes": {"columns": columns, "rows": rows}},
               "deviations": deviations(record), "figures": list(figures)}
    csv = "\n".join(",".join(_csv(c) for c in [*row["cells"], row["run"]])
                    for row in [{"cells": summary["headline"]["columns"], "run": "run"},
                                *headline]) + "\n"
    write_text(Path(out_dir) / "table.csv", csv)
    return write_summary(path, summary)


def _csv(cell: str) -> str:
    """One CSV cell, quoted where it holds a comma or a quote."""
    return f'"{cell.replace(chr(34), 2 * chr(34))}"' if ("," in cell or '"' in cell) else cell
