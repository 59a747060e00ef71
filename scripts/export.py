"""Export a policy's deterministic mean with :func:`agents.run.export.export_policy`.

Usage::

    python scripts/export.py --checkpoint runs/three_link-env3_rmp_residual \\
        --out exported/policy.jaxexport [--step N] [--train-seed-index 0] \\
        [--platforms cpu cuda] [--matmul-precision highest]
    python scripts/export.py --env three_link/env3 --policy rmp_residual \\
        --out exported/untrained.jaxexport [--seed 0]

The first form exports a trained policy: the newest (or ``--step``) checkpoint of a run
directory written by ``scripts/train.py``, one training seed, with its observation statistics
baked in (:func:`agents.run.loading.deterministic_policy`). The second exports a freshly initialised
policy of that kind (``params = module.init(PRNGKey(seed), zeros(obs_size))``). The export
itself is :func:`export_from_params`. Load the result with ``scripts/load_policy.py``.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import mjxrmp  # noqa: F401  (sets the XLA:CPU flag before JAX initialises)

# isort: split
import jax
import jax.numpy as jnp

import envs
from agents.ppo.policies import KINDS, make_env_and_policy
from agents.run.export import MATMUL_PRECISIONS, export_policy

#: Environments the policy classes support: the reaching environments (not ``point2d``).
EXPORTABLE_ENVS = tuple(sorted(
    name for name, factory in envs.ENVIRONMENTS.items()
    if isinstance(getattr(factory, "func", factory), type)
    and issubclass(getattr(factory, "func", factory), envs.ReachEnv)
))


def check_names(env_name: str, kind: str) -> None:
    """Raise ``ValueError`` listing the valid names if ``env_name`` or ``kind`` is unknown."""
    name = envs.BRAX_NAMES.get(env_name, env_name)
    if name not in EXPORTABLE_ENVS:
        what = "has no policy classes" if name in envs.ENVIRONMENTS else "is unknown"
        raise ValueError(
            f"env_name={env_name!r} {what}; valid names are {list(EXPORTABLE_ENVS)}"
        )
    if kind not in KINDS:
        raise ValueError(f"unknown policy kind={kind!r}; valid kinds are {list(KINDS)}")


def build(env_name: str, kind: str):
    """``(env, module)``: the environment ``env_name`` (wrapped as in training) and its policy
    module of ``kind``."""
    check_names(env_name, kind)
    return make_env_and_policy(env_name, kind)


def init_params(env_name: str, kind: str, seed: int = 0):
    """Freshly initialised parameters of the ``kind`` policy for ``env_name``."""
    env, module = build(env_name, kind)
    return jax.jit(module.init)(jax.random.PRNGKey(seed), jnp.zeros((env.observation_size,)))


def export_from_params(env_name: str, kind: str, params, out: str | os.PathLike,
                       metadata: dict | None = None,
                       platforms: Sequence[str] = ("cpu", "cuda"),
                       matmul_precision: str | None = None,
                       apply_fn: Callable | None = None) -> dict:
    """Export the deterministic mean of the ``kind`` policy for ``env_name`` with ``params``.

    ``apply_fn(params, obs) -> mean`` defaults to the module's mean on the raw observation;
    pass :func:`agents.run.loading.deterministic_policy`'s pair for a checkpoint (observation
    statistics included).

    The manifest's ``metadata`` holds ``env``, ``policy``, ``robot``, ``observation_layout``
    (``{name: [start, stop]}``) and ``action`` (what the action means), updated with
    ``metadata`` (e.g. ``iteration``, ``seed``, ``checkpoint``). ``platforms`` and
    ``matmul_precision`` go to :func:`agents.run.export.export_policy`. Returns the manifest.
    """
    env, module = build(env_name, kind)
    base = getattr(env, "unwrapped", env)
    layout = {k: [s.start, s.stop] for k, s in base.observation_layout().items()}
    meta = {
        "env": env_name,
        "policy": kind,
        "robot": str(base.robot_name),
        "observation_layout": layout,
        "action": ("raw residual RMP (A_r row-major, a_r), squashed by envs.RMPInEnv"
                   if kind == "rmp_residual_env"
                   else "joint-acceleration mean (unclipped; the environment clips)"),
    }
    meta.update(metadata or {})
    if apply_fn is None:
        def apply_fn(p, o):
            return module.apply(p, o)[0]
    return export_policy(
        apply_fn,
        params,
        int(env.observation_size),
        out,
        metadata=meta,
        platforms=platforms,
        matmul_precision=matmul_precision,
    )


def main(argv: list[str] | None = None) -> int:
    """CLI entry point (see the module docstring)."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--checkpoint", default=None, metavar="RUN_DIR",
                        help="export a trained policy from this run directory")
    parser.add_argument("--step", type=int, default=None,
                        help="checkpoint iteration (default: the newest)")
    parser.add_argument("--train-seed-index", type=int, default=0,
                        help="which of the run's training seeds to export")
    parser.add_argument("--env", default=None, choices=EXPORTABLE_ENVS,
                        help="environment name (an untrained policy; not with --checkpoint)")
    parser.add_argument("--policy", default=None, choices=list(KINDS), help="policy kind")
    parser.add_argument("--out", required=True, type=Path, help="output file (.jaxexport)")
    parser.add_argument("--seed", type=int, default=0, help="initialisation seed")
    parser.add_argument("--platforms", nargs="+", default=["cpu", "cuda"],
                        help="platforms to lower for (default: cpu cuda)")
    parser.add_argument("--matmul-precision", choices=MATMUL_PRECISIONS, default=None,
                        help="bake this float32 matmul precision in (default: the backend's)")
    args = parser.parse_args(argv)

    if args.checkpoint is not None:
        if args.env is not None or args.policy is not None:
            parser.error("--env/--policy come from the run directory with --checkpoint")
        from agents.run.loading import deterministic_policy, load_run

        try:
            run = load_run(args.checkpoint, args.step)
            apply_fn, params = deterministic_policy(run, args.train_seed_index)
        except (FileNotFoundError, ValueError, IndexError) as e:
            parser.error(str(e))
        env_name, kind = run.spec.env, run.spec.policy
        meta = {"source": "checkpoint", "checkpoint": os.path.abspath(args.checkpoint),
                "iteration": run.iteration, "seed": run.seeds[args.train_seed_index]}
    else:
        if args.env is None or args.policy is None:
            parser.error("give --checkpoint RUN_DIR, or --env and --policy")
        env_name, kind, apply_fn = args.env, args.policy, None
        params = init_params(env_name, kind, args.seed)
        meta = {"source": "init", "seed": args.seed, "iteration": 0}
    manifest = export_from_params(env_name, kind, params, args.out, meta,
                                  platforms=args.platforms,
                                  matmul_precision=args.matmul_precision, apply_fn=apply_fn)
    print(f"wrote {args.out} ({manifest['size_bytes']} bytes, sha256 {manifest['sha256'][:12]}…)"
          f" and {args.out.with_suffix('.json')}")
    print(f"obs ({manifest['obs_size']},) -> action ({manifest['action_size']},); platforms "
          f"{manifest['platforms']}")
    for p, err in manifest["platform_errors"].items():
        print(f"warning: not exported for {p}: {err.splitlines()[0]}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
