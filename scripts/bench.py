"""Benchmark table (docs/design.md §6): RMP² policy evaluations per second, latency and compile times.

For each robot's hand-designed RMP² policy (``mjxrmp.policies.default_config``):

* **batched** — ``jax.jit(jax.vmap(policy))`` at each batch size: evaluations/s = batch / (median
  time of one call over ``--repeats`` timed repeats, after warm-up; each repeat runs the call
  enough times to last ``--min-repeat-s`` and blocks once at the end);
* **single** — single-state latency of ``jax.jit(policy)`` on unbatched inputs: the median over
  ``--latency-calls`` calls, each blocked on its own (dispatch included);
* the same for the naive baseline (:func:`mjxrmp.core.naive.acceleration_naive`) at ``--naive-batches``
  and the ratio RMP²/naive at the largest batch both were run at (4096 by default).

"compile" is the wall time of the first call of each compiled function (trace + compile + run).
Inputs are random for every state: ``q`` uniform within the joint limits (±π where a joint has
none), ``q̇ ~ U(−1, 1)``, a random goal and three random obstacles (3-link: 15 control points ×
3 circles/cylinders + velocity caps + damping + target; Franka: 48 control points × 3 balls +
joint limits + velocity caps + damping + cspace target + target). The default float32 path is
measured (no x64, default matmul precision). Two input sets alternate between calls.

Usage::

    python scripts/bench.py                       # CPU: batches up to 4096; GPU: up to 262144
    python scripts/bench.py --robots franka --batches 1 4096 65536 --repeats 7
    python -m scripts.bench --quick --json /tmp/bench.json   # smoke test

Writes JSON (``--json``, default ``results/bench_<device>.json``) after every row, so a run cut
short still leaves its numbers.
"""

from __future__ import annotations

import argparse
import datetime
import functools
import json
import math
import os
import platform
import re
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import mjxrmp  # noqa: F401  (sets the XLA:CPU flag before JAX initialises)

# isort: split
import jax
import jax.numpy as jnp
import numpy as np

from mjxrmp import policies
from mjxrmp.core import naive
from mjxrmp.geometry import make_obstacles
from mjxrmp.robots import get

ROBOTS = ("three_link", "franka")
GPU_BATCHES = (1, 64, 1024, 4096, 16384, 65536, 262144)
CPU_BATCHES = (1, 64, 1024, 4096)
NAIVE_BATCHES = (1, 4096)
ENVS = ("three_link/env3", "franka")
GPU_ENV_BATCHES = (1024, 4096, 16384, 65536)
CPU_ENV_BATCHES = (16, 128)
NUM_OBSTACLES = 3
QD_RANGE = 1.0
ROOT = Path(__file__).resolve().parent.parent


# --------------------------------------------------------------------------------------------
# Inputs
# --------------------------------------------------------------------------------------------


def make_sampler(robot_name: str) -> Callable[[jax.Array, int], tuple]:
    """``sample(key, n) -> (q, qd, goal, obstacles)`` with a leading batch axis ``n``."""
    robot = get(robot_name)
    lo = np.where(np.isfinite(robot.q_lower), robot.q_lower, -np.pi).astype(np.float32)
    hi = np.where(np.isfinite(robot.q_upper), robot.q_upper, np.pi).astype(np.float32)
    dim = robot.workspace_dim

    def planar_points(key, n, r_min, r_max):
        kr, ka = jax.random.split(key)
        r = jax.random.uniform(kr, (n,), minval=r_min, maxval=r_max)
        a = jax.random.uniform(ka, (n,), minval=-jnp.pi, maxval=jnp.pi)
        return jnp.stack([r * jnp.cos(a), r * jnp.sin(a)], axis=-1)

    def sample_one(key):
        kq, kqd, kg, kc, kr = jax.random.split(key, 5)
        q = jax.random.uniform(kq, (robot.dof,), minval=lo, maxval=hi)
        qd = jax.random.uniform(kqd, (robot.dof,), minval=-QD_RANGE, maxval=QD_RANGE)
        if dim == 2:  # planar 3-link: reach 0.75 m
            goal = planar_points(kg, 1, 0.2, 0.7)[0]
            centers = planar_points(kc, NUM_OBSTACLES, 0.2, 0.8)
        else:  # Franka: a box in front of the robot
            goal = jax.random.uniform(kg, (3,), minval=jnp.array([0.3, -0.4, 0.2]),
                                      maxval=jnp.array([0.7, 0.4, 0.7]))
            centers = jax.random.uniform(kc, (NUM_OBSTACLES, 3), minval=jnp.array([0.2, -0.5, 0.0]),
                                         maxval=jnp.array([0.8, 0.5, 0.8]))
        radii = jax.random.uniform(kr, (NUM_OBSTACLES,), minval=0.05, maxval=0.15)
        return q, qd, goal, make_obstacles(centers, radii)

    @functools.partial(jax.jit, static_argnums=1)
    def sample(key, n):
        return jax.vmap(sample_one)(jax.random.split(key, n))

    return sample


def policy_function(robot_name: str, impl: str) -> Callable:
    """One-state policy ``(q, qd, goal, obstacles) -> qdd`` of the hand-designed preset."""
    cfg = policies.default_config(robot_name)
    if impl == "rmp2":
        return lambda q, qd, goal, obs: policies.acceleration(cfg, q, qd, goal, obs)
    if impl == "naive":
        return lambda q, qd, goal, obs: naive.acceleration_naive(
            policies.task_map, policies.leaf_rmps, q, qd, goal, obs, cfg
        )
    raise ValueError(f"impl must be 'rmp2' or 'naive', got {impl!r}")


# --------------------------------------------------------------------------------------------
# Timing
# --------------------------------------------------------------------------------------------


def _block(x):
    return jax.block_until_ready(x)


def _finite_fraction(out) -> float:
    return float(jnp.mean(jnp.all(jnp.isfinite(out), axis=-1).astype(jnp.float32)))


def measure_batched(fn, input_sets: Sequence[tuple], repeats: int, min_repeat_s: float) -> dict:
    """Compile (first call), warm up, then the median per-call time over ``repeats`` repeats."""
    t0 = time.perf_counter()
    out = _block(fn(*input_sets[0]))
    compile_s = time.perf_counter() - t0
    finite = _finite_fraction(out)
    _block(fn(*input_sets[1 % len(input_sets)]))  # warm-up
    t0 = time.perf_counter()
    _block(fn(*input_sets[0]))
    one = time.perf_counter() - t0
    calls = max(1, min(100_000, math.ceil(min_repeat_s / max(one, 1e-9))))
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for j in range(calls):
            out = fn(*input_sets[j % len(input_sets)])
        _block(out)
        times.append((time.perf_counter() - t0) / calls)
    return {
        "time_per_call_s": statistics.median(times),
        "time_min_s": min(times),
        "time_max_s": max(times),
        "compile_s": compile_s,
        "repeats": repeats,
        "calls_per_repeat": calls,
        "finite_fraction": finite,
    }


def measure_latency(fn, input_sets: Sequence[tuple], calls: int, budget_s: float) -> dict:
    """Median single-call latency (each call blocked on its own) after compile and warm-up.

    At most ``calls`` calls; fewer (but at least 20) where ``calls`` would outlast ``budget_s``.
    """
    t0 = time.perf_counter()
    out = _block(fn(*input_sets[0]))
    compile_s = time.perf_counter() - t0
    finite = float(jnp.all(jnp.isfinite(out)))
    t0 = time.perf_counter()
    for j in range(10):
        _block(fn(*input_sets[j % len(input_sets)]))
    one = (time.perf_counter() - t0) / 10
    n = int(max(20, min(calls, budget_s / max(one, 1e-9))))
    times = []
    for j in range(n):
        args = input_sets[j % len(input_sets)]
        t0 = time.perf_counter()
        _block(fn(*args))
        times.append(time.perf_counter() - t0)
    return {
        "time_per_call_s": statistics.median(times),
        "time_min_s": min(times),
        "time_max_s": max(times),
        "compile_s": compile_s,
        "repeats": 1,
        "calls_per_repeat": n,
        "finite_fraction": finite,
    }


def env_runner(env_name: str, policy: str, batch: int, steps: int):
    """``(reset, run)``: a batch of auto-resetting environments stepped ``steps`` control steps
    in one ``lax.scan`` with random actions (``policy="random"``) or the hand-designed RMP²
    policy in the loop (``"rmp2"``)."""
    import envs
    from envs.evaluate import hand_designed_policy
    from envs.wrappers import wrap

    base = envs.make(env_name)
    env = wrap(base)
    rmp2_policy = jax.vmap(hand_designed_policy(base))

    def act(state, key):
        if policy == "random":
            return jax.random.uniform(key, (batch, base.action_size), minval=-1.0, maxval=1.0)
        return rmp2_policy(state)

    def run(state, key):
        def body(s, k):
            s = env.step(s, act(s, k))
            return s, s.reward
        state, rewards = jax.lax.scan(body, state, jax.random.split(key, steps))
        return state, jnp.mean(rewards)

    return jax.jit(env.reset), jax.jit(run)


def measure_env(env_name: str, policy: str, batch: int, steps: int, repeats: int,
                key: jax.Array) -> dict:
    """Control steps/s (each = 3 physics substeps) of :func:`env_runner`; median of repeats."""
    reset, run = env_runner(env_name, policy, batch, steps)
    k_reset, k_run = jax.random.split(key)
    # brax's episode wrapper expects raw uint32 keys of shape (B, 2).
    state = _block(reset(jax.random.key_data(jax.random.split(k_reset, batch))))
    t0 = time.perf_counter()
    state, reward = _block(run(state, k_run))
    compile_s = time.perf_counter() - t0
    times = []
    for i in range(repeats):
        t0 = time.perf_counter()
        state, reward = _block(run(state, jax.random.fold_in(k_run, i)))
        times.append(time.perf_counter() - t0)
    t = statistics.median(times)
    return {
        "time_per_call_s": t / steps,
        "time_min_s": min(times) / steps,
        "time_max_s": max(times) / steps,
        "compile_s": compile_s,
        "repeats": repeats,
        "calls_per_repeat": steps,
        "finite_fraction": float(jnp.isfinite(reward)),
        "evals_per_s": batch * steps / t,
    }


# --------------------------------------------------------------------------------------------
# Formatting
# --------------------------------------------------------------------------------------------


def fmt_rate(x: float | None) -> str:
    """``2.31e7/s`` style."""
    if x is None or not math.isfinite(x) or x <= 0:
        return "-"
    mantissa, exponent = f"{x:.2e}".split("e")
    return f"{mantissa}e{int(exponent)}/s"


def fmt_time(s: float | None) -> str:
    if s is None or not math.isfinite(s):
        return "-"
    if s < 1e-3:
        return f"{s * 1e6:.1f} µs"
    if s < 1.0:
        return f"{s * 1e3:.2f} ms"
    return f"{s:.2f} s"


def format_table(rows: list[dict]) -> str:
    headers = ("robot", "impl", "mode", "batch", "evals/s", "time/call", "compile", "calls×reps")
    lines = []
    for r in rows:
        if r.get("error"):
            cells = (r["robot"], r["impl"], r["mode"], str(r["batch"]), "ERROR", "-", "-",
                     r["error"][:40])
        else:
            cells = (
                r["robot"], r["impl"], r["mode"], str(r["batch"]), fmt_rate(r["evals_per_s"]),
                fmt_time(r["time_per_call_s"]), fmt_time(r["compile_s"]),
                f"{r['calls_per_repeat']}×{r['repeats']}",
            )
        lines.append(cells)
    widths = [max(len(h), *(len(c[i]) for c in lines)) for i, h in enumerate(headers)]
    right = {3, 4, 5, 6, 7}

    def line(cells):
        return "  ".join(c.rjust(w) if i in right else c.ljust(w)
                         for i, (c, w) in enumerate(zip(cells, widths, strict=True)))

    out = [line(headers), line(tuple("-" * w for w in widths))]
    out += [line(c) for c in lines]
    return "\n".join(out)


def summarise(rows: list[dict]) -> dict:
    """Per robot: latency, best batch, naive ratio at the largest batch both impls ran; per
    environment and policy: the best control steps/s."""
    summary = {}
    for r in rows:
        if r["mode"] == "env" and not r.get("error"):
            s = summary.setdefault(f"env {r['robot']}", {})
            name = f"{r['impl']}_best_steps_per_s"
            if r["evals_per_s"] > s.get(name, 0.0):
                s[name] = r["evals_per_s"]
                s[f"{r['impl']}_best_env_batch"] = r["batch"]
    for robot in dict.fromkeys(r["robot"] for r in rows if r["mode"] != "env"):
        ok = [r for r in rows if r["robot"] == robot and not r.get("error") and r["mode"] != "env"]
        rmp2 = {r["batch"]: r for r in ok if r["impl"] == "rmp2" and r["mode"] == "batched"}
        nv = {r["batch"]: r for r in ok if r["impl"] == "naive" and r["mode"] == "batched"}
        s: dict = {}
        for impl in ("rmp2", "naive"):
            lat = [r for r in ok if r["impl"] == impl and r["mode"] == "single"]
            if lat:
                s[f"{impl}_latency_us"] = lat[0]["time_per_call_s"] * 1e6
        if rmp2:
            best = max(rmp2.values(), key=lambda r: r["evals_per_s"])
            s["rmp2_best_batch"] = best["batch"]
            s["rmp2_best_evals_per_s"] = best["evals_per_s"]
        common = sorted(set(rmp2) & set(nv))
        if common:
            b = common[-1]
            s["ratio_batch"] = b
            s["rmp2_over_naive"] = rmp2[b]["evals_per_s"] / nv[b]["evals_per_s"]
        summary[robot] = s
    return summary


def format_summary(summary: dict) -> str:
    lines = []
    for robot, s in summary.items():
        parts = []
        for impl in ("random", "rmp2"):
            if f"{impl}_best_steps_per_s" in s:
                parts.append(f"{impl} actions: best {fmt_rate(s[f'{impl}_best_steps_per_s'])} "
                             f"control steps (batch {s[f'{impl}_best_env_batch']})")
        if "rmp2_best_batch" in s:
            parts.append(f"best RMP² batch {s['rmp2_best_batch']} "
                         f"({fmt_rate(s['rmp2_best_evals_per_s'])})")
        if "rmp2_latency_us" in s:
            parts.append(f"single-state latency {s['rmp2_latency_us']:.1f} µs")
        if "rmp2_over_naive" in s:
            parts.append(f"RMP²/naive at batch {s['ratio_batch']} = {s['rmp2_over_naive']:.1f}×")
        lines.append(f"{robot}: " + "; ".join(parts))
    return "\n".join(lines)


# --------------------------------------------------------------------------------------------
# Driver
# --------------------------------------------------------------------------------------------


def device_info() -> dict:
    import jaxlib

    dev = jax.devices()[0]
    return {
        "platform": dev.platform,
        "device_kind": dev.device_kind,
        "device_count": jax.device_count(),
        "jax": jax.__version__,
        "jaxlib": jaxlib.__version__,
        "dtype": str(jnp.zeros(()).dtype),
        "matmul_precision": jax.config.jax_default_matmul_precision or "default",
        "python": platform.python_version(),
        "host_cpus": os.cpu_count(),
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
        "cpu_async_dispatch": bool(jax.config.values["jax_cpu_enable_async_dispatch"]),
        "cpu_affinity": sorted(os.sched_getaffinity(0)),
    }


def device_slug(info: dict) -> str:
    name = "cpu" if info["platform"] == "cpu" else info["device_kind"]
    return re.sub(r"[^a-z0-9]+", "_", name.lower()).strip("_")


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--robots", nargs="+", choices=ROBOTS, default=list(ROBOTS))
    p.add_argument("--batches", nargs="+", type=int, default=None,
                   help=f"RMP² batch sizes (default GPU {GPU_BATCHES}, CPU {CPU_BATCHES})")
    p.add_argument("--naive-batches", nargs="+", type=int, default=None,
                   help=f"naive-baseline batch sizes (default {NAIVE_BATCHES}; none: 0)")
    p.add_argument("--repeats", type=int, default=None, help="timed repeats (default 5)")
    p.add_argument("--latency-calls", type=int, default=None,
                   help="single-state calls for the latency median (default 1000)")
    p.add_argument("--min-repeat-s", type=float, default=None,
                   help="each timed repeat lasts at least this long (default 0.2 s)")
    p.add_argument("--full", action="store_true", help="on CPU, use the GPU batch sizes too")
    p.add_argument("--quick", action="store_true", help="tiny sizes, for a smoke test")
    p.add_argument("--json", type=Path, default=None,
                   help="output path (default results/bench_<device>.json)")
    p.add_argument("--envs", nargs="+", default=None,
                   help=f"environments for control-step throughput (default {ENVS}; "
                        "'none' skips; --quick skips unless given)")
    p.add_argument("--env-batches", nargs="+", type=int, default=None,
                   help=f"environment batch sizes (default GPU {GPU_ENV_BATCHES}, "
                        f"CPU {CPU_ENV_BATCHES})")
    p.add_argument("--env-steps", type=int, default=None,
                   help="control steps per timed call (default 100; CPU 20)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--async-dispatch", action="store_true",
                   help="on CPU, keep JAX's asynchronous dispatch (default: synchronous, the "
                        "low-latency setting for single-state control loops)")
    p.add_argument("--pin-cpu", type=int, default=None, metavar="CORE",
                   help="pin the process to one CPU core before JAX starts (Linux; the usual "
                        "setting for measuring single-state control-loop latency)")
    p.add_argument("--ppo", nargs="+", default=[], metavar="ENV:POLICY",
                   help="PPO training throughput rows, e.g. three_link/env3:rmp_residual")
    p.add_argument("--ppo-devices", nargs="+", type=int, default=[1],
                   help="device counts for the PPO rows (environment batch sharded)")
    p.add_argument("--ppo-iterations", type=int, default=3, help="iterations per timed chunk")
    p.add_argument("--ppo-seeds", type=int, default=4, help="vmapped seeds in the PPO rows")
    p.add_argument("--ppo-preset", default="thesis", help="PPO settings of the PPO rows")
    p.add_argument("--ppo-num-envs", type=int, default=None,
                   help="override the preset's num_envs (a larger batch for scaling runs)")
    p.add_argument("--ppo-only", action="store_true", help="only the PPO (and offline) rows")
    p.add_argument("--offline", nargs="+", default=[], metavar="LEARNER",
                   help="offline gradient-steps/s rows (scripts/bench_offline.py), e.g. atac")
    p.add_argument("--offline-seeds", nargs="+", type=int, default=[1, 8],
                   help="vmapped seed counts of the offline rows")
    args = p.parse_args(argv)
    if args.pin_cpu is not None:
        # Threads XLA creates later inherit this affinity: no hand-offs between cores.
        os.sched_setaffinity(0, {args.pin_cpu})
    on_cpu = jax.default_backend() == "cpu"
    if args.batches is None:
        args.batches = [1, 16] if args.quick else list(
            CPU_BATCHES if on_cpu and not args.full else GPU_BATCHES)
    if args.envs is None:
        args.envs = [] if args.quick else list(ENVS)
    args.envs = [e for e in args.envs if e != "none"]
    if args.env_batches is None:
        args.env_batches = [4] if args.quick else list(
            CPU_ENV_BATCHES if on_cpu and not args.full else GPU_ENV_BATCHES)
    if args.env_steps is None:
        args.env_steps = 5 if args.quick else (20 if on_cpu else 100)
    if args.naive_batches is None:
        args.naive_batches = [1, 16] if args.quick else list(NAIVE_BATCHES)
    args.naive_batches = [b for b in args.naive_batches if b > 0]
    if args.repeats is None:
        args.repeats = 2 if args.quick else 5
    if args.latency_calls is None:
        args.latency_calls = 50 if args.quick else 1000
    if args.min_repeat_s is None:
        args.min_repeat_s = 0.01 if args.quick else 0.2
    for name in ("batches", "naive_batches"):
        if any(b < 1 for b in getattr(args, name)):
            p.error(f"--{name.replace('_', '-')} must be positive integers")
    if args.repeats < 1 or args.latency_calls < 1:
        p.error("--repeats and --latency-calls must be >= 1")
    return args


def measure_ppo(env_name: str, policy: str, devices: int, iterations: int, seeds: int,
                preset_name: str, num_envs: int | None = None) -> dict:
    """PPO training throughput: environment steps/s of a compiled chunk of ``iterations``
    iterations for ``seeds`` vmapped seeds, the environment batch sharded over ``devices``
    devices (after a warm-up chunk); compile time; on one device also the per-iteration split
    (:func:`agents.run.training.profile_iteration`)."""
    from agents.run.training import RunSpec, build, make_mesh, preset, profile_iteration, seed_keys

    overrides = {} if num_envs is None else {"num_envs": num_envs}
    spec = RunSpec(env=env_name, policy=policy, seeds=tuple(range(seeds)),
                   ppo=preset(preset_name, **overrides))
    program = build(spec, make_mesh(devices))
    state = jax.block_until_ready(program.init(seed_keys(spec.seeds)))
    exe = program.executable(state, iterations)
    state, _ = jax.block_until_ready(exe(state))
    t0 = time.perf_counter()
    state, _ = jax.block_until_ready(exe(state))
    dt = time.perf_counter() - t0
    steps = iterations * spec.ppo.batch_size * seeds
    row = {"env": env_name, "policy": policy, "devices": devices, "seeds": seeds,
           "preset": preset_name, "num_envs": spec.ppo.num_envs, "iterations": iterations,
           "env_steps": steps,
           "seconds": dt, "steps_per_s": steps / dt, "iteration_s": dt / iterations,
           "compile_s": program.compile_seconds}
    if devices == 1:
        row["iteration_split_s"] = profile_iteration(program, state)
    return row


def precision_check(robot: str, key: jax.Array, n: int) -> dict:
    """Relative error of the float32 policy against float64 on ``n`` random states (same device).

    Shows that no reduced-precision (TF32) product slips into the RMP² contractions on GPUs.
    """
    sample = make_sampler(robot)
    fn = jax.jit(jax.vmap(policy_function(robot, "rmp2")))
    inputs = sample(key, n)
    out32 = np.asarray(fn(*inputs), np.float64)
    with jax.enable_x64(True):
        inputs64 = jax.tree.map(lambda a: jnp.asarray(np.asarray(a), jnp.float64), inputs)
        out64 = np.asarray(fn(*inputs64))
    rel = np.linalg.norm(out32 - out64, axis=-1) / np.maximum(np.linalg.norm(out64, axis=-1),
                                                              1e-6)
    return {"robot": robot, "states": n, "median_rel_err": float(np.median(rel)),
            "p99_rel_err": float(np.quantile(rel, 0.99)), "max_rel_err": float(rel.max())}


def _write(path: Path, result: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(result, indent=2) + "\n")
    tmp.replace(path)


def main(argv: Sequence[str] | None = None) -> dict:
    """Run the benchmark, print the table, write the JSON and return it."""
    args = parse_args(argv)
    if jax.default_backend() == "cpu" and not args.async_dispatch:
        # Execute small CPU programs on the calling thread: no hand-off to a worker thread per
        # call, which otherwise dominates (and scatters) single-state latency on few cores.
        jax.config.update("jax_cpu_enable_async_dispatch", False)
    info = device_info()
    path = args.json or ROOT / "results" / f"bench_{device_slug(info)}.json"
    print(f"device: {info['device_kind']} ({info['platform']}, {info['device_count']} device(s)); "
          f"jax {info['jax']}; dtype {info['dtype']}; matmul precision "
          f"{info['matmul_precision']}", flush=True)
    result = {
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "command": " ".join(["python scripts/bench.py", *(argv if argv is not None
                                                          else sys.argv[1:])]),
        "device": info,
        "settings": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
        "rows": [],
        "summary": {},
    }
    if args.ppo:
        result["ppo"] = []
        for item in args.ppo:
            env_name, _, policy = item.partition(":")
            for n in args.ppo_devices:
                row = measure_ppo(env_name, policy or "rmp_residual", n, args.ppo_iterations,
                                  args.ppo_seeds, args.ppo_preset, args.ppo_num_envs)
                result["ppo"].append(row)
                _write(path, result)
                print(f"PPO {row['policy']} on {row['env']}, {row['seeds']} seeds, {n} "
                      f"device(s): {row['steps_per_s']:.3g} env steps/s, "
                      f"{row['iteration_s']:.3f} s/iteration, compile {row['compile_s']:.1f} s"
                      + (f", split {row['iteration_split_s']}" if n == 1 else ""), flush=True)
    if args.offline:
        from scripts.bench_offline import measure as measure_offline

        chunk = 10_000 if jax.default_backend() == "cpu" else 20_000
        result["offline"] = [measure_offline(name, args.offline_seeds, 1000 if args.quick
                                             else chunk, scale=2 if args.quick else 8)
                             for name in args.offline]
        _write(path, result)
    if args.ppo_only:
        print(f"JSON: {path}", flush=True)
        return result
    key = jax.random.key(args.seed)
    plan = []
    for robot in args.robots:
        plan.append((robot, "rmp2", "single", 1))
        plan += [(robot, "rmp2", "batched", b) for b in args.batches]
        if args.naive_batches:
            plan.append((robot, "naive", "single", 1))
            plan += [(robot, "naive", "batched", b) for b in args.naive_batches]

    for env_name in args.envs:
        plan += [(env_name, policy, "env", b) for policy in ("random", "rmp2")
                 for b in args.env_batches]

    samplers = {robot: make_sampler(robot) for robot in args.robots}
    compiled: dict = {}
    for robot, impl, mode, batch in plan:
        if mode == "env":
            key, k = jax.random.split(key)
            row = {"robot": robot, "impl": impl, "mode": mode, "batch": batch}
            try:
                row.update(measure_env(robot, impl, batch, args.env_steps, args.repeats, k))
            except Exception as err:  # e.g. out of device memory at the largest batches
                row["error"] = f"{type(err).__name__}: {err}"[:500]
                row["evals_per_s"] = None
            result["rows"].append(row)
            result["summary"] = summarise(result["rows"])
            _write(path, result)
            continue
        fn = policy_function(robot, impl)
        if (robot, impl, mode) not in compiled:
            compiled[(robot, impl, mode)] = jax.jit(jax.vmap(fn) if mode == "batched" else fn)
        jfn = compiled[(robot, impl, mode)]
        key, k0, k1 = jax.random.split(key, 3)
        input_sets = [samplers[robot](k, batch) for k in (k0, k1)]
        if mode == "single":
            input_sets = [jax.tree.map(lambda a: a[0], s) for s in input_sets]
        row = {"robot": robot, "impl": impl, "mode": mode, "batch": batch}
        try:
            if mode == "single":
                row.update(measure_latency(jfn, input_sets, args.latency_calls,
                                           budget_s=2.0 if args.quick else 10.0))
            else:
                row.update(measure_batched(jfn, input_sets, args.repeats, args.min_repeat_s))
            row["evals_per_s"] = batch / row["time_per_call_s"]
        except Exception as err:  # e.g. out of device memory at the largest batches
            row["error"] = f"{type(err).__name__}: {err}"[:500]
            row["evals_per_s"] = None
        del input_sets
        result["rows"].append(row)
        result["summary"] = summarise(result["rows"])
        _write(path, result)
        status = row.get("error") or (f"{fmt_rate(row['evals_per_s'])}, "
                                      f"compile {fmt_time(row['compile_s'])}")
        print(f"  … {robot} {impl} {mode} batch {batch}: {status}", file=sys.stderr, flush=True)

    result["precision"] = [precision_check(robot, jax.random.fold_in(key, i),
                                           64 if args.quick else 4096)
                           for i, robot in enumerate(args.robots)]
    _write(path, result)
    print(format_table(result["rows"]))
    print(format_summary(result["summary"]))
    for p in result["precision"]:
        print(f"{p['robot']}: float32 vs float64 on {p['states']} states: relative error median "
              f"{p['median_rel_err']:.1e}, p99 {p['p99_rel_err']:.1e}, max {p['max_rel_err']:.1e}")
    print(f"JSON: {path}", flush=True)
    return result


if __name__ == "__main__":
    main()
