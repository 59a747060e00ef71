"""Thesis Fig. 8.2 on our grid world: PEVI with the true and three wrong rewards vs BC (§8.3.1).

::

    python scripts/reproduce_fig8_2.py          # docs/figures/fig8_2.png, results/fig8_2.json
    python scripts/reproduce_fig8_2.py --seed 3 --penalty 1.0

Collects suboptimal, length-biased data (:func:`offline.survival.tabular.collect`: lava episodes cut,
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

import mjxrmp  # noqa: F401  (sets the XLA:CPU flag before JAX initialises)

# isort: split
import numpy as np

from offline.survival import tabular

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
    p.add_argument("--figure", type=Path, default=ROOT / "docs/figures/fig8_2.png")
    p.add_argument("--json", type=Path, default=ROOT / "results/fig8_2.json")
    return p.parse_args(argv)


def _summary(roll: tabular.Rollout, world: tabular.GridWorld) -> dict:
    key_steps = np.flatnonzero(roll.states == world.key)
    return {"true_return": roll.return_, "reached_key": roll.reached_key,
            "touched_lava": roll.touched_lava,
            "steps_to_key": int(key_steps[0]) if key_steps.size else None,
            "path": roll.states.tolist()}


def run(args: argparse.Namespace) -> dict:
    """Collect the data, train PEVI per reward and BC, evaluate in the true MDP."""
    world = tabular.GridWorld()
    data_config = tabular.DataConfig(args.trajectories, args.episode_length, args.noise)
    pevi_config = tabular.PEVIConfig(penalty=args.penalty)
    data = tabular.collect(world, data_config, args.seed)
    lengths = {o: [len(t.actions) for t in data.trajectories if t.outcome == o]
               for o in tabular.OUTCOMES}
    bc = tabular.behaviour_cloning(data)
    results = {
        "world": {"layout": list(world.layout), "horizon": world.horizon},
        "data": {"seed": args.seed, **{k: v for k, v in vars(data_config).items()},
                 "state_visits": data.state_visits.tolist(),
                 **{f"num_{o}": len(v) for o, v in lengths.items()},
                 **{f"mean_length_{o}": float(np.mean(v)) if v else None
                    for o, v in lengths.items()}},
        "pevi": {"penalty": pevi_config.penalty, "reward_range": list(pevi_config.reward_range)},
        "optimal_true_return": float(world.optimal_values()[0][0, world.start]),
        "bc": _summary(tabular.rollout(world, bc), world),
        "pevi_by_reward": {},
    }
    for kind in tabular.REWARDS:
        table = tabular.reward_table(world, kind, args.seed)
        out = tabular.pevi(tabular.relabel(data, table, kind), pevi_config)
        policy = np.asarray(out.policy)
        entry = _summary(tabular.rollout(world, policy), world)
        entry["pessimistic_value"] = float(out.values[0, world.start])
        entry["true_value_under_data_reward"] = float(
            world.true_values(policy, table)[0][0, world.start])
        results["pevi_by_reward"][kind] = entry
    return results


def print_table(results: dict) -> None:
    """One row per method: true return, key reached, lava touched, steps to the key."""
    d = results["data"]
    print(f"data: {d['num_trajectories']} trajectories (key {d['num_key']}, lava {d['num_lava']}, "
          f"timeout {d['num_timeout']}); mean length key {d['mean_length_key']:.1f}, "
          f"lava {d['mean_length_lava']:.1f}, timeout {d['mean_length_timeout']:.1f}")
    rows = [("BC", results["bc"])] + [(f"PEVI ({k})", v)
                                      for k, v in results["pevi_by_reward"].items()]
    print(f"{'method':16s} {'return':>7s} {'key':>5s} {'lava':>5s} {'steps':>5s} "
          f"{'V̂(start)':>10s} {'V^π(start)':>10s}")
    for name, r in rows:
        pess = r.get("pessimistic_value")
        true_data = r.get("true_value_under_data_reward")
        print(f"{name:16s} {r['true_return']:7.1f} {r['reached_key']!s:>5s} "
              f"{r['touched_lava']!s:>5s} {r['steps_to_key'] or '-'!s:>5s} "
              f"{'-' if pess is None else f'{pess:.2f}':>10s} "
              f"{'-' if true_data is None else f'{true_data:.2f}':>10s}")
    print(f"optimal true return {results['optimal_true_return']:.1f}")


def draw(results: dict, path: Path) -> None:
    """Fig. 8.2 analogue: a panel per reward with data opacity, BC (red) and PEVI (blue) paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    layout = results["world"]["layout"]
    rows, cols = len(layout), len(layout[0])
    visits = np.asarray(results["data"]["state_visits"], float).reshape(rows, cols)
    opacity = np.sqrt(visits / visits.max())  # the absorbing key would wash out the rest
    kinds = list(results["pevi_by_reward"])
    fig, axes = plt.subplots(1, len(kinds), figsize=(3.2 * len(kinds), 2.9))
    for ax, kind in zip(axes, kinds, strict=True):
        image = np.ones((rows, cols, 4))
        image[..., :3] = (0.2, 0.45, 0.25)
        image[..., 3] = 0.85 * opacity
        ax.imshow(image, extent=(-0.5, cols - 0.5, rows - 0.5, -0.5))
        for r, row in enumerate(layout):
            for c, cell in enumerate(row):
                if cell == "L":
                    ax.add_patch(plt.Rectangle((c - 0.5, r - 0.5), 1, 1, color="#e8590c"))
                elif cell == "#":
                    ax.add_patch(plt.Rectangle((c - 0.5, r - 0.5), 1, 1, color="0.3"))
                elif cell in "SK":
                    ax.text(c, r, "start" if cell == "S" else "key", ha="center", va="center",
                            fontsize=8, fontweight="bold",
                            color="black" if cell == "S" else "#b8860b")
        for name, color, offset in (("bc", "tab:red", -0.12), (kind, "tab:blue", 0.12)):
            entry = results["bc"] if name == "bc" else results["pevi_by_reward"][kind]
            r, c = np.divmod(np.asarray(entry["path"]), cols)
            ax.plot(c + offset, r + offset, "-o", color=color, lw=2, ms=3,
                    label="BC" if name == "bc" else "PEVI")
        ax.set_xticks(np.arange(-0.5, cols, 1), minor=True)
        ax.set_yticks(np.arange(-0.5, rows, 1), minor=True)
        ax.grid(which="minor", color="0.8", lw=0.5)
        ax.tick_params(which="both", bottom=False, left=False, labelbottom=False,
                       labelleft=False)
        p = results["pevi_by_reward"][kind]
        ax.set_title(f"PEVI, {kind} reward: return {p['true_return']:+.0f}", fontsize=9)
    axes[0].legend(loc="lower left", fontsize=7, framealpha=0.9)
    fig.suptitle("Grid world (thesis Fig. 8.2): BC (red) vs PEVI (blue); "
                 "opacity = √(data state frequency)", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=130)
    plt.close(fig)


def main(argv: Sequence[str] | None = None) -> dict:
    """Run, print the table, write the JSON and the figure."""
    args = parse_args(argv)
    results = run(args)
    print_table(results)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(results, indent=1) + "\n")
    draw(results, args.figure)
    print(f"wrote {args.json} and {args.figure}")
    return results


if __name__ == "__main__":
    main()
