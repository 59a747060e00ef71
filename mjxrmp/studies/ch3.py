"""Thesis Figs 3.2 and 3.3: RMP²-CLF vs RMPflow-GDS on 2-D point robots (§3.2.7).

* **Fig 3.2** — one point robot with double-integrator dynamics reaches a goal past a circular
  obstacle. Leaves: the RMPflow collision-avoidance GDS (obstacle) and a goal attractor that is
  either RMP²-CLF (eq 3.32, ``P = I``) with the potential, spiral or sinusoidal nominal
  controller, or the RMPflow goal-attractor GDS. Metric and potential are the same in all cases.
* **Fig 3.3** — ``N`` point robots start on a circle and swap to the antipodal points; every
  pair of robots has the collision-avoidance GDS on its distance. The spiral RMP²-CLF goal
  attractor is compared with the GDS goal attractor; reported are the time until every robot is
  within a tolerance of its goal and the minimum pairwise distance.

The joint configuration is the stacked positions ``q ∈ R^{2N}``; the task map returns the goal
offsets ``(N, 2)`` and the obstacle / pairwise distances ``(·, 1)``;
:func:`mjxrmp.core.rmp2.acceleration` combines the leaves and a jitted ``lax.scan`` integrates
with semi-implicit Euler (dt = 0.01).

Choices the thesis leaves open (documented, not tuned per figure):

* RMPflow constants for both GDSs (see :mod:`mjxrmp.leaves.point_robot`); 8 robots on a circle
  of radius 5, pairwise safety radius 1, start positions perturbed by seeded noise of std 0.05
  (plus one exactly symmetric start), goal tolerance 0.05.
* CLF class-K function ``α = γ s²`` with ``γ = 2`` applied to the Riemannian speed
  ``s = ‖ẋ‖_G`` (``clf_leaf(..., speed="metric")``): it demands the same dissipation
  ``2 ẋᵀGẋ`` as the GDS attractor's damping ``B = 2 w(x) I``, so the two attractors differ only
  in their nominal behaviour. With ``α`` of the Euclidean speed exactly as in eq 3.30 the spiral
  still avoids the deadlock but its final approach is slow (dissipation ``2‖ẋ‖²`` against a
  metric ``w = 10`` at the goal); that variant is reported as ``spiral_clf_euclidean_alpha``.

:func:`reproduce` runs both figures and builds the ``fig3_3.json`` record; the plots are in
:mod:`mjxrmp.studies.ch3_figures` and the command line is ``scripts/reproduce_ch3.py``.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from mjxrmp.core import rmp2
from mjxrmp.leaves.clf import (
    clf_leaf,
    potential_nominal,
    quadratic_alpha,
    sinusoidal_nominal,
    spiral_nominal,
)
from mjxrmp.leaves.gds import Leaf, family
from mjxrmp.leaves.point_robot import (
    CollisionParams,
    GoalAttractorParams,
    collision_avoidance,
    goal_attractor,
    goal_metric,
    goal_offsets,
    goal_potential,
    obstacle_distance,
    pairwise_distances,
)

CONTROLLERS = ("gds", "potential", "spiral", "sinusoidal")

# --- Fig 3.2 scene (the 2-D example accompanying RMPflow / RMP²-CLF) -------------------------
SINGLE_GOAL = (-3.0, 3.0)
SINGLE_OBSTACLE = (0.0, 0.0)
SINGLE_OBSTACLE_RADIUS = 1.0
SINGLE_START = (2.5, -3.2)
SINGLE_START_VELOCITY = (-1.0, 1.0)
SINGLE_COLLISION = CollisionParams(epsilon=0.2, alpha=1e-5, eta=0.0)

# --- Fig 3.3 scene (multi-robot swap of Li et al. 2019) ---------------------------------------
SWAP_ROBOTS = 8
SWAP_RADIUS = 5.0  #: the robots start on, and swap across, a circle of this radius
SWAP_SAFETY = 1.0  #: ``R`` of the pairwise distance ``x = d/R − 1``
SWAP_NOISE = 0.05  #: std of the seeded perturbation of the start positions (breaks exact symmetry)
SWAP_COLLISION = CollisionParams(epsilon=1e-8, alpha=1e-5, eta=0.0)

#: Class-K function of the CLF goal attractors, ``α(s) = γ s²`` with ``γ = η = 2`` ...
CLF_GAMMA = 2.0
#: ... of the Riemannian speed ``s = ‖ẋ‖_G``: the dissipation of the GDS damping ``B = η w(x) I``.
CLF_SPEED = "metric"
DT = 0.01


__all__ = [
    "CONTROLLERS",
    "LABELS",
    "SWAP_VARIANTS",
    "Ch3Result",
    "fig3_3_record",
    "goal_leaf",
    "reproduce",
    "rollout",
    "run_fig3_2",
    "run_fig3_3",
    "simulate_single",
    "simulate_swap",
    "summary_lines",
    "swap_metrics",
    "swap_scene",
]


def goal_leaf(controller: str, p: GoalAttractorParams, t: jax.Array, gamma: float = CLF_GAMMA,
              speed: str = CLF_SPEED) -> Leaf:
    """Single-subtask goal-attractor leaf for ``controller`` (GDS or RMP²-CLF with P = I)."""
    if controller == "gds":
        return goal_attractor(p)
    Phi = goal_potential(p)
    if controller == "potential":
        nominal = potential_nominal(Phi)
    elif controller == "spiral":
        nominal = spiral_nominal(Phi)
    elif controller == "sinusoidal":
        nominal = sinusoidal_nominal(Phi, t)
    else:
        raise ValueError(f"controller must be one of {CONTROLLERS}, got {controller!r}")
    return clf_leaf(nominal, goal_metric(p), Phi, quadratic_alpha(gamma), P="identity",
                    speed=speed)


def rollout(accel: Callable, q0: jax.Array, qd0: jax.Array, steps: int,
            dt: float = DT) -> jax.Array:
    """Semi-implicit Euler ``q̇ ← q̇ + dt·q̈(q, q̇, t)``, ``q ← q + dt·q̇``; returns ``q`` of
    every step, shape ``(steps + 1, d)``."""

    def step(carry, k):
        q, qd = carry
        qdd = accel(q, qd, k * dt)
        qd = qd + dt * qdd
        q = q + dt * qd
        return (q, qd), q

    _, qs = jax.lax.scan(step, (q0, qd0), jnp.arange(steps, dtype=q0.dtype))
    return jnp.concatenate([q0[None], qs], axis=0)


# ---------------------------------------------------------------------------------------------
# Fig 3.2: single robot, circular obstacle
# ---------------------------------------------------------------------------------------------


def _single_task_map(q, goal, center, t):
    Y = q.reshape(1, 2)
    return {"goal": goal_offsets(Y, goal[None]),
            "obstacle": obstacle_distance(Y, center, SINGLE_OBSTACLE_RADIUS)}


@partial(jax.jit, static_argnames=("controller", "steps", "gamma", "speed"))
def simulate_single(controller: str, q0: jax.Array, qd0: jax.Array, steps: int,
                    goal: jax.Array, center: jax.Array, gamma: float = CLF_GAMMA,
                    speed: str = CLF_SPEED) -> jax.Array:
    """Trajectory ``(steps + 1, 2)`` of the Fig 3.2 point robot under ``controller``."""
    p = GoalAttractorParams()
    obstacle = family(collision_avoidance(SINGLE_COLLISION))

    def leaf_fn(x, xd, goal_, center_, t):
        g = family(goal_leaf(controller, p, t, gamma, speed))
        return {"goal": g(x["goal"], xd["goal"]),
                "obstacle": obstacle(x["obstacle"], xd["obstacle"])}

    def accel(q, qd, t):
        return rmp2.acceleration(_single_task_map, leaf_fn, q, qd, goal, center, t)

    return rollout(accel, q0, qd0, steps)


def run_fig3_2(steps: int = 4000) -> dict[str, np.ndarray]:
    """Trajectories of the four controllers on the Fig 3.2 scene."""
    q0 = jnp.asarray(SINGLE_START)
    qd0 = jnp.asarray(SINGLE_START_VELOCITY)
    goal = jnp.asarray(SINGLE_GOAL)
    center = jnp.asarray(SINGLE_OBSTACLE)
    return {c: np.asarray(simulate_single(c, q0, qd0, steps, goal, center)) for c in CONTROLLERS}


# ---------------------------------------------------------------------------------------------
# Fig 3.3: multi-robot antipodal swap
# ---------------------------------------------------------------------------------------------


def swap_scene(n: int = SWAP_ROBOTS, radius: float = SWAP_RADIUS, noise: float = SWAP_NOISE,
               seed: int = 0) -> tuple[jax.Array, jax.Array]:
    """Start positions ``(n, 2)`` on a circle (plus seeded noise) and antipodal goals ``(n, 2)``."""
    theta = 2.0 * jnp.pi * jnp.arange(n) / n
    ring = radius * jnp.stack([jnp.cos(theta), jnp.sin(theta)], axis=-1)
    start = ring + noise * jax.random.normal(jax.random.PRNGKey(seed), ring.shape)
    return start, -ring


def _swap_task_map(q, goals, t):
    Y = q.reshape(-1, 2)
    return {"goal": goal_offsets(Y, goals), "pairs": pairwise_distances(Y, SWAP_SAFETY)}


@partial(jax.jit, static_argnames=("controller", "steps", "gamma", "speed"))
def simulate_swap(controller: str, start: jax.Array, goals: jax.Array, steps: int,
                  gamma: float = CLF_GAMMA, speed: str = CLF_SPEED) -> jax.Array:
    """Positions ``(steps + 1, N, 2)`` of the Fig 3.3 robots (starting at rest) under
    ``controller`` (``"gds"`` or ``"spiral"``; any of :data:`CONTROLLERS` works)."""
    p = GoalAttractorParams()
    pairs = family(collision_avoidance(SWAP_COLLISION))

    def leaf_fn(x, xd, goals_, t):
        g = family(goal_leaf(controller, p, t, gamma, speed))
        return {"goal": g(x["goal"], xd["goal"]), "pairs": pairs(x["pairs"], xd["pairs"])}

    def accel(q, qd, t):
        return rmp2.acceleration(_swap_task_map, leaf_fn, q, qd, goals, t)

    q0 = start.reshape(-1)
    qs = rollout(accel, q0, jnp.zeros_like(q0), steps)
    return qs.reshape(steps + 1, -1, 2)


def swap_metrics(traj: np.ndarray, goals: np.ndarray, tol: float, dt: float = DT) -> dict:
    """Time until all robots are within ``tol`` of their goals (and stay there), the minimum
    pairwise distance, and the final largest goal error."""
    traj = np.asarray(traj, dtype=np.float64)
    err = np.linalg.norm(traj - np.asarray(goals)[None], axis=-1).max(axis=-1)  # (T,)
    inside = err <= tol
    # first index from which the team stays inside the tolerance until the end
    outside = np.flatnonzero(~inside)
    first = 0 if outside.size == 0 else int(outside[-1]) + 1
    reached = first < len(err)
    i, j = np.triu_indices(traj.shape[1], k=1)
    dists = np.linalg.norm(traj[:, i] - traj[:, j], axis=-1)
    return {
        "reached": bool(reached),
        "time_to_goal": float(first * dt) if reached else None,
        "min_pair_distance": float(dists.min()),
        "final_max_goal_error": float(err[-1]),
        "finite": bool(np.all(np.isfinite(traj))),
    }


#: Fig 3.3 variants: name -> (goal-attractor controller, argument of the CLF's class-K function).
SWAP_VARIANTS = {
    "spiral_clf": ("spiral", "metric"),
    "gds": ("gds", "metric"),
    # ablation: α of the Euclidean speed exactly as written in eq 3.30
    "spiral_clf_euclidean_alpha": ("spiral", "euclidean"),
}


def run_fig3_3(steps: int = 6000, n: int = SWAP_ROBOTS, tol: float = 0.05, seeds=(0,),
               variants=tuple(SWAP_VARIANTS), symmetric: bool = True) -> dict:
    """Swap trajectories and metrics for the spiral RMP²-CLF and GDS goal attractors.

    Every variant runs from the same seeded starts (``seeds``; the first is plotted) and, with
    ``symmetric``, once more from the exactly symmetric start (no noise).
    """
    out = {"trajectories": {}, "metrics": {}, "per_seed": {}, "symmetric_start": {}}
    for name in variants:
        controller, speed = SWAP_VARIANTS[name]
        per_seed = []
        for seed in seeds:
            start, goals = swap_scene(n=n, seed=seed)
            traj = np.asarray(simulate_swap(controller, start, goals, steps, speed=speed))
            per_seed.append(swap_metrics(traj, np.asarray(goals), tol))
            if seed == seeds[0]:
                out["trajectories"][name] = traj
                out["metrics"][name] = per_seed[-1]
                out["goals"] = np.asarray(goals)
                out["start"] = np.asarray(start)
        out["per_seed"][name] = per_seed
        if symmetric:
            start, goals = swap_scene(n=n, noise=0.0)
            traj = np.asarray(simulate_swap(controller, start, goals, steps, speed=speed))
            out["symmetric_start"][name] = swap_metrics(traj, np.asarray(goals), tol)
    return out


def fig3_3_record(res: dict, steps: int, tol: float, seeds) -> dict:
    """The JSON record written to ``fig3_3.json``."""
    def summary(name):
        runs = res["per_seed"][name]
        times = [m["time_to_goal"] for m in runs]
        return {
            "seed0": res["metrics"][name],
            "time_to_goal_per_seed": times,
            "min_pair_distance_per_seed": [m["min_pair_distance"] for m in runs],
            "reached_all_seeds": all(m["reached"] for m in runs),
            "mean_time_to_goal": (float(np.mean(times)) if all(t is not None for t in times)
                                  else None),
            "symmetric_start": res["symmetric_start"].get(name),
        }

    record = {
        "figure": "3.3",
        "n_robots": int(res["goals"].shape[0]),
        "circle_radius": SWAP_RADIUS,
        "safety_radius": SWAP_SAFETY,
        "start_noise_std": SWAP_NOISE,
        "dt": DT,
        "steps": steps,
        "horizon_s": steps * DT,
        "goal_tolerance": tol,
        "clf_alpha": f"alpha(s) = {CLF_GAMMA} s^2, s = Riemannian speed sqrt(xd^T G xd)",
        "clf_P": "identity",
        "gds_damping": "B = eta w(x) I, eta = 2",
        "seeds": list(seeds),
        "time_to_goal_definition": "first time after which every robot stays within "
                                   "goal_tolerance of its goal (null: never within horizon)",
    }
    for name in res["per_seed"]:
        record[name] = summary(name)
    return record


#: Labels of the Fig 3.2 goal attractors.
LABELS = {"potential": "potential", "spiral": "spiral", "sinusoidal": "sinusoidal",
          "gds": "RMPflow-GDS"}


@dataclasses.dataclass(frozen=True)
class Ch3Result:
    """Everything :func:`reproduce` computed: the Fig 3.2 trajectories per controller, the
    Fig 3.3 runs (:func:`run_fig3_3`), the ``fig3_3.json`` record and the wall time (s) of each
    figure."""

    fig3_2: dict[str, np.ndarray]
    fig3_3: dict
    record: dict
    tol: float
    seeds: tuple[int, ...]
    seconds: tuple[float, float]


def reproduce(steps: int = 6000, robots: int = SWAP_ROBOTS, tol: float = 0.05,
              seeds: int = 4) -> Ch3Result:
    """Run Fig 3.2 (``2/3`` of ``steps`` integration steps) and Fig 3.3 (``steps`` steps,
    ``robots`` robots, start-noise seeds ``0 … seeds − 1``, goal tolerance ``tol``)."""
    t0 = time.perf_counter()
    trajs = run_fig3_2(steps=max(1, (2 * steps) // 3))
    t1 = time.perf_counter()
    seed_list = tuple(range(seeds))
    res = run_fig3_3(steps=steps, n=robots, tol=tol, seeds=seed_list)
    record = fig3_3_record(res, steps, tol, seed_list)
    t2 = time.perf_counter()
    return Ch3Result(trajs, res, record, tol, seed_list, (t1 - t0, t2 - t1))


def summary_lines(result: Ch3Result) -> list[str]:
    """The console report: Fig 3.2 goal errors and clearances, Fig 3.3 times to goal and
    minimum pair distances per variant and seed."""

    def fmt(v: float | None) -> str:
        return "never" if v is None else f"{v:.2f}"

    lines = [f"Fig 3.2: final distance to goal ({result.seconds[0]:.1f} s)"]
    for c in CONTROLLERS:
        tr = result.fig3_2[c]
        d = float(np.linalg.norm(tr[-1] - np.asarray(SINGLE_GOAL)))
        clearance = float(np.min(np.linalg.norm(tr - np.asarray(SINGLE_OBSTACLE), axis=-1))
                          - SINGLE_OBSTACLE_RADIUS)
        lines.append(f"  {LABELS[c]:<12} goal error {d:.4f}   min obstacle clearance "
                     f"{clearance:.3f}")
    record, res = result.record, result.fig3_3
    lines += [f"Fig 3.3: {record['n_robots']} robots, tolerance {result.tol}, horizon "
              f"{record['horizon_s']:.0f} s ({result.seconds[1]:.1f} s)",
              f"  {'variant':<28}{'seed':>9}{'time-to-goal [s]':>18}{'min pair dist':>15}"]
    for name in res["per_seed"]:
        rows = [(str(seed), m) for seed, m in zip(result.seeds, res["per_seed"][name],
                                                  strict=True)]
        if name in res["symmetric_start"]:
            rows.append(("symmetric", res["symmetric_start"][name]))
        for label, m in rows:
            lines.append(f"  {name:<28}{label:>9}{fmt(m['time_to_goal']):>18}"
                         f"{m['min_pair_distance']:>15.3f}")
    return lines
