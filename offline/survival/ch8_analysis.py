"""The acceptance checks of ``scripts/reproduce_ch8.py`` computed from its results (thesis
§8.3–8.4, eq 8.3; docs/design.md §2.4):

(a) "well above BC": the mean over the three wrong rewards of a learner's mean score is at
    least BC's mean score + :data:`offline.survival.ch8.WELL_ABOVE` (10) points. Checked for
    ATAC and PSPI: it should hold on every ``-cut`` dataset and on no ``-full`` dataset;
(b) the eq 8.3 estimate (from mean normalised scores, ``Ĵ* = 100``) of ATAC and PSPI is larger
    on ``<recipe>-cut`` (and the deadline modes) than on ``<recipe>-full`` (∞ > any finite
    value);
(safety) on the filtered dataset, the collision rate (100 − safe %) of ATAC and PSPI is below
    that of BC on ``--safety-dataset`` and below their own on the unfiltered data.
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np

from offline.experiment.programs import result_rows
from offline.survival.ch8 import (
    DEADLINE_MODES,
    PESSIMISTIC,
    WELL_ABOVE,
    base_datasets,
    cell_key,
    data_path,
    filtered_name,
    load_dataset,
    split_name,
)
from offline.survival.ch8_train import standard_error
from offline.survival.rewards import WRONG_REWARDS, length_bias_statistics, positive_data_bias


def load_cells(args: Any) -> dict[tuple[str, str, str], dict]:
    """``(dataset, learner, reward) -> {mean, se, safe, success, n, scores}`` of the rows of
    ``OUT/results.jsonl`` made with the current settings (its cell keys)."""
    path = args.out / "results.jsonl"
    if not path.exists():
        raise SystemExit(f"no results at {path}: run --stage train first")
    cells = {}
    for r in result_rows(path):
        if r["cell"] != cell_key(r["dataset"], r["learner"], r["reward"], args):
            continue
        s = np.asarray(r["normalized_score"], np.float64)
        cell = cells[(r["dataset"], r["learner"], r["reward"])] = {
            "mean": float(s.mean()), "se": standard_error(s),
            "safe": float(np.mean(r["safe_pct"])),
            "success": float(np.mean(r["success_pct"])), "n": len(s), "scores": s.tolist()}
        if "curve" in r:  # --curve: steps × seeds
            points = np.asarray(r["curve"]["normalized_score"], np.float64)
            cell["curve"] = {"steps": list(r["curve"]["steps"]),
                             "mean": points.mean(axis=1).tolist(),
                             "se": [standard_error(p) for p in points]}
    return cells


def json_float(x: float) -> float | str | None:
    """JSON-safe float: ``"inf"`` for ∞, None for NaN."""
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return None
    return "inf" if math.isinf(x) else float(x)


def bias_estimates(cells: dict) -> dict[tuple[str, str], float]:
    """Eq 8.3 per (dataset, learner) with all three wrong-reward scores (means, Ĵ* = 100)."""

    out = {}
    for d, lrn in {(d, lrn) for d, lrn, _ in cells}:
        if all((d, lrn, r) in cells for r in WRONG_REWARDS):
            out[(d, lrn)] = positive_data_bias({r: cells[(d, lrn, r)]["mean"]
                                                for r in WRONG_REWARDS})
    return out


def acceptance(args: Any, cells: dict, bias: dict, lengths: dict) -> dict:
    """The acceptance checks of the module docstring, computed from ``cells``."""
    base = base_datasets(args.recipes, args.goal_deadline)
    well_above, wrong_mean = {}, {}
    for d in base:
        bc = cells.get((d, "BC", "none"))
        for lrn in PESSIMISTIC:
            if bc is None or not all((d, lrn, r) in cells for r in WRONG_REWARDS):
                continue
            m = float(np.mean([cells[(d, lrn, r)]["mean"] for r in WRONG_REWARDS]))
            wrong_mean[f"{d}/{lrn}"] = m
            well_above[f"{d}/{lrn}"] = bool(m >= bc["mean"] + WELL_ABOVE)
    biased = [v for k, v in well_above.items() if split_name(k.split("/")[0])[1]]
    unbiased = [v for k, v in well_above.items() if not split_name(k.split("/")[0])[1]]
    larger = {}
    for recipe in args.recipes:
        for lrn in PESSIMISTIC:
            full = bias.get((f"{recipe}-full", lrn))
            for mode in ("cut", *DEADLINE_MODES):
                name = recipe if mode == "cut" else f"{recipe}-{mode}"
                biased_bias = bias.get((f"{recipe}-{mode}", lrn))
                if biased_bias is not None and full is not None:
                    larger[f"{name}/{lrn}"] = bool(biased_bias > full)
    summary = {
        "reward_form": args.reward_form,
        "rule_a": f"'well above BC': mean over the wrong rewards {list(WRONG_REWARDS)} of the "
                  f"mean normalised score >= BC's mean + {WELL_ABOVE:g}; checked for "
                  f"{list(PESSIMISTIC)}",
        "wrong_reward_mean": wrong_mean,
        "bc_mean": {d: cells[(d, "BC", "none")]["mean"] for d in base
                    if (d, "BC", "none") in cells},
        "well_above_bc": well_above,
        "a_length_biased_well_above_bc": bool(all(biased)) if biased else None,
        "a_unbiased_not_well_above_bc": (not any(unbiased)) if unbiased else None,
        "rule_b": "eq 8.3 estimate (mean normalised scores, J* = 100) on <recipe>-cut (and "
                  "<recipe>-deadline, -goal, -arrive) > on <recipe>-full (inf > any finite value)",
        "bias_estimate": {f"{d}/{lrn}": json_float(v) for (d, lrn), v in sorted(bias.items())},
        "bias_larger_on_length_biased": larger,
        "b_bias_larger_on_length_biased": bool(all(larger.values())) if larger else None,
        "length_return_correlation": {d: json_float(v["length_return_correlation"])
                                      for d, v in lengths.items()},
        "cut_fraction": {d: json_float(v["cut_fraction"]) for d, v in lengths.items()},
    }
    parts = [summary["a_length_biased_well_above_bc"], summary["a_unbiased_not_well_above_bc"]]
    summary["a"] = bool(all(parts)) if None not in parts else None
    summary["b"] = summary["b_bias_larger_on_length_biased"]
    return summary


def safety_summary(args: Any, cells: dict) -> dict:
    """Return and collision rate (100 − safe %) on filtered vs unfiltered data, and BC's."""
    f, u = filtered_name(args), args.safety_dataset
    out = {"filtered_dataset": f, "unfiltered_dataset": u, "margin_m": args.margin,
           "rule": "collision rate (100 - safe %) of the learner on the filtered data < BC's "
                   "on the unfiltered data and < the learner's own on the unfiltered data",
           "rows": {}, "checks": {}}
    bc = cells.get((u, "BC", "none"))
    for name, key in (("BC", (u, "BC", "none")), ("BC (filtered)", (f, "BC", "none")),
                      *[(f"{lrn} ({tag})", (d, lrn, "original")) for lrn in PESSIMISTIC
                        for tag, d in (("unfiltered", u), ("filtered", f))]):
        if key in cells:
            c = cells[key]
            out["rows"][name] = {"score": c["mean"], "score_se": c["se"],
                                 "collision_pct": 100.0 - c["safe"], "success_pct": c["success"]}
    for lrn in PESSIMISTIC:
        fil, unf = cells.get((f, lrn, "original")), cells.get((u, lrn, "original"))
        if fil is None or unf is None or bc is None:
            continue
        out["checks"][lrn] = bool(100.0 - fil["safe"] < 100.0 - bc["safe"]
                                  and 100.0 - fil["safe"] < 100.0 - unf["safe"])
    out["all"] = bool(all(out["checks"].values())) if out["checks"] else None
    return out


def length_statistics(args: Any) -> dict[str, dict]:
    """Fig 8.5's per-dataset length/return statistics
    (:func:`offline.survival.rewards.length_bias_statistics`), computed from the datasets in
    ``OUT/data`` and cached in ``OUT/length_bias.json``, so the figures can be redrawn where
    only the results were copied (the datasets are large); cached entries fill in datasets
    that are missing."""
    cache = args.out / "length_bias.json"
    stats = json.loads(cache.read_text()) if cache.exists() else {}
    for d in base_datasets(args.recipes, args.goal_deadline):
        if data_path(args, *split_name(d)[:2]).exists():
            stats[d] = length_bias_statistics(load_dataset(args, d))
    stats = {d: stats[d] for d in base_datasets(args.recipes, args.goal_deadline) if d in stats}
    if stats:
        cache.write_text(json.dumps(stats))
    else:
        print(f"[figures] no datasets in {args.out / 'data'} and no {cache}: Fig 8.5 and the "
              f"length statistics are left out (run --stage collect first)", flush=True)
    return stats


__all__ = [
    "acceptance",
    "bias_estimates",
    "json_float",
    "length_statistics",
    "load_cells",
    "safety_summary",
]
