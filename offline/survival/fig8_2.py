"""Thesis Fig. 8.2 on our grid world (§8.3.1; docs/design.md §2.4): PEVI with the true and three
wrong rewards vs BC on suboptimal, length-biased data — the computation, the printed table and
the figure of ``scripts/reproduce_fig8_2.py``.

:func:`run` collects the data (:func:`offline.survival.tabular.collect`: lava episodes cut,
time-outs after ``T`` steps, the absorbing key continued to ``H``), trains PEVI on it with the
true, zero, random and negated rewards, clones the data (BC), rolls every policy out in the true
MDP and reports the true return, whether the key was reached and whether lava was touched.
:func:`draw` has one panel per reward: state-visitation opacity of the data (darker = more
frequent), the BC path (red) and the PEVI path (blue).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from offline.survival import tabular
from offline.survival.gridworld import GridWorld, Rollout, rollout


def _summary(roll: Rollout, world: GridWorld) -> dict:
    """The JSON entry of one policy's rollout: true return, key reached, lava touched, steps to
    the key and the visited states."""
    key_steps = np.flatnonzero(roll.states == world.key)
    return {"true_return": roll.return_, "reached_key": roll.reached_key,
            "touched_lava": roll.touched_lava,
            "steps_to_key": int(key_steps[0]) if key_steps.size else None,
            "path": roll.states.tolist()}


def run(seed: int = 0, data_config: tabular.DataConfig | None = None,
        pevi_config: tabular.PEVIConfig | None = None) -> dict:
    """Collect the data (``data_config``, seed ``seed``), train PEVI (``pevi_config``) with every
    reward of :data:`offline.survival.tabular.REWARDS` (the random one drawn with ``seed``) and
    BC, evaluate them in the true MDP; the JSON-ready results."""
    world = GridWorld()
    data_config = tabular.DataConfig() if data_config is None else data_config
    pevi_config = tabular.PEVIConfig() if pevi_config is None else pevi_config
    data = tabular.collect(world, data_config, seed)
    lengths = {o: [len(t.actions) for t in data.trajectories if t.outcome == o]
               for o in tabular.OUTCOMES}
    bc = tabular.behaviour_cloning(data)
    results = {
        "world": {"layout": list(world.layout), "horizon": world.horizon},
        "data": {"seed": seed, **{k: v for k, v in vars(data_config).items()},
                 "state_visits": data.state_visits.tolist(),
                 **{f"num_{o}": len(v) for o, v in lengths.items()},
                 **{f"mean_length_{o}": float(np.mean(v)) if v else None
                    for o, v in lengths.items()}},
        "pevi": {"penalty": pevi_config.penalty, "reward_range": list(pevi_config.reward_range)},
        "optimal_true_return": float(world.optimal_values()[0][0, world.start]),
        "bc": _summary(rollout(world, bc), world),
        "pevi_by_reward": {},
    }
    for kind in tabular.REWARDS:
        table = tabular.reward_table(world, kind, seed)
        out = tabular.pevi(tabular.relabel(data, table, kind), pevi_config)
        policy = np.asarray(out.policy)
        entry = _summary(rollout(world, policy), world)
        entry["pessimistic_value"] = float(out.values[0, world.start])
        entry["true_value_under_data_reward"] = float(
            world.true_values(policy, table)[0][0, world.start])
        results["pevi_by_reward"][kind] = entry
    return results


def table_lines(results: dict) -> list[str]:
    """The printed summary of :func:`run`: the data, then one row per method (true return, key
    reached, lava touched, steps to the key, PEVI's pessimistic value and the true value under
    the data reward), then the optimal true return."""
    d = results["data"]
    lines = [f"data: {d['num_trajectories']} trajectories (key {d['num_key']}, lava "
             f"{d['num_lava']}, timeout {d['num_timeout']}); mean length key "
             f"{d['mean_length_key']:.1f}, lava {d['mean_length_lava']:.1f}, timeout "
             f"{d['mean_length_timeout']:.1f}"]
    rows = [("BC", results["bc"])] + [(f"PEVI ({k})", v)
                                      for k, v in results["pevi_by_reward"].items()]
    lines.append(f"{'method':16s} {'return':>7s} {'key':>5s} {'lava':>5s} {'steps':>5s} "
                 f"{'V̂(start)':>10s} {'V^π(start)':>10s}")
    for name, r in rows:
        pess = r.get("pessimistic_value")
        true_data = r.get("true_value_under_data_reward")
        lines.append(f"{name:16s} {r['true_return']:7.1f} {r['reached_key']!s:>5s} "
                     f"{r['touched_lava']!s:>5s} {r['steps_to_key'] or '-'!s:>5s} "
                     f"{'-' if pess is None else f'{pess:.2f}':>10s} "
                     f"{'-' if true_data is None else f'{true_data:.2f}':>10s}")
    lines.append(f"optimal true return {results['optimal_true_return']:.1f}")
    return lines


def draw(results: dict, path: Path) -> None:
    """Fig. 8.2 analogue: a panel per reward with data opacity, BC (red) and PEVI (blue) paths."""
    import matplotlib  # lazy: optional dependency (the plots extra)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # lazy: optional dependency (the plots extra)

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


__all__ = ["draw", "run", "table_lines"]
