"""The figures of ``scripts/reproduce_ch8.py`` (thesis Figs 8.4–8.6, eq 8.3; docs/design.md
§2.4): scores per data reward, episode length against return, the positive-data-bias estimate
and learning curves. Needs matplotlib (the ``plots`` extra).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from offline.survival.ch8 import LEARNERS, base_datasets
from offline.survival.rewards import REWARD_VARIANTS


def _pyplot() -> Any:
    """``matplotlib.pyplot`` with the non-interactive Agg backend."""
    import matplotlib  # lazy: optional dependency (the plots extra)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # lazy: optional dependency (the plots extra)

    return plt


def plot_scores(args: Any, cells: dict, bias: dict, lengths: dict) -> None:
    """Fig 8.4 (``fig8_4.png``: rows datasets, columns learners, bars per data reward:
    normalised score ± s.e. over seeds, BC dashed), Fig 8.5 (:func:`plot_lengths`, when there
    are length statistics) and Fig 8.6 (:func:`plot_bias`), of the cells with results."""
    plt = _pyplot()
    # Rows and columns with results only (a sweep may train part of the grid).
    trained = {(d, lrn) for d, lrn, _ in cells}
    base = [d for d in base_datasets(args.recipes, args.goal_deadline)
            if any((d, lrn) in trained for lrn in LEARNERS)]
    learners = [lrn for lrn in LEARNERS if lrn != "BC" and any((d, lrn) in trained for d in base)]
    if not base or not learners:
        print("[figures] no trained cells: Figs 8.4 and 8.6 are left out", flush=True)
        return
    colours = dict(zip(REWARD_VARIANTS, ("tab:green", "tab:grey", "tab:orange", "tab:red"),
                       strict=True))
    fig, axes = plt.subplots(len(base), len(learners), figsize=(3.2 * len(learners),
                                                                 2.6 * len(base)),
                             squeeze=False, sharey=True)
    for i, d in enumerate(base):
        for j, lrn in enumerate(learners):
            ax = axes[i][j]
            for k, r in enumerate(REWARD_VARIANTS):
                c = cells.get((d, lrn, r))
                if c is not None:
                    ax.bar(k, c["mean"], yerr=c["se"], color=colours[r], capsize=3)
            if (d, "BC", "none") in cells:
                ax.axhline(cells[(d, "BC", "none")]["mean"], ls="--", c="k", lw=1, label="BC")
            ax.set_xticks(range(len(REWARD_VARIANTS)), REWARD_VARIANTS, fontsize=7)
            ax.set_title(f"{d} — {lrn}", fontsize=8)
            if j == 0:
                ax.set_ylabel("normalised score")
    sep = "\n" if len(learners) < 3 else " "  # one or two columns are too narrow for one line
    fig.suptitle(f"Fig 8.4 (env3): last-iterate normalised score ± s.e.{sep}per data reward; "
                 "dashed: BC", fontsize=9)
    fig.tight_layout()
    fig.savefig(args.out / "fig8_4.png", dpi=110)
    plt.close(fig)

    if lengths:
        plot_lengths(args, lengths)
    plot_bias(args, bias, base, learners)


def plot_bias(args: Any, bias: dict, base: list[str], learners: list[str]) -> None:
    """Fig 8.6 (``fig8_6.png``): the eq 8.3 positive-data-bias estimate per dataset and learner;
    ∞ drawn as a capped, hatched, labelled bar."""
    plt = _pyplot()
    finite = [v for v in bias.values() if math.isfinite(v)]
    cap = 1.5 * max([*finite, 2.0])
    fig, ax = plt.subplots(figsize=(1.2 + 1.6 * len(base), 3.2))
    width = 0.8 / len(learners)
    for j, lrn in enumerate(learners):
        for i, d in enumerate(base):
            v = bias.get((d, lrn))
            if v is None:
                continue
            x = i + (j - (len(learners) - 1) / 2) * width
            ax.bar(x, min(v, cap), width, color=f"C{j}", hatch="//" if math.isinf(v) else None,
                   label=lrn if i == 0 else None)
            if math.isinf(v):
                ax.text(x, cap, "∞", ha="center", va="bottom")
    ax.set_xticks(range(len(base)), base, fontsize=8)
    ax.set_ylabel("estimated positive data bias (eq 8.3)")
    if ax.get_legend_handles_labels()[0]:  # no estimate without all three wrong rewards
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(args.out / "fig8_6.png", dpi=110)
    plt.close(fig)


def plot_lengths(args: Any, lengths: dict) -> None:
    """Fig 8.5 (``fig8_5.png``): episode length vs true return, one panel per dataset."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(lengths), figsize=(3.4 * len(lengths), 3), squeeze=False)
    for ax, (d, st) in zip(axes[0], lengths.items(), strict=True):
        ax.scatter(st["lengths"], st["returns"], s=6, alpha=0.6)
        corr = st["length_return_correlation"]
        ax.set_title(f"{d}: corr " + ("undefined" if math.isnan(corr) else f"{corr:.2f}"),
                     fontsize=8)
        ax.set_xlabel("episode length")
        ax.set_ylabel("return (true reward)")
    fig.tight_layout()
    fig.savefig(args.out / "fig8_5.png", dpi=110)
    plt.close(fig)


def plot_curves(args: Any, cells: dict) -> None:
    """``fig8_curves.png``: normalised score ± s.e. against gradient steps per dataset, one line
    per learner and reward (cells trained with ``--curve``); BC's final score dashed."""
    plt = _pyplot()
    datasets = list(dict.fromkeys(d for (d, _, _), c in cells.items() if "curve" in c))
    if not datasets:
        return
    fig, axes = plt.subplots(1, len(datasets), figsize=(4.2 * len(datasets), 3.2),
                             squeeze=False, sharey=True)
    # one colour per (learner, reward) in every panel, in a fixed order
    lines = sorted({(lrn, r) for (_, lrn, r), c in cells.items() if "curve" in c})
    colour = {line: f"C{i % 10}" for i, line in enumerate(lines)}
    for ax, d in zip(axes[0], datasets, strict=True):
        for line in lines:
            c = cells.get((d, *line))
            if c is None or "curve" not in c:
                continue
            x, m, e = (np.asarray(c["curve"][k], np.float64) for k in ("steps", "mean", "se"))
            ax.plot(x, m, marker=".", c=colour[line], label=" ".join(line))
            ax.fill_between(x, m - e, m + e, color=colour[line], alpha=0.2)
        if (d, "BC", "none") in cells:
            ax.axhline(cells[(d, "BC", "none")]["mean"], ls="--", c="k", lw=1,
                       label="BC (final)")
        ax.set_title(d, fontsize=9)
        ax.set_xlabel("gradient steps")
        ax.xaxis.set_major_formatter(lambda v, _: f"{v / 1000:g}k")
        ax.legend(fontsize=7)
    axes[0][0].set_ylabel("normalised score")
    fig.tight_layout()
    fig.savefig(args.out / "fig8_curves.png", dpi=110)
    plt.close(fig)


__all__ = ["plot_bias", "plot_curves", "plot_lengths", "plot_scores"]
