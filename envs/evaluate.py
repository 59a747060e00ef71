"""Roll out a policy (by default the hand-designed RMP² policy) over many episodes in one call.

``evaluate(env, num_episodes)`` vmaps ``num_episodes`` episodes and runs ``lax.scan`` over the
horizon (600 control steps). Each episode is frozen once it is done (no auto-reset), so the
per-episode statistics are exact:

* ``return``: sum of control-step rewards until the episode ended;
* ``safe``: no collision and no non-finite state;
* ``success``: safe and the goal within ``success_radius`` (0.05 m) at the end of the horizon;
* ``final_goal_distance``, ``length``.

The policy is :func:`mjxrmp.policies.acceleration` with the environment's goal and obstacles,
``q`` measured and ``q̇`` the virtual velocity (as in the original), clipped to ±``action_limit``.

CLI: ``python -m envs.evaluate --env three_link/env3 --episodes 64 [--action-limit 1]``.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
from brax.envs.base import Env, State

from envs.reaching import ReachEnv
from envs.registry import make
from mjxrmp import policies

__all__ = ["evaluate", "frozen_step", "hand_designed_policy", "make_rollout", "summarize"]


def hand_designed_policy(env: ReachEnv, variant: str = "hand_designed"
                         ) -> Callable[[State], jax.Array]:
    """``policy(state) -> action`` for a single (un-batched) environment state."""
    cfg = policies.default_config(env.robot_name, variant)

    def policy(state):
        q, qd, goal, obstacles = env.policy_inputs(state)
        acc = policies.acceleration(cfg, q, qd, goal, obstacles)
        return jnp.clip(acc, -env.action_limit, env.action_limit)

    return policy


def frozen_step(env: Env, policy: Callable[[State], jax.Array]) -> Callable[[State], State]:
    """``step(state) -> state``: one control step of ``policy``, or ``state`` unchanged once
    the episode is done (no auto-reset, so per-episode statistics stay exact)."""

    def step(state: State) -> State:
        new = env.step(state, policy(state))
        frozen = state.done > 0
        return jax.tree.map(lambda a, b: jnp.where(frozen, b, a), new, state)

    return step


def make_rollout(env: ReachEnv, num_episodes: int, horizon: int | None = None,
                 policy: Callable[[State], jax.Array] | None = None
                 ) -> Callable[[jax.Array], dict[str, jax.Array]]:
    """Jitted ``rollout(key) -> dict`` of per-episode arrays ``(num_episodes,)``."""
    horizon = env.horizon if horizon is None else horizon
    policy = hand_designed_policy(env) if policy is None else policy
    step = frozen_step(env, policy)

    def episode(key):
        state = env.reset(key)
        state, _ = jax.lax.scan(lambda s, _: (step(s), None), state, None, length=horizon)
        info, m = state.info, state.metrics
        safe = (info["episode_collided"] == 0) & (info["episode_nonfinite"] == 0)
        final = m["goal_distance"]
        return {
            "return": info["episode_return"],
            "length": info["episode_length"],
            "safe": safe.astype(jnp.float32),
            "success": (safe & (final < env.success_radius)).astype(jnp.float32),
            "final_goal_distance": final,
            "nonfinite": info["episode_nonfinite"],
            "sampler_ok": info["sampler_ok"],
        }

    @jax.jit
    def rollout(key):
        return jax.vmap(episode)(jax.random.split(key, num_episodes))

    return rollout


def summarize(per_episode: dict) -> dict:
    """Mean return, success %, safe % and friends from :func:`make_rollout`'s output."""
    return {
        "episodes": int(per_episode["return"].shape[0]),
        "mean_return": float(jnp.mean(per_episode["return"])),
        "success_pct": 100.0 * float(jnp.mean(per_episode["success"])),
        "safe_pct": 100.0 * float(jnp.mean(per_episode["safe"])),
        "mean_final_goal_distance": float(jnp.mean(per_episode["final_goal_distance"])),
        "mean_length": float(jnp.mean(per_episode["length"])),
        "nonfinite_pct": 100.0 * float(jnp.mean(per_episode["nonfinite"])),
        "sampler_ok_pct": 100.0 * float(jnp.mean(per_episode["sampler_ok"])),
    }


def evaluate(env: ReachEnv, num_episodes: int = 64, seed: int = 0,
             horizon: int | None = None) -> dict:
    """Summary statistics and wall times (compile and run, seconds) of the hand-designed policy."""
    rollout = make_rollout(env, num_episodes, horizon)
    key = jax.random.PRNGKey(seed)
    t0 = time.perf_counter()
    compiled = rollout.lower(key).compile()
    t1 = time.perf_counter()
    out = jax.block_until_ready(compiled(key))
    t2 = time.perf_counter()
    summary = summarize(out)
    summary.update(compile_s=t1 - t0, run_s=t2 - t1, device=jax.devices()[0].platform)
    return summary


def main(argv: list[str] | None = None) -> dict:
    """CLI entry point (module docstring): print and return the summary as JSON."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--env", default="three_link/env3")
    p.add_argument("--episodes", type=int, default=64)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--horizon", type=int, default=None)
    p.add_argument("--action-limit", type=float, default=1.0)
    p.add_argument("--obstacle-sampler", default=None, help="3-link only: thesis|original")
    args = p.parse_args(argv)
    kwargs = {"action_limit": args.action_limit}
    if args.obstacle_sampler is not None:
        kwargs["obstacle_sampler"] = args.obstacle_sampler
    env = make(args.env, **kwargs)
    summary = {"env": args.env, **evaluate(env, args.episodes, args.seed, args.horizon)}
    print(json.dumps(summary))
    return summary


if __name__ == "__main__":
    main()
