"""Packed sweeps: one compiled program trains every run of a grid of environment setups ×
policy kinds × scalar PPO hyper-parameters × seeds (docs/design.md §2.3).

A :class:`agents.run.sweep_spec.SweepSpec` is a base :class:`agents.run.spec.RunSpec`, a list of
environment setups that share a model (e.g. ``three_link/env2`` and ``three_link/env3``, which
differ only in the goal region), a list of policy kinds that share a network (``nn`` and
``nn_residual``: the hand-designed base added with weight 0 or 1,
:func:`agents.ppo.policies.packed_kind`) and a grid over names of
:data:`agents.ppo.hparams.SWEEPABLE`; its *points* are the setups × the kinds × the grid's
cartesian product, each an ordinary ``RunSpec`` (the base with the point's environment, kind and
values) trained for the base's seeds. All ``points × seeds`` runs share one program
(:meth:`~agents.run.sweep_spec.SweepSpec.program_spec`, :func:`agents.run.program.build`): the
runs are rows of its ``vmap``; each row carries its own values in ``TrainState.hparams``
(:mod:`agents.ppo.hparams`, the base's weight included) and its environments their own scene
parameters in ``info["scene"]`` (:meth:`envs.reaching.ReachEnv.reset`), so a point computes what
its separate run computes up to float32 rounding (its values are data instead of constants).

:func:`run_sweep` writes ``<out>/sweep.json`` (the sweep), ``<out>/sweep.csv`` (one row per point:
its values and final metrics, mean ± std over seeds), ``<out>/sweep_curves.png`` and, per point,
``<out>/<point name>/`` — an ordinary run directory (:mod:`agents.run.training`: ``run.json``,
``metrics.csv``, TensorBoard, ``learning_curves.png``, checkpoints without ``hparams``), which
``scripts/eval.py``, ``scripts/export.py`` and ``scripts/train.py --resume`` read like any other.
``resume=True`` restores every point from its newest checkpoint and continues exactly as the
uninterrupted sweep (iteration ``i`` of every row draws from ``fold_in(key, i)``).
"""

from __future__ import annotations

import contextlib
import json
import os
import warnings
from collections.abc import Sequence
from typing import IO, Any

import jax
import jax.numpy as jnp
import numpy as np

from agents.ppo import TrainState
from agents.run import checkpoint
from agents.run.curves import episode_window
from agents.run.directory import check_dir, lock_run_directory, write_spec
from agents.run.logs import ProgressBar, summary_line
from agents.run.program import Program, build, seed_keys
from agents.run.rows import rows as rows_of
from agents.run.rows import stacked
from agents.run.sweep_spec import SweepSpec, row_scenes, row_values
from agents.run.training import (
    RunResult,
    _history_from_json,
    _plot,
    _RunLog,
    _Saver,
    _train_chunks,
)
from mjxrmp.atomic import atomic_write


class _SweepLog:
    """The points' run logs (no bars of their own) behind the one interface of
    :class:`agents.run.training._RunLog`, with one progress bar for the sweep."""

    def __init__(self, logs: list[_RunLog], num_seeds: int, bar: ProgressBar | None,
                 steps_per_iteration: int):
        self.logs, self.n, self.bar, self.steps = logs, num_seeds, bar, steps_per_iteration

    @property
    def history(self) -> dict[str, np.ndarray]:
        """Every point's history stacked along the row axis ({} before the first chunk)."""
        if not self.logs[0].history:
            return {}
        return {k: np.concatenate([log.history[k] for log in self.logs])
                for k in self.logs[0].history}

    def append(self, metrics: dict[str, np.ndarray], start: int, done: int,
               seconds: float) -> None:
        """Each point's rows to its log; the sweep's bar."""
        for i, log in enumerate(self.logs):
            log.append({k: v[i * self.n:(i + 1) * self.n] for k, v in metrics.items()},
                       start, done, seconds)
        if self.bar is not None:
            rate = (done - start) * self.steps * self.n * len(self.logs) / seconds
            self.bar.update(done, summary_line(self.history, rate, window=done - start))

    def close_bar(self) -> None:
        """End the progress bar's line."""
        if self.bar is not None:
            self.bar.close()

    def close(self) -> None:
        """Close every point's TensorBoard writer."""
        for log in self.logs:
            log.close()


class _SweepSaver:
    """Each point's rows of the state (without ``hparams``) checkpointed in its directory."""

    def __init__(self, savers: list[_Saver], num_seeds: int):
        self.savers, self.n = savers, num_seeds
        self.ckpt_dir = savers[0].ckpt_dir

    def save(self, at: int, state: TrainState, history: dict[str, np.ndarray]) -> None:
        """Checkpoint every point as iteration ``at``."""
        state = state._replace(hparams=None)
        for i, saver in enumerate(self.savers):
            rows = slice(i * self.n, (i + 1) * self.n)
            saver.save(at, rows_of(state, i * self.n, self.n),
                       {k: v[rows] for k, v in history.items()})


def initial_rows(program: Program, sweep: SweepSpec) -> TrainState:
    """The fresh stacked state of every row of ``sweep`` (point-major, then seed), each row with
    its hyper-parameters, for ``program`` (:func:`agents.run.program.build` of the first
    point)."""
    keys = seed_keys(sweep.base.seeds)
    state = program.initial_state(jnp.concatenate([keys] * len(sweep.points())),
                                  row_scenes(sweep))
    return state._replace(hparams=row_values(sweep)[0])


def _initial_state(program: Program, sweep: SweepSpec, dirs: list[str], resume: bool
                   ) -> tuple[TrainState, list[dict[str, np.ndarray]], int]:
    """The stacked state of every row (fresh, or each point's newest checkpoint, which must
    match the point's identity and all be at the same iteration), the points' histories and
    the iterations done."""
    if not resume:
        return initial_rows(program, sweep), [{} for _ in dirs], 0
    keys = seed_keys(sweep.base.seeds)
    hp, _ = row_values(sweep)
    template = jax.eval_shape(program.init, keys)
    states, histories, done = [], [], set()
    for d, (_, spec) in zip(dirs, sweep.points(), strict=True):
        state, meta = checkpoint.restore(os.path.join(d, "checkpoints"), template,
                                         expected=spec.identity())
        states.append(state)
        histories.append(_history_from_json(meta["history"]))
        done.add(int(meta["iteration"]))
    if len(done) != 1:
        raise ValueError(f"the sweep's points were checkpointed at different iterations "
                         f"{sorted(done)}; resume each point with scripts/train.py --resume or "
                         "start the sweep again")
    return stacked(states)._replace(hparams=hp), histories, done.pop()


def final_table(sweep: SweepSpec, histories: list[dict[str, np.ndarray]]) -> list[dict]:
    """One row per point: its values and, over its seeds (mean, std), the last iteration's mean
    step reward and the final mean episode return, safe % and success % (trailing ≥ 100
    episodes, :func:`episode_window`; NaN before any episode has finished)."""
    rows = []
    for (name, spec), hist in zip(sweep.points(), histories, strict=True):
        row: dict[str, Any] = {"point": name, **({"env": spec.env} if sweep.envs else {}),
                               **({"policy": spec.policy} if sweep.policies else {}),
                               **{k: getattr(spec.ppo, k) for k, _ in sweep.grid}}
        last = hist["mean_reward"][:, -1] if hist else np.full(1, np.nan)
        row["mean_reward"], row["mean_reward_std"] = float(np.mean(last)), float(np.std(last))
        for key, scale in (("mean_episode_return", 1.0), ("safe_fraction", 100.0),
                           ("success_fraction", 100.0)):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                final = episode_window(hist, key)[:, -1] * scale if hist else np.full(1, np.nan)
                row[key], row[f"{key}_std"] = float(np.nanmean(final)), float(np.nanstd(final))
        rows.append(row)
    return rows


def _write_outputs(sweep: SweepSpec, out_dir: str, histories: list[dict[str, np.ndarray]]
                   ) -> None:
    """``sweep.csv`` and ``sweep_curves.png`` (mean episode return per point over iterations,
    mean over seeds)."""
    rows = final_table(sweep, histories)
    cols = list(rows[0])
    text = ",".join(cols) + "\n" + "".join(
        ",".join(f"{r[c]:.6g}" if isinstance(r[c], float) else str(r[c]).replace(",", ";")
                 for c in cols) + "\n" for r in rows)
    atomic_write(os.path.join(out_dir, "sweep.csv"), text.encode())
    import matplotlib  # lazy: optional dependency (the "plots" extra)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # lazy: optional dependency (after the backend is set)

    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for (name, _), hist in zip(sweep.points(), histories, strict=True):
        if hist:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                curve = np.nanmean(episode_window(hist, "mean_episode_return"), axis=0)
            ax.plot(np.arange(1, curve.size + 1), curve, lw=1.3, label=name)
    ax.set_xlabel("iteration")
    ax.set_ylabel("mean episode return (mean over seeds)")
    ax.set_title(f"{', '.join(sweep.policies or (sweep.base.policy,))} on "
                 f"{', '.join(sweep.envs or (sweep.base.env,))}: sweep")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    path = os.path.join(out_dir, "sweep_curves.png")
    fig.savefig(path + ".tmp.png", dpi=110)
    plt.close(fig)
    os.replace(path + ".tmp.png", path)


def run_sweep(sweep: SweepSpec, out_dir: str, resume: bool = False, progress: bool = True,
              stream: IO[str] | None = None, point_dirs: Sequence[str] | None = None
              ) -> RunResult:
    """Train every point × seed of ``sweep`` in one program into ``out_dir`` (see the module
    docstring) under the directory's lock; ``point_dirs`` places the points' run directories
    elsewhere (default ``<out_dir>/<point name>``; each is locked too). The result's history
    and state are every row's (point-major, then seed)."""
    if not resume:
        os.makedirs(out_dir, exist_ok=True)
    elif not os.path.isdir(out_dir):
        raise FileNotFoundError(f"resume=True but {out_dir} does not exist (no sweep to resume)")
    row_scenes(sweep)  # refuses setups that do not share a model before anything is written
    points = sweep.points()
    dirs = list(point_dirs or [os.path.join(out_dir, name) for name, _ in points])
    if len(dirs) != len(points):
        raise ValueError(f"point_dirs must name one directory per point ({len(points)}), got "
                         f"{len(dirs)}")
    with contextlib.ExitStack() as held:
        held.enter_context(lock_run_directory(out_dir))
        for d in dirs:
            os.makedirs(d, exist_ok=True)
            if point_dirs is not None:
                held.enter_context(lock_run_directory(d))
        ckpt_dirs = [check_dir(d, resume) for d in dirs]
        program = build(sweep.program_spec())
        compile_before = program.compile_seconds
        state, histories, done = _initial_state(program, sweep, dirs, resume)
        atomic_write(os.path.join(out_dir, "sweep.json"),
                     json.dumps(sweep.to_json(), indent=1).encode())
        logs = []
        for d, (_, spec), hist in zip(dirs, points, histories, strict=True):
            write_spec(spec, d)
            logs.append(_RunLog(spec, d, hist, None))
        base = sweep.base
        total = base.ppo.total_iterations
        log = _SweepLog(logs, len(base.seeds), ProgressBar(total, stream) if progress else None,
                        base.ppo.batch_size)
        saver = _SweepSaver([_Saver(s, c, done) for (_, s), c in zip(points, ckpt_dirs,
                                                                     strict=True)],
                            len(base.seeds))
        try:
            state, done, train_s = _train_chunks(program, base, state, done, log, saver,
                                                 row_values(sweep)[1])
        finally:
            for d, (_, spec), run_log in zip(dirs, points, logs, strict=True):
                if run_log.history:
                    _plot(program, spec, run_log.history, d)
            _write_outputs(sweep, out_dir, [run_log.history for run_log in logs])
    steps = done * base.ppo.batch_size * len(base.seeds) * len(points) if log.history else 0
    return RunResult(log.history, state, program.trainer,
                     program.compile_seconds - compile_before, train_s, steps)


__all__ = ["final_table", "initial_rows", "run_sweep"]
