"""PPO at scale, the ``scaling`` study: packed sweeps on one GPU (R runs as rows of one
program, :mod:`agents.run.sweep`; ``setups``: runs of environment setups that share a model,
env2 and env3, in one program against one setup's runs) and data parallelism over 1, 2 and 4
GPUs of one host (weak scaling: a fixed environment batch per GPU; strong: a fixed total
batch).

Each part is measured on its own machine and kept as ``results/scaling/<part>.json`` (the rows
and the run record); :func:`write_scaling_study` renders ``summary.json`` and ``table.csv`` from
the parts present, so either part can be measured again alone.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from agents.bench.throughput import measure_ppo, time_chunk
from agents.run.program import build
from agents.run.spec import RunSpec, preset
from agents.run.sweep import initial_rows
from agents.run.sweep_spec import SweepSpec
from mjxrmp.atomic import atomic_write
from mjxrmp.results.summary import write_study

PARTS = ("sweeps", "setups", "data_parallel")


def measure_sweep(env: str, policy: str, runs: int, iterations: int, preset_name: str,
                  seeds: int = 4, setups: tuple[str, ...] = (), **overrides: Any
                  ) -> dict[str, Any]:
    """Throughput of a packed sweep of ``runs`` rows: the environment setups ``setups`` (none:
    ``env`` alone) × ``runs // (seeds · setups)`` learning rates (log-spaced from the preset's
    value up to 3× it) × ``seeds`` seeds, one chunk of ``iterations`` timed after a warm-up
    chunk; ``overrides`` change the preset."""
    per_point = seeds * max(len(setups), 1)
    if runs % per_point:
        raise ValueError(f"runs={runs} must be a multiple of seeds × setups = {per_point}")
    base = RunSpec(env=setups[0] if setups else env, policy=policy,
                   seeds=tuple(range(seeds)), ppo=preset(preset_name, **overrides))
    lr = base.ppo.learning_rate
    points = runs // per_point
    grid = (("learning_rate", tuple(float(v) for v in np.geomspace(lr, 3 * lr, points))),)
    sweep = SweepSpec(base, grid if points > 1 or not setups else (), tuple(setups))
    program = build(sweep.points()[0][1])
    compiled_before = program.compile_seconds  # the program is shared by every ``runs``
    _, dt = time_chunk(program, initial_rows(program, sweep), iterations)
    steps = iterations * base.ppo.batch_size * runs
    return {"env": base.env, "setups": list(setups), "policy": policy, "runs": runs,
            "seeds": seeds, "points": points,
            "num_envs_per_run": base.ppo.num_envs, "iterations": iterations,
            "env_steps": steps, "seconds": dt, "steps_per_s": steps / dt,
            "iteration_s": dt / iterations,
            "compile_s": program.compile_seconds - compiled_before}


def measure_data_parallel(env: str, policy: str, devices: list[int], per_device_envs: int,
                          strong_envs: int, seeds: int, iterations: int,
                          preset_name: str) -> list[dict[str, Any]]:
    """PPO env steps/s on ``devices`` GPUs (:func:`agents.bench.throughput.measure_ppo`):
    weak scaling with ``per_device_envs × d`` environments, strong scaling with
    ``strong_envs`` (each row marked ``mode``)."""
    rows = []
    for d in devices:
        for mode, n in (("weak", per_device_envs * d), ("strong", strong_envs)):
            if d == 1 and mode == "strong" and n == per_device_envs:
                continue  # the one-GPU row is both modes' baseline
            row = measure_ppo(env, policy, d, iterations, seeds, preset_name, n, split=False)
            rows.append({**row, "mode": mode})
    return rows


def write_part(out_dir: str | Path, part: str, rows: Any, record: dict[str, Any]) -> Path:
    """``out_dir/<part>.json`` (atomically): the rows and the run record."""
    if part not in PARTS:
        raise ValueError(f"part must be one of {PARTS}, got {part!r}")
    path = Path(out_dir) / f"{part}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, json.dumps({"record": record, "rows": rows}, indent=1).encode())
    return path


def _sweep_rows(rows: list[dict]) -> tuple[list[list[str]], list[tuple[str, list[str]]]]:
    base = min(rows, key=lambda r: r["runs"])
    table = [["packed sweep", "1", f"{r['runs']} ({r['points']} × {r['seeds']} seeds)",
              str(r["runs"] * r["num_envs_per_run"]), f"{r['steps_per_s']:.3g}",
              f"{r['iteration_s']:.2f}", f"{r['steps_per_s'] / base['steps_per_s']:.2f}×"]
             for r in sorted(rows, key=lambda r: r["runs"])]
    top = max(rows, key=lambda r: r["runs"])
    head = [("sweeps", [f"packed sweep: {top['runs']} runs in one program vs {base['runs']}, "
                        "env steps/s", "–",
                        f"{top['steps_per_s'] / base['steps_per_s']:.1f}× "
                        f"({top['steps_per_s']:.3g} vs {base['steps_per_s']:.3g})"])]
    return table, head


def _setup_rows(rows: list[dict]) -> tuple[list[list[str]], list[tuple[str, list[str]]]]:
    one = next(r for r in rows if not r["setups"])
    table = []
    for r in sorted(rows, key=lambda r: (bool(r["setups"]), r["runs"])):
        names = "+".join(e.split("/")[-1] for e in r["setups"]) or r["env"].split("/")[-1]
        what = (f"{r['runs']} ({len(r['setups'])} setups × {r['points']} × {r['seeds']} seeds)"
                if r["setups"] else f"{r['runs']} ({r['seeds']} seeds)")
        table.append([f"setups packed ({names})" if r["setups"] else f"one setup ({names})",
                      "1", what, str(r["runs"] * r["num_envs_per_run"]),
                      f"{r['steps_per_s']:.3g}", f"{r['iteration_s']:.2f}",
                      f"{r['steps_per_s'] / one['steps_per_s']:.2f}×"])
    packed = min((r for r in rows if r["setups"]), key=lambda r: r["runs"])
    head = [("setups", [f"{packed['runs']} runs of {len(packed['setups'])} setups in one "
                        f"program vs {one['runs']} of one, s / iteration", "–",
                        f"{packed['iteration_s']:.2f} vs {one['iteration_s']:.2f} "
                        f"({packed['iteration_s'] / one['iteration_s']:.2f}× the time for "
                        f"{packed['runs'] / one['runs']:.0f}× the runs)"])]
    return table, head


def _dp_rows(rows: list[dict]) -> tuple[list[list[str]], list[tuple[str, list[str]]]]:
    one = next(r for r in rows if r["devices"] == 1)
    table, head = [], []
    for r in sorted(rows, key=lambda r: (r["mode"] != "weak", r["devices"])):
        ratio = r["steps_per_s"] / one["steps_per_s"]
        label = "data parallel" if r["devices"] == 1 else f"data parallel ({r['mode']})"
        table.append([label, str(r["devices"]), str(r["seeds"]),
                      f"{r['num_envs']} ({r['num_envs'] // r['devices']} per GPU)",
                      f"{r['steps_per_s']:.3g}", f"{r['iteration_s']:.2f}", f"{ratio:.2f}×"])
        if r["devices"] == max(x["devices"] for x in rows) and r["devices"] > 1:
            target = "≥ 3.5×" if r["mode"] == "weak" else "reported"
            head.append(("data_parallel", [f"PPO on {r['devices']} GPUs, {r['mode']} scaling",
                                           target, f"{ratio:.2f}×"]))
    if not head:
        head.append(("data_parallel", ["PPO on 1 GPU, env steps/s", "–",
                                       f"{one['steps_per_s']:.3g}"]))
    return table, head


def write_scaling_study(out_dir: str | Path) -> Path:
    """``summary.json`` and ``table.csv`` of the ``scaling`` study from the parts in
    ``out_dir``; ``FileNotFoundError`` when there is none."""
    out_dir = Path(out_dir)
    parts = {p: json.loads((out_dir / f"{p}.json").read_text()) for p in PARTS
             if (out_dir / f"{p}.json").exists()}
    if not parts:
        raise FileNotFoundError(f"no part ({', '.join(PARTS)}) in {out_dir}")
    table, headline = [], []
    for part, render in (("sweeps", _sweep_rows), ("setups", _setup_rows),
                         ("data_parallel", _dp_rows)):
        if part in parts:
            rows, head = render(parts[part]["rows"])
            table += rows
            headline += head
    head = {"study": "scaling", "title": "PPO at scale: packed sweeps and several GPUs",
            "report": "docs/reports/scaling.md"}
    columns = ["measurement", "GPUs", "runs (seeds)", "environments", "env steps/s",
               "s / iteration", "× first row of its kind"]
    return write_study(out_dir, head, {p: d["record"] for p, d in parts.items()}, headline,
                       ("scaling", columns, table), {p: d["rows"] for p, d in parts.items()})


__all__ = ["PARTS", "measure_data_parallel", "measure_sweep", "write_part",
           "write_scaling_study"]
