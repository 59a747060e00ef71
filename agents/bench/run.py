"""The benchmark of ``scripts/bench.py``: RMP² evaluations per second, latency, environment and
PPO throughput and (optionally) offline-learner gradient steps per second, written as JSON after
every row so that a run cut short still leaves its numbers.

``settings`` is the script's argument dictionary (:func:`fill_defaults` completes it): for each
robot the RMP² single-state latency and batched throughput at ``batches``, the same for the
naive baseline at ``naive_batches``; control steps/s of ``envs`` at ``env_batches`` with random
and RMP² actions; PPO rows (``ppo``: ``ENV:POLICY`` items) over ``ppo_devices``; offline rows
(``offline``: learner names, measured by the ``offline_measure`` the caller passes — the
script passes :func:`offline.experiment.bench.measure`, which this package cannot import:
docs/design.md §1); float32 vs float64.
"""

from __future__ import annotations

import datetime
import functools
import json
import sys
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import jax

from agents.bench.rmp2 import (
    make_sampler,
    measure_batched,
    measure_latency,
    policy_function,
    precision_check,
)
from agents.bench.table import (
    device_info,
    device_slug,
    fmt_rate,
    fmt_time,
    format_summary,
    format_table,
    summarise,
)
from agents.bench.throughput import measure_env, measure_ppo

GPU_BATCHES = (1, 64, 1024, 4096, 16384, 65536, 262144)
CPU_BATCHES = (1, 64, 1024, 4096)
NAIVE_BATCHES = (1, 4096)
ENVS = ("three_link/env3", "franka")
GPU_ENV_BATCHES = (1024, 4096, 16384, 65536)
CPU_ENV_BATCHES = (16, 128)


def fill_defaults(settings: dict[str, Any]) -> dict[str, Any]:
    """``settings`` with every ``None`` size filled for this backend: CPU batches up to 4096
    (``full``: the GPU sizes), GPU batches up to 262144, tiny sizes with ``quick``."""
    s = dict(settings)
    quick, big = s["quick"], not (jax.default_backend() == "cpu" and not s["full"])
    on_cpu = jax.default_backend() == "cpu"
    if s["batches"] is None:
        s["batches"] = [1, 16] if quick else list(GPU_BATCHES if big else CPU_BATCHES)
    if s["envs"] is None:
        s["envs"] = [] if quick else list(ENVS)
    s["envs"] = [e for e in s["envs"] if e != "none"]
    if s["env_batches"] is None:
        s["env_batches"] = [4] if quick else list(GPU_ENV_BATCHES if big else CPU_ENV_BATCHES)
    if s["env_steps"] is None:
        s["env_steps"] = 5 if quick else (20 if on_cpu else 100)
    if s["naive_batches"] is None:
        s["naive_batches"] = [1, 16] if quick else list(NAIVE_BATCHES)
    s["naive_batches"] = [b for b in s["naive_batches"] if b > 0]
    for name, quick_value, value in (("repeats", 2, 5), ("latency_calls", 50, 1000),
                                     ("min_repeat_s", 0.01, 0.2)):
        if s[name] is None:
            s[name] = quick_value if quick else value
    return s


def _write(path: Path, result: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(result, indent=2) + "\n")
    tmp.replace(path)


def _ppo_rows(s: Mapping[str, Any], result: dict, path: Path) -> None:
    result["ppo"] = []
    for item in s["ppo"]:
        env_name, _, policy = item.partition(":")
        for n in s["ppo_devices"]:
            row = measure_ppo(env_name, policy or "rmp_residual", n, s["ppo_iterations"],
                              s["ppo_seeds"], s["ppo_preset"], s["ppo_num_envs"])
            result["ppo"].append(row)
            _write(path, result)
            print(f"PPO {row['policy']} on {row['env']}, {row['seeds']} seeds, {n} "
                  f"device(s): {row['steps_per_s']:.3g} env steps/s, "
                  f"{row['iteration_s']:.3f} s/iteration, compile {row['compile_s']:.1f} s"
                  + (f", split {row['iteration_split_s']}" if n == 1 else ""), flush=True)


def _plan(s: Mapping[str, Any]) -> list[tuple[str, str, str, int]]:
    """``(robot or environment, impl, mode, batch)`` of every row, in order."""
    plan = []
    for robot in s["robots"]:
        plan.append((robot, "rmp2", "single", 1))
        plan += [(robot, "rmp2", "batched", b) for b in s["batches"]]
        if s["naive_batches"]:
            plan.append((robot, "naive", "single", 1))
            plan += [(robot, "naive", "batched", b) for b in s["naive_batches"]]
    for env_name in s["envs"]:
        plan += [(env_name, policy, "env", b) for policy in ("random", "rmp2")
                 for b in s["env_batches"]]
    return plan


def _policy_row(s: Mapping[str, Any], mode: str, batch: int, jfn: Any, sample: Any,
                keys: tuple[jax.Array, jax.Array]) -> dict:
    """Timing of the compiled policy ``jfn`` on two sets of random inputs (single or batched)."""
    input_sets = [sample(k, batch) for k in keys]
    if mode == "single":
        input_sets = [jax.tree.map(lambda a: a[0], x) for x in input_sets]
        row = measure_latency(jfn, input_sets, s["latency_calls"],
                              budget_s=2.0 if s["quick"] else 10.0)
    else:
        row = measure_batched(jfn, input_sets, s["repeats"], s["min_repeat_s"])
    row["evals_per_s"] = batch / row["time_per_call_s"]
    return row


def _measure(s: Mapping[str, Any], item: tuple[str, str, str, int], key: jax.Array,
             compiled: dict, samplers: dict) -> tuple[dict, jax.Array]:
    """``(row, key)``: one row of :func:`_plan` (an error, e.g. out of device memory at the
    largest batches, is recorded in the row) and the advanced key."""
    robot, impl, mode, batch = item
    row: dict[str, Any] = {"robot": robot, "impl": impl, "mode": mode, "batch": batch}
    if mode == "env":
        key, k = jax.random.split(key)
        measure = functools.partial(measure_env, robot, impl, batch, s["env_steps"],
                                    s["repeats"], k)
    else:
        if (robot, impl, mode) not in compiled:
            fn = policy_function(robot, impl)
            compiled[(robot, impl, mode)] = jax.jit(jax.vmap(fn) if mode == "batched" else fn)
        key, k0, k1 = jax.random.split(key, 3)
        measure = functools.partial(_policy_row, s, mode, batch, compiled[(robot, impl, mode)],
                                    samplers[robot], (k0, k1))
    try:
        row.update(measure())
    except Exception as err:  # recorded in the row; the benchmark goes on
        row["error"] = f"{type(err).__name__}: {err}"[:500]
        row["evals_per_s"] = None
    return row, key


def _rows(s: Mapping[str, Any], result: dict, path: Path, key: jax.Array) -> jax.Array:
    """Measure every row of :func:`_plan`, rewriting the JSON after each; the advanced key."""
    compiled: dict = {}
    samplers = {robot: make_sampler(robot) for robot in s["robots"]}
    for item in _plan(s):
        row, key = _measure(s, item, key, compiled, samplers)
        result["rows"].append(row)
        result["summary"] = summarise(result["rows"])
        _write(path, result)
        if row["mode"] != "env":
            status = row.get("error") or (f"{fmt_rate(row['evals_per_s'])}, "
                                          f"compile {fmt_time(row['compile_s'])}")
            print(f"  … {' '.join(str(x) for x in item[:3])} batch {item[3]}: {status}",
                  file=sys.stderr, flush=True)
    return key


def _print_report(result: dict) -> None:
    print(format_table(result["rows"]))
    print(format_summary(result["summary"]))
    for p in result["precision"]:
        print(f"{p['robot']}: float32 vs float64 on {p['states']} states: relative error median "
              f"{p['median_rel_err']:.1e}, p99 {p['p99_rel_err']:.1e}, max {p['max_rel_err']:.1e}")


def run_benchmark(settings: dict[str, Any], command: str, results_dir: Path,
                  offline_measure: Callable[..., dict] | None = None) -> dict:
    """Run the benchmark of ``settings`` (see the module docstring), print the table and the
    summary, write the JSON (``settings["json"]``, default ``results_dir/bench_<device>.json``)
    after every row and return the result. ``offline_measure(name, seeds, steps, scale=)``
    measures the offline rows (required when ``settings["offline"]`` names learners)."""
    if settings.get("offline") and offline_measure is None:
        raise ValueError(f"settings['offline']={settings['offline']} names learners, but no "
                         "offline_measure was given to measure them")
    s = fill_defaults(settings)
    if jax.default_backend() == "cpu" and not s["async_dispatch"]:
        # Execute small CPU programs on the calling thread: no hand-off to a worker thread per
        # call, which otherwise dominates (and scatters) single-state latency on few cores.
        jax.config.update("jax_cpu_enable_async_dispatch", False)
    info = device_info()
    path = Path(s["json"] or results_dir / f"bench_{device_slug(info)}.json")
    print(f"device: {info['device_kind']} ({info['platform']}, {info['device_count']} device(s)); "
          f"jax {info['jax']}; dtype {info['dtype']}; matmul precision "
          f"{info['matmul_precision']}", flush=True)
    result: dict[str, Any] = {
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "command": command, "device": info,
        "settings": {k: (str(v) if isinstance(v, Path) else v) for k, v in s.items()},
        "rows": [], "summary": {},
    }
    if s["ppo"]:
        _ppo_rows(s, result, path)
    if s["offline"]:
        chunk = 10_000 if jax.default_backend() == "cpu" else 20_000
        result["offline"] = [offline_measure(name, s["offline_seeds"], 1000 if s["quick"]
                                             else chunk, scale=2 if s["quick"] else 8)
                             for name in s["offline"]]
        _write(path, result)
    if s["ppo_only"]:
        print(f"JSON: {path}", flush=True)
        return result
    key = _rows(s, result, path, jax.random.key(s["seed"]))
    result["precision"] = [precision_check(robot, jax.random.fold_in(key, i),
                                           64 if s["quick"] else 4096)
                           for i, robot in enumerate(s["robots"])]
    _write(path, result)
    _print_report(result)
    print(f"JSON: {path}", flush=True)
    return result


__all__ = ["CPU_BATCHES", "CPU_ENV_BATCHES", "ENVS", "GPU_BATCHES", "GPU_ENV_BATCHES",
           "NAIVE_BATCHES", "fill_defaults", "run_benchmark"]
