"""Collect an offline dataset of a named recipe on a reaching environment.

::

    python scripts/collect.py --env three_link/env3 --recipe mixed --episodes 200 --seed 0 \\
        --out data/env3_mixed.npz [--ppo-run RUN_DIR [--ppo-step N] [--ppo-deterministic]] \\
        [--horizon H] [--batch-size B] [--action-limit A]

``--episodes`` is the recipe's *scale*: episodes **per source** (``mixed`` has 4 sources
without a PPO run, 6 plus the medium-replay checkpoints with one; see
:mod:`offline.data.collect` for the recipe table). Without ``--ppo-run`` the recipes ``medium``,
``medium-replay`` and ``medium-expert`` contain no PPO data — the expert with Gaussian action
noise stands in — and ``mixed`` lacks the PPO sources: the script prints a warning and the
dataset's metadata records it (``metadata["fallback"]``).

Prints progress, the sources, per-source and overall statistics (episodes, transitions, mean
return, terminals vs timeouts, safe %, success %) and saves with :func:`offline.data.dataset.save`.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--env", default="three_link/env3",
                   help="environment name (envs.make), e.g. three_link/env1..env3, franka")
    p.add_argument("--recipe", default="mixed",
                   help="random | medium | medium-replay | medium-expert | expert | mixed")
    p.add_argument("--episodes", type=int, default=200,
                   help="episodes per source (the recipe's scale)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", required=True, help="output file (.npz)")
    p.add_argument("--ppo-run", default=None,
                   help="PPO run directory (scripts/train.py) for the medium / low sources")
    p.add_argument("--ppo-step", type=int, default=None,
                   help="checkpoint used as 'medium' (default: the run's newest)")
    p.add_argument("--ppo-seed-index", type=int, default=0,
                   help="which training seed of the run acts")
    p.add_argument("--ppo-deterministic", action="store_true",
                   help="medium/low PPO sources act with the Gaussian mean instead of sampling")
    p.add_argument("--horizon", type=int, default=None,
                   help="control steps per episode (default: the environment's 600)")
    p.add_argument("--batch-size", type=int, default=None,
                   help="episodes per compiled call (default: --episodes)")
    p.add_argument("--action-limit", type=float, default=None,
                   help="environment action limit (default: the environment's, 1)")
    p.add_argument("--force", action="store_true", help="overwrite an existing --out file")
    return p


def _fmt_summary(name: str, s: dict) -> str:
    return (f"{name:<24} episodes {s['episodes']:>5}  transitions {s['transitions']:>8}  "
            f"return {s['return_mean']:9.2f} ± {s['return_std']:7.2f}  "
            f"terminals {s['terminals']:>4}  timeouts {s['timeouts']:>4}  "
            f"safe {s['safe_pct']:5.1f}%  success {s['success_pct']:5.1f}%")


def main(argv=None) -> dict:
    args = _parser().parse_args(argv)

    import envs
    from offline.data import collect as oc
    from offline.data import dataset as odata

    def fail(msg: str) -> None:
        print(f"error: {msg}", file=sys.stderr)
        raise SystemExit(2)

    # point2d has no RMP² expert: it is not a data-collection environment.
    valid_envs = sorted(n for n in envs.ENVIRONMENTS if n != "point2d")
    env_name = envs.BRAX_NAMES.get(args.env, args.env)
    if env_name not in valid_envs:
        fail(f"unknown --env {args.env!r}; valid names are {valid_envs}")
    if args.recipe not in oc.RECIPES:
        fail(f"unknown --recipe {args.recipe!r}; valid recipes are {list(oc.RECIPES)}")
    if args.episodes < 1:
        fail(f"--episodes must be >= 1, got {args.episodes}")
    if os.path.exists(args.out) and not args.force:
        fail(f"{args.out} exists (pass --force to overwrite)")
    env_kwargs = {} if args.action_limit is None else {"action_limit": args.action_limit}

    sources, fallback = oc.recipe_sources(args.recipe, args.episodes, ppo_run=args.ppo_run,
                                          ppo_step=args.ppo_step,
                                          ppo_seed_index=args.ppo_seed_index,
                                          ppo_stochastic=not args.ppo_deterministic)
    total = sum(s.episodes for s in sources)
    print(f"collecting recipe {args.recipe!r} on {env_name}: {len(sources)} source(s), "
          f"{args.episodes} episodes per source, {total} episodes in all, seed {args.seed}",
          file=sys.stderr)
    for s in sources:
        tag = "  (FALLBACK stand-in)" if s.fallback else ""
        print(f"  {s.role:<14} {s.behaviour.name:<24} {s.episodes:>5} episodes{tag}",
              file=sys.stderr)
    if fallback is not None:
        bar = "!" * 78
        print(f"{bar}\nWARNING: {fallback}.\nPass --ppo-run RUN_DIR for PPO data. The "
              f"dataset's metadata['fallback'] records this.\n{bar}", file=sys.stderr)

    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # printed above already
        ds = oc.collect_recipe(env_name, args.recipe, args.episodes, seed=args.seed,
                               ppo_run=args.ppo_run, ppo_step=args.ppo_step,
                               ppo_seed_index=args.ppo_seed_index,
                               ppo_stochastic=not args.ppo_deterministic,
                               env_kwargs=env_kwargs, horizon=args.horizon,
                               batch_size=args.batch_size,
                               progress=lambda m: print(m, file=sys.stderr, flush=True))
    seconds = time.perf_counter() - t0
    path = odata.save(ds, args.out)

    print("\nper source:")
    for s in ds.metadata["sources"]:
        print("  " + _fmt_summary(s["behaviour"]["name"], s["summary"]))
    _, summ = odata.episode_statistics(ds)
    eps = summ["num_episodes"]
    safe = [s["summary"]["safe_pct"] * s["episodes"] for s in ds.metadata["sources"]]
    success = [s["summary"]["success_pct"] * s["episodes"] for s in ds.metadata["sources"]]
    overall = {
        "episodes": eps, "transitions": summ["num_transitions"],
        "return_mean": summ["return_mean"], "return_std": summ["return_std"],
        "terminals": summ["num_terminals"], "timeouts": summ["num_timeouts"],
        "safe_pct": sum(safe) / eps, "success_pct": sum(success) / eps,
    }
    print("  " + _fmt_summary("ALL", overall))
    report = {"out": path, "env": env_name, "recipe": args.recipe, "seed": args.seed,
              "episodes_per_source": args.episodes, "seconds": round(seconds, 2),
              "fallback": fallback, **overall}
    print(json.dumps(report))
    if fallback is not None:
        print(f"WARNING: {fallback}", file=sys.stderr)
    return report


if __name__ == "__main__":
    main()
