"""Resumable runs of the reproduction scripts (docs/design.md §2.4, §2.5): compiled training
programs checkpointed after every chunk (:func:`train_program`), learning curves kept across
interruptions (:class:`LearningCurve`), results as JSON lines skipped when already there
(:func:`done_cells`), cached dataset files (:func:`collect_cached`) and the stages of a script
(:func:`run_stages`)."""

from __future__ import annotations

import json
import os
import shutil
import sys
import time
import warnings
import zlib
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np

from agents.run import checkpoint
from offline.data import collect
from offline.data import dataset as odata
from offline.experiment.run import init_runs, train_chunked
from offline.learners.base import Trainer


def result_rows(results: Path) -> list[dict[str, Any]]:
    """The rows of a results JSONL file, one dict per non-empty line (empty when the file does
    not exist)."""
    if not results.exists():
        return []
    return [json.loads(line) for line in results.read_text().splitlines() if line.strip()]


def done_cells(results: Path) -> set[str]:
    """The ``"cell"`` keys already in a results JSONL file (empty when it does not exist):
    the resumable scripts (``scripts/reproduce_ch7.py``, ``scripts/reproduce_ch8.py``) skip
    them."""
    return {r["cell"] for r in result_rows(results)}


def progress_printer(name: str, total_steps: int, t0: float) -> Callable[[Any, dict, int], None]:
    """An ``on_chunk`` callback for :func:`offline.experiment.run.train_chunked` printing
    ``name: steps/total, seconds since t0`` and the first three loss metrics (seed means)."""

    def progress(state: Any, means: dict, steps: int) -> None:
        loss = {k: float(np.mean(v)) for k, v in means.items() if "loss" in k}
        shown = " ".join(f"{k} {v:.3g}" for k, v in list(loss.items())[:3])
        print(f"  {name}: {steps}/{total_steps} steps, {time.perf_counter() - t0:.0f} s  {shown}",
              flush=True)

    return progress


class LearningCurve:
    """Learning curves of one program (``--curve``): after every chunk ``evaluate(state)``
    scores its runs exactly as the last iterate is scored, returning one ``{metric: per-seed
    values}`` dict per group of runs (a cell). With ``path`` (:func:`curve_path` of the
    program's checkpoint folder) the points are also written there, atomically, after each
    chunk and read back when the program is started again, so a program resumed from a
    checkpoint keeps the points from before the interruption. ``seconds`` is the time spent
    evaluating in this process."""

    def __init__(self, evaluate: Callable[[Any], list[dict[str, list[float]]]],
                 path: Path | None = None):
        self.evaluate = evaluate
        self.path = path
        saved = json.loads(path.read_text()) if path is not None and path.exists() else {}
        self.steps: list[int] = list(saved.get("steps", []))
        self.points: list[list[dict[str, list[float]]]] = list(saved.get("points", []))
        self.seconds = 0.0

    def record(self, state: Any, steps: int) -> None:
        """Evaluate ``state`` (after ``steps`` gradient steps) and keep the results."""
        t0 = time.perf_counter()
        self.points.append(self.evaluate(state))
        self.steps.append(int(steps))
        self.seconds += time.perf_counter() - t0
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            tmp = self.path.with_name(self.path.name + ".tmp")
            tmp.write_text(json.dumps({"steps": self.steps, "points": self.points}))
            os.replace(tmp, self.path)
        score = np.mean(self.points[-1][0]["normalized_score"])
        print(f"    [curve] step {steps}: first cell's score {score:.1f}", flush=True)

    def after(self, on_chunk: Callable[[Any, dict, int], None]
              ) -> Callable[[Any, dict, int], None]:
        """An ``on_chunk`` callback: ``on_chunk`` (e.g. :func:`progress_printer`), then
        :meth:`record`."""
        def both(state: Any, means: dict, steps: int) -> None:
            on_chunk(state, means, steps)
            self.record(state, steps)

        return both

    def groups(self) -> list[dict[str, list]]:
        """Per group: ``{"steps": [...], <metric>: [[per-seed values] per step]}``."""
        n = len(self.points[0]) if self.points else 0
        return [{"steps": self.steps, **{k: [p[g][k] for p in self.points]
                                         for k in self.points[0][g]}} for g in range(n)]


def program_checkpoint_dir(root: Path | None, program: str) -> Path | None:
    """The checkpoint folder of one compiled program (a cell or, in chapter 8, the cells of
    several rewards) under ``root``: ``root / <crc32 of program>``; ``None`` when ``root`` is."""
    if root is None:
        return None
    return Path(root) / f"{zlib.crc32(program.encode()):08x}"


def curve_path(checkpoint_dir: Path | None) -> Path | None:
    """Where :class:`LearningCurve` keeps the points of the program whose checkpoints are in
    ``checkpoint_dir`` (a file beside that folder; None when it is None)."""
    return None if checkpoint_dir is None else checkpoint_dir.with_name(
        checkpoint_dir.name + "_curve.json")


def remove_program_checkpoints(checkpoint_dir: Path | None) -> None:
    """Delete a finished program's checkpoint folder and its :func:`curve_path` file (once its
    results are written); nothing for None."""
    if checkpoint_dir is None:
        return
    shutil.rmtree(checkpoint_dir, ignore_errors=True)
    curve_path(checkpoint_dir).unlink(missing_ok=True)


def train_program(trainer: Trainer, keys: Any, chunk: int,
                  on_chunk: Callable[[Any, dict, int], None] | None = None,
                  checkpoint_dir: Path | None = None, meta: Mapping[str, Any] | None = None,
                  betas: Sequence[float] | None = None, *, name: str = "offline learner",
                  runs: Sequence[str] | None = None) -> Any:
    """Train the runs ``keys`` (at ``betas``, :func:`offline.experiment.run.init_runs`) in chunks
    (:func:`offline.experiment.run.train_chunked`) and return the final state. With
    ``checkpoint_dir`` the state is saved there after every chunk (:mod:`agents.run.checkpoint`:
    orbax, atomic, the newest three kept) with ``meta`` (e.g. the cell key), and a program
    started again with the same folder continues from its newest checkpoint instead of step 0,
    so a run stopped by a time limit loses at most one chunk. A checkpoint whose meta differs
    from ``meta`` is refused (:class:`agents.run.checkpoint.IncompatibleCheckpointError`). The
    caller removes the folder once the program's results are written. A run that diverges
    raises :class:`mjxrmp.divergence.DivergenceError` (``name``, ``runs``: the labels of
    :func:`~offline.experiment.run.train_chunked`) before its chunk is saved, so the folder keeps
    the last finite checkpoints."""
    meta = dict(meta or {})
    start = 0
    if checkpoint_dir is not None and checkpoint.latest_step(checkpoint_dir) is not None:
        template = jax.eval_shape(lambda k: init_runs(trainer, k, betas), keys)
        state, saved = checkpoint.restore(checkpoint_dir, template, expected=meta)
        start = int(saved["step"])
        print(f"resumed from step {start} of {checkpoint_dir}", file=sys.stderr, flush=True)
    else:
        state = init_runs(trainer, keys, betas)

    def after_chunk(st: Any, means: dict, done: int) -> None:
        if checkpoint_dir is not None:
            checkpoint.save(checkpoint_dir, done, st, meta)
        if on_chunk is not None:
            on_chunk(st, means, done)

    state, _ = train_chunked(trainer, keys, chunk, after_chunk, state=state, start=start,
                             name=name, runs=runs)
    return state


def collect_cached(path: Path, env_name: str, recipe: str, scale: int, seed: int, label: str,
                   **collect_kwargs: Any) -> None:
    """Collect ``recipe`` on ``env_name`` (:func:`offline.data.collect.collect_recipe`, the
    documented no-PPO fallback's warning silenced) and save it to ``path``, unless ``path`` exists;
    prints one ``[collect] label: …`` line either way."""
    if path.exists():
        print(f"[collect] {path} exists", flush=True)
        return
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        ds = collect.collect_recipe(env_name, recipe, scale, seed=seed, **collect_kwargs)
    path.parent.mkdir(parents=True, exist_ok=True)
    odata.save(ds, path)
    s = ds.metadata["summary"]
    print(f"[collect] {label}: {s['num_episodes']} episodes, {ds.size} transitions, "
          f"{s['num_terminals']} terminals, return {s['return_mean']:.1f}, "
          f"{time.perf_counter() - t0:.1f} s → {path}", flush=True)


def run_stages(args: Any, stages: Mapping[str, Callable[[Any], Any]], header: str) -> None:
    """Run the stages of a reproduction script in order: all of them when ``args.stage`` is
    ``"all"``, else the named one; ``header`` (device, preset, sizes) goes to stderr first and
    ``args.out`` is created."""
    os.makedirs(args.out, exist_ok=True)
    print(header, file=sys.stderr, flush=True)
    for name, stage in stages.items():
        if args.stage in ("all", name):
            stage(args)


__all__ = [
    "LearningCurve",
    "collect_cached",
    "curve_path",
    "done_cells",
    "program_checkpoint_dir",
    "progress_printer",
    "remove_program_checkpoints",
    "result_rows",
    "run_stages",
    "train_program",
]
