"""The figures of thesis Figs 3.2 and 3.3 (§3.2.7) from a :class:`mjxrmp.studies.ch3.Ch3Result`.

Needs matplotlib (``pip install -e ".[plots]"``). Figures are built with matplotlib's object
API (no pyplot, no global backend switch); save them with ``fig.savefig(path, **SAVE_KWARGS)``.
"""

from __future__ import annotations

import matplotlib
import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Circle

from mjxrmp.studies.ch3 import (
    DT,
    LABELS,
    SINGLE_GOAL,
    SINGLE_OBSTACLE,
    SINGLE_OBSTACLE_RADIUS,
    SINGLE_START,
    Ch3Result,
)

#: Colours of the Fig 3.2 goal attractors.
COLORS = {"potential": "tab:blue", "spiral": "tab:orange", "sinusoidal": "tab:green",
          "gds": "tab:red"}
#: Keyword arguments of ``Figure.savefig`` for both figures.
SAVE_KWARGS = {"dpi": 120, "bbox_inches": "tight", "pad_inches": 0.15}

__all__ = ["COLORS", "SAVE_KWARGS", "figures", "plot_fig3_2", "plot_fig3_3"]


def plot_fig3_2(trajs: dict[str, np.ndarray]) -> Figure:
    """Fig 3.2: (a) RMP²-CLF with the three nominal controllers, (b) the RMPflow-GDS attractor."""
    fig = Figure(figsize=(10, 5), layout="constrained")
    axes = fig.subplots(1, 2)
    panels = [("(a) RMP²-CLF, three nominal controllers", ("potential", "spiral", "sinusoidal")),
              ("(b) RMPflow-GDS goal attractor", ("gds",))]
    for ax, (title, names) in zip(axes, panels, strict=True):
        ax.add_patch(Circle(SINGLE_OBSTACLE, SINGLE_OBSTACLE_RADIUS, color="0.6"))
        for c in names:
            tr = trajs[c]
            ax.plot(tr[:, 0], tr[:, 1], color=COLORS[c], lw=1.6, label=LABELS[c])
        ax.plot(*SINGLE_GOAL, marker="*", ms=14, color="tab:green", mec="k", ls="none",
                label="goal")
        ax.plot(*SINGLE_START, marker="o", ms=7, color="k", ls="none", label="start")
        ax.set_xlim(-5, 5)
        ax.set_ylim(-5, 5)
        ax.set_aspect("equal")
        ax.set_title(title)
        ax.legend(loc="lower left", fontsize=8)
        ax.grid(alpha=0.3)
    return fig


def _swap_panel(ax, res: dict, name: str, title: str, lim: float) -> None:
    """One robot-swap panel: every robot's path, start and goal, titled with its metrics."""
    goals, start = res["goals"], res["start"]
    cmap = matplotlib.colormaps["tab10"]
    tr = res["trajectories"][name]
    for i in range(goals.shape[0]):
        ax.plot(tr[:, i, 0], tr[:, i, 1], color=cmap(i % 10), lw=1.2)
        ax.plot(*start[i], "o", color=cmap(i % 10), ms=6)
        ax.plot(*goals[i], "*", color=cmap(i % 10), ms=12, mec="k")
    m = res["metrics"][name]
    ttg = f"{m['time_to_goal']:.1f} s" if m["reached"] else "not reached"
    ax.set_title(f"{title}\ntime to goal {ttg}, min dist {m['min_pair_distance']:.2f}")
    ax.set_xlim(-lim, lim)
    ax.set_ylim(-lim, lim)
    ax.set_aspect("equal")
    ax.grid(alpha=0.3)


def plot_fig3_3(res: dict, tol: float) -> Figure:
    """Fig 3.3: the swap with (a) the spiral RMP²-CLF and (b) the GDS goal attractors, and
    (c) the largest goal error over time of every variant (``res`` from ``run_fig3_3``)."""
    fig = Figure(figsize=(15, 5.4), layout="constrained")
    axes = fig.subplots(1, 3)
    goals = res["goals"]
    lim = 1.25 * float(np.abs(goals).max())
    _swap_panel(axes[0], res, "spiral_clf", "(a) RMP²-CLF, spiral nominal", lim)
    _swap_panel(axes[1], res, "gds", "(b) RMPflow-GDS", lim)
    ax = axes[2]
    styles = {"spiral_clf": ("tab:orange", "-", "RMP²-CLF spiral"),
              "gds": ("tab:red", "-", "RMPflow-GDS"),
              "spiral_clf_euclidean_alpha": ("tab:orange", ":", "RMP²-CLF spiral, α(‖ẋ‖)")}
    for c, (color, ls, label) in styles.items():
        if c not in res["trajectories"]:
            continue
        err = np.linalg.norm(res["trajectories"][c] - goals[None], axis=-1).max(axis=-1)
        ax.semilogy(np.arange(len(err)) * DT, err, color=color, ls=ls, label=label)
    ax.axhline(tol, color="k", ls="--", lw=0.8, label=f"tolerance {tol}")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("max distance to goal")
    ax.set_title("(c) largest goal error")
    ax.legend()
    ax.grid(alpha=0.3, which="both")
    return fig


def figures(result: Ch3Result) -> dict[str, Figure]:
    """``{"fig3_2.png": …, "fig3_3.png": …}``: both figures of a :func:`reproduce` run."""
    return {"fig3_2.png": plot_fig3_2(result.fig3_2),
            "fig3_3.png": plot_fig3_3(result.fig3_3, result.tol)}
