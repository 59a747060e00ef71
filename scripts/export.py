"""Export a policy's deterministic mean with :func:`agents.export.export_policy`.

Usage::

    python scripts/export.py --env three_link/env3 --policy rmp_residual \\
        --out exported/policy.jaxexport [--seed 0] [--platforms cpu cuda] \\
        [--matmul-precision highest]

exports a freshly initialised policy of that kind (``make_policy(kind, envs.make(env))``,
``params = module.init(PRNGKey(seed), zeros(obs_size))``). The export itself is
:func:`export_from_params`, which takes any parameters of that policy (e.g. from a training
checkpoint). Load the result with ``scripts/load_policy.py``.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence
from pathlib import Path

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import mjxrmp  # noqa: F401  (sets the XLA:CPU flag before JAX initialises)

# isort: split
import jax
import jax.numpy as jnp

import envs
from agents.export import MATMUL_PRECISIONS, export_policy
from agents.policies import KINDS, make_policy

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
    """``(env, module)``: the environment ``env_name`` and its policy module of ``kind``."""
    check_names(env_name, kind)
    env = envs.make(env_name)
    return env, make_policy(kind, env)


def init_params(env_name: str, kind: str, seed: int = 0):
    """Freshly initialised parameters of the ``kind`` policy for ``env_name``."""
    env, module = build(env_name, kind)
    return jax.jit(module.init)(jax.random.PRNGKey(seed), jnp.zeros((env.observation_size,)))


def export_from_params(env_name: str, kind: str, params, out: str | os.PathLike,
                       metadata: dict | None = None,
                       platforms: Sequence[str] = ("cpu", "cuda"),
                       matmul_precision: str | None = None) -> dict:
    """Export the deterministic mean of the ``kind`` policy for ``env_name`` with ``params``.

    The manifest's ``metadata`` holds ``env``, ``policy``, ``robot``, ``observation_layout``
    (``{name: [start, stop]}``) and ``action`` (what the action means), updated with
    ``metadata`` (e.g. ``iteration``, ``seed``, ``checkpoint``). ``platforms`` and
    ``matmul_precision`` go to :func:`agents.export.export_policy`. Returns the manifest.
    """
    env, module = build(env_name, kind)
    base = getattr(env, "unwrapped", env)
    layout = {k: [s.start, s.stop] for k, s in base.observation_layout().items()}
    meta = {
        "env": env_name,
        "policy": kind,
        "robot": str(base.robot_name),
        "observation_layout": layout,
        "action": "joint-acceleration mean (unclipped; the environment clips)",
    }
    meta.update(metadata or {})
    return export_policy(
        lambda p, o: module.apply(p, o)[0],
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
    parser.add_argument("--env", required=True, choices=EXPORTABLE_ENVS,
                        help="environment name")
    parser.add_argument("--policy", required=True, choices=list(KINDS), help="policy kind")
    parser.add_argument("--out", required=True, type=Path, help="output file (.jaxexport)")
    parser.add_argument("--seed", type=int, default=0, help="initialisation seed")
    parser.add_argument("--platforms", nargs="+", default=["cpu", "cuda"],
                        help="platforms to lower for (default: cpu cuda)")
    parser.add_argument("--matmul-precision", choices=MATMUL_PRECISIONS, default=None,
                        help="bake this float32 matmul precision in (default: the backend's)")
    args = parser.parse_args(argv)

    params = init_params(args.env, args.policy, args.seed)
    manifest = export_from_params(args.env, args.policy, params, args.out,
                                  {"source": "init", "seed": args.seed, "iteration": 0},
                                  platforms=args.platforms,
                                  matmul_precision=args.matmul_precision)
    print(f"wrote {args.out} ({manifest['size_bytes']} bytes, sha256 {manifest['sha256'][:12]}…)"
          f" and {args.out.with_suffix('.json')}")
    print(f"obs ({manifest['obs_size']},) -> action ({manifest['action_size']},); platforms "
          f"{manifest['platforms']}")
    for p, err in manifest["platform_errors"].items():
        print(f"warning: not exported for {p}: {err.splitlines()[0]}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
