"""Thesis chapter 6 as a study record: the hand-designed baseline, ``results/ch6/summary.json``
and ``table.csv``, and the stages of ``scripts/reproduce_ch6.py`` (:func:`reproduce`).

* ``baseline`` (:func:`evaluate_baselines`) — the hand-designed RMP² policy (the fixed
  baseline of §6.2.2, nothing learned) acting with its deterministic acceleration for
  ``episodes`` frozen episodes per setup (:func:`envs.evaluate.evaluate`), written to
  ``<runs>/hand_designed.json``; the figures draw it as a dashed line.
* ``plot`` — :func:`agents.run.ch6.plot_all`, then :func:`write_ch6_study`: the study record
  with one ``runs`` entry per trained run (its command, and the device, date and versions of
  its ``speed.json``), the headline against the thesis's statements (§6.2.4, §6.3), the main
  table (every setup and policy class, the baseline included, with each run's GPU wall time)
  and the collision-length-scale ablation, all computed from the run directories.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from agents.run.ch6 import (
    ENVS,
    LABELS,
    POLICIES,
    plot_all,
    run_dir,
    run_name,
    summary_row,
    train_all,
)
from agents.run.logs import read_csv
from envs.evaluate import evaluate
from envs.registry import make
from mjxrmp.results.summary import run_record, write_summary, write_text

HEAD = {"study": "ch6", "title": "Chapter 6: RL with RMP² residual policies (Figs 6.2–6.4)",
        "report": "docs/reports/ch6.md"}
BASELINES = "hand_designed.json"
#: The 500-iteration env3 RMP-RESIDUAL run with the original collision length scale 0.02.
ABLATION = os.path.join("ablation_sigma_e_0.02", "three_link-env3_rmp_residual_metrics.csv")
FIGURES = ["fig6_2.png", "fig6_3.png", "fig6_4.png"]
TRAIN_COMMAND = ("python scripts/reproduce_ch6.py --stage train --envs {env} --policies {policy}"
                 " --no-progress --no-profile")
#: The ``runs`` entry of the whole grid (its GPU time): every device its runs used.
GRID = "grid"


def evaluate_baselines(runs: str, envs: Sequence[str] = ENVS, episodes: int = 1024,
                       seed: int = 0) -> dict[str, Any]:
    """The ``baseline`` stage: the hand-designed policy's mean return, safe % and success % over
    ``episodes`` episodes (scenes from ``seed``) on each setup, merged into
    ``<runs>/hand_designed.json`` (other setups already there are kept); returns the file's
    content."""
    out = load_baselines(runs)
    command = (f"python scripts/reproduce_ch6.py --stage baseline --envs {' '.join(envs)} "
               f"--baseline-episodes {episodes}")
    for env in envs:
        stats = evaluate(make(env), episodes, seed)
        out[env] = {**stats, "seed": seed, "record": run_record(command)}
        print(f"hand-designed on {env}: return {stats['mean_return']:.1f}, safe "
              f"{stats['safe_pct']:.1f} %, success {stats['success_pct']:.1f} % "
              f"({episodes} episodes)")
    os.makedirs(runs, exist_ok=True)
    write_text(os.path.join(runs, BASELINES), json.dumps(out, indent=1) + "\n")
    return out


def load_baselines(runs: str) -> dict[str, Any]:
    """``<runs>/hand_designed.json`` (``{}`` when the baseline stage has not run)."""
    path = os.path.join(runs, BASELINES)
    return json.loads(Path(path).read_text()) if os.path.exists(path) else {}


def _speed(runs: str, env: str, policy: str) -> dict[str, Any]:
    path = os.path.join(run_dir(runs, env, policy), "speed.json")
    return json.loads(Path(path).read_text()) if os.path.exists(path) else {}


def _record(runs: str, env: str, policy: str) -> dict[str, Any]:
    """A trained run's ``runs`` entry from its ``speed.json`` (device, date, versions); the
    command of a packed run trains every run it was packed with (``packed_with``)."""
    speed = _speed(runs, env, policy)
    last = (speed.get("segments") or [{}])[-1]
    cell = {os.path.basename(run_dir("", e, p)): (e, p) for e in ENVS for p in LABELS}
    cells = [cell[name] for name in speed.get("packed_with", [])] or [(env, policy)]
    setups, kinds = (" ".join(dict.fromkeys(c[i] for c in cells)) for i in (0, 1))
    return {"command": TRAIN_COMMAND.format(env=setups, policy=kinds),
            "device": speed.get("device", "unknown"), "versions": last.get("versions", {}),
            "date": speed.get("date", "unknown")}


def _short(env: str) -> str:
    return env.split("/")[-1]


def _fmt_int(x: float) -> str:
    return f"{round(x):,}"


def main_table(rows: Sequence[dict], baselines: dict[str, Any],
               runs: str) -> tuple[list[str], list[list[Any]]]:
    """Columns and rows of the main table: per setup the hand-designed baseline, then each
    learned class (final reward, safe % minimum / mean, collisions, GPU wall time)."""
    columns = ["setup", "policy", "it.", "final reward (± std over seeds)",
               "safe %: min over iterations / mean", "collisions / episodes", "GPU wall (s)"]
    out = []
    for env in ENVS:
        if env in baselines:
            b = baselines[env]
            unsafe = b["episodes"] * (1.0 - b["safe_pct"] / 100.0)
            out.append([_short(env), "HAND-DESIGNED (fixed)", "—", f"{b['mean_return']:.1f}",
                        f"{b['safe_pct']:.1f} (deterministic)",
                        f"{_fmt_int(unsafe)} / {_fmt_int(b['episodes'])}", "—"])
        for r in (r for r in rows if r["env"] == env):
            wall = _speed(runs, env, r["policy"]).get("wall_s")
            out.append([_short(env), LABELS[r["policy"]], r["iterations"],
                        f"{r['final_reward']:.1f} ± {r['final_reward_std']:.1f}",
                        f"{r['min_safe_pct_100ep']:.1f} / {r['mean_safe_pct']:.1f}",
                        f"{_fmt_int(r['collisions'])} / {_fmt_int(r['episodes'])}",
                        "—" if wall is None else f"{wall:.0f}"])
    return columns, out


def grid_wall_s(runs: str) -> float:
    """The GPU wall time of every trained run (``speed.json``), summed: the grid on one GPU."""
    return sum(_speed(runs, e, p).get("wall_s", 0.0) for e in ENVS for p in POLICIES)


def _final(by: dict, env: str, policy: str) -> str:
    r = by[(env, policy)]
    return f"{r['final_reward']:.1f} ± {r['final_reward_std']:.1f}"


def headline(by: dict, wall_s: float) -> list[tuple[str, list[str]]]:
    """``(run, cells)`` rows: each thesis statement of §6.2.4 and §6.3 next to ours. A row that
    compares cells trained by different programs cites the whole grid's command where the grid
    is complete."""
    e1, e2, e3, fr = "three_link/env1", "three_link/env2", "three_link/env3", "franka"
    complete = len(by) == len(ENVS) * len(POLICIES)

    def cited(env: str, policy: str) -> str:  # a row over cells of several programs
        return GRID if complete else run_name(env, policy)

    rows: list[tuple[str, list[str]]] = []
    if all((e1, p) in by for p in POLICIES):
        rows.append((cited(e1, "rmp_residual"), [
            "env1 final reward, NN / NN-RESIDUAL / RMP-RESIDUAL", "all three about 400",
            " / ".join(f"{by[(e1, p)]['final_reward']:.1f}" for p in POLICIES)]))
    if all((e2, p) in by for p in ("nn", "rmp_residual")):
        nn, rmp = by[(e2, "nn")], by[(e2, "rmp_residual")]
        rows.append((cited(e2, "nn"), [
            "env2 final reward (mean safe %), NN vs RMP-RESIDUAL",
            "NN learns slightly faster with high variance and is unsafe; RMP-RESIDUAL similar "
            "reward, few collisions",
            f"{_final(by, e2, 'nn')} ({nn['mean_safe_pct']:.1f} %) vs "
            f"{_final(by, e2, 'rmp_residual')} ({rmp['mean_safe_pct']:.1f} %)"]))
    if all((e3, p) in by for p in POLICIES):
        ratio = by[(e3, "rmp_residual")]["final_reward"] / max(by[(e3, "nn")]["final_reward"],
                                                                1e-9)
        rows.append((cited(e3, "rmp_residual"), [
            "env3 final reward, RMP-RESIDUAL vs NN", "RMP-RESIDUAL improves by more than one-fold",
            f"{_final(by, e3, 'rmp_residual')} vs {_final(by, e3, 'nn')}, {ratio:.1f}×"]))
        rows.append((run_name(e3, "nn_residual"), [
            "env3 final reward, NN-RESIDUAL", "improves slowly, with a slope like NN's",
            _final(by, e3, "nn_residual")]))
    if all((fr, p) in by for p in ("nn_residual", "rmp_residual")):
        rows.append((cited(fr, "rmp_residual"), [
            "Franka final reward, NN-RESIDUAL vs RMP-RESIDUAL",
            "NN-RESIDUAL slightly higher after 500 iterations",
            f"{_final(by, fr, 'nn_residual')} vs {_final(by, fr, 'rmp_residual')}"]))
    rmp = [(e, by[(e, "rmp_residual")]) for e in ENVS if (e, "rmp_residual") in by]
    if rmp:
        rows.append((cited(rmp[-1][0], "rmp_residual"), [
            "RMP-RESIDUAL collisions / episodes, " + " / ".join(_short(e) for e, _ in rmp),
            "collisions kept low; zero on the Franka",
            " / ".join(f"{_fmt_int(r['collisions'])} of {_fmt_int(r['episodes'])}"
                       for _, r in rmp)]))
    if complete:
        rows.append((GRID, [
            f"the grid on one GPU: {len(ENVS)} setups × {len(POLICIES)} classes × 4 seeds × "
            "500 iterations, GPU wall time summed", "—", f"{wall_s / 60:.1f} min"]))
    return rows


def ablation_table(figures: str, by: dict) -> tuple[list[str], list[list[Any]]] | None:
    """env3 RMP-RESIDUAL with the original collision length scale σ_e = 0.02 (the metrics
    file :data:`ABLATION` under ``figures``) against the kept 0.1 (the grid's run)."""
    path = os.path.join(figures, ABLATION)
    key = ("three_link/env3", "rmp_residual")
    if not os.path.exists(path) or key not in by:
        return None
    rows = [("0.02 (original)", summary_row(*key, read_csv(path)[0])), ("0.1 (kept)", by[key])]
    return (["env3 RMP-RESIDUAL, σ_e", "it.", "final reward", "mean safe %",
             "collisions / episodes"],
            [[label, r["iterations"], f"{r['final_reward']:.1f} ± {r['final_reward_std']:.1f}",
              f"{r['mean_safe_pct']:.1f}", f"{_fmt_int(r['collisions'])} / "
              f"{_fmt_int(r['episodes'])}"] for label, r in rows])


def deviations(by: dict, wall_s: float, devices: Sequence[str] = ()) -> list[str]:
    """Where the runs differ from the thesis's statements (each sentence only when the data
    shows it); ``devices`` ran the grid."""
    e1, e3, fr = "three_link/env1", "three_link/env3", "franka"
    out = []
    env1 = [by[(e1, p)]["final_reward"] for p in POLICIES if (e1, p) in by]
    if env1 and max(env1) < 380:
        out.append(f"env1 ends at {min(env1):.0f}–{max(env1):.0f} rather than the thesis's "
                   "about 400.")
    n3, r3 = by.get((e3, "nn_residual")), by.get((e3, "rmp_residual"))
    if n3 and r3 and n3["final_reward"] > 0.8 * r3["final_reward"]:
        out.append(f"NN-RESIDUAL learns nearly as fast as RMP-RESIDUAL (env3 "
                   f"{n3['final_reward']:.1f} vs {r3['final_reward']:.1f}) where the thesis "
                   "found it slow: it starts from the hand-designed RMP² policy (σ_e = 0.1) "
                   "under a ±1 rad/s² clip.")
    nf, rf = by.get((fr, "nn_residual")), by.get((fr, "rmp_residual"))
    if rf and rf["collisions"] > 0:
        out.append(f"RMP-RESIDUAL collides on the Franka in {_fmt_int(rf['collisions'])} of "
                   f"{_fmt_int(rf['episodes'])} training episodes "
                   f"({100 * rf['collisions'] / rf['episodes']:.2f} %); the thesis reports "
                   "zero collisions.")
    if nf and rf and nf["final_reward"] < rf["final_reward"]:
        out.append(f"On the Franka RMP-RESIDUAL ends above NN-RESIDUAL "
                   f"({rf['final_reward']:.1f} vs {nf['final_reward']:.1f}); in the thesis "
                   "NN-RESIDUAL is slightly higher.")
    if wall_s > 30 * 60:
        on = f" ({', '.join(devices)})" if devices else ""
        out.append(f"The grid takes {wall_s / 60:.1f} min of GPU time{on}, above the 30-minute "
                   "target.")
    return out


def write_ch6_study(figures: str, runs: str, summary: dict[str, Any]) -> Path:
    """``figures/summary.json`` and ``figures/table.csv`` (the main table) from the plot
    stage's ``summary`` and the run directories under ``runs``."""
    by = {(r["env"], r["policy"]): r for r in summary["rows"]}
    baselines = load_baselines(runs)
    wall = grid_wall_s(runs)
    records = {run_name(e, p): _record(runs, e, p) for e, p in sorted(by)}
    devices = sorted({r["device"] for r in records.values()} - {"unknown"})
    if len(by) == len(ENVS) * len(POLICIES):
        newest = max(records.values(), key=lambda r: r["date"])
        records[GRID] = {"command": TRAIN_COMMAND.format(env=" ".join(ENVS),
                                                         policy=" ".join(POLICIES)),
                         "device": ", ".join(devices), "versions": newest["versions"],
                         "date": newest["date"]}
    records.update({run_name(e, "hand_designed"): b["record"]
                    for e, b in baselines.items()})
    columns, rows = main_table(summary["rows"], baselines, runs)
    tables = {"main": {"columns": columns, "rows": rows}}
    ablation = ablation_table(figures, by)
    if ablation is not None:
        tables["ablation"] = {"columns": ablation[0], "rows": ablation[1]}
    heads = headline(by, wall)
    study = {**HEAD, "runs": records,
             "headline": {"columns": ["quantity", "thesis or peer figure", "ours"],
                          "rows": [{"run": run, "cells": cells} for run, cells in heads]},
             "tables": tables, "deviations": deviations(by, wall, devices),
             "figures": [f for f in FIGURES if os.path.exists(os.path.join(figures, f))]}
    csv = "\n".join(",".join(f'"{c}"' if "," in str(c) else str(c) for c in row)
                    for row in [columns, *rows]) + "\n"
    write_text(os.path.join(figures, "table.csv"), csv)
    return write_summary(os.path.join(figures, "summary.json"), study)


def reproduce(stage: str, runs: str, figures: str, smooth: int = 100,
              baseline_episodes: int = 1024, **train: Any) -> dict[str, Any] | None:
    """Run the ``train``, ``baseline`` and/or ``plot`` stage (``stage``: ``all`` or one of
    them); ``train`` holds :func:`agents.run.ch6.train_all`'s settings (its ``envs`` also
    choose the baseline's setups). Returns the summary of the plot stage."""
    if stage in ("all", "train"):
        train_all(runs, **train)
    if stage in ("all", "baseline"):
        evaluate_baselines(runs, train.get("envs", ENVS), baseline_episodes)
    if stage in ("all", "plot"):
        summary = plot_all(runs, figures, smooth, load_baselines(runs))
        write_ch6_study(figures, runs, summary)
        return summary
    return None


__all__ = ["ABLATION", "BASELINES", "GRID", "deviations", "evaluate_baselines", "grid_wall_s",
           "headline", "load_baselines", "main_table", "reproduce", "write_ch6_study"]
