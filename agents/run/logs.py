"""What a training run reports while it runs: a progress bar with live metrics, ``metrics.csv``
(one row per iteration and seed) and TensorBoard scalars (seed mean and per seed)."""

from __future__ import annotations

import csv
import os
import sys
import time
import warnings
from typing import IO, Any

import numpy as np

#: Metrics averaged over the episodes that finished (weighted by their count in summaries).
EPISODE_METRICS = ("mean_episode_return", "safe_fraction", "success_fraction")


class ProgressBar:
    """A one-line progress bar with live metrics on a terminal; a line per update otherwise."""

    def __init__(self, total: int, stream: IO[str] | None = None, width: int = 24):
        self.total, self.width = total, width
        self.stream = sys.stderr if stream is None else stream
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.start = time.perf_counter()

    def update(self, done: int, text: str) -> None:
        """Show ``done`` of ``total`` with ``text``, the elapsed time and an ETA."""
        frac = done / max(self.total, 1)
        filled = round(self.width * frac)
        elapsed = time.perf_counter() - self.start
        eta = elapsed / frac * (1 - frac) if frac > 0 else float("nan")
        line = (f"[{'#' * filled}{'.' * (self.width - filled)}] {done}/{self.total} "
                f"{text} | {elapsed:5.0f}s elapsed, ETA {eta:4.0f}s")
        if self.tty:
            self.stream.write("\r" + line)
        else:
            self.stream.write(line + "\n")
        self.stream.flush()

    def close(self) -> None:
        """End the line on a terminal."""
        if self.tty:
            self.stream.write("\n")
            self.stream.flush()


def _fmt(x: float, scale: float = 1.0, spec: str = ".3g") -> str:
    return "  n/a" if not np.isfinite(x) else format(x * scale, spec)


def nanmean(x: np.ndarray, axis: int | None = None) -> np.ndarray | float:
    """``np.nanmean`` that returns NaN for all-NaN slices without a warning."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmean(x, axis=axis)


def summary_line(history: dict[str, np.ndarray], steps_per_second: float,
                 window: int = 1) -> str:
    """Seed-mean metrics of the newest ``window`` iterations (episode metrics weighted by the
    episodes that finished in each), formatted for the progress bar."""
    eps = np.nan_to_num(history["episodes"][:, -window:]) if "episodes" in history else None
    last = {}
    for k, v in history.items():
        v = v[:, -window:]
        if eps is not None and k in EPISODE_METRICS and eps.sum() > 0:
            last[k] = float(np.nansum(np.nan_to_num(v) * eps) / eps.sum())
        else:
            last[k] = float(nanmean(v))
    return (f"reward {_fmt(last['mean_reward'])} | "
            f"return {_fmt(last['mean_episode_return'])} | "
            f"safe {_fmt(last['safe_fraction'], 100, '.1f')}% | "
            f"success {_fmt(last['success_fraction'], 100, '.1f')}% | "
            f"{steps_per_second:.3g} steps/s")


def first_nonfinite_metric(history: dict[str, np.ndarray]) -> tuple[int, int, str, float] | None:
    """The earliest non-finite logged value as ``(iteration index, seed index, metric, value)``
    (``loss`` named first when several are non-finite at that iteration), or None. Episode
    metrics (:data:`EPISODE_METRICS`) count only where episodes finished (they are NaN by
    design where none did)."""
    eps = history.get("episodes")
    found = []
    for k, v in history.items():
        bad = ~np.isfinite(v)
        if k in EPISODE_METRICS and eps is not None:
            bad &= eps > 0
        its = np.flatnonzero(bad.any(0))
        if its.size:
            s = int(np.flatnonzero(bad[:, its[0]])[0])
            found.append((int(its[0]), k != "loss", k, s, float(v[s, its[0]])))
    if not found:
        return None
    it, _, k, s, value = min(found)
    return it, s, k, value


def improvement_summary(history: dict[str, np.ndarray]) -> str:
    """First vs last tenth of the run (at least one, at most 10 iterations each): seed-mean
    step reward and episode return, and whether the final policy beats the initial one — no
    verdict when a logged value is non-finite (:func:`first_nonfinite_metric`)."""
    n = history["mean_reward"].shape[1]
    k = max(1, min(10, n // 10))
    fault = first_nonfinite_metric(history)
    parts = []
    for key, label in (("mean_reward", "mean step reward"),
                       ("mean_episode_return", "mean episode return")):
        first, last = float(nanmean(history[key][:, :k])), float(nanmean(history[key][:, -k:]))
        verdict = "" if fault is not None else ": improved" if last > first else ": not improved"
        parts.append(f"{label} {first:.4g} (first {k} it.) → {last:.4g} (last {k} it.)"
                     f"{verdict}")
    if fault is not None:
        it, _, key, value = fault
        parts.append(f"no verdict: the run has non-finite values ({key} is {value:g} at "
                     f"iteration {it + 1})")
    return "\n".join(parts)


def write_csv(path: str, history: dict[str, np.ndarray], seeds: tuple[int, ...],
              batch_size: int) -> None:
    """Rewrite ``path`` with one row per (iteration, seed) (atomic: temporary file + rename)."""
    names = sorted(history)
    n_iter = next(iter(history.values())).shape[1] if history else 0
    tmp = path + ".tmp"
    with open(tmp, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["iteration", "seed", "env_steps", *names])
        for it in range(n_iter):
            for s, seed in enumerate(seeds):
                w.writerow([it + 1, seed, (it + 1) * batch_size,
                            *(f"{float(history[k][s, it]):.7g}" for k in names)])
    os.replace(tmp, path)


def read_csv(path: str) -> tuple[dict[str, np.ndarray], tuple[int, ...]]:
    """``(history, seeds)`` from a ``metrics.csv`` written by :func:`write_csv`."""
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        raise ValueError(f"{path} has no rows")
    seeds = tuple(dict.fromkeys(int(r["seed"]) for r in rows))
    names = [k for k in rows[0] if k not in ("iteration", "seed", "env_steps")]
    n_iter = max(int(r["iteration"]) for r in rows)
    history = {k: np.full((len(seeds), n_iter), np.nan) for k in names}
    index = {s: i for i, s in enumerate(seeds)}
    for r in rows:
        for k in names:
            history[k][index[int(r["seed"])], int(r["iteration"]) - 1] = float(r[k])
    return history, seeds


class TensorBoard:
    """TensorBoard scalars through tensorboardX (skipped, with a note, if it is missing)."""

    def __init__(self, logdir: str):
        try:
            from tensorboardX import SummaryWriter  # lazy: optional dependency
        except ImportError:  # pragma: no cover - tensorboardX comes with brax
            print("tensorboardX not installed: no TensorBoard event files", file=sys.stderr)
            self.writer: Any = None
            return
        self.writer = SummaryWriter(logdir)

    def write(self, history: dict[str, np.ndarray], start: int, seeds: tuple[int, ...],
              batch_size: int) -> None:
        """Add iterations ``start..`` of ``history``: ``mean/<metric>`` and
        ``seed<seed>/<metric>`` at the environment-step count."""
        if self.writer is None:
            return
        n_iter = next(iter(history.values())).shape[1]
        for it in range(start, n_iter):
            step = (it + 1) * batch_size
            for k, v in history.items():
                col = v[:, it]
                if np.any(np.isfinite(col)):
                    self.writer.add_scalar(f"mean/{k}", float(nanmean(col)), step)
                for s, seed in enumerate(seeds):
                    if np.isfinite(col[s]):
                        self.writer.add_scalar(f"seed{seed}/{k}", float(col[s]), step)
        self.writer.flush()

    def close(self) -> None:
        """Close the event file."""
        if self.writer is not None:
            self.writer.close()


__all__ = ["ProgressBar", "TensorBoard", "first_nonfinite_metric", "improvement_summary",
           "nanmean", "read_csv", "summary_line", "write_csv"]
