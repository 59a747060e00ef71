"""The Table 7.3-style table of ``scripts/reproduce_ch7.py`` and the script's :func:`run` (thesis
§7.4; docs/design.md §2.4, §6): ``OUT/table.md`` and ``OUT/table.csv`` of the ``--envs`` cells the
same command's train stage makes (same steps, seeds, network, data and expert-set sizes, terminal
handling, evaluation episodes, learner settings and control rate): mean ± standard error over seeds
per cell; in each row the entries within 90 % of the best non-Oracle score are bold (the table's
rule).
"""

from __future__ import annotations

import math
from typing import Any

import jax
import numpy as np

from offline.experiment.ch7 import SCENARIO_ORDER, cell_key, collect_stage, train_stage
from offline.experiment.programs import result_rows, run_stages
from offline.experiment.settings import setting_fields
from offline.learners.registry import TABLE_LEARNERS

#: One cell: (mean, standard error, mean safe %, seeds).
Cell = tuple[float, float, float, int]


def load_cells(args: Any) -> dict[tuple[str, str, str], Cell]:
    """``(env, scenario, learner) -> (mean, se, safe %, seeds)`` of the rows of
    ``OUT/results.jsonl`` of the ``--envs`` cells with the key ``args`` gives them (run budget,
    learner settings, expert-set size and control rate; RL-sample keys do not depend on the
    expert set). ``SystemExit`` when there are none."""
    path = args.out / "results.jsonl"
    if not path.exists():
        raise SystemExit(f"no results at {path}: run --stage train first")
    rows = [r for r in result_rows(path) if r["env"] in args.envs
            and r["cell"] == cell_key(r["env"], r["scenario"], r["learner"], args)]
    if not rows:
        settings = ", ".join(f"{k}={v}" for k, v in {
            "steps": args.steps, "seeds": args.seeds, "scale": args.scale,
            **setting_fields(args), "expert_scale": args.expert_scale,
            "substeps": args.substeps}.items())
        raise SystemExit(f"no results with {settings} in {path}")
    cells = {}
    for r in rows:
        s = np.asarray(r["normalized_score"], np.float64)
        cells[(r["env"], r["scenario"], r["learner"])] = (
            float(s.mean()), float(s.std(ddof=1) / math.sqrt(len(s))) if len(s) > 1 else 0.0,
            float(np.mean(r["safe_pct"])), len(s))
    return cells


def _fmt(mean: float, se: float, bold: bool) -> str:
    s = f"{mean:.1f} ± {se:.1f}"
    return f"**{s}**" if bold else s


def _table_row(scenario: str, env: str, here: dict[str, Cell], csv: list[str]
               ) -> tuple[str, float]:
    """The markdown row of one scenario × environment (CSV lines appended to ``csv``) and its
    bold threshold: within 90 % of the best non-Oracle score (none bold in an Oracle-only
    row)."""
    best = max((v[0] for k, v in here.items() if k != "Oracle"), default=None)
    thresh = math.inf if best is None else best - 0.1 * abs(best)
    entries = []
    for lrn in TABLE_LEARNERS:
        if lrn not in here:
            entries.append("–")
            continue
        mean, se, safe, n = here[lrn]
        bold = lrn != "Oracle" and mean >= thresh
        entries.append(_fmt(mean, se, bold))
        csv.append(f"{scenario},{env},{lrn},{mean:.3f},{se:.3f},{safe:.2f},{n},{int(bold)}")
    return f"| {scenario} | {env} | " + " | ".join(entries) + " |", thresh


def table_stage(args: Any) -> dict[str, Any]:
    """Write and print the Table 7.3-style table; return the per-cell summary: cells, how many
    have MAHALO within 90 % of the best, and per environment whether MAHALO beats BC and BCO
    in ILfO (None when BC or BCO was not run)."""
    cells = load_cells(args)
    envs = list(dict.fromkeys(env for env, _, _ in cells))
    header = ["scenario", "dataset", *TABLE_LEARNERS]
    md = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    csv = [",".join(["scenario", "dataset", "learner", "mean", "se", "safe_pct", "seeds",
                     "bold"])]
    summary: dict[str, Any] = {"cells": 0, "mahalo_within_90": 0, "mahalo_beats_bc_bco_ilfo": {}}
    for scenario in SCENARIO_ORDER:
        for env in envs:
            here = {lrn: cells[(env, scenario, lrn)] for lrn in TABLE_LEARNERS
                    if (env, scenario, lrn) in cells}
            if not here:
                continue
            line, thresh = _table_row(scenario, env, here, csv)
            md.append(line)
            summary["cells"] += 1
            if "MAHALO" in here and here["MAHALO"][0] >= thresh:
                summary["mahalo_within_90"] += 1
            if scenario == "ILfO" and "MAHALO" in here:  # None: BC or BCO not run
                summary["mahalo_beats_bc_bco_ilfo"][env] = (
                    bool(all(here["MAHALO"][0] > here[b][0] for b in ("BC", "BCO")))
                    if all(b in here for b in ("BC", "BCO")) else None)
    text = "\n".join(md)
    note = (f"\nMAHALO within 90 % of the best non-Oracle score in "
            f"{summary['mahalo_within_90']} of {summary['cells']} scenario × dataset cells; "
            f"MAHALO > BC and BCO in ILfO: {summary['mahalo_beats_bc_bco_ilfo']}\n")
    (args.out / "table.md").write_text(text + "\n" + note)
    (args.out / "table.csv").write_text("\n".join(csv) + "\n")
    print(text + "\n" + note, flush=True)
    return summary


def run(args: Any) -> None:
    """Run the selected stages of ``scripts/reproduce_ch7.py`` (collect, train, table)."""
    run_stages(args, {"collect": collect_stage, "train": train_stage, "table": table_stage},
               f"device {jax.devices()[0].device_kind}; preset {args.preset}: envs {args.envs}, "
               f"{args.seeds} seeds × {args.steps} steps, hidden {args.hidden}, "
               f"scale {args.scale}, normalize observations {args.normalize_observations}, "
               f"actor {args.actor}")


__all__ = ["load_cells", "run", "table_stage"]
