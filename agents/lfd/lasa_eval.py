"""Learning stable LASA dynamics with Euclideanizing flows and checking them (thesis §4.2,
Figs 4.4 and 4.7; ``scripts/lfd_lasa.py``).

:func:`evaluate_shapes` trains every requested shape in **one** compiled program: the shapes'
demonstrations ``(7, 235, 2)`` are stacked along a leading axis and
:func:`agents.lfd.flow_training.make_train`'s training step is ``vmap``-ped over it (one
``lax.scan`` per chunk of ``log_every`` iterations, which is when progress is logged). Shape
``k`` of :data:`mjxrmp.data.lasa.LASA_SHAPES` draws its key from ``fold_in(PRNGKey(seed), k)``,
so a shape's result does not depend on which others are trained with it.

Rollouts use ``LfdConfig.integrator`` (default ``"latent"``, :func:`agents.lfd.flow_field.rollout`):
``y = ψ(x)`` moves straight to the origin without ever overshooting it and ``x = ψ⁻¹(y)`` with
the flow's exact inverse, so ``‖ψ(x_k)‖`` is non-increasing for every start and step. The
record (:mod:`agents.lfd.lasa_summary`) holds per shape the trajectory metrics between each
rollout's first ``T`` samples and its demonstration (``rmse`` at equal times, beside DTW and
the swept area) and the same for a straight-line baseline, the **arrival check** (distance to
the goal at ``1.2×`` the demonstration's duration, where the stored rollouts end, and the time
from which each stays within 1 %; :mod:`agents.lfd.lasa_summary`, "Timing"), the training
summary, the **converged** end points of the same rollouts run on to
``check_steps`` (default ``10·T``; ``"auto"``: the guaranteed arrival bound of every start,
:func:`agents.lfd.flow_field.arrival_steps`) steps (acceptance: below 1 % of the workspace,
0.01, since the normalised demonstrations span 1), and a convergence check: rollouts from
``check_starts`` uniform random starts in the demonstrations' bounding box enlarged by 20 % for
``check_steps`` steps — fraction within ``goal_radius`` of the goal, maximum final distance,
count of non-finite rollouts (NaN/inf anywhere counts as not converged, distance ``inf``),
fraction of rollouts along which ``‖ψ(x_k)‖`` (recomputed from the positions) is non-increasing
— and the minimum speed on a grid of that box away from the goal and the speed at the goal.

:func:`time_epochs` times full-batch training epochs (docs/design.md §5.6).
"""

from __future__ import annotations

import dataclasses
import functools
import os
import time
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from agents.lfd.config import LfdConfig
from agents.lfd.flow_field import FlowField, arrival_steps, rollout
from agents.lfd.flow_training import LfdResult, Trainer, make_train, train_batched
from agents.lfd.lasa_summary import (
    ACCEPT_FINAL_ERROR,
    ARRIVAL_HORIZON,
    arrival_times,
    format_summary,
    horizon_steps,
    shape_line,
    shape_record,
    summary_table,
)
from mjxrmp.data.lasa import LASA_SHAPES, load_shape

__all__ = [
    "BOX_MARGIN",
    "GRID",
    "MONOTONE_RTOL",
    "NPZ_KEYS",
    "LasaRun",
    "box",
    "canonical_shapes",
    "check_horizon",
    "convergence_stats",
    "evaluate_shapes",
    "latent_norms",
    "load_data",
    "time_epochs",
    "train_shapes",
    "velocity_program",
]

Log = Callable[[str], None]

#: Keys every ``<shape>.npz`` holds.
NPZ_KEYS = ("demos", "rollouts", "dt", "losses")
#: Enlargement of the demonstrations' bounding box for the convergence check and the figures.
BOX_MARGIN = 0.2
#: Rounding allowance of the monotonicity check of ``‖ψ(x_k)‖``, relative to ``max(‖ψ(x_0)‖, 1)``
#: (``ψ`` recomputed from positions that went through ``ψ⁻¹``: float32 rounding ~1e-6).
MONOTONE_RTOL = 1e-5
#: Points per axis of the speed grid of the convergence check.
GRID = 41


def canonical_shapes(names: list[str]) -> list[str]:
    """Map names case-insensitively onto :data:`LASA_SHAPES`; unknown names raise ``ValueError``
    listing the valid ones."""
    lower = {s.lower(): s for s in LASA_SHAPES}
    out, bad = [], []
    for n in names:
        (out if n.lower() in lower else bad).append(lower.get(n.lower(), n))
    if bad:
        raise ValueError(f"unknown LASA shape(s) {', '.join(map(repr, bad))}; the 30 valid "
                         f"names are: {', '.join(LASA_SHAPES)}")
    if len(set(out)) != len(out):
        raise ValueError(f"shapes listed more than once: {names}")
    return out


def load_data(names: list[str]) -> dict[str, np.ndarray]:
    """The shapes' ``demos (S, 7, T, 2)``, ``velocities`` (same) and ``dt (S,)``, float32."""
    shapes = [load_shape(n) for n in names]
    return {"demos": np.stack([s.demos for s in shapes]).astype(np.float32),
            "velocities": np.stack([s.velocities for s in shapes]).astype(np.float32),
            "dt": np.asarray([s.dt for s in shapes], np.float32)}


def box(demos: np.ndarray, margin: float = BOX_MARGIN) -> tuple[np.ndarray, np.ndarray]:
    """The bounding box of ``demos (..., 2)`` enlarged by ``margin`` (fraction of its size)
    about its centre: ``(lo (2,), hi (2,))``."""
    lo = demos.reshape(-1, 2).min(0)
    hi = demos.reshape(-1, 2).max(0)
    c, h = 0.5 * (lo + hi), 0.5 * (hi - lo) * (1.0 + margin)
    return c - h, c + h


def train_shapes(names: list[str], data: dict, config: LfdConfig, seed: int,
                 log_every: int, log: Log = print) -> tuple[Trainer, LfdResult]:
    """Train all shapes in one vmapped program (:func:`agents.lfd.flow_training.train_batched`),
    in compiled chunks of ``log_every`` steps with a progress line after each. Returns
    ``(trainer, result)`` with every leaf of ``result`` stacked over shapes."""
    base = jax.random.PRNGKey(seed)
    keys = jnp.stack([jax.random.fold_in(base, LASA_SHAPES.index(n)) for n in names])
    t0 = time.perf_counter()

    def progress(done, total, ls, state):
        el = time.perf_counter() - t0
        per = "  ".join(f"{name}={ls[i, -1]:.5f}" for i, name in enumerate(names[:6]))
        more = f"  (+{len(names) - 6} more)" if len(names) > 6 else ""
        stopped = int(np.sum(np.asarray(state.stopped)))
        log(f"[{done:>5d}/{total}] {el:7.1f} s  mean loss {ls[:, -1].mean():.5f}  {per}{more}"
            + (f"  early-stopped: {stopped}/{len(names)}" if stopped else ""))

    return train_batched(config, keys, data["demos"], data["velocities"], dt=data["dt"],
                         log_every=log_every, callback=progress, labels=list(names))


@functools.lru_cache(maxsize=8)
def _rollout_program(field: FlowField, num_steps: int, method: str) -> Callable[..., jax.Array]:
    """``(variables, x0 (S, n, 2), dt (S,)) -> (S, n, num_steps + 1, 2)``, jitted (cached)."""
    return jax.jit(jax.vmap(lambda var, x0, dt: rollout(field, var, x0, num_steps, dt, method)))


@functools.lru_cache(maxsize=8)
def velocity_program(field: FlowField) -> Callable[[Any, jax.Array], jax.Array]:
    """``field.velocity`` jitted and ``vmap``-ped over shapes (cached)."""
    return jax.jit(jax.vmap(field.velocity))


def check_horizon(check_steps: int | str | None, config: LfdConfig, field: FlowField,
                  variables: Any, data: dict, starts: np.ndarray) -> int:
    """Steps of the convergence rollouts: ``10·T`` (``None``), the given number, or for
    ``"auto"`` :func:`agents.lfd.flow_field.arrival_steps` over the random ``starts (S, n, 2)``
    and the demonstrations' starts with each shape's ``dt`` (at least ``T − 1``): every start then
    reaches ``10⁻³·ε`` of the goal in the latent space by construction, so the check measures
    whether the goal is reached, not whether it is reached within a fixed time."""
    T = data["demos"].shape[2]
    if check_steps is None:
        return 10 * T
    if check_steps != "auto":
        return int(check_steps)
    if config.integrator != "latent":
        raise ValueError(f"check_steps 'auto' needs the latent integrator (the bound is for "
                         f"agents.lfd.flow_field.latent_step), got "
                         f"integrator={config.integrator!r}")
    points = np.concatenate([np.asarray(starts, np.float32),
                             np.asarray(data["demos"][:, :, 0], np.float32)], axis=1)
    r0 = np.asarray(_latent_norm_program(field)(variables, jnp.asarray(points)[:, :, None]))
    return max(arrival_steps(config, r0[..., 0], np.asarray(data["dt"])[:, None]), T - 1)


@functools.lru_cache(maxsize=8)
def _latent_norm_program(field: FlowField) -> Callable[[Any, jax.Array], jax.Array]:
    return jax.jit(jax.vmap(lambda var, x: jnp.linalg.norm(field.latent(var, x), axis=-1)))


def latent_norms(field: FlowField, variables: Any, xs: jax.Array, chunk: int = 2048
                 ) -> np.ndarray:
    """``‖ψ(x)‖`` along rollouts ``xs (S, n, K, 2)``: ``(S, n, K)``, evaluated ``chunk`` steps at
    a time so that long checks (``check_steps="auto"``) fit in device memory."""
    program = _latent_norm_program(field)
    return np.concatenate([np.asarray(program(variables, xs[:, :, k:k + chunk]))
                           for k in range(0, xs.shape[2], chunk)], axis=-1)


def convergence_stats(field: FlowField, variables: Any, xs: jax.Array,
                      rtol: float = MONOTONE_RTOL) -> tuple[np.ndarray, np.ndarray]:
    """For rollouts ``xs (S, n, K, 2)`` (goal at the origin): the final distances to the goal
    ``(S, n)`` (``inf`` where any sample is NaN/inf, so a non-finite rollout always counts as
    not converged) and whether ``‖ψ(x_k)‖`` (the Lyapunov function of §4.3.1, recomputed from
    the positions) is non-increasing along each rollout, up to ``rtol·‖ψ(x_0)‖`` of rounding
    ``(S, n)`` (``False`` where non-finite)."""
    r = latent_norms(field, variables, xs)                            # (S, n, K)
    x = np.asarray(xs)
    finite = np.all(np.isfinite(x), axis=(-2, -1)) & np.all(np.isfinite(r), axis=-1)
    final = np.where(finite, np.linalg.norm(x[..., -1, :], axis=-1), np.inf)
    rise = np.max(np.diff(r, axis=-1), axis=-1, initial=0.0)
    monotone = finite & (rise <= rtol * np.maximum(r[..., 0], 1.0))
    return final, monotone


def time_epochs(config: LfdConfig, num_epochs: int, seed: int = 0, shape: str = "Sshape",
                log: Log = print) -> dict:
    """Wall time of one full-batch training epoch (one gradient step on all ``7 × 235`` samples
    of ``shape``, :func:`agents.lfd.flow_training.make_train`'s step) after compilation:
    ``num_epochs`` calls of the jitted one-step ``run``, each waited for. Logs and returns the
    median (ms), with the minimum, the device and the 1-minute load average (other processes on
    the CPU)."""
    data = load_data([shape])
    x, v = jnp.asarray(data["demos"][0]), jnp.asarray(data["velocities"][0])
    trainer = make_train(config)
    run = jax.jit(functools.partial(trainer.run, num_steps=1, dt=float(data["dt"][0])))
    state = trainer.init(jax.random.PRNGKey(seed), x, v)
    t0 = time.perf_counter()
    state, _ = jax.block_until_ready(run(state, x, v))
    compile_s = time.perf_counter() - t0
    times = []
    for _ in range(num_epochs):
        t0 = time.perf_counter()
        state, _ = jax.block_until_ready(run(state, x, v))
        times.append(time.perf_counter() - t0)
    out = {"shape": shape, "epochs": num_epochs, "median_ms": 1e3 * float(np.median(times)),
           "min_ms": 1e3 * float(np.min(times)), "compile_s": compile_s,
           "device": jax.devices()[0].device_kind, "load_average_1min": os.getloadavg()[0],
           "config": {"num_layers": config.num_layers, "num_features": config.num_features}}
    log(f"one training epoch on {shape} ({out['device']}, {config.num_layers} coupling "
        f"layers x {config.num_features} features): median {out['median_ms']:.1f} ms over "
        f"{num_epochs} (min {out['min_ms']:.1f} ms; compile {compile_s:.1f} s; load average "
        f"{out['load_average_1min']:.2f})")
    return out



class LasaRun(NamedTuple):
    """What :func:`evaluate_shapes` returns: the ``record`` (``metrics.json``), the loaded
    ``data`` (:func:`load_data`), the reproductions ``rollouts (S, 7, K, 2)`` over ``1.2·D``
    (``K − 1 =`` :func:`agents.lfd.lasa_summary.horizon_steps`), the trained
    ``field`` and its training ``result`` (leaves stacked over shapes) and the shapes'
    enlarged bounding ``boxes``."""

    record: dict
    data: dict
    rollouts: np.ndarray
    field: FlowField
    result: LfdResult
    boxes: list[tuple[np.ndarray, np.ndarray]]


def _grid_speeds(field: FlowField, variables: Any, boxes: list, goal_radius: float,
                 size: int = GRID) -> tuple[np.ndarray, np.ndarray]:
    """Per shape the minimum speed on a ``size × size`` grid of its box farther than
    ``goal_radius`` from the goal, and the speed at the goal: ``((S,), (S,))``."""
    grids = np.stack([np.stack(np.meshgrid(np.linspace(lo[0], hi[0], size),
                                           np.linspace(lo[1], hi[1], size)), -1).reshape(-1, 2)
                      for lo, hi in boxes]).astype(np.float32)      # (S, G·G, 2)
    points = np.concatenate([grids, np.zeros((len(boxes), 1, 2), np.float32)], axis=1)
    speeds = np.linalg.norm(np.asarray(velocity_program(field)(variables, jnp.asarray(points))),
                            axis=-1)
    away = np.linalg.norm(grids, axis=-1) > goal_radius
    return np.array([s[:-1][a].min() for s, a in zip(speeds, away, strict=True)]), speeds[:, -1]


def _record_header(config: LfdConfig, seed: int, train_s: float, steps: int, T: int,
                   check_starts: int, check_steps: int | str | None, goal_radius: float) -> dict:
    """The settings part of the record (units, device, configuration, rules of the checks)."""
    return {
        "units": "normalised coordinates of mjxrmp.data.lasa (each shape's demonstrations span "
                 "1 along each axis; goal at the origin); times in s",
        "device": jax.devices()[0].device_kind,
        "seed": seed,
        "config": dataclasses.asdict(config),
        "train_seconds": train_s,
        "rollout": f"method {config.integrator!r} of agents.lfd.flow_field.rollout with each "
                   f"shape's dt from each demonstration's first sample; metrics on the first T "
                   f"samples ('rmse' against the demonstration at equal times), 'arrival' at "
                   f"step {horizon_steps(T)} (>= {ARRIVAL_HORIZON} x the demonstration's "
                   f"duration (T - 1)·dt; within {ACCEPT_FINAL_ERROR} of the goal), "
                   f"'final_error_converged' after {max(steps, horizon_steps(T))} steps",
        "baseline": "straight line from the demonstration's start to the goal at uniform speed "
                    "over the demonstration's duration",
        "convergence_check": {"starts": check_starts, "steps": steps,
                              "steps_rule": {None: "10·T", "auto": "guaranteed arrival bound "
                                             "(agents.lfd.flow_field.arrival_steps)"}.get(
                                                 check_steps, "given"),
                              "box": f"demonstrations' bounding box enlarged by "
                                     f"{BOX_MARGIN:.0%}",
                              "goal_radius": goal_radius, "grid": f"{GRID}x{GRID}"},
        "shapes": {},
    }


def evaluate_shapes(names: list[str], config: LfdConfig, *, seed: int = 0, log_every: int = 100,
                    check_starts: int = 64, check_steps: int | str | None = None,
                    goal_radius: float = 0.05, log: Log = print) -> LasaRun:
    """Train the shapes ``names``, roll out from the demonstrations' starts and from
    ``check_starts`` random starts for the ``check_steps`` rule (:func:`check_horizon`), and
    build the record of the module docstring, logging progress and one line per shape."""
    log(f"training {len(names)} shape(s) on {jax.devices()[0].platform}: {', '.join(names)}; "
        f"{config.iterations} iterations, seed {seed}")
    data = load_data(names)
    t0 = time.perf_counter()
    trainer, result = train_shapes(names, data, config, seed, log_every, log)
    train_s = time.perf_counter() - t0
    field, variables = trainer.field, result.variables
    T = data["demos"].shape[2]
    boxes = [box(d) for d in data["demos"]]
    rng = np.random.default_rng(seed)
    starts = np.stack([rng.uniform(lo, hi, (check_starts, 2)) for lo, hi in boxes])
    steps = check_horizon(check_steps, config, field, variables, data, starts)
    # Reproductions from each demonstration's start, run on to convergence: the trajectory
    # metrics use the first T samples, the arrival check the sample at 1.2·D, the acceptance
    # the converged end point.
    dts = jnp.asarray(data["dt"])
    horizon = horizon_steps(T)
    long = _rollout_program(field, max(steps, horizon), config.integrator)(
        variables, jnp.asarray(data["demos"][:, :, 0]), dts)
    rollouts = np.asarray(long[:, :, :horizon + 1])
    arrival = arrival_times(np.asarray(long), T)
    demo_final, demo_monotone = convergence_stats(field, variables, long)
    check = _rollout_program(field, steps, config.integrator)(
        variables, jnp.asarray(starts, jnp.float32), dts)
    final_dist, monotone = convergence_stats(field, variables, check)
    del long, check
    min_speed, goal_speed = _grid_speeds(field, variables, boxes, goal_radius)
    record = _record_header(config, seed, train_s, steps, T, check_starts, check_steps,
                            goal_radius)
    losses = np.asarray(result.losses)
    for i, name in enumerate(names):
        training = {"final_loss": float(losses[i, -1]), "best_loss": float(result.best_loss[i]),
                    "best_step": int(result.best_step[i]),
                    "stopped_early": bool(result.stopped[i])}
        convergence = {
            "fraction_within_radius": float(np.mean(final_dist[i] < goal_radius)),
            "non_finite": int(np.sum(~np.isfinite(final_dist[i]))),
            "max_final_distance": float(final_dist[i].max()),
            "mean_final_distance": float(final_dist[i].mean()),
            "fraction_monotone": float(np.mean(monotone[i])),
            "min_speed_away_from_goal": float(min_speed[i]),
            "speed_at_goal": float(goal_speed[i])}
        record["shapes"][name] = shape_record(data["demos"][i], rollouts[i], data["dt"][i],
                                              training, demo_final[i], demo_monotone[i],
                                              convergence, arrival[i])
        log(shape_line(name, record["shapes"][name]))
    keys = list(record["shapes"][names[0]]["metrics"])
    record["mean_over_shapes"] = {
        k: float(np.mean([record["shapes"][n]["metrics"][k] for n in names])) for k in keys}
    record["summary"] = summary_table(record["shapes"], goal_radius)
    log(format_summary(record["summary"]))
    return LasaRun(record, data, rollouts, field, result, boxes)
