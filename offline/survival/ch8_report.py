"""The figures stage of ``scripts/reproduce_ch8.py`` and the script's :func:`run` (thesis
§8.3–8.4; docs/design.md §2.4, §6): ``fig8_4.png``, ``fig8_5.png``, ``fig8_6.png``,
``fig8_curves.png`` (:mod:`offline.survival.ch8_figures`), ``table.md`` / ``table.csv``,
``safety.md`` / ``safety.json`` and ``summary.json`` with the acceptance checks
(:mod:`offline.survival.ch8_analysis`).
"""

from __future__ import annotations

import json
import math
from typing import Any

import jax

from offline.experiment.programs import run_stages
from offline.survival.ch8 import LEARNERS, REWARD_FORM_TEXT, collect_stage
from offline.survival.ch8_analysis import (
    acceptance,
    bias_estimates,
    length_statistics,
    load_cells,
    safety_summary,
)
from offline.survival.ch8_figures import plot_curves, plot_scores
from offline.survival.ch8_train import train_stage
from offline.survival.rewards import REWARD_VARIANTS


def results_table(cells: dict, bias: dict) -> tuple[list[str], list[str]]:
    """``(markdown lines, CSV lines)`` of the results: per dataset and learner the mean ± s.e.
    per data reward, BC's mean and the eq 8.3 estimate (the CSV has one line per cell)."""
    datasets = list(dict.fromkeys(d for d, _, _ in cells))
    header = ["dataset", "learner", *REWARD_VARIANTS, "BC", "bias (eq 8.3)"]
    md = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    csv = ["dataset,learner,reward,mean,se,safe_pct,success_pct,seeds,bias"]
    for d in datasets:
        bc = cells.get((d, "BC", "none"))
        for lrn in LEARNERS:
            rewards = ["none"] if lrn == "BC" else list(REWARD_VARIANTS)
            here = {r: cells[(d, lrn, r)] for r in rewards if (d, lrn, r) in cells}
            if not here:
                continue
            b = bias.get((d, lrn))
            for r, c in here.items():
                csv.append(f"{d},{lrn},{r},{c['mean']:.3f},{c['se']:.3f},{c['safe']:.2f},"
                           f"{c['success']:.2f},{c['n']},{'' if b is None else b}")
            if lrn == "BC":
                continue
            entries = [f"{here[r]['mean']:.1f} ± {here[r]['se']:.1f}" if r in here else "–"
                       for r in REWARD_VARIANTS]
            bc_text = "–" if bc is None else f"{bc['mean']:.1f}"
            b_text = "–" if b is None else ("∞" if math.isinf(b) else f"{b:.2f}")
            md.append(f"| {d} | {lrn} | " + " | ".join(entries) + f" | {bc_text} | {b_text} |")
    return md, csv


def _write_safety(args: Any, safety: dict) -> None:
    """``safety.md`` and ``safety.json`` (printed too)."""
    srows = ["| policy | score | collision % | success % |", "|---|---|---|---|"]
    srows += [f"| {k} | {v['score']:.1f} ± {v['score_se']:.1f} | {v['collision_pct']:.1f} | "
              f"{v['success_pct']:.1f} |" for k, v in safety["rows"].items()]
    (args.out / "safety.md").write_text(
        f"Safety from filtered data (thesis §8.4.2): {safety['filtered_dataset']} = "
        f"{safety['unfiltered_dataset']} without transitions of clearance < "
        f"{safety['margin_m']} m.\n\n" + "\n".join(srows) +
        f"\n\nRule: {safety['rule']}. Checks: {safety['checks']} → {safety['all']}\n")
    (args.out / "safety.json").write_text(json.dumps(safety, indent=1))
    print((args.out / "safety.md").read_text(), flush=True)


def figures_stage(args: Any) -> dict:
    """Write the figures, tables, safety report and acceptance summary; return the summary."""
    cells = load_cells(args)
    bias = bias_estimates(cells)
    lengths = length_statistics(args)
    md, csv = results_table(cells, bias)
    summary = acceptance(args, cells, bias, lengths)
    safety = safety_summary(args, cells)
    summary["safety"] = safety["all"] if args.safety else None
    note = (f"\n(a) ATAC/PSPI with wrong rewards well above BC on every length-biased dataset: "
            f"{summary['a_length_biased_well_above_bc']}; on no unbiased dataset: "
            f"{summary['a_unbiased_not_well_above_bc']}  ({summary['rule_a']})\n"
            f"(b) bias estimate larger with length bias: {summary['b']} "
            f"{summary['bias_larger_on_length_biased']}\n"
            f"True reward's form: {args.reward_form} ({REWARD_FORM_TEXT[args.reward_form]})\n")
    (args.out / "table.md").write_text("\n".join(md) + "\n" + note)
    (args.out / "table.csv").write_text("\n".join(csv) + "\n")
    (args.out / "summary.json").write_text(json.dumps(summary, indent=1))
    plot_scores(args, cells, bias, lengths)
    plot_curves(args, cells)
    print("\n".join(md) + "\n" + note, flush=True)
    if not args.safety or not safety["rows"]:
        print("[figures] --no-safety, or no filtered-data or safety-dataset cells: safety.md "
              "is left out", flush=True)
        return summary
    _write_safety(args, safety)
    return summary


def run(args: Any) -> None:
    """Run the selected stages of ``scripts/reproduce_ch8.py`` (collect, train, figures)."""
    run_stages(
        args, {"collect": collect_stage, "train": train_stage, "figures": figures_stage},
        f"device {jax.devices()[0].device_kind}; preset {args.preset}: datasets "
        f"{args.datasets}, learners {args.learners}, rewards {args.rewards}, {args.seeds} "
        f"seeds × {args.steps} steps, hidden {args.hidden}, scale {args.scale}, normalize "
        f"observations {args.normalize_observations}, actor {args.actor}, reward form "
        f"{args.reward_form}")


__all__ = ["figures_stage", "results_table", "run"]
