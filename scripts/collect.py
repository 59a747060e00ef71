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
from collections.abc import Sequence

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from mjxrmp import _xla  # sets the XLA:CPU flag before JAX initialises

# isort: split
from offline.data import collect as oc
from offline.data import dataset as odata

_xla.configure_script()  # XLA:CPU flag and compile cache (docs/design.md §5.6)


def _parser() -> argparse.ArgumentParser:
    """Command-line options."""
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
    """One statistics line of a source (or of the whole dataset)."""
    return (f"{name:<24} episodes {s['episodes']:>5}  transitions {s['transitions']:>8}  "
            f"return {s['return_mean']:9.2f} ± {s['return_std']:7.2f}  "
            f"terminals {s['terminals']:>4}  timeouts {s['timeouts']:>4}  "
            f"safe {s['safe_pct']:5.1f}%  success {s['success_pct']:5.1f}%")


def main(argv: Sequence[str] | None = None) -> dict:
    """Collect the recipe, save it, print the sources and statistics; return the report."""
    args = _parser().parse_args(argv)

    def fail(msg: str) -> None:
        print(f"error: {msg}", file=sys.stderr)
        raise SystemExit(2)

    try:
        env_name = oc.resolve_request(args.env, args.recipe, args.episodes)
    except ValueError as e:
        fail(str(e))
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
    overall = oc.overall_summary(ds)
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
