"""The ``peers`` study (``results/peers/summary.json`` and ``table.csv``): the rows of
:func:`agents.bench.peers.run_peers`, one run per device and layout, so that a GPU run adds or
replaces its own rows and keeps the CPU rows (and the other way round)."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

from agents.bench.peer_common import PolicyNet
from agents.ppo import PPOConfig
from mjxrmp.results.summary import run_record, write_summary, write_text

COLUMNS = ["device", "layout", "trainer", "seeds × environments", "env steps (per policy)",
           "env steps/s (steady)", "wall s", "compile + set-up s", "eval return", "eval success %"]
_TRAINER_ORDER = {"ours": 0, "brax": 1, "rejax": 2}


def settings_table(config: PPOConfig, net: PolicyNet) -> list[list[str]]:
    """``[setting, value]`` rows of what every trainer shares (environments aside)."""
    return [
        ["unroll (rollout) length", str(config.rollout_length)],
        ["minibatches × epochs", f"{config.num_minibatches} × {config.update_epochs}"],
        ["learning rate", f"{config.learning_rate:g}"],
        ["γ / GAE λ / clip ε", f"{config.gamma:g} / {config.gae_lambda:g} / {config.clip_eps:g}"],
        ["value / entropy coefficient", f"{config.vf_coef:g} / {config.ent_coef:g}"],
        ["gradient clipping", "none" if config.max_grad_norm is None
         else f"global norm {config.max_grad_norm:g}"],
        ["advantage / observation normalisation",
         f"{config.normalize_advantages} / {config.normalize_observations}"],
        ["policy MLP", f"{net.hidden_sizes} {net.activation}, Gaussian, log-std "
                       f"{net.log_std_init:g} (state-independent)"],
        ["value MLP", f"{config.value_hidden_sizes} {config.value_activation}"],
    ]


def run_name(device: str, layout: str) -> str:
    """The run key of a device and layout, e.g. ``thesis_nvidia_h100_80gb_hbm3``."""
    slug = re.sub(r"[^a-z0-9]+", "_", device.lower()).strip("_")
    return f"{layout}_{slug}"


def _rate(x: float) -> str:
    return f"{x:.3g}"


def _table_row(row: dict[str, Any]) -> list[str]:
    who = f"{row['seeds']} × {row['num_envs']}"
    if "error" in row:
        return [row["device"], row["layout"], row["trainer"], who, "—", row["error"][:80],
                "—", "—", "—", "—"]
    return [row["device"], row["layout"], row["trainer"], who,
            f"{row['env_steps']} ({row['policy_env_steps']})",
            _rate(row["steps_per_s"]), f"{row['wall_s']:.1f}", f"{row['compile_s']:.1f}",
            f"{row['eval_return']:.1f}", f"{row['eval_success_pct']:.0f}"]


def _headline(run: str, rows: list[dict[str, Any]]) -> dict[str, Any] | None:
    """Ours against the fastest peer (steady env steps/s) for one run, or None without both; a
    peer without a finished row in the run (not run, failed, cut short) is named as not
    measured, so the fastest peer shown is only the fastest of those measured."""
    ok = [r for r in rows if "error" not in r]
    ours = [r for r in ok if r["trainer"] == "ours"]
    peers = [r for r in ok if r["trainer"] != "ours"]
    if not ours or not peers:
        return None
    best = max(peers, key=lambda r: r["steps_per_s"])
    quantity = (f"{best['env']} PPO, {best['layout']} layout ({best['num_envs']} environments "
                f"× {best['rollout_length']} steps per iteration): steady env steps/s, fastest "
                "peer / ours (seeds × environments, × the peer)")
    cells = " / ".join(f"{_rate(r['steps_per_s'])} ({r['seeds']} × {r['num_envs']}, "
                       f"{r['steps_per_s'] / best['steps_per_s']:.2f}×)" for r in ours)
    measured = {r["trainer"] for r in peers}
    missing = [t for t in _TRAINER_ORDER if t not in measured | {"ours"}]
    fastest = f"{_rate(best['steps_per_s'])} ({best['trainer']})" + (
        f"; not measured in this run: {', '.join(missing)}" if missing else "")
    return {"run": run, "cells": [quantity, fastest, cells]}


def _key(row: dict[str, Any]) -> tuple:
    """What a new row replaces: the row of the same device, layout, trainer and size."""
    return row["device"], row["layout"], row["trainer"], row["seeds"], row["num_envs"]


def _read(path: Path) -> dict[str, Any] | None:
    return json.loads(path.read_text()) if path.exists() else None


def write_peers(rows: list[dict[str, Any]], out_dir: Path, command: str,
                settings: list[list[str]], device: str | None = None) -> Path:
    """Write ``out_dir/summary.json`` and ``table.csv`` with ``rows`` (measured now on
    ``device``, default this machine's) replacing the earlier rows of the same device, layout,
    trainer and size; every other row is kept (the run of a device and layout is the latest
    command that wrote one of its rows)."""
    record = run_record(command, device)
    new = [{**r, "device": record["device"]} for r in rows]
    mine = {_key(r) for r in new}
    old = _read(out_dir / "summary.json")
    kept = [r for r in (old["raw"]["rows"] if old else []) if _key(r) not in mine]
    every = sorted(kept + new, key=lambda r: (r["device"], r["layout"],
                                              _TRAINER_ORDER.get(r["trainer"], 9), r["seeds"]))
    fresh = {(r["device"], r["layout"]) for r in new}
    runs = {run_name(d, lay): (old["runs"][run_name(d, lay)] if (d, lay) not in fresh else record)
            for d, lay in dict.fromkeys((r["device"], r["layout"]) for r in every)}
    headline = [h for run in runs
                if (h := _headline(run, [r for r in every
                                          if run_name(r["device"], r["layout"]) == run]))]
    if not headline:  # the schema needs a row; say what is missing
        run = next(iter(runs))
        headline = [{"run": run, "cells": ["ours vs the fastest peer", "not measured",
                                           "not measured"]}]
    table = [_table_row(r) for r in every]
    summary = {
        "study": "peers", "title": "PPO peers side by side",
        "report": "docs/reports/peers.md", "runs": runs,
        "headline": {"columns": ["quantity", "fastest peer", "ours"], "rows": headline},
        "tables": {"runs": {"columns": COLUMNS, "rows": table},
                   "settings": {"columns": ["setting (every trainer)", "value"],
                                "rows": settings}},
        "deviations": ["A speed comparison: each trainer runs a few iterations of the thesis "
                       "preset, not the thesis' 500, so the returns compare trainers at equal "
                       "environment steps, not trained policies."],
        "raw": {"rows": every},
    }
    csv = "\n".join(",".join(f'"{c}"' if "," in str(c) else str(c) for c in line)
                    for line in [COLUMNS, *table]) + "\n"
    write_text(out_dir / "table.csv", csv)
    return write_summary(out_dir / "summary.json", summary)


__all__ = ["COLUMNS", "run_name", "settings_table", "write_peers"]
