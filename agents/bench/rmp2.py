"""RMP² policy evaluations per second and latency for each robot's hand-designed policy
(:func:`mjxrmp.policies.default_config`) and the naive baseline
(:func:`mjxrmp.core.naive.acceleration_naive`).

Inputs are random for every state: ``q`` uniform within the joint limits (±π where a joint has
none), ``q̇ ~ U(−1, 1)``, a random goal and three random obstacles (3-link: 15 control points ×
3 circles/cylinders + velocity caps + damping + target; Franka: 48 control points × 3 balls +
joint limits + velocity caps + damping + cspace target + target). The default float32 path is
measured (no x64, default matmul precision). "compile" is the wall time of the first call of
each compiled function (trace + compile + run).
"""

from __future__ import annotations

import functools
import math
import statistics
import time
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from mjxrmp import policies
from mjxrmp.core import naive
from mjxrmp.geometry import make_obstacles
from mjxrmp.robots import get

ROBOTS = ("three_link", "franka")
NUM_OBSTACLES = 3
QD_RANGE = 1.0


def _planar_points(key: jax.Array, n: int, r_min: float, r_max: float) -> jax.Array:
    """``n`` points of the plane at radius ``U(r_min, r_max)``, angle ``U(−π, π)``."""
    kr, ka = jax.random.split(key)
    r = jax.random.uniform(kr, (n,), minval=r_min, maxval=r_max)
    a = jax.random.uniform(ka, (n,), minval=-jnp.pi, maxval=jnp.pi)
    return jnp.stack([r * jnp.cos(a), r * jnp.sin(a)], axis=-1)


def make_sampler(robot_name: str) -> Callable[[jax.Array, int], tuple]:
    """``sample(key, n) -> (q, qd, goal, obstacles)`` with a leading batch axis ``n``."""
    robot = get(robot_name)
    lo = np.where(np.isfinite(robot.q_lower), robot.q_lower, -np.pi).astype(np.float32)
    hi = np.where(np.isfinite(robot.q_upper), robot.q_upper, np.pi).astype(np.float32)

    def sample_one(key):
        kq, kqd, kg, kc, kr = jax.random.split(key, 5)
        q = jax.random.uniform(kq, (robot.dof,), minval=lo, maxval=hi)
        qd = jax.random.uniform(kqd, (robot.dof,), minval=-QD_RANGE, maxval=QD_RANGE)
        if robot.workspace_dim == 2:  # planar 3-link: reach 0.75 m
            goal = _planar_points(kg, 1, 0.2, 0.7)[0]
            centers = _planar_points(kc, NUM_OBSTACLES, 0.2, 0.8)
        else:  # Franka: a box in front of the robot
            goal = jax.random.uniform(kg, (3,), minval=jnp.array([0.3, -0.4, 0.2]),
                                      maxval=jnp.array([0.7, 0.4, 0.7]))
            centers = jax.random.uniform(kc, (NUM_OBSTACLES, 3),
                                         minval=jnp.array([0.2, -0.5, 0.0]),
                                         maxval=jnp.array([0.8, 0.5, 0.8]))
        radii = jax.random.uniform(kr, (NUM_OBSTACLES,), minval=0.05, maxval=0.15)
        return q, qd, goal, make_obstacles(centers, radii)

    @functools.partial(jax.jit, static_argnums=1)
    def sample(key, n):
        return jax.vmap(sample_one)(jax.random.split(key, n))

    return sample


def policy_function(robot_name: str, impl: str) -> Callable:
    """One-state policy ``(q, qd, goal, obstacles) -> qdd`` of the hand-designed preset, by
    RMP² (``impl="rmp2"``, eq 3.12 resolved over the leaves) or the naive baseline."""
    cfg = policies.default_config(robot_name)
    if impl == "rmp2":
        return lambda q, qd, goal, obs: policies.acceleration(cfg, q, qd, goal, obs)
    if impl == "naive":
        return lambda q, qd, goal, obs: naive.acceleration_naive(
            policies.task_map, policies.leaf_rmps, q, qd, goal, obs, cfg
        )
    raise ValueError(f"impl must be 'rmp2' or 'naive', got {impl!r}")


def _block(x):
    return jax.block_until_ready(x)


def _first_call(fn: Callable, inputs: tuple) -> tuple[object, float]:
    """``(output, seconds)`` of the first (compiling) call."""
    t0 = time.perf_counter()
    out = _block(fn(*inputs))
    return out, time.perf_counter() - t0


def _timing(times: Sequence[float], compile_s: float, repeats: int, calls: int,
            finite: float) -> dict:
    return {
        "time_per_call_s": statistics.median(times),
        "time_min_s": min(times),
        "time_max_s": max(times),
        "compile_s": compile_s,
        "repeats": repeats,
        "calls_per_repeat": calls,
        "finite_fraction": finite,
    }


def measure_batched(fn: Callable, input_sets: Sequence[tuple], repeats: int,
                    min_repeat_s: float) -> dict:
    """Compile (first call), warm up, then the median per-call time over ``repeats`` repeats;
    each repeat runs the call enough times to last ``min_repeat_s`` and blocks once at the
    end. Two input sets alternate between calls."""
    out, compile_s = _first_call(fn, input_sets[0])
    finite = float(jnp.mean(jnp.all(jnp.isfinite(out), axis=-1).astype(jnp.float32)))
    _block(fn(*input_sets[1 % len(input_sets)]))  # warm-up
    _, one = _first_call(fn, input_sets[0])
    calls = max(1, min(100_000, math.ceil(min_repeat_s / max(one, 1e-9))))
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for j in range(calls):
            out = fn(*input_sets[j % len(input_sets)])
        _block(out)
        times.append((time.perf_counter() - t0) / calls)
    return _timing(times, compile_s, repeats, calls, finite)


def measure_latency(fn: Callable, input_sets: Sequence[tuple], calls: int,
                    budget_s: float) -> dict:
    """Median single-call latency (each call blocked on its own, dispatch included) after
    compile and warm-up. At most ``calls`` calls; fewer (but at least 20) where ``calls`` would
    outlast ``budget_s``."""
    out, compile_s = _first_call(fn, input_sets[0])
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
    return _timing(times, compile_s, 1, n, finite)


def precision_check(robot: str, key: jax.Array, n: int) -> dict:
    """Relative error of the float32 policy against float64 on ``n`` random states (same
    device): shows that no reduced-precision (TF32) product slips into the RMP² contractions on
    GPUs (docs/design.md §5.4)."""
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


__all__ = ["ROBOTS", "make_sampler", "measure_batched", "measure_latency", "policy_function",
           "precision_check"]
