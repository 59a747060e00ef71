"""Training runs: PPO on a reaching task for several seeds (vmapped), in compiled chunks, with
progress, CSV/TensorBoard logs, learning-curve PNGs and resumable orbax checkpoints.

:func:`run_training` is what ``scripts/train.py`` calls. A run directory holds

* ``run.json`` — the :class:`RunSpec`;
* ``metrics.csv`` — one row per (iteration, seed): every PPO metric (:mod:`agents.ppo.train`) plus
  ``env_steps``;
* ``tb/`` — TensorBoard event files (seed mean and per seed);
* ``learning_curves.png`` — mean episode return, safe % and success % over iterations
  (mean ± 1 std over seeds);
* ``checkpoints/<iteration>/`` — orbax checkpoints (:mod:`agents.run.checkpoint`) every
  ``checkpoint_every`` iterations and at the end (and on Ctrl-C); the ``keep_checkpoints``
  newest are kept (all with ``None``).

Iterations run in compiled chunks of ``log_every`` (one ``lax.scan`` each, all seeds in one
``vmap``); a checkpoint holds the complete state, and iteration ``i`` draws its random numbers
from ``fold_in(key, i)``, so a resumed run continues exactly as the uninterrupted one.
"""

from __future__ import annotations

import csv
import dataclasses
import functools
import json
import math
import os
import sys
import time
import warnings
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh

from agents.ppo.policies import KINDS, make_env_and_policy
from agents.ppo.train import PPOConfig, Trainer, TrainState, make_trainer
from agents.run import checkpoint

#: Curves drawn by :func:`plot_curves`: (metric, label, scale).
CURVES = (("mean_episode_return", "mean episode return", 1.0),
          ("mean_reward", "mean step reward", 1.0),
          ("safe_fraction", "safe episodes (%)", 100.0),
          ("success_fraction", "successful episodes (%)", 100.0))


def cpu_preset(**overrides) -> PPOConfig:
    """The main job's CPU-sized PPO settings: 64 environments × 128 steps, 4 minibatches of
    2,048, 4 epochs, 400 iterations (3.3 M environment steps; about 5 minutes on 2 CPU cores
    for ``rmp_residual`` on ``three_link/env3``)."""
    base = dict(num_envs=64, rollout_length=128, num_minibatches=4, update_epochs=4,
                learning_rate=3e-4, gamma=0.99, gae_lambda=0.95, max_grad_norm=0.5,
                total_iterations=400)
    base.update(overrides)
    return PPOConfig(**base)


PRESETS: dict[str, Callable[..., PPOConfig]] = {"cpu": cpu_preset, "thesis": PPOConfig.thesis}


def preset(name: str, **overrides) -> PPOConfig:
    """The PPO settings called ``name`` (:data:`PRESETS`) with ``overrides``. Network sizes per
    robot and policy kind come from :func:`agents.ppo.policies.make_policy`, not from the preset."""
    if name not in PRESETS:
        raise ValueError(f"unknown preset={name!r}; valid presets are {sorted(PRESETS)}")
    return PRESETS[name](**overrides)


@dataclasses.dataclass(frozen=True)
class RunSpec:
    """What to train: environment, policy kind, seeds and PPO settings, and how to log."""

    env: str = "three_link/env3"
    policy: str = "rmp_residual"
    seeds: tuple[int, ...] = (0,)
    ppo: PPOConfig = dataclasses.field(default_factory=cpu_preset)
    log_every: int = 5
    checkpoint_every: int = 25
    #: How many of the newest checkpoints to keep; ``None`` keeps every one (what an offline
    #: ``medium-replay`` dataset of the run's snapshots needs, :mod:`offline.data.collect`).
    keep_checkpoints: int | None = 3

    def __post_init__(self):
        if self.policy not in KINDS:
            raise ValueError(f"unknown policy={self.policy!r}; valid kinds are {KINDS}")
        if not (isinstance(self.seeds, tuple) and self.seeds
                and all(isinstance(s, int) and s >= 0 for s in self.seeds)):
            raise ValueError(f"seeds must be a non-empty tuple of integers >= 0, got "
                             f"{self.seeds!r}")
        if len(set(self.seeds)) != len(self.seeds):
            raise ValueError(f"seeds must be distinct, got {self.seeds!r}")
        for name in ("log_every", "checkpoint_every"):
            v = getattr(self, name)
            if not isinstance(v, int) or v < 1:
                raise ValueError(f"{name} must be a positive integer, got {v!r}")
        if self.keep_checkpoints is not None and not (
                isinstance(self.keep_checkpoints, int) and self.keep_checkpoints >= 1):
            raise ValueError(f"keep_checkpoints must be a positive integer or None (keep all), "
                             f"got {self.keep_checkpoints!r}")
        if self.checkpoint_every % self.log_every:
            raise ValueError(f"checkpoint_every={self.checkpoint_every} must be a multiple of "
                             f"log_every={self.log_every}")

    def identity(self) -> dict[str, Any]:
        """What a checkpoint must match to be resumed by this run (everything but the length
        of the run and the logging cadence)."""
        ppo = dataclasses.asdict(self.ppo)
        ppo.pop("total_iterations")
        return {"env": self.env, "policy": self.policy, "seeds": list(self.seeds),
                "ppo": json.loads(json.dumps(ppo))}

    def to_json(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        return json.loads(json.dumps(d))


@dataclasses.dataclass
class RunResult:
    """``history[metric]`` is ``(num_seeds, iterations)``; ``state`` the final (stacked)
    :class:`TrainState`; timings in seconds."""

    history: dict[str, np.ndarray]
    state: TrainState
    trainer: Trainer
    compile_seconds: float
    train_seconds: float
    env_steps: int


# ---------------------------------------------------------------------------------------------
# logging


class ProgressBar:
    """A one-line progress bar with live metrics on a terminal; a line per update otherwise."""

    def __init__(self, total: int, stream=None, width: int = 24):
        self.total, self.width = total, width
        self.stream = sys.stderr if stream is None else stream
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.start = time.perf_counter()

    def update(self, done: int, text: str) -> None:
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
        if self.tty:
            self.stream.write("\n")
            self.stream.flush()


def _fmt(x: float, scale: float = 1.0, spec: str = ".3g") -> str:
    return "  n/a" if not np.isfinite(x) else format(x * scale, spec)


def nanmean(x: np.ndarray, axis=None) -> np.ndarray | float:
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
        if eps is not None and k in ("mean_episode_return", "safe_fraction",
                                     "success_fraction") and eps.sum() > 0:
            last[k] = float(np.nansum(np.nan_to_num(v) * eps) / eps.sum())
        else:
            last[k] = float(nanmean(v))
    return (f"reward {_fmt(last['mean_reward'])} | "
            f"return {_fmt(last['mean_episode_return'])} | "
            f"safe {_fmt(last['safe_fraction'], 100, '.1f')}% | "
            f"success {_fmt(last['success_fraction'], 100, '.1f')}% | "
            f"{steps_per_second:.3g} steps/s")


def improvement_summary(history: dict[str, np.ndarray]) -> str:
    """First vs last tenth of the run (at least one, at most 10 iterations each): seed-mean
    step reward and episode return, and whether the final policy beats the initial one."""
    n = history["mean_reward"].shape[1]
    k = max(1, min(10, n // 10))
    parts = []
    for key, label in (("mean_reward", "mean step reward"),
                       ("mean_episode_return", "mean episode return")):
        first, last = float(nanmean(history[key][:, :k])), float(nanmean(history[key][:, -k:]))
        verdict = "improved" if last > first else "not improved"
        parts.append(f"{label} {first:.4g} (first {k} it.) → {last:.4g} (last {k} it.): "
                     f"{verdict}")
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
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

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


class _TensorBoard:
    """TensorBoard scalars through tensorboardX (skipped, with a note, if it is missing)."""

    def __init__(self, logdir: str):
        try:
            from tensorboardX import SummaryWriter
        except ImportError:  # pragma: no cover - tensorboardX comes with brax
            print("tensorboardX not installed: no TensorBoard event files", file=sys.stderr)
            self.writer = None
            return
        self.writer = SummaryWriter(logdir)

    def write(self, history: dict[str, np.ndarray], start: int, seeds, batch_size: int):
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

    def close(self):
        if self.writer is not None:
            self.writer.close()


# ---------------------------------------------------------------------------------------------
# the run


def make_mesh(num_devices: int | None) -> Mesh | None:
    """A 1-D ``("batch",)`` mesh over the first ``num_devices`` devices (None for 1 or None)."""
    if num_devices is None or num_devices == 1:
        return None
    devices = jax.devices()
    if not (isinstance(num_devices, int) and 1 <= num_devices <= len(devices)):
        raise ValueError(f"num_devices must be between 1 and {len(devices)} (the devices JAX "
                         f"sees), got {num_devices!r}")
    return Mesh(np.array(devices[:num_devices]), ("batch",))


@dataclasses.dataclass
class Program:
    """A trainer with ``init(keys)`` and ``run(state, n)`` vmapped over seeds and jitted, plus
    the ahead-of-time compiled chunk executables (one per chunk length)."""

    trainer: Trainer
    init: Callable
    run: Callable
    executables: dict[int, Any] = dataclasses.field(default_factory=dict)
    compile_seconds: float = 0.0

    def executable(self, state: TrainState, n: int):
        """The compiled ``run(·, n)`` (compiled on first use; the time is added to
        ``compile_seconds``)."""
        if n not in self.executables:
            t0 = time.perf_counter()
            self.executables[n] = self.run.lower(state, n).compile()
            self.compile_seconds += time.perf_counter() - t0
        return self.executables[n]


@functools.lru_cache(maxsize=8)
def _program(env: str, policy: str, ppo: PPOConfig, mesh: Mesh | None) -> Program:
    env_obj, module = make_env_and_policy(env, policy)
    trainer = make_trainer(env_obj, module, ppo, mesh)
    init = jax.jit(jax.vmap(trainer.init))
    run = jax.jit(jax.vmap(trainer.run, in_axes=(0, None)), static_argnums=1)
    return Program(trainer, init, run)


def build(spec: RunSpec, mesh: Mesh | None = None) -> Program:
    """The :class:`Program` of ``spec`` (cached: runs that differ only in length, seeds or
    logging share compiled code)."""
    return _program(spec.env, spec.policy, dataclasses.replace(spec.ppo, total_iterations=1),
                    mesh)


def profile_iteration(program: Program, state: TrainState, repeats: int = 3) -> dict[str, float]:
    """Median wall time (s) of one iteration's pieces for all seeds, compiled separately:
    ``rollout`` (environment + policy sampling, ``rollout_length`` steps), ``policy_forward``
    (the policy alone — RMP² included — on the rollout's ``rollout_length × num_envs``
    observations) and ``update`` (GAE + every epoch and minibatch, RMP² backprop included).
    Does not change ``state``."""
    trainer = program.trainer
    n = trainer.config.rollout_length
    key = jax.random.PRNGKey(0)
    keys = jnp.broadcast_to(key, (state.iteration.shape[0], 2))
    rollout = jax.jit(jax.vmap(trainer.rollout))
    update = jax.jit(jax.vmap(trainer.update))
    _, tr = rollout(state, keys)

    def forward(ts, obs):
        def body(c, o):
            return c, trainer.policy.apply(ts.params["policy"], o, trainer.policy_norm(ts))[0]

        return jax.lax.scan(body, 0, obs)[1]

    forward = jax.jit(jax.vmap(forward))
    pieces = {"rollout": lambda: rollout(state, keys),
              "policy_forward": lambda: forward(state, tr.obs[:, :n]),
              "update": lambda: update(state, tr, keys)}
    out = {}
    for name, fn in pieces.items():
        jax.block_until_ready(fn())
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            jax.block_until_ready(fn())
            times.append(time.perf_counter() - t0)
        out[name] = float(np.median(times))
    return out


def seed_keys(seeds: tuple[int, ...]) -> jax.Array:
    """Raw keys ``(num_seeds, 2)`` for the seeds."""
    return jnp.stack([jax.random.PRNGKey(s) for s in seeds])


def _history_to_json(history: dict[str, np.ndarray]) -> dict[str, list]:
    return {k: [[None if not math.isfinite(x) else float(x) for x in row] for row in v]
            for k, v in history.items()}


def _history_from_json(d: dict[str, list]) -> dict[str, np.ndarray]:
    return {k: np.array([[np.nan if x is None else x for x in row] for row in v], np.float64)
            for k, v in d.items()}


def run_training(spec: RunSpec, out_dir: str, resume: bool = False, progress: bool = True,
                 mesh: Mesh | None = None, stream=None) -> RunResult:
    """Train ``spec`` into ``out_dir`` (see the module docstring); ``resume`` continues from the
    newest checkpoint there (refusing one of another environment, policy or configuration)."""
    ckpt_dir = os.path.join(out_dir, "checkpoints")
    has_ckpt = checkpoint.latest_step(ckpt_dir) is not None
    if has_ckpt and not resume:
        raise FileExistsError(f"{out_dir} already holds a run; pass resume=True (--resume) to "
                              "continue it or choose another output directory")
    if resume and not has_ckpt:
        raise FileNotFoundError(f"resume=True but there is no checkpoint in {ckpt_dir}")
    os.makedirs(out_dir, exist_ok=True)
    with open(os.path.join(out_dir, "run.json.tmp"), "w") as f:
        json.dump(spec.to_json(), f, indent=1)
    os.replace(os.path.join(out_dir, "run.json.tmp"), os.path.join(out_dir, "run.json"))

    program = build(spec, mesh)
    compile_before = program.compile_seconds
    keys = seed_keys(spec.seeds)
    cfg = spec.ppo
    if resume:
        template = jax.eval_shape(program.init, keys)
        state, meta = checkpoint.restore(ckpt_dir, template, expected=spec.identity())
        history = _history_from_json(meta["history"])
        done = int(meta["iteration"])
    else:
        state = program.init(keys)
        history, done = {}, 0
    total = cfg.total_iterations
    if done >= total:
        print(f"run already has {done} >= {total} iterations", file=stream or sys.stderr)

    csv_path = os.path.join(out_dir, "metrics.csv")
    tb = _TensorBoard(os.path.join(out_dir, "tb"))
    if history:
        write_csv(csv_path, history, spec.seeds, cfg.batch_size)
    bar = ProgressBar(total, stream) if progress else None
    train_s = 0.0
    steps_per_iter = cfg.batch_size * len(spec.seeds)

    saved = [done]

    def save(at: int):
        if at == saved[0] and checkpoint.latest_step(ckpt_dir) == at:
            return
        meta = dict(spec.identity(), iteration=at, history=_history_to_json(history),
                    run=spec.to_json())
        checkpoint.save(ckpt_dir, at, state, meta, max_to_keep=spec.keep_checkpoints)
        saved[0] = at

    try:
        while done < total:
            n = min(spec.log_every, total - done)
            executable = program.executable(state, n)
            t0 = time.perf_counter()
            new_state, metrics = executable(state)
            metrics = jax.tree.map(np.asarray, metrics)  # blocks until the chunk is done
            dt = time.perf_counter() - t0
            train_s += dt
            state = new_state
            start = done
            done += n
            for k, v in metrics.items():
                v = v.astype(np.float64)
                history[k] = v if k not in history else np.concatenate([history[k], v], 1)
            write_csv(csv_path, history, spec.seeds, cfg.batch_size)
            tb.write(history, start, spec.seeds, cfg.batch_size)
            if bar is not None:
                bar.update(done, summary_line(history, n * steps_per_iter / dt, window=n))
            if done % spec.checkpoint_every == 0 or done == total:
                save(done)
    except KeyboardInterrupt:
        if bar is not None:
            bar.close()
        if done > 0:
            save(done)
            print(f"\ninterrupted: checkpoint of iteration {done} written to {ckpt_dir}; "
                  "continue with --resume", file=sys.stderr)
        raise
    finally:
        tb.close()
    if bar is not None:
        bar.close()
    if history:
        horizon = cfg.episode_length or int(getattr(program.trainer.env.unwrapped, "horizon",
                                                    cfg.rollout_length))
        plot_curves(history, os.path.join(out_dir, "learning_curves.png"),
                    f"{spec.policy} on {spec.env} ({len(spec.seeds)} seed(s))",
                    min_episodes=max(100, 3 * cfg.num_envs),
                    reward_window=-(-horizon // cfg.rollout_length))
    return RunResult(history, state, program.trainer,
                     program.compile_seconds - compile_before, train_s,
                     (done * steps_per_iter) if history else 0)


__all__ = [
    "CURVES",
    "PRESETS",
    "Program",
    "ProgressBar",
    "RunResult",
    "RunSpec",
    "build",
    "cpu_preset",
    "episode_window",
    "improvement_summary",
    "make_mesh",
    "moving_average",
    "nanmean",
    "plot_curves",
    "preset",
    "profile_iteration",
    "read_csv",
    "run_training",
    "seed_keys",
    "summary_line",
    "write_csv",
]
