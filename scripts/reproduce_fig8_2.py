"""Thesis Fig. 8.2 on our grid world: PEVI with the true and three wrong rewards vs BC (§8.3.1).

::

    python scripts/reproduce_fig8_2.py          # results/fig8_2/fig8_2.png and fig8_2.json
    python scripts/reproduce_fig8_2.py --seed 3 --penalty 1.0

The computation, table and figure are :mod:`offline.survival.fig8_2`. Collects suboptimal,
length-biased data (:func:`offline.survival.tabular.collect`: lava episodes cut,
time-outs after ``T`` steps, the absorbing key continued to ``H``), trains PEVI on it with the
true, zero, random and negated rewards, clones the data (BC), rolls every policy out in the true
MDP and reports the true return, whether the key was reached and whether lava was touched. The
figure has one panel per reward: state-visitation opacity of the data (darker = more frequent),
the BC path (red) and the PEVI path (blue). Runs in a few seconds on a CPU.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Sequence
from pathlib import Path

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from mjxrmp import _xla  # sets the XLA:CPU flag before JAX initialises

# isort: split
from offline.survival import fig8_2, tabular

_xla.configure_script()  # XLA:CPU flag and compile cache (docs/design.md §5.6)

ROOT = Path(__file__).resolve().parent.parent


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """Command-line options."""
    defaults, data_defaults = tabular.PEVIConfig(), tabular.DataConfig()
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seed", type=int, default=0, help="data seed (and random-reward seed)")
    p.add_argument("--penalty", type=float, default=defaults.penalty,
                   help="PEVI penalty scale c in Γ = c/√n")
    p.add_argument("--trajectories", type=int, default=data_defaults.num_trajectories)
    p.add_argument("--episode-length", type=int, default=data_defaults.episode_length,
                   help="data time limit T (the horizon H of the world is larger)")
    p.add_argument("--noise", type=float, default=data_defaults.noise,
                   help="behaviour policy's uniform action-noise probability")
    p.add_argument("--figure", type=Path, default=ROOT / "results/fig8_2/fig8_2.png")
    p.add_argument("--json", type=Path, default=ROOT / "results/fig8_2/fig8_2.json")
    return p.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> dict:
    """Run, print the table, write the JSON and the figure."""
    args = parse_args(argv)
    results = fig8_2.run(args.seed,
                         tabular.DataConfig(args.trajectories, args.episode_length, args.noise),
                         tabular.PEVIConfig(penalty=args.penalty))
    print("\n".join(fig8_2.table_lines(results)))
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(results, indent=1) + "\n")
    fig8_2.draw(results, args.figure)
    print(f"wrote {args.json} and {args.figure}")
    return results


if __name__ == "__main__":
    main()
