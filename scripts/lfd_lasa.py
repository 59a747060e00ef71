"""Learn stable LASA dynamics with Euclideanizing flows (thesis §4.2, Figs 4.4 and 4.7).

Usage::

    python scripts/lfd_lasa.py --shapes Angle Sshape [--iterations N] [--seed 0] \\
        [--out results/lfd_lasa]
    python scripts/lfd_lasa.py --all [...]

Every requested shape is trained in **one** compiled program: the shapes' demonstrations
``(7, 235, 2)`` are stacked along a leading axis and :func:`agents.lfd.flow_field.make_train`'s training
step is ``vmap``-ped over it (one ``lax.scan`` per chunk of ``--log-every`` iterations, which is
when progress is printed). Shape ``k`` of :data:`mjxrmp.data.lasa.LASA_SHAPES` draws its key from
``fold_in(PRNGKey(seed), k)``, so a shape's result does not depend on which others are trained
with it. Model and optimiser are :class:`agents.lfd.flow_field.LfdConfig`'s defaults (docs/design.md §4.6);
``--iterations`` overrides the iteration budget (default 5000, early stop after 250 iterations
without improvement), ``--tiny`` uses :meth:`LfdConfig.tiny` (tests).

``--time-epochs N`` only times ``N`` full-batch training epochs on Sshape after compilation
(acceptance 2; prints the median and the load average) and trains nothing.

Rollouts use ``LfdConfig.integrator`` (default ``"latent"``, :func:`agents.lfd.flow_field.rollout`):
``y = ψ(x)`` moves straight to the origin without ever overshooting it and ``x = ψ⁻¹(y)`` with
the flow's exact inverse, so ``‖ψ(x_k)‖`` is non-increasing for every start and step.

Writes to ``--out`` (one folder: ``tar czf lasa.tgz -C DIR .``):

* ``<shape>.npz`` — ``demos (7, T, 2)``, ``rollouts (7, T, 2)`` (the learned system from each
  demonstration's first sample with the demonstrations' ``dt``, as many samples as the
  demonstration), ``dt`` (scalar), ``losses`` (training loss per iteration);
* ``metrics.json`` — per shape: :func:`mjxrmp.metrics.trajectory.all_metrics` between each rollout's
  first ``T`` samples and its demonstration (RMSE, mean error, DTW and DTW / warping-path
  length, Fréchet, final-point error, swept error area), their means over demonstrations, the
  same for a straight-line baseline (uniform speed from the demonstration's start to the goal
  over its duration), the training summary, the **converged** end points of the same rollouts
  run on to ``--check-steps`` (default ``10·T``; ``auto``: the guaranteed arrival bound of every
  start, :func:`agents.lfd.flow_field.arrival_steps`) steps (``final_error_converged``; acceptance:
  below 1 % of the workspace, 0.01, since the normalised demonstrations span 1), and a
  convergence check: rollouts from ``--check-starts`` uniform random starts in the
  demonstrations' bounding box enlarged by 20 % for ``--check-steps`` steps — fraction within
  ``--goal-radius`` of the goal, maximum final distance, count of non-finite rollouts (NaN/inf
  anywhere counts as not converged, distance ``inf``), fraction of rollouts along which
  ``‖ψ(x_k)‖`` (recomputed from the positions) is non-increasing — the minimum speed on a grid
  of that box away from the goal and the speed at the goal; ``summary``: medians over shapes of
  DTW / length and swept error area with one row per shape (also printed as a table). Lengths
  are in the normalised coordinates of :mod:`mjxrmp.data.lasa` (goal at the origin);
* ``<shape>_field.png`` — streamlines of the learned field with the demonstrations and the
  reproductions (as Fig 4.4); ``<shape>_potential.png`` — iso-contours of
  ``Φ(x) = ½‖φ(x) − φ(0)‖²`` with the demonstrations (as Fig 4.7).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import jax
import jax.numpy as jnp
import numpy as np

import mjxrmp  # noqa: F401  (sets XLA flags before any JAX computation)
from agents.lfd.flow_field import LfdConfig, arrival_steps, make_train, rollout, train_batched
from mjxrmp.data.lasa import LASA_SHAPES, load_shape
from mjxrmp.metrics.trajectory import all_metrics

#: Keys every ``<shape>.npz`` holds.
NPZ_KEYS = ("demos", "rollouts", "dt", "losses")
#: Enlargement of the demonstrations' bounding box for the convergence check and the figures.
BOX_MARGIN = 0.2
#: Acceptance: a rollout from a demonstration start ends within 1 % of the workspace size (the
#: normalised demonstrations span 1 along each axis) of the goal.
ACCEPT_FINAL_ERROR = 0.01
#: Rounding allowance of the monotonicity check of ``‖ψ(x_k)‖``, relative to ``max(‖ψ(x_0)‖, 1)``
#: (``ψ`` recomputed from positions that went through ``ψ⁻¹``: float32 rounding ~1e-6).
MONOTONE_RTOL = 1e-5


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
                 log_every: int, log=print):
    """Train all shapes in one vmapped program (:func:`agents.lfd.flow_field.train_batched`), in compiled
    chunks of ``log_every`` steps with a progress line after each. Returns ``(trainer,
    result)`` with every leaf of ``result`` stacked over shapes."""
    base = jax.random.PRNGKey(seed)
    keys = jnp.stack([jax.random.fold_in(base, LASA_SHAPES.index(n)) for n in names])
    t0 = time.perf_counter()

    def progress(done, total, ls, state):
        el = time.perf_counter() - t0
        per = "  ".join(f"{name}={ls[i, -1]:.5f}" for i, name in enumerate(names[:6]))
        more = f"  (+{len(names) - 6} more)" if len(names) > 6 else ""
        stopped = int(np.sum(np.asarray(state.stopped)))
        log(f"[{done:>5d}/{total}] {el:7.1f} s  mean loss {ls[:, -1].mean():.5f}  {per}{more}"
            + (f"  early-stopped: {stopped}/{len(names)}" if stopped else ""), flush=True)

    return train_batched(config, keys, data["demos"], data["velocities"],
                         log_every=log_every, callback=progress)


@functools.lru_cache(maxsize=8)
def _rollout_program(field, num_steps: int, method: str):
    """``(variables, x0 (S, n, 2), dt (S,)) -> (S, n, num_steps + 1, 2)``, jitted (cached)."""
    return jax.jit(jax.vmap(lambda var, x0, dt: rollout(field, var, x0, num_steps, dt, method)))


@functools.lru_cache(maxsize=8)
def _velocity_program(field):
    return jax.jit(jax.vmap(field.velocity))


def _check_steps(value: str) -> int | str:
    """``--check-steps``: a positive integer or ``"auto"``."""
    if value == "auto":
        return value
    try:
        steps = int(value)
    except ValueError:
        steps = 0
    if steps < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer or 'auto', got {value!r}")
    return steps


def check_horizon(check_steps: int | str | None, config: LfdConfig, field, variables,
                  data: dict, starts: np.ndarray) -> int:
    """Steps of the convergence rollouts: ``10·T`` (``None``), the given number, or for
    ``"auto"`` :func:`agents.lfd.flow_field.arrival_steps` over the random ``starts (S, n, 2)`` and the
    demonstrations' starts with each shape's ``dt`` (at least ``T − 1``): every start then
    reaches ``10⁻³·ε`` of the goal in the latent space by construction, so the check measures
    whether the goal is reached, not whether it is reached within a fixed time."""
    T = data["demos"].shape[2]
    if check_steps is None:
        return 10 * T
    if check_steps != "auto":
        return int(check_steps)
    if config.integrator != "latent":
        raise SystemExit(f"--check-steps auto needs the latent integrator (the bound is for "
                         f"agents.lfd.flow_field.latent_step), got integrator={config.integrator!r}")
    points = np.concatenate([np.asarray(starts, np.float32),
                             np.asarray(data["demos"][:, :, 0], np.float32)], axis=1)
    r0 = np.asarray(_latent_norm_program(field)(variables, jnp.asarray(points)[:, :, None]))
    return max(arrival_steps(config, r0[..., 0], np.asarray(data["dt"])[:, None]), T - 1)


def straight_line(demos: np.ndarray) -> np.ndarray:
    """Uniform-speed straight line from each demonstration's start to the goal (origin), as many
    samples as the demonstration: ``(N, T, 2)``."""
    T = demos.shape[1]
    return demos[:, :1] * (1.0 - np.linspace(0.0, 1.0, T))[None, :, None]


@functools.lru_cache(maxsize=8)
def _latent_norm_program(field):
    return jax.jit(jax.vmap(lambda var, x: jnp.linalg.norm(field.latent(var, x), axis=-1)))


def latent_norms(field, variables, xs: jax.Array, chunk: int = 2048) -> np.ndarray:
    """``‖ψ(x)‖`` along rollouts ``xs (S, n, K, 2)``: ``(S, n, K)``, evaluated ``chunk`` steps at
    a time so that long checks (``--check-steps auto``) fit in device memory."""
    program = _latent_norm_program(field)
    return np.concatenate([np.asarray(program(variables, xs[:, :, k:k + chunk]))
                           for k in range(0, xs.shape[2], chunk)], axis=-1)


def convergence_stats(field, variables, xs: jax.Array, rtol: float = MONOTONE_RTOL
                      ) -> tuple[np.ndarray, np.ndarray]:
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


def summary_table(shapes: dict, goal_radius: float) -> dict:
    """Medians over shapes of DTW / path length and swept error area, the worst converged
    final error and check results, and one row per shape (the acceptance numbers)."""
    rows = {n: {"dtw_normalized": r["metrics"]["dtw_normalized"],
                "swept_error_area": r["metrics"]["swept_error_area"],
                "max_final_error_converged": r["max_final_error_converged"],
                "fraction_converged": r["convergence"]["fraction_within_radius"],
                "fraction_monotone": r["convergence"]["fraction_monotone"],
                "max_final_distance": r["convergence"]["max_final_distance"]}
            for n, r in shapes.items()}
    col = lambda k: np.asarray([row[k] for row in rows.values()])  # noqa: E731
    return {
        "median_dtw_normalized": float(np.median(col("dtw_normalized"))),
        "median_swept_error_area": float(np.median(col("swept_error_area"))),
        "max_final_error_converged": float(col("max_final_error_converged").max()),
        "shapes_demo_rollouts_within_1pct": int(np.sum(col("max_final_error_converged")
                                                       < ACCEPT_FINAL_ERROR)),
        "shapes_all_starts_converged": int(np.sum(col("fraction_converged") == 1.0)),
        "shapes_all_monotone": int(np.sum(col("fraction_monotone") == 1.0)),
        "num_shapes": len(rows),
        "goal_radius": goal_radius,
        "per_shape": rows,
    }


def format_summary(summary: dict) -> str:
    """The summary table as text (one line per shape, then the medians)."""
    head = (f"{'shape':>16s}  {'DTW/len':>8s}  {'area':>8s}  {'conv. final':>11s}  "
            f"{'converged':>9s}  {'monotone':>8s}  {'max dist':>9s}")
    lines = [head]
    for n, r in summary["per_shape"].items():
        lines.append(f"{n:>16s}  {r['dtw_normalized']:8.4f}  {r['swept_error_area']:8.4f}  "
                     f"{r['max_final_error_converged']:11.2e}  {r['fraction_converged']:9.0%}  "
                     f"{r['fraction_monotone']:8.0%}  {r['max_final_distance']:9.2e}")
    k = summary["num_shapes"]
    lines.append(f"{'median':>16s}  {summary['median_dtw_normalized']:8.4f}  "
                 f"{summary['median_swept_error_area']:8.4f}  "
                 f"{summary['max_final_error_converged']:11.2e} (max)")
    lines.append(f"demonstration rollouts within 1 % of the goal: "
                 f"{summary['shapes_demo_rollouts_within_1pct']}/{k} shapes; all random starts "
                 f"within {summary['goal_radius']}: {summary['shapes_all_starts_converged']}/{k};"
                 f" ‖ψ‖ monotone on every rollout: {summary['shapes_all_monotone']}/{k}")
    return "\n".join(lines)


def metric_summary(rollouts: np.ndarray, demos: np.ndarray) -> dict:
    per = [all_metrics(r, d) for r, d in zip(rollouts, demos, strict=True)]
    keys = list(per[0])
    return {"mean": {k: float(np.mean([p[k] for p in per])) for k in keys},
            "per_demo": {k: [float(p[k]) for p in per] for k in keys}}


def time_epochs(config: LfdConfig, num_epochs: int, seed: int = 0,
                shape: str = "Sshape") -> dict:
    """Wall time of one full-batch training epoch (one gradient step on all ``7 × 235`` samples
    of ``shape``, :func:`agents.lfd.flow_field.make_train`'s step) after compilation: ``num_epochs`` calls
    of the jitted one-step ``run``, each waited for. Prints and returns the median (ms), with
    the minimum, the device and the 1-minute load average (other processes on the CPU)."""
    data = load_data([shape])
    x, v = jnp.asarray(data["demos"][0]), jnp.asarray(data["velocities"][0])
    trainer = make_train(config)
    run = jax.jit(functools.partial(trainer.run, num_steps=1))
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
    print(f"one training epoch on {shape} ({out['device']}, {config.num_layers} coupling "
          f"layers x {config.num_features} features): median {out['median_ms']:.1f} ms over "
          f"{num_epochs} (min {out['min_ms']:.1f} ms; compile {compile_s:.1f} s; load average "
          f"{out['load_average_1min']:.2f})", flush=True)
    return out


def main(argv=None) -> dict:
    """Train the selected shapes, roll out, check convergence, write files; return metrics."""
    # docs/design.md §5.4: GPUs default to TF32 matrix products. Their ~1e-3 relative error breaks the
    # flow's exact inverse (ψ(ψ⁻¹(y)) ≠ y), so the latent rollout's monotone ‖ψ‖ held on only
    # 2 of 30 shapes on an H100; with full float32 products it holds on all 30.
    jax.config.update("jax_default_matmul_precision", "highest")
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    g = p.add_mutually_exclusive_group()
    g.add_argument("--shapes", nargs="+", metavar="SHAPE", help="LASA shape names")
    g.add_argument("--all", action="store_true", help="all 30 LASA shapes")
    p.add_argument("--iterations", type=int, default=None,
                   help="gradient steps (default: LfdConfig's 5000, with early stop)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="results/lfd_lasa")
    p.add_argument("--log-every", type=int, default=100, help="iterations per compiled chunk")
    p.add_argument("--tiny", action="store_true", help="LfdConfig.tiny() (tests)")
    p.add_argument("--check-starts", type=int, default=64)
    p.add_argument("--check-steps", type=_check_steps, default=None,
                   help="rollout steps of the convergence check and of the converged "
                        "demonstration rollouts: a number, or 'auto' = the guaranteed arrival "
                        "bound of every start (agents.lfd.flow_field.arrival_steps; latent integrator); "
                        "default 10·T")
    p.add_argument("--goal-radius", type=float, default=0.05,
                   help="convergence radius of the check (normalised units)")
    p.add_argument("--no-figures", action="store_true")
    p.add_argument("--time-epochs", type=int, default=None, metavar="N",
                   help="only time N full-batch training epochs on Sshape (after compilation) "
                        "and print their median (acceptance 2)")
    args = p.parse_args(argv)
    if args.time_epochs is not None:
        if args.time_epochs < 1:
            p.error(f"--time-epochs must be >= 1, got {args.time_epochs}")
        config = LfdConfig.tiny() if args.tiny else LfdConfig()
        return time_epochs(config, args.time_epochs, args.seed)
    if not (args.all or args.shapes):
        p.error("one of --shapes, --all or --time-epochs is required")
    try:
        names = list(LASA_SHAPES) if args.all else canonical_shapes(args.shapes)
    except ValueError as err:
        p.error(str(err))
    for flag in ("iterations", "log_every", "check_starts"):
        val = getattr(args, flag)
        if val is not None and val < 1:
            p.error(f"--{flag.replace('_', '-')} must be >= 1, got {val}")
    if not args.goal_radius > 0:
        p.error(f"--goal-radius must be > 0, got {args.goal_radius}")

    config = LfdConfig.tiny() if args.tiny else LfdConfig()
    if args.iterations is not None:
        config = config.replace(iterations=args.iterations)
    os.makedirs(args.out, exist_ok=True)
    print(f"training {len(names)} shape(s) on {jax.devices()[0].platform}: {', '.join(names)}; "
          f"{config.iterations} iterations, seed {args.seed}", flush=True)

    data = load_data(names)
    t0 = time.perf_counter()
    trainer, result = train_shapes(names, data, config, args.seed, args.log_every)
    train_s = time.perf_counter() - t0
    field, variables = trainer.field, result.variables
    T = data["demos"].shape[2]

    # Random starts of the convergence check (in the enlarged box) and the check's length:
    # 10·T steps, a given number, or 'auto', the guaranteed arrival bound of every start.
    boxes = [box(d) for d in data["demos"]]
    rng = np.random.default_rng(args.seed)
    starts = np.stack([rng.uniform(lo, hi, (args.check_starts, 2)) for lo, hi in boxes])
    steps = check_horizon(args.check_steps, config, field, variables, data, starts)
    # Reproductions from each demonstration's start, run on to convergence: the trajectory
    # metrics use the first T samples, the acceptance the converged end point.
    dts = jnp.asarray(data["dt"])
    long = _rollout_program(field, max(steps, T - 1), config.integrator)(
        variables, jnp.asarray(data["demos"][:, :, 0]), dts)
    rollouts = np.asarray(long[:, :, :T])
    demo_final, demo_monotone = convergence_stats(field, variables, long)

    # Convergence check from the random starts, and speeds on a grid of the box.
    check = _rollout_program(field, steps, config.integrator)(
        variables, jnp.asarray(starts, jnp.float32), dts)
    final_dist, monotone = convergence_stats(field, variables, check)
    del long, check
    S = len(names)
    G = 41
    grids = np.stack([np.stack(np.meshgrid(np.linspace(lo[0], hi[0], G),
                                           np.linspace(lo[1], hi[1], G)), -1).reshape(-1, 2)
                      for lo, hi in boxes]).astype(np.float32)      # (S, G·G, 2)
    points = np.concatenate([grids, np.zeros((S, 1, 2), np.float32)], axis=1)  # + the goal
    speeds = np.linalg.norm(np.asarray(_velocity_program(field)(variables, jnp.asarray(points))),
                            axis=-1)
    grid_speed, goal_speed = speeds[:, :-1], speeds[:, -1]
    away = np.linalg.norm(grids, axis=-1) > args.goal_radius
    record = {
        "units": "normalised coordinates of mjxrmp.data.lasa (each shape's demonstrations span "
                 "1 along each axis; goal at the origin); times in s",
        "device": jax.devices()[0].device_kind,
        "seed": args.seed,
        "config": dataclasses.asdict(config),
        "train_seconds": train_s,
        "rollout": f"method {config.integrator!r} of agents.lfd.flow_field.rollout with each shape's dt "
                   f"from each demonstration's first sample; metrics on the first T samples, "
                   f"'final_error_converged' after {max(steps, T - 1)} steps",
        "baseline": "straight line from the demonstration's start to the goal at uniform speed "
                    "over the demonstration's duration",
        "convergence_check": {"starts": args.check_starts, "steps": steps,
                              "steps_rule": {None: "10·T", "auto": "guaranteed arrival bound "
                                             "(agents.lfd.flow_field.arrival_steps)"}.get(
                                                 args.check_steps, "given"),
                              "box": f"demonstrations' bounding box enlarged by "
                                     f"{BOX_MARGIN:.0%}",
                              "goal_radius": args.goal_radius, "grid": f"{G}x{G}"},
        "shapes": {},
    }
    losses = np.asarray(result.losses)
    for i, name in enumerate(names):
        demos = data["demos"][i]
        summary = metric_summary(rollouts[i], demos)
        record["shapes"][name] = {
            "dt": float(data["dt"][i]),
            "metrics": summary["mean"],
            "per_demo": summary["per_demo"],
            "baseline_straight_line": metric_summary(straight_line(demos), demos)["mean"],
            "final_loss": float(losses[i, -1]),
            "best_loss": float(result.best_loss[i]),
            "best_step": int(result.best_step[i]),
            "stopped_early": bool(result.stopped[i]),
            "final_error_converged": [float(d) for d in demo_final[i]],
            "max_final_error_converged": float(demo_final[i].max()),
            "demo_rollouts_monotone": bool(demo_monotone[i].all()),
            "convergence": {
                "fraction_within_radius": float(np.mean(final_dist[i] < args.goal_radius)),
                "non_finite": int(np.sum(~np.isfinite(final_dist[i]))),
                "max_final_distance": float(final_dist[i].max()),
                "mean_final_distance": float(final_dist[i].mean()),
                "fraction_monotone": float(np.mean(monotone[i])),
                "min_speed_away_from_goal": float(grid_speed[i][away[i]].min()),
                "speed_at_goal": float(goal_speed[i]),
            },
        }
        np.savez(os.path.join(args.out, f"{name}.npz"), demos=demos, rollouts=rollouts[i],
                 dt=np.float32(data["dt"][i]), losses=losses[i].astype(np.float32))
        m, b = summary["mean"], record["shapes"][name]["baseline_straight_line"]
        c = record["shapes"][name]["convergence"]
        print(f"{name:>16s}: RMSE {m['rmse']:.4f} (straight line {b['rmse']:.4f})  "
              f"DTW/len {m['dtw_normalized']:.4f}  Fréchet {m['frechet']:.4f}  "
              f"area {m['swept_error_area']:.4f}  final {m['final_point_error']:.4f}  | "
              f"converged {c['fraction_within_radius']:.0%} (max dist "
              f"{c['max_final_distance']:.4f}, ‖ψ‖ monotone {c['fraction_monotone']:.0%})  "
              f"converged final error {record['shapes'][name]['max_final_error_converged']:.2e}"
              f"  min speed {c['min_speed_away_from_goal']:.2e}", flush=True)
    keys = list(record["shapes"][names[0]]["metrics"])
    record["mean_over_shapes"] = {
        k: float(np.mean([record["shapes"][n]["metrics"][k] for n in names])) for k in keys}
    record["summary"] = summary_table(record["shapes"], args.goal_radius)
    print(format_summary(record["summary"]), flush=True)
    with open(os.path.join(args.out, "metrics.json"), "w") as f:
        json.dump(record, f, indent=1)

    if not args.no_figures:
        plot_all(names, data, rollouts, field, variables, boxes, args.out)
    print(f"wrote {args.out}/ ({train_s:.0f} s training)")
    return record


def plot_all(names, data, rollouts, field, variables, boxes, out: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    G = 80
    pad = [box(d, 0.5) for d in data["demos"]]                      # figure extent
    grids = np.stack([np.stack(np.meshgrid(np.linspace(lo[0], hi[0], G),
                                           np.linspace(lo[1], hi[1], G)), -1)
                      for lo, hi in pad]).astype(np.float32)
    vel = np.asarray(_velocity_program(field)(variables, jnp.asarray(grids)))
    pot = np.asarray(jax.jit(jax.vmap(field.potential))(variables, jnp.asarray(grids)))
    for i, name in enumerate(names):
        X, Y = grids[i, ..., 0], grids[i, ..., 1]
        demos = data["demos"][i]

        fig, ax = plt.subplots(figsize=(5, 5))
        speed = np.linalg.norm(vel[i], axis=-1)
        ax.streamplot(X, Y, vel[i, ..., 0], vel[i, ..., 1], color=speed, cmap="viridis",
                      density=1.4, linewidth=0.7, arrowsize=0.8)
        for k, d in enumerate(demos):
            ax.plot(d[:, 0], d[:, 1], color="k", lw=2.2, label="demonstrations" if k == 0
                    else None)
            ax.plot(rollouts[i, k, :, 0], rollouts[i, k, :, 1], color="r", lw=1.4, ls="--",
                    label="reproductions" if k == 0 else None)
        ax.plot(0, 0, "x", color="limegreen", ms=12, mew=3, label="goal")
        ax.set_xlim(X.min(), X.max())
        ax.set_ylim(Y.min(), Y.max())
        ax.set_aspect("equal")
        ax.set_title(f"{name}: learned field (cf. Fig 4.4)")
        ax.legend(loc="lower left", fontsize=7)
        fig.tight_layout()
        fig.savefig(os.path.join(out, f"{name}_field.png"), dpi=90)
        plt.close(fig)

        fig, ax = plt.subplots(figsize=(5, 5))
        # Equally spaced latent radii ‖φ(x) − φ(0)‖ up to 1.3× the largest on the demos.
        r_demo = np.sqrt(2.0 * np.asarray(field.potential(
            jax.tree.map(lambda a, i=i: a[i], variables), jnp.asarray(demos))).max())
        levels = 0.5 * np.linspace(0.0, 1.3 * r_demo, 16)[1:] ** 2
        ax.contour(X, Y, pot[i], levels=levels, cmap="viridis", linewidths=1.0)
        for d in demos:
            ax.plot(d[:, 0], d[:, 1], color="k", lw=1.8)
        ax.plot(0, 0, "x", color="limegreen", ms=12, mew=3)
        ax.set_aspect("equal")
        ax.set_title(f"{name}: Φ(x) = ½‖φ(x) − φ(0)‖² (cf. Fig 4.7)")
        fig.tight_layout()
        fig.savefig(os.path.join(out, f"{name}_potential.png"), dpi=90)
        plt.close(fig)


if __name__ == "__main__":
    main()
