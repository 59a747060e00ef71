"""Run-loop pieces of the chapter-8 sweep (thesis §8.4.1): one compiled program trains a
learner on **several data rewards × several seeds** of one dataset.

The wrong-reward variants of a dataset (:func:`offline.survival.rewards.variant`) differ only in their
``rewards`` array, so a learner's trainer (:func:`offline.experiment.run.build`, which closes over
the dataset) can be built *inside* a traced function of the rewards:
:func:`reward_batched` returns a :class:`~offline.learners.base.Trainer` whose ``init`` takes
``(rewards, key)`` and whose state carries the rewards row, so
``offline.experiment.run.train_chunked(trainer, reward_seed_keys(rows, seeds), chunk)`` vmaps over
``len(rows) × len(seeds)`` runs. Each run is the run of ``build(learner,
dataset.replace(rewards=row), None, budget)`` from ``PRNGKey(seed)`` (the same computation,
batched; a test checks this in floating point).
"""

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
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from offline.data import dataset as odata
from offline.experiment import run as experiment
from offline.learners.base import Trainer, actor_params
from offline.learners.residual_actor import ACTORS
from offline.survival import rewards as survival

#: Learners whose data reward matters (trained once per reward variant); BC reads no reward.
REWARD_LEARNERS = ("ATAC", "PSPI", "IQL", "CQL")
#: On a plain dataset, :func:`offline.experiment.run.build`'s "Oracle" is ATAC on the dataset's
#: own rewards (:func:`offline.learners.plfo_baselines.make_train_oracle`) — here those are the
#: (possibly wrong) data rewards, so that is the chapter-8 "ATAC".
_BUILD_NAME = {"ATAC": "Oracle"}


def build_plain(learner: str, dataset: odata.Dataset, budget: experiment.Budget) -> Trainer:
    """The trainer of ``learner`` (:data:`REWARD_LEARNERS` or ``"BC"``) on a plain dataset
    with its own rewards (:func:`offline.experiment.run.build` without a scenario)."""
    if learner not in (*REWARD_LEARNERS, "BC"):
        raise ValueError(f"learner must be one of {[*REWARD_LEARNERS, 'BC']}, got {learner!r}")
    return experiment.build(_BUILD_NAME.get(learner, learner), dataset, None, budget)


class RewardBatchedState(NamedTuple):
    """The state of one run of :func:`reward_batched`: its data rewards and the learner's
    own state."""

    rewards: jax.Array
    inner: Any


def reward_key(seed: int, dataset_name: str) -> jax.Array:
    """The key of a dataset's ``"random"`` rewards: ``fold_in(PRNGKey(seed), crc32(name))``
    (the convention of :func:`offline.survival.rewards.variant_grid`)."""
    return jax.random.fold_in(jax.random.PRNGKey(int(seed)),
                              zlib.crc32(dataset_name.encode()) & 0x7FFFFFFF)


def reward_rows(dataset: odata.Dataset, rewards: Sequence[str], terminals: str,
                key: jax.Array) -> tuple[odata.Dataset, np.ndarray]:
    """``(base, rows)``: the dataset with terminal handling ``terminals`` and its true rewards
    (:func:`offline.survival.rewards.variant` ``"original"``), and the float32 data rewards of each
    variant in ``rewards`` (thesis §8.4.1; ``"random"`` drawn with ``key``), shape
    ``(len(rewards), N)``."""
    if not rewards:
        raise ValueError("rewards must name at least one reward variant")
    base = survival.variant(dataset, "original", terminals)
    rows = [np.asarray(survival.variant(dataset, r, terminals, key).rewards, np.float32)
            for r in rewards]
    return base, np.stack(rows)


def reward_batched(learner: str, dataset: odata.Dataset, budget: experiment.Budget) -> Trainer:
    """``learner`` (one of :data:`REWARD_LEARNERS`) on ``dataset`` with the data rewards given
    per run (module docstring): ``init((rewards (N,), key), beta=None)``,
    ``run(state, n)`` and ``act`` as for :func:`offline.experiment.run.build`."""
    if learner not in REWARD_LEARNERS:
        raise ValueError(f"learner must be one of {list(REWARD_LEARNERS)}, got {learner!r}")
    concrete = build_plain(learner, dataset, budget)

    def inner(rewards: jax.Array) -> Trainer:
        # Built inside the traced init/run: what depends only on the (concrete) dataset — its
        # preparation, the NN-RESIDUAL actor's precomputed RMP² bases — is evaluated when
        # traced, not staged into the program and recomputed on every call.
        with jax.ensure_compile_time_eval():
            return build_plain(learner, dataset.replace(rewards=rewards), budget)

    def init(arg: tuple[jax.Array, jax.Array], beta: Any = None) -> RewardBatchedState:
        rewards, key = arg
        return RewardBatchedState(rewards, inner(rewards).init(key, beta))

    def run(state: RewardBatchedState, n: int) -> tuple[RewardBatchedState, dict]:
        new, metrics = inner(state.rewards).run(state.inner, n)
        return RewardBatchedState(state.rewards, new), metrics

    return Trainer(init, run, concrete.act, concrete.num_steps)


def reward_seed_keys(rows: np.ndarray, seeds: Sequence[int]) -> tuple[jax.Array, jax.Array]:
    """The vmapped ``init`` argument of :func:`reward_batched`: every (reward row, seed) pair,
    reward-major — ``(rows repeated, PRNGKey(seed) tiled)``, leading size
    ``len(rows) · len(seeds)``."""
    rows = jnp.asarray(rows, jnp.float32)
    keys = experiment.seed_keys(seeds)
    v, s = rows.shape[0], keys.shape[0]
    return jnp.repeat(rows, s, axis=0), jnp.tile(keys, (v, 1))


def run_actor_params(state: Any) -> Any:
    """The actor parameters of a (possibly reward-batched) learner state."""
    return actor_params(state.inner if isinstance(state, RewardBatchedState) else state)


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


def add_learner_options(parser: Any) -> None:
    """The learner settings shared by the offline scripts: ``--normalize-observations``,
    ``--actor`` (:data:`offline.learners.residual_actor.ACTORS`), ``--warmstart`` and ``--actor-rate``
    (:data:`offline.experiment.run.ACTOR_RATES`) — the :class:`offline.experiment.run.Budget` fields of
    :func:`setting_fields`. Settings other than the original ones give result cells their own
    key (:func:`setting_key`)."""
    parser.add_argument("--normalize-observations", action="store_true",
                        help="standardise observations with the dynamics data's statistics "
                             "(offline.learners.base.ObservationNormalizer; cells get their own key)")
    parser.add_argument("--actor", choices=ACTORS, default="mlp",
                        help="actor class of every learner: a tanh-Gaussian MLP, or the MLP "
                             "added to the chapter-6 NN-RESIDUAL RMP² base "
                             "(offline.learners.residual_actor; cells get their own key)")
    parser.add_argument("--warmstart", type=float, default=experiment.DEFAULT_WARMSTART,
                        metavar="FRACTION",
                        help="fraction of the steps spent in ATAC's BC warm start (published: "
                             "100 k of 1 M; cells get their own key)")
    parser.add_argument("--actor-rate", choices=experiment.ACTOR_RATES, default="published",
                        help="ATAC-type actor rate of a shortened run: the published 5e-7 "
                             "(default), or 5e-7 x 1e6/steps, the rule of the first tables "
                             "(offline.experiment.run.atac_config; cells get their own key)")


def add_substeps_option(parser: Any) -> None:
    """``--substeps N`` of the reproduction scripts: the control rate (see
    :func:`control_rate_kwargs`)."""
    parser.add_argument("--substeps", type=int, default=None, metavar="N",
                        help="physics substeps per control step (default: the environment's 3, "
                             "i.e. 80 Hz; 24 is 10 Hz). The horizon keeps the episode length in "
                             "seconds; step counts such as --goal-deadline are control steps at "
                             "this rate. Data files and cell keys get their own names")


def control_rate_kwargs(env_name: str, substeps: int | None) -> dict[str, int] | None:
    """The constructor arguments of environment ``env_name`` for ``substeps`` physics substeps
    per control step (``None``: its defaults), with the horizon that keeps the episode's length
    in seconds. Raises ``ValueError`` when the episode is not a whole number of control steps."""
    if substeps is None:
        return None
    from offline.data.collect import make_env

    env = make_env(env_name)
    total = env.horizon * env.substeps
    if isinstance(substeps, bool) or not isinstance(substeps, int) or substeps < 1 \
            or total % substeps:
        raise ValueError(f"--substeps must be a positive divisor of the episode's {total} "
                         f"physics steps on {env_name}, got {substeps!r}")
    return {"substeps": substeps, "horizon": total // substeps}


def substeps_tag(substeps: int | None) -> list:
    """Cell-key and file-name entries of a non-default control rate (``[]`` for the
    environment's own, so earlier results keep their keys)."""
    return [] if substeps is None else ["substeps", int(substeps)]


def add_checkpoint_option(parser: Any) -> None:
    """``--checkpoints DIR`` of the sweep scripts (:func:`train_program`)."""
    parser.add_argument("--checkpoints", type=Path, default=None, metavar="DIR",
                        help="save every program's state under DIR after each --chunk steps "
                             "and continue an interrupted program from there (default: off)")


#: The learner settings our first results were made with: result rows and checkpoints from
#: before a setting existed have these values, and cell keys name only the settings that differ.
ORIGINAL_SETTINGS = {"normalize_observations": False, "actor": "mlp",
                     "warmstart": experiment.DEFAULT_WARMSTART, "actor_rate": "scaled"}


def setting_fields(args: Any) -> dict[str, Any]:
    """The learner settings of ``args`` as result-row fields (also
    :class:`offline.experiment.run.Budget` keyword arguments), in :data:`ORIGINAL_SETTINGS` order."""
    return {"normalize_observations": bool(args.normalize_observations), "actor": args.actor,
            "warmstart": float(args.warmstart), "actor_rate": args.actor_rate}


def setting_changes(args: Any) -> dict[str, Any]:
    """The learner settings of ``args`` that differ from :data:`ORIGINAL_SETTINGS`."""
    return {k: v for k, v in setting_fields(args).items() if v != ORIGINAL_SETTINGS[k]}


def setting_key(args: Any) -> list:
    """Cell-key entries of :func:`setting_changes` (a flag for ``normalize_observations``, name
    and value for the others), so results made before a setting existed keep their keys
    whatever the current default."""
    key: list = []
    for k, v in setting_changes(args).items():
        key += [k] if k == "normalize_observations" else [k, v]
    return key


def apply_preset(parser: Any, args: Any, preset: Mapping[str, Any],
                 positive: Sequence[str]) -> Any:
    """Fill the arguments left at ``None`` from ``preset`` and refuse (``parser.error``) any of
    ``positive`` that is below 1; returns ``args``."""
    for k, v in preset.items():
        if getattr(args, k) is None:
            setattr(args, k, v)
    for name in positive:
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be a positive integer")
    return args


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
                  betas: Sequence[float] | None = None) -> Any:
    """Train the runs ``keys`` (at ``betas``, :func:`offline.experiment.run.init_runs`) in chunks
    (:func:`offline.experiment.run.train_chunked`) and return the final state. With
    ``checkpoint_dir`` the state is saved there after every chunk (:mod:`agents.run.checkpoint`:
    orbax, atomic, the newest three kept) with ``meta`` (e.g. the cell key), and a program
    started again with the same folder continues from its newest checkpoint instead of step 0,
    so a run stopped by a time limit loses at most one chunk. A checkpoint whose meta differs
    from ``meta`` is refused (:class:`agents.checkpoint.IncompatibleCheckpointError`). The
    caller removes the folder once the program's results are written."""
    from agents.run import checkpoint

    meta = dict(meta or {})
    start = 0
    if checkpoint_dir is not None and checkpoint.latest_step(checkpoint_dir) is not None:
        template = jax.eval_shape(lambda k: experiment.init_runs(trainer, k, betas), keys)
        state, saved = checkpoint.restore(checkpoint_dir, template, expected=meta)
        start = int(saved["step"])
        print(f"resumed from step {start} of {checkpoint_dir}", file=sys.stderr, flush=True)
    else:
        state = experiment.init_runs(trainer, keys, betas)

    def after_chunk(st: Any, means: dict, done: int) -> None:
        if checkpoint_dir is not None:
            checkpoint.save(checkpoint_dir, done, st, meta)
        if on_chunk is not None:
            on_chunk(st, means, done)

    state, _ = experiment.train_chunked(trainer, keys, chunk, after_chunk, state=state,
                                        start=start)
    return state


def collect_cached(path: Path, env_name: str, recipe: str, scale: int, seed: int, label: str,
                   **collect_kwargs: Any) -> None:
    """Collect ``recipe`` on ``env_name`` (:func:`offline.data.collect.collect_recipe`, the documented
    no-PPO fallback's warning silenced) and save it to ``path``, unless ``path`` exists; prints
    one ``[collect] label: …`` line either way."""
    from offline.data import collect

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
    "ORIGINAL_SETTINGS",
    "REWARD_LEARNERS",
    "LearningCurve",
    "RewardBatchedState",
    "add_checkpoint_option",
    "add_learner_options",
    "add_substeps_option",
    "apply_preset",
    "build_plain",
    "control_rate_kwargs",
    "done_cells",
    "program_checkpoint_dir",
    "progress_printer",
    "result_rows",
    "reward_batched",
    "reward_key",
    "reward_rows",
    "reward_seed_keys",
    "run_actor_params",
    "run_stages",
    "setting_changes",
    "setting_fields",
    "setting_key",
    "substeps_tag",
    "train_program",
]
