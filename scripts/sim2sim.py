"""Sim-to-sim: exported policies in MuJoCo's own simulator next to their MJX evaluation.

Usage::

    python scripts/sim2sim.py --env three_link/env3 --hand-designed \\
        --policy runs/exported/three_link_rmp_residual.jaxexport [--scenes 256] [--seed 0] \\
        [--horizon 600] [--out results/sim2sim]
    python scripts/sim2sim.py --env franka --viewer [--policy P.jaxexport]   # needs a display

Each policy (``--policy``, repeatable: a blob of ``scripts/export.py``; ``--hand-designed``: the
hand-designed RMP² policy, exported the same way first) runs the same ``--scenes`` scenes
(seed ``--seed``) in MuJoCo C (``mujoco.mj_step``) and in MJX; the records go to ``--out``
(``summary.json`` and ``table.csv``; other environments' records there are kept), see
:mod:`agents.run.sim2sim`. ``--viewer`` instead shows scene 0 in MuJoCo's passive viewer
(the first ``--policy``, else the hand-designed one). Bad arguments exit with status 2.
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
from pathlib import Path

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from mjxrmp import _xla  # sets the XLA:CPU flag before JAX initialises

# isort: split
from agents.run.sim2sim import COLUMNS, sim2sim, table_row, view, write_results

_xla.configure_script()  # XLA:CPU flag and compile cache (docs/design.md §5.6)


def main(argv: list[str] | None = None) -> int:
    """CLI entry point (see the module docstring)."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", required=True, help="three_link/env1|env2|env3 or franka")
    parser.add_argument("--policy", action="append", default=[], type=Path,
                        help="exported policy (.jaxexport; repeatable)")
    parser.add_argument("--hand-designed", action="store_true",
                        help="also run the hand-designed RMP² policy (exported first)")
    parser.add_argument("--scenes", type=int, default=256, help="scenes (episodes) per policy")
    parser.add_argument("--seed", type=int, default=0, help="scene seed")
    parser.add_argument("--horizon", type=int, default=None,
                        help="control steps per episode (default: the environment's 600)")
    parser.add_argument("--out", type=Path, default=Path("results/sim2sim"),
                        help="study folder for summary.json and table.csv")
    parser.add_argument("--viewer", action="store_true",
                        help="show scene 0 in MuJoCo's passive viewer instead (needs a display)")
    args = parser.parse_args(argv)
    try:
        if args.viewer:
            view(args.env, args.policy[0] if args.policy else None, args.seed, args.horizon)
            return 0
        records = sim2sim(args.env, args.policy, args.hand_designed, args.scenes, args.seed,
                          args.horizon)
    except (FileNotFoundError, ValueError, RuntimeError) as e:
        parser.error(str(e))
    command = shlex.join(["python", "scripts/sim2sim.py", *(sys.argv[1:] if argv is None
                                                             else argv)])
    path = write_results(args.out, records, command)
    for r in records:
        print(", ".join(f"{c}: {v}" for c, v in zip(COLUMNS, table_row(r), strict=True)))
    print(f"wrote {path} and {path.with_name('table.csv')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
