"""Export a policy's deterministic mean with :func:`agents.run.export.export_policy`.

Usage::

    python scripts/export.py --checkpoint runs/three_link-env3_rmp_residual \\
        --out exported/policy.jaxexport [--step N] [--train-seed-index 0] \\
        [--platforms cpu cuda] [--matmul-precision highest] [--force]
    python scripts/export.py --env three_link/env3 --policy rmp_residual \\
        --out exported/untrained.jaxexport [--seed 0]
    python scripts/export.py --hand-designed --env franka --out exported/franka_hd.jaxexport
    python scripts/export.py --skill results/lfd_lasa/skills/Angle --out exported/angle.jaxexport

The first form exports a trained policy: the newest (or ``--step``) checkpoint of a run
directory written by ``scripts/train.py``, one training seed, with its observation statistics
baked in (:func:`agents.run.loading.deterministic_policy`). The second exports a freshly
initialised policy of that kind (``params = module.init(PRNGKey(seed), zeros(obs_size))``); the
third the hand-designed RMP² policy (kind ``hand_designed``: nothing learned in its mean). The
export itself is :func:`agents.run.export.export_run`. The fourth exports a saved LfD skill's
velocity ``x (b, dim) → ẋ (b, dim)`` (``scripts/lfd_lasa.py --save-skills``;
:func:`agents.lfd.skills.export_skill`, full float32 matrix products unless
``--matmul-precision`` says otherwise). Load the result with ``scripts/load_policy.py``.

An existing ``--out`` (or its ``.json`` manifest) is not overwritten without ``--force``; a
corrupt checkpoint (the newest intact one is used unless ``--step`` names it) and NaN/inf
parameters are refused with a one-line error (exit status 2).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from mjxrmp import _xla  # sets the XLA:CPU flag before JAX initialises

# isort: split
from agents.lfd.skills import export_skill
from agents.ppo import KINDS
from agents.run.export import EXPORTABLE_ENVS, MATMUL_PRECISIONS, export_run

_xla.configure_script()  # XLA:CPU flag and compile cache (docs/design.md §5.6)


def main(argv: list[str] | None = None) -> int:
    """CLI entry point (see the module docstring)."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--checkpoint", default=None, metavar="RUN_DIR",
                        help="export a trained policy from this run directory")
    parser.add_argument("--step", type=int, default=None,
                        help="checkpoint iteration (default: the newest)")
    parser.add_argument("--train-seed-index", type=int, default=0,
                        help="which of the run's training seeds to export")
    parser.add_argument("--skill", default=None, metavar="SKILL_DIR",
                        help="export a saved LfD skill (agents.lfd.skills) from this folder")
    parser.add_argument("--env", default=None, choices=EXPORTABLE_ENVS,
                        help="environment name (an untrained policy; not with --checkpoint)")
    parser.add_argument("--policy", default=None, choices=list(KINDS), help="policy kind")
    parser.add_argument("--hand-designed", action="store_true",
                        help="export the hand-designed RMP² policy of --env "
                             "(the same as --policy hand_designed)")
    parser.add_argument("--out", required=True, type=Path, help="output file (.jaxexport)")
    parser.add_argument("--seed", type=int, default=0, help="initialisation seed")
    parser.add_argument("--platforms", nargs="+", default=["cpu", "cuda"],
                        help="platforms to lower for (default: cpu cuda)")
    parser.add_argument("--matmul-precision", choices=MATMUL_PRECISIONS, default=None,
                        help="bake this float32 matmul precision in (default: the backend's)")
    parser.add_argument("--force", action="store_true",
                        help="overwrite an existing --out file and its .json manifest")
    args = parser.parse_args(argv)
    if args.hand_designed:
        if args.policy not in (None, "hand_designed"):
            parser.error(f"--hand-designed exports the hand_designed policy, not --policy "
                         f"{args.policy}")
        args.policy = "hand_designed"
    sources = [args.checkpoint, args.skill, args.env or args.policy]
    if sum(s is not None for s in sources) > 1:
        parser.error("give one of --checkpoint RUN_DIR, --skill SKILL_DIR or --env/--policy")
    if args.checkpoint is None and args.skill is None and (args.env is None
                                                           or args.policy is None):
        parser.error("give --checkpoint RUN_DIR, --skill SKILL_DIR, or --env and --policy")

    try:
        if args.skill is not None:
            manifest = export_skill(args.skill, args.out, platforms=args.platforms,
                                    matmul_precision=args.matmul_precision or "highest",
                                    force=args.force)
        else:
            manifest = export_run(args.out, args.checkpoint, args.step, args.train_seed_index,
                                  args.env, args.policy, args.seed, platforms=args.platforms,
                                  matmul_precision=args.matmul_precision, force=args.force)
    except (FileNotFoundError, FileExistsError, ValueError, IndexError) as e:
        parser.error(str(e))
    print(f"wrote {args.out} ({manifest['size_bytes']} bytes, sha256 {manifest['sha256'][:12]}…)"
          f" and {args.out.with_suffix('.json')}")
    print(f"obs ({manifest['obs_size']},) -> action ({manifest['action_size']},); platforms "
          f"{manifest['platforms']}")
    for p, err in manifest["platform_errors"].items():
        print(f"warning: not exported for {p}: {err.splitlines()[0]}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
