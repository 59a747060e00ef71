"""Training runs: PPO on a reaching task for several seeds (vmapped), in compiled chunks, with
progress, CSV/TensorBoard logs, learning-curve PNGs and resumable orbax checkpoints.

:func:`run_training` is what ``scripts/train.py`` calls. A run directory holds

* ``run.json`` — the :class:`agents.run.spec.RunSpec` (written once the directory and, on
  resume, the checkpoint have been checked against it);
* ``.lock`` — held (``fcntl.flock``) by the process training into the directory, with its id;
  a second process on the same directory is refused
  (:class:`agents.run.directory.RunDirectoryInUseError`); the operating system releases the
  lock when the process ends, ``kill -9`` included;
* ``metrics.csv`` — one row per (iteration, seed): every PPO metric (:mod:`agents.ppo.train`) plus
  ``env_steps`` (:mod:`agents.run.logs`);
* ``tb/`` — TensorBoard event files (seed mean and per seed);
* ``learning_curves.png`` — mean episode return, safe % and success % over iterations
  (mean ± 1 std over seeds; :mod:`agents.run.curves`);
* ``checkpoints/<iteration>/`` — orbax checkpoints (:mod:`agents.run.checkpoint`) every
  ``checkpoint_every`` iterations and at the end (and on Ctrl-C); the ``keep_checkpoints``
  newest are kept (all with ``None``).

Iterations run in compiled chunks of ``log_every`` (one ``lax.scan`` each, all seeds in one
``vmap``; :mod:`agents.run.program`); a checkpoint holds the complete state, and iteration ``i``
draws its random numbers from ``fold_in(key, i)``, so a resumed run continues exactly as the
uninterrupted one.

After every chunk the divergence guard checks the chunk's metrics
(:func:`agents.run.logs.first_nonfinite_metric`) and, in one reduction on the device, the new
parameters: on a non-finite value the run stops with :class:`DivergenceError` naming the
iteration, seed and quantity; the logs and curves keep what was logged, the non-finite state is
not checkpointed.

**Multi-process runs** (:mod:`agents.run.distributed`, docs/multihost.md): every process trains
into the same (shared) directory and computes every chunk; process 0 alone holds the lock and
writes ``run.json``, the logs, the curves and the checkpoints (of the state gathered to its host)
while the others wait at a barrier; a refusal (directory in use, no checkpoint to resume) stops
every process. A checkpoint restores in any number of processes and devices (a sharded run
restores on the host and places the arrays as a fresh state's). An interrupted multi-process run
writes no checkpoint on the way out (resume from the last periodic one).
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import sys
import time
from concurrent.futures import Future
from typing import IO, Any, NamedTuple

import jax
import numpy as np
from jax.sharding import Mesh

from agents.ppo import Trainer, TrainState
from agents.run import checkpoint
from agents.run.curves import plot_curves
from agents.run.directory import (
    RunDirectoryInUseError,
    check_dir,
    lock_run_directory,
    write_spec,
)
from agents.run.distributed import agree, barrier, is_multiprocess, is_writer, place, to_host
from agents.run.logs import (
    ProgressBar,
    TensorBoard,
    first_nonfinite_metric,
    improvement_summary,
    summary_line,
    write_csv,
)
from agents.run.program import Program, build, seed_keys
from agents.run.program_cache import in_background
from agents.run.spec import RunSpec
from mjxrmp.divergence import DivergenceError, all_finite, guard_finite_tree


@dataclasses.dataclass
class RunResult:
    """``history[metric]`` is ``(num_seeds, iterations)``; ``state`` the final (stacked)
    :class:`agents.ppo.state.TrainState`; timings in seconds."""

    history: dict[str, np.ndarray]
    state: TrainState
    trainer: Trainer
    compile_seconds: float
    train_seconds: float
    env_steps: int


def _history_to_json(history: dict[str, np.ndarray]) -> dict[str, list]:
    return {k: [[None if not math.isfinite(x) else float(x) for x in row] for row in v]
            for k, v in history.items()}


def _history_from_json(d: dict[str, list]) -> dict[str, np.ndarray]:
    return {k: np.array([[np.nan if x is None else x for x in row] for row in v], np.float64)
            for k, v in d.items()}


def _initial_state(program: Program, spec: RunSpec, ckpt_dir: str, resume: bool,
                   sharded: bool) -> tuple[TrainState, dict[str, np.ndarray], int]:
    """``(state, history, iterations done)``: fresh, or the newest checkpoint (which must
    match ``spec.identity()``; ``sharded``: placed on the devices as a fresh state is)."""
    keys = seed_keys(spec.seeds)
    if not resume:
        return program.initial_state(keys), {}, 0
    template = program.state_shapes(keys)
    state, meta = checkpoint.restore(ckpt_dir, template, expected=spec.identity())
    if sharded:  # written by any number of devices and processes, restored on the host
        fresh = program.initial_state(keys)
        state = place(state, jax.tree.map(lambda x: x.sharding, fresh))
    return state, _history_from_json(meta["history"]), int(meta["iteration"])


class _RunLog:
    """The run's metric history and its outputs: ``metrics.csv``, TensorBoard, progress (only
    the history on a process that does not write: :func:`agents.run.distributed.is_writer`)."""

    def __init__(self, spec: RunSpec, out_dir: str, history: dict[str, np.ndarray],
                 bar: ProgressBar | None):
        self.spec, self.history, self.bar = spec, history, bar
        self.csv_path = os.path.join(out_dir, "metrics.csv")
        self.tb = TensorBoard(os.path.join(out_dir, "tb")) if is_writer() else None
        if history and self.tb is not None:
            write_csv(self.csv_path, history, spec.seeds, spec.ppo.batch_size)

    def append(self, metrics: dict[str, np.ndarray], start: int, done: int,
               seconds: float) -> None:
        """Add the chunk of iterations ``start..done`` and write every output."""
        for k, v in metrics.items():
            v = v.astype(np.float64)
            self.history[k] = v if k not in self.history else np.concatenate(
                [self.history[k], v], 1)
        batch = self.spec.ppo.batch_size
        if self.tb is None:
            return
        write_csv(self.csv_path, self.history, self.spec.seeds, batch)
        self.tb.write(self.history, start, self.spec.seeds, batch)
        if self.bar is not None:
            rate = (done - start) * batch * len(self.spec.seeds) / seconds
            self.bar.update(done, summary_line(self.history, rate, window=done - start))

    def close_bar(self) -> None:
        """End the progress bar's line."""
        if self.bar is not None:
            self.bar.close()

    def close(self) -> None:
        """Close the TensorBoard writer."""
        if self.tb is not None:
            self.tb.close()


class _Saver:
    """Checkpoints of the run (each iteration count written once; by process 0 alone, of the
    state gathered to its host, in a multi-process run)."""

    def __init__(self, spec: RunSpec, ckpt_dir: str, done: int):
        self.spec, self.ckpt_dir, self.saved = spec, ckpt_dir, done

    def save(self, at: int, state: TrainState, history: dict[str, np.ndarray]) -> None:
        """Checkpoint ``state`` as iteration ``at`` with the history in its meta."""
        if at == self.saved and checkpoint.latest_step(self.ckpt_dir) == at:
            return
        meta = dict(self.spec.identity(), iteration=at, history=_history_to_json(history),
                    run=self.spec.to_json())
        if is_multiprocess():
            state = to_host(state)  # a collective: every process gathers
        if is_writer():
            checkpoint.save(self.ckpt_dir, at, state, meta,
                            max_to_keep=self.spec.keep_checkpoints)
        barrier(f"checkpoint {self.ckpt_dir} {at}")
        self.saved = at


def _divergence(runs: list[str], metrics: dict[str, np.ndarray], params: Any,
                start: int, finite: Any = None) -> DivergenceError | None:
    """What went non-finite in the chunk of iterations after ``start`` (its metrics first, then
    the parameters it ends with, reduced to one flag on the device: ``finite`` when already
    dispatched), or None if nothing did; ``runs`` names the rows of the vmapped axis."""
    fault = first_nonfinite_metric(metrics)
    if fault is not None:
        it, s, name, value = fault
        return DivergenceError("training", start + it + 1, name, value, unit="iteration",
                               run=runs[s])
    end = start + next(iter(metrics.values())).shape[1]
    try:
        guard_finite_tree(params, "training", end, unit="iteration", runs=runs, batched=True,
                          finite=finite)
    except DivergenceError as e:
        return e
    return None


def _divergence_error(error: DivergenceError, ckpt_dir: str) -> DivergenceError:
    """``error`` with the newest intact checkpoint named (the last finite one: a diverged chunk
    is never saved)."""
    last = checkpoint.latest_intact_step(ckpt_dir)
    return error.with_note(
        f"the last finite checkpoint is iteration {last} in {ckpt_dir}" if last is not None
        else f"no checkpoint was written before it (none in {ckpt_dir})")


class _Chunk(NamedTuple):
    """A dispatched chunk of iterations ``start..start + n``: its (pending) state, metrics and
    parameter-finiteness flag (None in a multi-process run, which gathers the parameters)."""

    start: int
    n: int
    state: TrainState
    metrics: dict[str, Any]
    finite: Any

    @property
    def end(self) -> int:
        """The iteration count after the chunk."""
        return self.start + self.n


def _chunk_length(spec: RunSpec, start: int) -> int:
    """How many iterations the chunk after iteration ``start`` runs (0 when the run is done)."""
    return max(0, min(spec.log_every, spec.ppo.total_iterations - start))


def _first_chunk(spec: RunSpec, ckpt_dir: str, resume: bool) -> int:
    """The length of the run's first chunk, to compile ahead: for a resume, the chunk after the
    newest checkpoint when it verifies and belongs to ``spec`` (else 0: nothing is compiled
    ahead and the restore raises or warns as usual)."""
    if not resume:
        return _chunk_length(spec, 0)
    step = checkpoint.latest_step(ckpt_dir)
    if step is None:
        return 0
    try:
        meta = checkpoint.load_meta(ckpt_dir, step)
        checkpoint.check_compatible(meta, spec.identity())
    except (checkpoint.CorruptCheckpointError, checkpoint.IncompatibleCheckpointError):
        return 0
    return _chunk_length(spec, int(meta["iteration"]))


def _launch(program: Program, spec: RunSpec, state: TrainState, start: int) -> _Chunk | None:
    """Dispatch the chunk that follows iteration ``start`` (None when the run is complete);
    on the CPU JAX returns before the device has run it (docs/design.md §5.7)."""
    n = _chunk_length(spec, start)
    if n == 0:
        return None
    new_state, metrics = program.executable(state, n)(state)
    finite = None if is_multiprocess() else all_finite(new_state.params)
    return _Chunk(start, n, new_state, metrics, finite)


def _launch_ahead(program: Program, spec: RunSpec, state: TrainState, start: int) -> Future:
    """:func:`_launch` from a thread of its own, so that the caller can log and checkpoint the
    previous chunk meanwhile: on a GPU the call returns only once the device has run nearly the
    whole chunk (Franka thesis chunk on an H200: 0.13 s before the end of 11.7 s; presumably
    XLA's host reading loop conditions back), which on the caller's thread would serialise the
    host's work with the device's (docs/design.md §5.7). A compile the chunk needs happens
    here, on the caller's thread, so that its time is counted in the chunk it delays."""
    n = _chunk_length(spec, start)
    if n:
        program.executable(state, n)
    return in_background(lambda: _launch(program, spec, state, start), f"chunk from {start}")


def _train_chunks(program: Program, spec: RunSpec, state: TrainState, done: int,
                  log: _RunLog, saver: _Saver, runs: list[str] | None = None
                  ) -> tuple[TrainState, int, float]:
    """Run chunks of ``log_every`` iterations up to ``total_iterations``, logging each and
    checkpointing every ``checkpoint_every`` and at the end; on Ctrl-C checkpoint what is done
    and re-raise; on a non-finite metric or parameter log the chunk and raise
    :class:`DivergenceError` (without checkpointing it). In one process the next chunk is
    dispatched (from a thread: :func:`_launch_ahead`) before this one's results are read, so
    the device runs it while the host logs and checkpoints (a diverged chunk's successor is
    discarded). Returns ``(state, iterations done, training seconds)``: the wall time from the
    first dispatch to the last chunk read, less compiles. ``runs`` names the rows of the
    vmapped axis (default: the seeds)."""
    train_s, diverged, serial = 0.0, None, is_multiprocess()
    runs = runs or [f"seed {s}" for s in spec.seeds]
    t0, compiled = time.perf_counter(), program.compile_seconds
    try:
        chunk = _launch(program, spec, state, done)
        while chunk is not None:
            ahead = None if serial else _launch_ahead(program, spec, chunk.state, chunk.end)
            metrics = to_host(chunk.metrics)  # blocks until the chunk is done
            t1 = time.perf_counter()
            dt = t1 - t0 - (program.compile_seconds - compiled)
            train_s, t0, compiled = train_s + dt, t1, program.compile_seconds
            params = to_host(chunk.state.params) if serial else chunk.state.params
            diverged = _divergence(runs, metrics, params, chunk.start, chunk.finite)
            if diverged is None:
                state, done = chunk.state, chunk.end
            log.append(metrics, chunk.start, chunk.end, dt)
            if diverged is not None:
                log.close_bar()
                raise _divergence_error(diverged, saver.ckpt_dir)
            if done % spec.checkpoint_every == 0 or done == spec.ppo.total_iterations:
                saver.save(done, state, log.history)
            chunk = _launch(program, spec, state, done) if serial else ahead.result()
    except KeyboardInterrupt:
        log.close_bar()
        if done > 0 and diverged is None and not serial:
            saver.save(done, state, log.history)
            print(f"\ninterrupted: checkpoint of iteration {done} written to "
                  f"{saver.ckpt_dir}; continue with --resume", file=sys.stderr)
        raise
    finally:
        log.close()
    log.close_bar()
    return state, done, train_s


def _plot(program: Program, spec: RunSpec, history: dict[str, np.ndarray], out_dir: str) -> None:
    """``learning_curves.png``: episode metrics over ≥ 3 rollouts' worth of episodes, the step
    reward smoothed over one episode length."""
    cfg = spec.ppo
    horizon = cfg.episode_length or int(getattr(program.trainer.env.unwrapped, "horizon",
                                                cfg.rollout_length))
    plot_curves(history, os.path.join(out_dir, "learning_curves.png"),
                f"{spec.policy} on {spec.env} ({len(spec.seeds)} seed(s))",
                min_episodes=max(100, 3 * cfg.num_envs),
                reward_window=-(-horizon // cfg.rollout_length))


def run_training(spec: RunSpec, out_dir: str, resume: bool = False, progress: bool = True,
                 mesh: Mesh | None = None, stream: IO[str] | None = None) -> RunResult:
    """Train ``spec`` into ``out_dir`` (see the module docstring) under the directory's lock;
    ``resume`` continues from the newest checkpoint there (refusing one of another
    environment, policy or configuration before ``run.json`` is written). In a multi-process
    run every process calls this with the same arguments and a global ``mesh``; the result's
    ``state`` then holds global arrays (:func:`agents.run.distributed.to_host` gathers them)."""
    if not resume:
        os.makedirs(out_dir, exist_ok=True)
    elif not os.path.isdir(out_dir):
        raise FileNotFoundError(f"resume=True but {out_dir} does not exist (no checkpoint to "
                                "resume)")
    # every process of a multi-host run trains into the same directory: process 0 locks it
    with contextlib.ExitStack() as held:
        refused = None
        try:
            if is_writer():
                held.enter_context(lock_run_directory(out_dir))
            ckpt_dir = check_dir(out_dir, resume)
        except (RunDirectoryInUseError, FileExistsError, FileNotFoundError) as e:
            refused = e
        agree(refused, f"training into {out_dir}")
        sharded = mesh is not None or is_multiprocess()
        # A resume reads its newest checkpoint's meta (importing orbax) while the environment
        # builds, which on a GPU mostly waits for the device (docs/design.md §5.6).
        first_job = None if sharded else in_background(
            lambda: _first_chunk(spec, ckpt_dir, resume), "first-chunk")
        program = build(spec, mesh)
        compile_before = program.compile_seconds
        first = 0 if first_job is None else first_job.result()
        if first:
            program.compile_ahead(seed_keys(spec.seeds), first, hold_init=not resume)
        state, history, done = _initial_state(program, spec, ckpt_dir, resume, sharded)
        writer, total = is_writer(), spec.ppo.total_iterations
        if writer:
            write_spec(spec, out_dir)
        if done >= total and writer:
            print(f"run already has {done} >= {total} iterations", file=stream or sys.stderr)
        log = _RunLog(spec, out_dir, history,
                      ProgressBar(total, stream) if progress and writer else None)
        try:
            state, done, train_s = _train_chunks(program, spec, state, done, log,
                                                 _Saver(spec, ckpt_dir, done))
        except DivergenceError:
            if writer:
                _plot(program, spec, history, out_dir)
            raise
        if history and writer:
            _plot(program, spec, history, out_dir)
    steps = done * spec.ppo.batch_size * len(spec.seeds) if history else 0
    return RunResult(history, state, program.trainer,
                     program.compile_seconds - compile_before, train_s, steps)


def result_summary(result: RunResult) -> str:
    """What ``scripts/train.py`` prints at the end: the improvement over the run
    (:func:`agents.run.logs.improvement_summary`), compile and training time, steps/s."""
    rate = result.env_steps / max(result.train_seconds, 1e-9)
    return (f"{improvement_summary(result.history)}\ncompile {result.compile_seconds:.1f} s, "
            f"training {result.train_seconds:.1f} s, {rate:.3g} env steps/s")


__all__ = ["RunResult", "result_summary", "run_training"]
