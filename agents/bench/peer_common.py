"""What every trainer of the PPO peer comparison shares (:mod:`agents.bench.peers`,
docs/reports/peers.md): the timed run it hands back, how its chunks are timed, and the one
evaluator every final policy is scored with.

Timing is the same for every trainer: the wall clock runs from before the trainer is built to
the end of its last chunk of iterations (each chunk blocked on); the *steady* time of a chunk is
the median of the chunks after the first (the first holds the trainers' lazy compiles);
*compile and set-up* is the wall time minus the chunks at their steady time.
"""

from __future__ import annotations

import dataclasses
import statistics
import time
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

import envs
from envs.evaluate import make_rollout, summarize


@dataclasses.dataclass(frozen=True)
class PolicyNet:
    """The policy MLP every trainer uses: hidden sizes, activation, initial log-std."""

    hidden_sizes: tuple[int, ...]
    activation: str
    log_std_init: float


@dataclasses.dataclass
class PeerRun:
    """One trainer's run: the final policy's deterministic action ``act(obs) -> action`` for
    one observation, the wall time of every chunk of iterations, the whole wall time (set-up
    and compiles included) and the environment steps trained (all seeds)."""

    act: Callable[[jax.Array], jax.Array]
    chunk_s: list[float]
    wall_s: float
    env_steps: int


def timed_chunks(run_chunk: Callable[[Any], Any], state: Any, chunks: int
                 ) -> tuple[Any, list[float]]:
    """``(state, seconds)``: ``state`` advanced by ``chunks`` calls of ``run_chunk`` and the
    wall time of each call, blocked on its result."""
    times = []
    for _ in range(chunks):
        t0 = time.perf_counter()
        state = jax.block_until_ready(run_chunk(state))
        times.append(time.perf_counter() - t0)
    return state, times


def timing(run: PeerRun) -> dict[str, float]:
    """Steady environment steps/s (median chunk after the first), the steady chunk time, the
    wall time and the compile-and-set-up time of ``run`` (module docstring)."""
    steady = statistics.median(run.chunk_s[1:] if len(run.chunk_s) > 1 else run.chunk_s)
    per_chunk = run.env_steps / len(run.chunk_s)
    return {"steps_per_s": per_chunk / steady, "chunk_s": steady, "wall_s": run.wall_s,
            "compile_s": max(run.wall_s - steady * len(run.chunk_s), 0.0)}


def evaluate_act(env_name: str, act: Callable[[jax.Array], jax.Array], episodes: int,
                 horizon: int | None, seed: int) -> dict[str, float]:
    """:func:`envs.evaluate.summarize` of ``episodes`` episodes of ``act`` (the observation's
    deterministic action, clipped by the environment) on ``envs.make(env_name)``: the same
    scenes for every trainer (the key of ``seed``), each episode frozen once done."""
    env = envs.make(env_name)
    rollout = make_rollout(env, episodes, horizon, lambda state: act(state.obs))
    return summarize(rollout(jax.random.PRNGKey(seed)))


def first_seed(tree: Any) -> Any:
    """Every leaf of ``tree`` at index 0 of its leading (seed) axis."""
    return jax.tree.map(lambda a: jnp.asarray(a)[0], tree)


__all__ = ["PeerRun", "PolicyNet", "evaluate_act", "first_seed", "timed_chunks", "timing"]
