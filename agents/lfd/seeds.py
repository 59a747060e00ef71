"""Paired summary over seeds of Franka comparison runs (thesis §5.3.2, Fig 5.7).

Each run is the ``metrics.json`` of one :func:`agents.lfd.franka_eval.compare_strategies` run
(``scripts/lfd_franka.py``). A seed changes both the training keys of every fold and the draw of
the new starts, so each run is an independent replication of the whole Franka comparison. The
runs must agree on every setting but the seed (and where they were written); they are refused
otherwise, naming the setting (:func:`load_runs`).

Within a run all strategies are rolled out from the same starts, so the comparison of the
reference strategy with every other one is *paired by seed*: per task and metric
:func:`summarise` gives, over seeds, the mean and standard error of each strategy's value, the
mean and standard error of the paired difference (reference − other), and in how many seeds the
reference is strictly better (lower error; higher success). Pooled counts are the sums over
seeds of successful (or colliding) rollouts. :func:`markdown` renders the tables
(docs/design.md §6).
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence

import numpy as np

__all__ = ["FREE_SETTINGS", "METRICS", "POOLED", "load_runs", "markdown", "summarise"]

#: Settings that may differ between the runs of one summary.
FREE_SETTINGS = ("seed", "out", "figures", "seconds", "devices", "root")
#: (key in a strategy's metrics, label, True where lower is better, scale for the table).
METRICS = (
    ("mean_position_error", "held-out error (cm)", True, 100.0),
    ("success_rate", "goals reached (%)", False, 100.0),
    ("task_success_rate", "task success, corridor (%)", False, 100.0),
    ("success_rate_obstacle", "with obstacle (%)", False, 100.0),
    ("success_rate_no_posture", "without posture leaf (%)", False, 100.0),
)
#: Per-fold counts pooled over seeds: (fold key, label).
POOLED = (("success", "goals reached"), ("task_success", "task success (corridor)"))


def load_runs(run_dirs: Sequence[str]) -> list[dict]:
    """The ``metrics.json`` of every run directory, checked to differ only in
    :data:`FREE_SETTINGS` and to have distinct seeds and the same tasks and strategies."""
    if len(run_dirs) < 2:
        raise ValueError(f"run_dirs: need at least 2 runs to summarise over seeds, "
                         f"got {len(run_dirs)}")
    runs = []
    for d in run_dirs:
        path = os.path.join(d, "metrics.json")
        if not os.path.isfile(path):
            raise FileNotFoundError(f"run_dirs: {d!r} has no metrics.json "
                                    f"(expected the --out of a scripts/lfd_franka.py run)")
        with open(path) as fh:
            runs.append(json.load(fh))
    first = runs[0]
    for d, run in zip(run_dirs[1:], runs[1:], strict=True):
        for k in sorted(set(first["settings"]) | set(run["settings"])):
            if k in FREE_SETTINGS:
                continue
            a, b = first["settings"].get(k), run["settings"].get(k)
            if a != b:
                raise ValueError(f"run_dirs: {d!r} differs from {run_dirs[0]!r} in setting "
                                 f"{k!r} ({b!r} vs {a!r}); only the seed may differ")
        for task in first["tasks"]:
            if set(run["tasks"].get(task, {})) != set(first["tasks"][task]):
                raise ValueError(f"run_dirs: {d!r} has other strategies for task {task!r}")
    seeds = [r["settings"]["seed"] for r in runs]
    if len(set(seeds)) != len(seeds):
        raise ValueError(f"run_dirs: every run must have its own seed, got {seeds}")
    return runs


def _mean_se(values: np.ndarray) -> tuple[float, float]:
    n = values.size
    se = float(np.std(values, ddof=1) / math.sqrt(n)) if n > 1 else float("nan")
    return float(np.mean(values)), se


def summarise(runs: Sequence[dict], reference: str = "joint") -> dict:
    """Per task: per strategy the per-seed values, mean and standard error of every metric of
    :data:`METRICS`, the pooled counts of :data:`POOLED` and the obstacle collisions; per other
    strategy the paired comparison with ``reference`` (module docstring)."""
    seeds = [r["settings"]["seed"] for r in runs]
    out: dict = {"seeds": seeds, "reference": reference, "tasks": {}}
    for task, strategies in runs[0]["tasks"].items():
        if reference not in strategies:
            raise ValueError(f"reference: strategy {reference!r} is not in the runs of task "
                             f"{task!r} (have {sorted(strategies)})")
        per: dict = {}
        for s in strategies:
            ms = [r["tasks"][task][s] for r in runs]
            entry: dict = {}
            for key, _, _, _ in METRICS:
                v = np.array([m[key] for m in ms], dtype=float)
                mean, se = _mean_se(v)
                entry[key] = {"per_seed": v.tolist(), "mean": mean, "se": se}
            for key, _ in POOLED:
                entry[f"pooled_{key}"] = [int(sum(f[key] for m in ms for f in m["folds"])),
                                          int(sum(len(f["corridor_excursions"])
                                                  for m in ms for f in m["folds"]))]
            entry["pooled_colliding"] = [int(sum(m["colliding_rollouts"] for m in ms)),
                                         int(sum(m["obstacle_rollouts"] for m in ms))]
            entry["min_clearance_obstacle"] = float(min(m["min_clearance_obstacle"] for m in ms))
            entry["joint_limit_violations"] = int(sum(m["joint_limit_violations"] for m in ms))
            per[s] = entry
        comparisons: dict = {}
        for s in strategies:
            if s == reference:
                continue
            comparisons[s] = {}
            for key, _, lower, _ in METRICS:
                ref = np.array(per[reference][key]["per_seed"])
                other = np.array(per[s][key]["per_seed"])
                diff = ref - other
                mean, se = _mean_se(diff)
                better = int(np.sum(ref < other if lower else ref > other))
                comparisons[s][key] = {"mean_difference": mean, "se": se,
                                       "reference_better": better, "seeds": len(seeds)}
        out["tasks"][task] = {"strategies": per, "comparisons": comparisons}
    return out


def markdown(summary: dict) -> str:
    """The summary as markdown tables: per task, mean ± standard error over seeds and pooled
    counts; then the paired comparisons with the reference strategy."""
    ref, n = summary["reference"], len(summary["seeds"])
    lines = [f"Seeds {summary['seeds']} ({n} runs); mean ± standard error over seeds; pooled "
             f"counts summed over seeds.", ""]
    head = "| task | strategy | " + " | ".join(label for _, label, _, _ in METRICS) \
        + " | goals reached (pooled) | task success (pooled) | colliding with obstacle |"
    lines += [head, "|" + "---|" * (2 + len(METRICS) + 3)]
    for task, t in summary["tasks"].items():
        for s, e in t["strategies"].items():
            cells = [f"{e[k]['mean'] * sc:.1f} ± {e[k]['se'] * sc:.1f}"
                     for k, _, _, sc in METRICS]
            pooled = [f"{e[f'pooled_{k}'][0]}/{e[f'pooled_{k}'][1]}" for k, _ in POOLED]
            col = f"{e['pooled_colliding'][0]}/{e['pooled_colliding'][1]}"
            name = f"**{s}**" if s == ref else s
            lines.append(f"| {task} | {name} | " + " | ".join(cells + pooled + [col]) + " |")
    lines += ["", f"Paired by seed: {ref} − other (mean ± standard error of the difference; "
              f"seeds where {ref} is strictly better, of {n}).", ""]
    lines += ["| task | vs | " + " | ".join(label for _, label, _, _ in METRICS) + " |",
              "|" + "---|" * (2 + len(METRICS))]
    for task, t in summary["tasks"].items():
        for s, c in t["comparisons"].items():
            cells = [f"{c[k]['mean_difference'] * sc:+.1f} ± {c[k]['se'] * sc:.1f} "
                     f"({c[k]['reference_better']}/{n})" for k, _, _, sc in METRICS]
            lines.append(f"| {task} | {s} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
