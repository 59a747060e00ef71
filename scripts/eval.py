"""Evaluate training checkpoints: many checkpoints × setups × training seeds × episodes at once.

::

    python scripts/eval.py RUN_DIR [RUN_DIR ...] [--steps all|latest|N ...]
        [--setups three_link/env1 three_link/env2 three_link/env3 | franka]
        [--episodes 256] [--eval-seed 0] [--horizon H] [--json out.json] [--gif out.gif]

Every checkpoint (``--steps``, default ``latest``, of every run directory written by
``scripts/train.py``) is restored with :func:`agents.run.loading.load_run`; each of its training seeds
acts with its deterministic policy — the Gaussian mean, clipped by the environment — for
``--episodes`` episodes of ``--horizon`` control steps (default: the environment's 600) on each
setup (default: the run's own environment), with :func:`envs.evaluate.make_rollout` (episodes
frozen once done, so the per-episode statistics are exact).

**One compiled call.** Checkpoints of the same environment and policy kind form a group; a
group runs as one ``jax.jit``: for each setup (a branch of a Python loop inside the traced
function, so setups with different observation sizes live side by side) a ``vmap`` over the
stacked (checkpoint, training seed) parameters around the ``vmap`` over episodes. Checkpoints of
different environments or policy kinds cannot share parameter stacks: they are evaluated as
separate groups, one compiled call each (the script says so). Every member of a group sees the
same episodes (scenes from ``--eval-seed``): common random numbers across checkpoints, seeds and
runs.

**Other setups.** A policy reads the observation layout it was trained on, so a 3-link policy
runs on another 3-link setup only when the observations agree (``env1`` has 1 obstacle,
observation size 16; ``env2``/``env3`` have 3, size 26): mismatches are refused naming both
sizes.

**Output.** A table (run, iteration, setup, mean episode return ± std over training seeds,
success %, safe %, final goal distance) and, with ``--json``, every number: per training seed
and aggregated, the groups with their compile and run seconds. ``--gif`` renders episode 0 of
the best row (highest mean return; its best seed) with the functions of ``scripts/render.py``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
import time
from collections.abc import Sequence
from typing import Any

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from mjxrmp import _xla

_xla.configure_cpu_flags()

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from agents.run.loading import (  # noqa: E402
    LoadedRun,
    checkpoint_steps,
    env_policy,
    load_run,
    make_env,
    mean_action_fn,
    policy_params,
    read_spec,
)
from envs.evaluate import make_rollout, summarize  # noqa: E402

#: Setups a reaching policy can be evaluated on (every reaching environment).
SETUPS = ("three_link/env1", "three_link/env2", "three_link/env3", "franka")
#: Per-episode statistics of :func:`envs.evaluate.make_rollout` kept by the sweep.
STATS = ("return", "success", "safe", "final_goal_distance", "length", "nonfinite")


# ---------------------------------------------------------------------------------------------
# choosing checkpoints and setups


def resolve_steps(run_dir: str, tokens: Sequence[str | int] = ("latest",)) -> list[int]:
    """The checkpoint steps of ``run_dir`` that ``tokens`` name (ascending, distinct):
    ``"all"``, ``"latest"`` or iteration numbers. Raises ``FileNotFoundError`` for a missing
    directory or ``run.json``, a run without checkpoints or a step it does not have (listing the
    available ones)."""
    read_spec(run_dir)  # clear errors for a missing directory or run.json first
    available = checkpoint_steps(run_dir)
    if not available:
        raise FileNotFoundError(f"no checkpoint in {os.path.join(run_dir, 'checkpoints')!r}")
    out: set[int] = set()
    for tok in tokens:
        if tok == "all":
            out.update(available)
        elif tok == "latest":
            out.add(available[-1])
        else:
            try:
                step = int(tok)
            except ValueError:
                raise ValueError(f"--steps takes 'all', 'latest' or iteration numbers, got "
                                 f"{tok!r}") from None
            if step not in available:
                raise FileNotFoundError(f"{run_dir!r} has no checkpoint of iteration {step}; "
                                        f"available: {available}")
            out.add(step)
    return sorted(out)


def group_key(loaded: LoadedRun) -> tuple:
    """Checkpoints with equal keys can be stacked into one parameter batch: same environment,
    policy kind and policy parameter structure (shapes, dtypes, observation statistics)."""
    one = jax.eval_shape(lambda: policy_params(loaded, 0))
    leaves, treedef = jax.tree.flatten(one)
    return (loaded.spec.env, loaded.spec.policy, treedef,
            tuple((x.shape, str(x.dtype)) for x in leaves))


def group_checkpoints(checkpoints: Sequence[LoadedRun]) -> list[list[LoadedRun]]:
    """``checkpoints`` split into stackable groups (:func:`group_key`), in first-seen order."""
    groups: dict[tuple, list[LoadedRun]] = {}
    for c in checkpoints:
        groups.setdefault(group_key(c), []).append(c)
    return list(groups.values())


def _layout(env) -> dict[str, tuple[int, int]]:
    base = env.unwrapped
    return {k: (s.start, s.stop) for k, s in base.observation_layout().items()}


def setup_env(loaded: LoadedRun, setup: str):
    """The single environment ``setup`` as ``loaded``'s policy kind acts on it. Raises
    ``ValueError`` when the policy cannot read its observations (naming both observation
    sizes) or its action size differs."""
    if setup not in SETUPS:
        raise ValueError(f"unknown setup={setup!r}; valid setups are {list(SETUPS)}")
    train_env = make_env(loaded.spec.env, loaded.spec.policy)
    env = train_env if setup == loaded.spec.env else make_env(setup, loaded.spec.policy)
    what = f"the {loaded.spec.policy} policy trained on {loaded.spec.env}"
    a, b = int(train_env.observation_size), int(env.observation_size)
    if a != b:
        raise ValueError(f"cannot evaluate {what} (observation size {a}) on {setup} "
                         f"(observation size {b}): observation sizes differ")
    if _layout(train_env) != _layout(env):
        raise ValueError(f"cannot evaluate {what} on {setup}: both observations have size {a} "
                         f"but different layouts ({_layout(train_env)} vs {_layout(env)})")
    if int(train_env.action_size) != int(env.action_size):
        raise ValueError(f"cannot evaluate {what} (action size {train_env.action_size}) on "
                         f"{setup} (action size {env.action_size})")
    return env


# ---------------------------------------------------------------------------------------------
# the compiled sweep


@dataclasses.dataclass
class Sweep:
    """Per-episode results of one group: ``episodes[setup][stat]`` is ``(members,
    num_episodes)``; member ``i`` is training seed ``members[i][1]`` (an index into
    ``checkpoints[members[i][0]].seeds``) of checkpoint ``members[i][0]``."""

    checkpoints: list[LoadedRun]
    setups: tuple[str, ...]
    members: list[tuple[int, int]]
    episodes: dict[str, dict[str, np.ndarray]]
    horizons: dict[str, int]
    compile_seconds: float
    run_seconds: float


def stack_params(checkpoints: Sequence[LoadedRun]):
    """``(stack, members)``: every checkpoint's per-seed :class:`agents.run.loading.PolicyParams`
    concatenated along the leading axis, and ``(checkpoint index, seed index)`` per row."""
    stack = jax.tree.map(lambda *xs: jnp.concatenate(xs),
                         *[policy_params(c) for c in checkpoints])
    members = [(i, s) for i, c in enumerate(checkpoints) for s in range(len(c.seeds))]
    return stack, members


def make_sweep(checkpoints: Sequence[LoadedRun], setups: Sequence[str], num_episodes: int,
               horizon: int | None = None):
    """``(sweep, horizons)``: ``sweep(stack, key) -> {setup: {stat: (members, num_episodes)}}``
    for a parameter ``stack`` of :func:`stack_params` (not jitted; :func:`run_sweep` jits it).
    Every member plays the same ``num_episodes`` episodes, keys ``split(key, num_episodes)``."""
    first = checkpoints[0]
    apply_fn = mean_action_fn(first)
    env_of = {s: setup_env(first, s) for s in setups}
    horizons = {s: int(env.horizon if horizon is None else horizon) for s, env in env_of.items()}

    def sweep(stack, key):
        out = {}
        for s, env in env_of.items():
            def one(p, env=env, s=s):
                per_episode = make_rollout(env, num_episodes, horizons[s],
                                           policy=env_policy(apply_fn, p))(key)
                return {k: per_episode[k] for k in STATS}

            out[s] = jax.vmap(one)(stack)
        return out

    return sweep, horizons


def run_sweep(checkpoints: Sequence[LoadedRun], setups: Sequence[str] | None = None,
              num_episodes: int = 256, eval_seed: int = 0, horizon: int | None = None) -> Sweep:
    """Evaluate every (checkpoint, training seed) of one group on every setup (default: the
    group's training environment) in one compiled call; see :class:`Sweep`. Raises
    ``ValueError`` for checkpoints of different groups (:func:`group_checkpoints`) and setups
    the policy cannot act on (:func:`setup_env`)."""
    checkpoints = list(checkpoints)
    if not checkpoints:
        raise ValueError("no checkpoints to evaluate")
    if len(group_checkpoints(checkpoints)) != 1:
        kinds = sorted({(c.spec.env, c.spec.policy) for c in checkpoints})
        raise ValueError(f"checkpoints of different environments/policy kinds {kinds} cannot "
                         "share one compiled call; split them with group_checkpoints")
    if not (isinstance(num_episodes, int) and num_episodes >= 1):
        raise ValueError(f"num_episodes must be a positive integer, got {num_episodes!r}")
    if horizon is not None and not (isinstance(horizon, int) and horizon >= 1):
        raise ValueError(f"horizon must be None or a positive integer, got {horizon!r}")
    setups = tuple(dict.fromkeys(setups or (checkpoints[0].spec.env,)))
    sweep, horizons = make_sweep(checkpoints, setups, num_episodes, horizon)
    stack, members = stack_params(checkpoints)
    key = jax.random.PRNGKey(eval_seed)
    t0 = time.perf_counter()
    compiled = jax.jit(sweep).lower(stack, key).compile()
    t1 = time.perf_counter()
    out = jax.tree.map(np.asarray, jax.block_until_ready(compiled(stack, key)))
    t2 = time.perf_counter()
    return Sweep(checkpoints, setups, members, out, horizons, t1 - t0, t2 - t1)


# ---------------------------------------------------------------------------------------------
# summaries


def _num(x: float) -> float | None:
    return float(x) if math.isfinite(float(x)) else None


def seed_summary(per_episode: dict[str, np.ndarray]) -> dict[str, float]:
    """Mean return, success %, safe %, final goal distance, length and non-finite % over one
    member's episodes (arrays ``(num_episodes,)``; :func:`envs.evaluate.summarize`)."""
    keys = ("mean_return", "success_pct", "safe_pct", "mean_final_goal_distance",
            "mean_length", "nonfinite_pct")
    summary = summarize({**per_episode, "sampler_ok": np.ones_like(per_episode["return"])})
    return {k: summary[k] for k in keys}


def summarize_sweep(sweep: Sweep, per_episode: bool = False) -> list[dict[str, Any]]:
    """One row per (checkpoint, setup): per-seed statistics (:func:`seed_summary`) and their
    mean and standard deviation over training seeds (population std, 0 for one seed);
    ``per_episode`` adds the raw per-episode arrays."""
    rows = []
    for ci, c in enumerate(sweep.checkpoints):
        idx = [m for m, (cj, _) in enumerate(sweep.members) if cj == ci]
        for s in sweep.setups:
            eps = sweep.episodes[s]
            per_seed = [seed_summary({k: eps[k][m] for k in STATS}) for m in idx]
            row: dict[str, Any] = {
                "run": c.run_dir, "name": os.path.basename(os.path.normpath(c.run_dir)),
                "env": c.spec.env, "policy": c.spec.policy, "step": c.step,
                "iteration": c.iteration, "setup": s, "seeds": list(c.seeds),
                "episodes": int(eps["return"].shape[1]), "horizon": sweep.horizons[s],
                "per_seed": {k: [_num(p[k]) for p in per_seed] for k in per_seed[0]},
            }
            for k in per_seed[0]:
                v = np.array([p[k] for p in per_seed])
                row[k] = _num(np.mean(v))
                row[k + "_std"] = _num(np.std(v))
            if per_episode:
                row["per_episode"] = {k: eps[k][idx].tolist() for k in STATS}
            rows.append(row)
    return rows


def evaluate(checkpoints: Sequence[LoadedRun], setups: Sequence[str] | None = None,
             num_episodes: int = 256, eval_seed: int = 0, horizon: int | None = None,
             per_episode: bool = False, stream=None) -> dict[str, Any]:
    """Group the checkpoints (:func:`group_checkpoints`), run one :func:`run_sweep` per group
    and return the JSON report: ``rows`` (:func:`summarize_sweep`), ``groups`` (what each
    compiled call held, its compile and run seconds), totals and the evaluation settings.
    Setups are checked for every group before anything compiles."""
    groups = group_checkpoints(checkpoints)
    for g in groups:
        for s in (setups or (g[0].spec.env,)):
            setup_env(g[0], s)
    if len(groups) > 1 and stream is not None:
        print(f"{len(groups)} groups of different environments/policy kinds: one compiled call "
              "per group", file=stream)
    report: dict[str, Any] = {
        "episodes": num_episodes, "eval_seed": eval_seed, "horizon": horizon,
        "device": jax.devices()[0].platform, "groups": [], "rows": [],
    }
    for g in groups:
        sweep = run_sweep(g, setups, num_episodes, eval_seed, horizon)
        report["groups"].append({
            "env": g[0].spec.env, "policy": g[0].spec.policy,
            "checkpoints": [{"run": c.run_dir, "step": c.step} for c in g],
            "setups": list(sweep.setups), "members": len(sweep.members),
            "horizons": sweep.horizons,
            "compile_seconds": sweep.compile_seconds, "run_seconds": sweep.run_seconds,
        })
        report["rows"].extend(summarize_sweep(sweep, per_episode))
        if stream is not None:
            print(f"group {g[0].spec.policy} on {g[0].spec.env}: {len(g)} checkpoint(s), "
                  f"{len(sweep.members)} parameter sets × {len(sweep.setups)} setup(s) × "
                  f"{num_episodes} episodes: compile {sweep.compile_seconds:.1f} s, run "
                  f"{sweep.run_seconds:.1f} s", file=stream)
    report["compile_seconds"] = sum(g["compile_seconds"] for g in report["groups"])
    report["run_seconds"] = sum(g["run_seconds"] for g in report["groups"])
    best = best_row(report["rows"])
    report["best"] = None if best is None else {k: best[k] for k in (
        "run", "step", "iteration", "setup", "mean_return", "success_pct", "best_seed")}
    return report


def best_row(rows: Sequence[dict[str, Any]]) -> dict[str, Any] | None:
    """The row of the highest mean return (ties: success %), with ``best_seed`` (the training
    seed of the highest mean return in it) added; None if no row has a finite return."""
    finite = [r for r in rows if r["mean_return"] is not None]
    if not finite:
        return None
    best = dict(max(finite, key=lambda r: (r["mean_return"], r["success_pct"] or 0.0)))
    returns = [-math.inf if x is None else x for x in best["per_seed"]["mean_return"]]
    best["best_seed"] = best["seeds"][int(np.argmax(returns))]
    return best


def format_table(rows: Sequence[dict[str, Any]]) -> str:
    """The screen table: run, iteration, setup, return mean ± std over seeds, success %, safe %,
    final goal distance (success/safe/distance: mean over seeds)."""
    def pm(r, k, spec):
        m, s = r[k], r[k + "_std"]
        return "n/a" if m is None else f"{m:{spec}} ± {s:.2g}"

    head = ("run", "iter", "setup", "seeds", "return (± std)", "success %", "safe %",
            "final dist")
    body = [(r["name"], str(r["iteration"]), r["setup"], str(len(r["seeds"])),
             pm(r, "mean_return", ".4g"), pm(r, "success_pct", ".1f"),
             pm(r, "safe_pct", ".1f"),
             "n/a" if r["mean_final_goal_distance"] is None
             else f"{r['mean_final_goal_distance']:.3f}") for r in rows]
    widths = [max(len(x) for x in col) for col in zip(head, *body, strict=True)]
    lines = ["  ".join(x.ljust(w) if i in (0, 2) else x.rjust(w)
                       for i, (x, w) in enumerate(zip(line, widths, strict=True)))
             for line in (head, *body)]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------
# animation


def render_gif(loaded: LoadedRun, seed: int, setup: str, path: str, eval_seed: int = 0,
               num_episodes: int = 256, horizon: int | None = None, every: int = 3,
               fps: int = 20) -> dict[str, Any]:
    """Write a GIF of episode 0 of the evaluation (same scene: key ``split(PRNGKey(eval_seed),
    num_episodes)[0]``) played by training seed ``seed`` of ``loaded`` on ``setup``, drawn with
    ``scripts/render.py``'s animation functions; returns the trajectory."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib import animation

    from scripts import render

    env = setup_env(loaded, setup)
    steps = int(env.horizon if horizon is None else horizon)
    apply_fn, params = mean_action_fn(loaded), policy_params(loaded, loaded.seeds.index(seed))
    key = jax.random.split(jax.random.PRNGKey(eval_seed), num_episodes)[0]
    data = render.trajectory(env, env_policy(apply_fn, params), key, steps)
    sub = {k: (v[::every] if k in ("q", "done", "goal_distance") else v) for k, v in data.items()}
    robot = env.unwrapped.robot_name
    anim_fn = render._animate_three_link if robot == "three_link" else render._animate_franka
    fig, anim = anim_fn(sub, fps)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    anim.save(path, writer=animation.PillowWriter(fps=fps))
    plt.close(fig)
    return data


# ---------------------------------------------------------------------------------------------
# CLI


def main(argv: list[str] | None = None) -> int:
    """CLI entry point (see the module docstring); returns the exit status."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("runs", nargs="+", metavar="RUN_DIR", help="run directories (train.py)")
    p.add_argument("--steps", nargs="+", default=["latest"],
                   help="checkpoints of every run: all, latest or iteration numbers")
    p.add_argument("--setups", nargs="+", default=None, choices=SETUPS,
                   help="setups to evaluate on (default: each run's own environment)")
    p.add_argument("--episodes", type=int, default=256, help="episodes per parameter set")
    p.add_argument("--eval-seed", type=int, default=0, help="seed of the evaluation scenes")
    p.add_argument("--horizon", type=int, default=None,
                   help="control steps per episode (default: the environment's, 600)")
    p.add_argument("--json", default=None, help="write every number to this JSON file")
    p.add_argument("--per-episode", action="store_true",
                   help="include the per-episode arrays in the JSON")
    p.add_argument("--gif", default=None, help="render episode 0 of the best checkpoint")
    args = p.parse_args(argv)
    if args.episodes < 1:
        p.error(f"--episodes must be >= 1, got {args.episodes}")
    if args.horizon is not None and args.horizon < 1:
        p.error(f"--horizon must be >= 1, got {args.horizon}")

    from agents.run.checkpoint import IncompatibleCheckpointError

    try:
        checkpoints = [load_run(r, step) for r in args.runs
                       for step in resolve_steps(r, args.steps)]
        report = evaluate(checkpoints, args.setups, args.episodes, args.eval_seed,
                          args.horizon, args.per_episode, stream=sys.stderr)
    except (FileNotFoundError, ValueError, IncompatibleCheckpointError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(format_table(report["rows"]))
    print(f"compile {report['compile_seconds']:.1f} s, run {report['run_seconds']:.1f} s "
          f"({len(report['groups'])} compiled call(s), {args.episodes} episodes per parameter "
          f"set, device {report['device']})")
    report["gif"] = None
    if args.gif and report["best"] is not None:
        b = report["best"]
        loaded = next(c for c in checkpoints if c.run_dir == b["run"] and c.step == b["step"])
        data = render_gif(loaded, b["best_seed"], b["setup"], args.gif, args.eval_seed,
                          args.episodes, args.horizon)
        report["gif"] = {"path": args.gif, "run": b["run"], "step": b["step"],
                         "seed": b["best_seed"], "setup": b["setup"], "episode": 0,
                         "return": data["return"]}
        print(f"wrote {args.gif}: {os.path.basename(os.path.normpath(b['run']))} iteration "
              f"{b['iteration']} seed {b['best_seed']} on {b['setup']}, episode 0, return "
              f"{data['return']:.2f}")
    if args.json:
        os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
        tmp = args.json + ".tmp"
        with open(tmp, "w") as f:
            json.dump(report, f, indent=1, allow_nan=False)
        os.replace(tmp, args.json)
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
