"""Environment and PPO throughput: control steps per second of a batch of auto-resetting
environments (random actions or the hand-designed RMP² policy in the loop) and environment
steps per second of PPO training (:mod:`agents.run.program`)."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

import jax
import jax.numpy as jnp

import envs
from agents.ppo import TrainState, make_mesh
from agents.run.program import Program, build, profile_iteration, seed_keys
from agents.run.spec import RunSpec, preset
from envs.evaluate import hand_designed_policy
from envs.wrappers import wrap


def env_runner(env_name: str, policy: str, batch: int, steps: int
               ) -> tuple[Callable, Callable]:
    """``(reset, run)``: a batch of auto-resetting environments stepped ``steps`` control steps
    in one ``lax.scan`` with random actions (``policy="random"``) or the hand-designed RMP²
    policy in the loop (``"rmp2"``)."""
    base = envs.make(env_name)
    env = wrap(base)
    rmp2_policy = jax.vmap(hand_designed_policy(base))

    def act(state, key):
        if policy == "random":
            return jax.random.uniform(key, (batch, base.action_size), minval=-1.0, maxval=1.0)
        return rmp2_policy(state)

    def run(state, key):
        def body(s, k):
            s = env.step(s, act(s, k))
            return s, s.reward
        state, rewards = jax.lax.scan(body, state, jax.random.split(key, steps))
        return state, jnp.mean(rewards)

    return jax.jit(env.reset), jax.jit(run)


def measure_env(env_name: str, policy: str, batch: int, steps: int, repeats: int,
                key: jax.Array) -> dict:
    """Control steps/s (each = 3 physics substeps) of :func:`env_runner`; median of repeats."""
    reset, run = env_runner(env_name, policy, batch, steps)
    k_reset, k_run = jax.random.split(key)
    # brax's episode wrapper expects raw uint32 keys of shape (B, 2).
    state = jax.block_until_ready(reset(jax.random.key_data(jax.random.split(k_reset, batch))))
    t0 = time.perf_counter()
    state, reward = jax.block_until_ready(run(state, k_run))
    compile_s = time.perf_counter() - t0
    times = []
    for i in range(repeats):
        t0 = time.perf_counter()
        state, reward = jax.block_until_ready(run(state, jax.random.fold_in(k_run, i)))
        times.append(time.perf_counter() - t0)
    t = statistics.median(times)
    return {
        "time_per_call_s": t / steps,
        "time_min_s": min(times) / steps,
        "time_max_s": max(times) / steps,
        "compile_s": compile_s,
        "repeats": repeats,
        "calls_per_repeat": steps,
        "finite_fraction": float(jnp.isfinite(reward)),
        "evals_per_s": batch * steps / t,
    }


def time_chunk(program: Program, state: TrainState, iterations: int
               ) -> tuple[TrainState, float]:
    """``(state after two chunks, seconds of the second)``: the compiled chunk of
    ``iterations`` iterations of ``program`` run once as a warm-up, then timed."""
    exe = program.executable(jax.block_until_ready(state), iterations)
    state, _ = jax.block_until_ready(exe(state))
    t0 = time.perf_counter()
    state, _ = jax.block_until_ready(exe(state))
    return state, time.perf_counter() - t0


def measure_ppo(env_name: str, policy: str, devices: int, iterations: int, seeds: int,
                preset_name: str, num_envs: int | None = None, split: bool = True) -> dict:
    """PPO training throughput: environment steps/s of a compiled chunk of ``iterations``
    iterations for ``seeds`` vmapped seeds, the environment batch sharded over ``devices``
    devices (after a warm-up chunk); compile time; on one device and with ``split`` also the
    per-iteration split (:func:`agents.run.program.profile_iteration`)."""
    overrides = {} if num_envs is None else {"num_envs": num_envs}
    spec = RunSpec(env=env_name, policy=policy, seeds=tuple(range(seeds)),
                   ppo=preset(preset_name, **overrides))
    program = build(spec, make_mesh(devices))
    state, dt = time_chunk(program, program.init(seed_keys(spec.seeds)), iterations)
    steps = iterations * spec.ppo.batch_size * seeds
    row = {"env": env_name, "policy": policy, "devices": devices, "seeds": seeds,
           "preset": preset_name, "num_envs": spec.ppo.num_envs, "iterations": iterations,
           "env_steps": steps,
           "seconds": dt, "steps_per_s": steps / dt, "iteration_s": dt / iterations,
           "compile_s": program.compile_seconds}
    if devices == 1 and split:
        row["iteration_split_s"] = profile_iteration(program, state)
    return row


__all__ = ["env_runner", "measure_env", "measure_ppo", "time_chunk"]
