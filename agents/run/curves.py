"""Learning curves of a training run as the thesis draws them: episode metrics averaged over
the trailing ≥ 100 finished episodes (RLlib's reporting), mean ± 1 std over seeds."""

from __future__ import annotations

import os
import warnings

import numpy as np

from agents.run.logs import nanmean

#: Curves drawn by :func:`plot_curves`: (metric, label, scale).
CURVES = (("mean_episode_return", "mean episode return", 1.0),
          ("mean_reward", "mean step reward", 1.0),
          ("safe_fraction", "safe episodes (%)", 100.0),
          ("success_fraction", "successful episodes (%)", 100.0))


def episode_window(history: dict[str, np.ndarray], key: str,
                   min_episodes: int = 100) -> np.ndarray:
    """Per-episode metric ``key`` averaged, at every iteration, over the episodes finished in
    the trailing window of iterations that holds at least ``min_episodes`` episodes — RLlib's
    reporting (``metrics_num_episodes_for_smoothing = 100``), which the thesis's curves use.

    Per-iteration values are noisy here because the 128 environments start together: an
    iteration in which only a few (early-terminated, i.e. collided) episodes end reports e.g.
    0 % safe from one episode. ``(seeds, iterations)`` in, same shape out.
    """
    n = np.nan_to_num(history["episodes"])
    v = np.nan_to_num(history[key]) * n
    out = np.full(n.shape, np.nan)
    for s in range(n.shape[0]):
        for i in range(n.shape[1]):
            j, total, acc = i, 0.0, 0.0
            while j >= 0 and total < min_episodes:
                total, acc = total + n[s, j], acc + v[s, j]
                j -= 1
            if total > 0:
                out[s, i] = acc / total
    return out


def moving_average(x: np.ndarray, k: int) -> np.ndarray:
    """Trailing NaN-aware moving average over the last axis (window ``k`` iterations)."""
    if k <= 1:
        return x
    out = np.full(x.shape, np.nan)
    for i in range(x.shape[-1]):
        out[..., i] = nanmean(x[..., max(0, i - k + 1): i + 1], axis=-1)
    return out


def plot_curves(history: dict[str, np.ndarray], path: str, title: str = "",
                min_episodes: int = 100, reward_window: int = 1) -> None:
    """Learning curves (mean ± 1 std over seeds) of :data:`CURVES` to the PNG ``path``.

    Episode metrics average the trailing ≥ ``min_episodes`` finished episodes
    (:func:`episode_window`); the step reward is a ``reward_window``-iteration moving average
    (one episode length smooths out the phase of episodes that start together)."""
    import matplotlib  # lazy: optional dependency (the "plots" extra)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # lazy: optional dependency (after the backend is set)

    fig, axes = plt.subplots(1, len(CURVES), figsize=(4.2 * len(CURVES), 3.4))
    for ax, (key, label, scale) in zip(axes, CURVES, strict=True):
        if key not in history:
            ax.set_visible(False)
            continue
        if key == "mean_reward" or "episodes" not in history:
            v = moving_average(history[key], reward_window) * scale
        else:
            v = episode_window(history, key, min_episodes) * scale
        it = np.arange(1, v.shape[1] + 1)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            mean, std = np.nanmean(v, axis=0), np.nanstd(v, axis=0)
        ax.plot(it, mean, lw=1.5)
        ax.fill_between(it, mean - std, mean + std, alpha=0.25)
        ax.set_xlabel("iteration")
        ax.set_ylabel(label)
        if scale == 100.0:
            ax.set_ylim(-2, 102)
        ax.grid(alpha=0.3)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    tmp = path + ".tmp.png"
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    os.replace(tmp, path)


__all__ = ["CURVES", "episode_window", "moving_average", "plot_curves"]
