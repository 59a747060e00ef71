"""Figures of the LfD evaluations (docs/design.md §2.5): the LASA fields and potentials (as Figs
4.4 and 4.7), the Franka reproductions and error/success panels (as Figs 5.1, 5.4 and 5.7), and
the per-seed values of a seed summary. Needs the optional ``matplotlib`` (``pip install -e
".[plots]"``), imported when a figure is drawn.
"""

from __future__ import annotations

import os
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from agents.lfd.franka_eval import LABELS
from agents.lfd.lasa_eval import LasaRun, box, velocity_program
from agents.lfd.seeds import METRICS
from mjxrmp.data import franka_demos

__all__ = ["plot_franka_errors", "plot_franka_task", "plot_lasa", "plot_lasa_overview",
           "plot_seeds"]


def _pyplot() -> Any:
    """``matplotlib.pyplot`` with the non-interactive Agg backend."""
    import matplotlib  # lazy: optional dependency (the plots extra)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # lazy: optional dependency (the plots extra)

    return plt


def _triangles(ax: Any, pts: np.ndarray, color: str, every: int) -> None:
    """Control-point triangles every ``every`` samples and the centre path of ``pts (T, 3, 3)``."""
    for t in range(0, len(pts), every):
        tri = pts[t][[0, 1, 2, 0]]
        ax.plot(tri[:, 0], tri[:, 1], tri[:, 2], color=color, lw=0.6, alpha=0.6)
    ax.plot(pts[:, 0, 0], pts[:, 0, 1], pts[:, 0, 2], color=color, lw=1.2)


def plot_franka_task(path: str, task: str, demos: list[franka_demos.FrankaDemo],
                     folds: list[int], reproductions: dict[str, list[np.ndarray]],
                     strategies: list[str]) -> None:
    """3-D demonstrated vs reproduced (held-out) control-point triangles and centre paths of one
    task, one panel per strategy (as Figs 5.1/5.4)."""
    plt = _pyplot()

    cols = 1 + len(strategies)
    fig = plt.figure(figsize=(4 * cols, 4))
    colors = plt.cm.tab10(np.arange(10))
    ax = fig.add_subplot(1, cols, 1, projection="3d")
    for i, f in enumerate(folds):
        _triangles(ax, demos[f].points, colors[i % 10], max(demos[f].length // 12, 1))
    ax.set_title(f"{task}: demonstrations")
    for j, s in enumerate(strategies):
        ax = fig.add_subplot(1, cols, 2 + j, projection="3d")
        for i, f in enumerate(folds):
            rep = reproductions[s][i]
            ax.plot(*demos[f].points[:, 0].T, color=colors[i % 10], lw=0.8, ls="--")
            _triangles(ax, rep, colors[i % 10], max(len(rep) // 12, 1))
        ax.set_title(f"{LABELS[s]} (held out)")
    for a in fig.axes:
        a.set_xlabel("x (m)", fontsize=7)
        a.set_ylabel("y (m)", fontsize=7)
        a.set_zlabel("z (m)", fontsize=7, labelpad=2)
        a.tick_params(labelsize=6)
        a.set_box_aspect(None, zoom=0.82)   # keeps the z label inside the axes' box
    fig.subplots_adjust(left=0.01, right=0.97, bottom=0.03, top=0.92, wspace=0.12)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_franka_errors(path: str, metrics: dict[str, dict[str, dict]]) -> None:
    """Per task: box plots of the held-out errors, the success rates and the corridor
    excursions per strategy (as Fig 5.7)."""
    plt = _pyplot()

    tasks = list(metrics)
    fig, axes = plt.subplots(3, len(tasks), figsize=(5.5 * len(tasks), 10), squeeze=False)
    for j, task in enumerate(tasks):
        strategies = list(metrics[task])
        labels = [LABELS[s] for s in strategies]
        data = [[p["mean_position_error"] * 100 for p in metrics[task][s]["folds"]]
                for s in strategies]
        axes[0, j].boxplot(data)
        axes[0, j].set_xticks(range(1, len(strategies) + 1), labels, fontsize=8)
        axes[0, j].set_ylabel("mean position error (cm)")
        axes[0, j].set_title(f"{task}: leave-one-out reproduction")
        x = np.arange(len(strategies))
        bars = (("success_rate", "goals reached"),
                ("task_success_rate", "goals + corridor"),
                ("success_rate_obstacle", "cylinder obstacle"),
                ("success_rate_no_posture", "goals, no posture leaf"))
        for b, (key, label) in enumerate(bars):
            axes[1, j].bar(x + 0.2 * (b - 1.5), [metrics[task][s][key] * 100 for s in strategies],
                           0.2, label=label)
        axes[1, j].set_xticks(x, labels, fontsize=8)
        axes[1, j].set_ylim(0, 130)
        axes[1, j].set_ylabel("success from new starts (%)")
        axes[1, j].legend(fontsize=7, loc="upper center", ncol=2)
        excursions = [[e * 100 for p in metrics[task][s]["folds"]
                       for e in p["corridor_excursions"]] for s in strategies]
        axes[2, j].boxplot(excursions)
        tol = metrics[task][strategies[0]]["corridor_tolerance"] * 100
        axes[2, j].axhline(tol, color="k", ls=":", lw=1, label=f"tolerance {tol:g} cm")
        axes[2, j].set_xticks(range(1, len(strategies) + 1), labels, fontsize=8)
        axes[2, j].set_ylabel("excursion from the demonstrated corridor (cm)")
        axes[2, j].set_title("new starts: max distance to the training paths − start's", fontsize=9)
        axes[2, j].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)



def plot_seeds(path: str, summary: dict) -> None:
    """Per task (columns) and metric (rows) of :func:`agents.lfd.seeds.summarise`: every seed's
    value per strategy, with the mean."""
    plt = _pyplot()

    tasks = list(summary["tasks"])
    fig, axes = plt.subplots(len(METRICS), len(tasks), figsize=(5.0 * len(tasks),
                                                                 2.6 * len(METRICS)),
                             squeeze=False)
    rng = np.random.default_rng(0)
    for j, task in enumerate(tasks):
        per = summary["tasks"][task]["strategies"]
        names = list(per)
        for i, (key, label, _, sc) in enumerate(METRICS):
            ax = axes[i, j]
            for x, s in enumerate(names):
                v = np.array(per[s][key]["per_seed"]) * sc
                ax.scatter(x + rng.uniform(-0.12, 0.12, v.size), v, s=12, alpha=0.7)
                ax.plot([x - 0.25, x + 0.25], [v.mean()] * 2, color="k", lw=2)
            ax.set_xticks(range(len(names)), names, fontsize=8)
            ax.set_ylabel(label, fontsize=8)
            if i == 0:
                ax.set_title(f"{task}: {len(summary['seeds'])} seeds", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)



def _field_grids(run: LasaRun, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Per shape a ``size × size`` grid over its demonstrations' box enlarged by 50 % and the
    learned velocity on it: ``((S, size, size, 2), (S, size, size, 2))``."""
    pad = [box(d, 0.5) for d in run.data["demos"]]
    grids = np.stack([np.stack(np.meshgrid(np.linspace(lo[0], hi[0], size),
                                           np.linspace(lo[1], hi[1], size)), -1)
                      for lo, hi in pad]).astype(np.float32)
    vel = np.asarray(velocity_program(run.field)(run.result.variables, jnp.asarray(grids)))
    return grids, vel


def _field_panel(ax: Any, grid: np.ndarray, vel: np.ndarray, demos: np.ndarray,
                 rollouts: np.ndarray, legend: bool) -> None:
    """Streamlines of one learned field with the demonstrations (black) and the reproductions
    over 1.2 × the demonstrations' duration (red), as Fig 4.4."""
    X, Y = grid[..., 0], grid[..., 1]
    ax.streamplot(X, Y, vel[..., 0], vel[..., 1], color=np.linalg.norm(vel, axis=-1),
                  cmap="viridis", density=1.4, linewidth=0.7, arrowsize=0.8)
    for k, (d, r) in enumerate(zip(demos, rollouts, strict=True)):
        ax.plot(d[:, 0], d[:, 1], color="k", lw=2.2, label="demonstrations" if k == 0 else None)
        ax.plot(r[:, 0], r[:, 1], color="r", lw=1.4, ls="--",
                label="reproductions" if k == 0 else None)
    ax.plot(0, 0, "x", color="limegreen", ms=12, mew=3, label="goal")
    ax.set_xlim(X.min(), X.max())
    ax.set_ylim(Y.min(), Y.max())
    ax.set_aspect("equal")
    if legend:
        ax.legend(loc="lower left", fontsize=7)


def plot_lasa(run: LasaRun, out: str) -> None:
    """Per shape of :func:`agents.lfd.lasa_eval.evaluate_shapes`' ``run``: ``<shape>_field.png``,
    streamlines of the learned field with the demonstrations and the reproductions (as Fig 4.4),
    and ``<shape>_potential.png``, iso-contours of ``Φ(x) = ½‖φ(x) − φ(0)‖²`` with the
    demonstrations (as Fig 4.7), in ``out``."""
    plt = _pyplot()
    data, field, variables = run.data, run.field, run.result.variables
    names = list(run.record["shapes"])
    grids, vel = _field_grids(run, 80)
    pot = np.asarray(jax.jit(jax.vmap(field.potential))(variables, jnp.asarray(grids)))
    for i, name in enumerate(names):
        X, Y = grids[i, ..., 0], grids[i, ..., 1]
        demos = data["demos"][i]

        fig, ax = plt.subplots(figsize=(5, 5))
        _field_panel(ax, grids[i], vel[i], demos, run.rollouts[i], legend=True)
        ax.set_title(f"{name}: learned field (cf. Fig 4.4)")
        fig.tight_layout()
        fig.savefig(os.path.join(out, f"{name}_field.png"), dpi=90)
        plt.close(fig)

        fig, ax = plt.subplots(figsize=(5, 5))
        # Equally spaced latent radii ‖φ(x) − φ(0)‖ up to 1.3× the largest on the demos.
        r_demo = np.sqrt(2.0 * np.asarray(field.potential(
            jax.tree.map(lambda a, i=i: a[i], variables), jnp.asarray(demos))).max())
        levels = 0.5 * np.linspace(0.0, 1.3 * r_demo, 16)[1:] ** 2
        ax.contour(X, Y, pot[i], levels=levels, cmap="viridis", linewidths=1.0)
        for d in demos:
            ax.plot(d[:, 0], d[:, 1], color="k", lw=1.8)
        ax.plot(0, 0, "x", color="limegreen", ms=12, mew=3)
        ax.set_aspect("equal")
        ax.set_title(f"{name}: Φ(x) = ½‖φ(x) − φ(0)‖² (cf. Fig 4.7)")
        fig.tight_layout()
        fig.savefig(os.path.join(out, f"{name}_potential.png"), dpi=90)
        plt.close(fig)


def plot_lasa_overview(run: LasaRun, path: str, columns: int = 6) -> None:
    """All shapes of ``run`` in one figure ``path``: one :func:`plot_lasa` field panel per
    shape (streamlines, demonstrations, reproductions over 1.2 × the duration), ``columns``
    per row, titled with the shape and its arrival count at 1.2 × the duration."""
    plt = _pyplot()
    names = list(run.record["shapes"])
    grids, vel = _field_grids(run, 60)
    rows = -(-len(names) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(3.2 * columns, 3.2 * rows), squeeze=False)
    for ax in axes.flat[len(names):]:
        ax.axis("off")
    for i, (name, ax) in enumerate(zip(names, axes.flat, strict=False)):
        _field_panel(ax, grids[i], vel[i], run.data["demos"][i], run.rollouts[i], legend=False)
        a = run.record["shapes"][name]["arrival"]
        ax.set_title(f"{name} ({a['within_1pct_at_horizon']}/{len(a['distance_at_horizon'])} "
                     f"at 1.2·D)", fontsize=9)
        ax.tick_params(labelsize=6)
    fig.suptitle(f"LASA: learned fields, demonstrations (black) and reproductions over 1.2 × "
                 f"the demonstrations' duration (red), {run.record['device']}")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
