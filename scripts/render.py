"""Render one rollout of the hand-designed RMP² policy as an animated GIF (:mod:`envs.render`).

3-link: top-down view with links, control points, goal and obstacle circles. Franka: 3-D
matplotlib view with the link chain, control points, ball obstacles and the goal.

    python scripts/render.py --env three_link/env3 --seed 0 --steps 300 --out rollout.gif
"""

from __future__ import annotations

import argparse
import os
import sys

os.environ.setdefault("JAX_PLATFORMS", "cpu")
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from envs.render import render_rollout
from mjxrmp import _xla

_xla.configure_script()  # XLA:CPU flag and compile cache (docs/design.md §5.6)


def main(argv: list[str] | None = None) -> str:
    """Parse the arguments, write the GIF and return its path."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--env", default="three_link/env3",
                   help="three_link/env1|env2|env3 or franka")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--every", type=int, default=3, help="draw every n-th control step")
    p.add_argument("--fps", type=int, default=20)
    p.add_argument("--out", default="rollout.gif")
    args = p.parse_args(argv)
    data = render_rollout(args.env, args.out, seed=args.seed, steps=args.steps,
                          every=args.every, fps=args.fps)
    print(f"wrote {args.out}: {data['frames']} frames, return {data['return']:.1f}, "
          f"final goal distance {data['goal_distance'][-1]:.3f}")
    return args.out


if __name__ == "__main__":
    main()
