"""Rollouts of a behaviour policy inside one compiled graph, the engine of
:mod:`offline.data.collect` (thesis chapters 7–8, docs/design.md §2.4).

:func:`rollout` runs a behaviour policy on a reaching environment (:func:`envs.make` name)
for ``num_episodes`` episodes: ``jax.jit(jax.vmap(episode))`` with a ``lax.scan`` over the
horizon (the environment's 600 control steps unless ``horizon`` is given), as
:func:`envs.evaluate.make_rollout`. There is **no auto-reset**: each vmapped slot runs exactly
one episode and is frozen once the environment reports ``done`` (a collision, or a non-finite
state), so

* the ``next_observations`` of an episode's last transition is the true terminal observation
  (the state the collision happened in), never the first observation of another episode;
* a transition whose ``done`` is set is a **terminal** (absorbing: learners use ``d = 1``);
  an episode still running at the end of the horizon gets a **timeout** on its last transition
  (:func:`offline.data.dataset.from_transitions` with ``unfinished="timeout"``);
* the frozen steps after a terminal are dropped through the ``valid`` mask.

Episodes are cut at collisions, which is what gives the data the length bias of thesis §8.3.3.

**Datasets without length bias** (``cut_at_collision=False`` in :func:`rollout`,
:func:`offline.data.collect.collect` and :func:`offline.data.collect.collect_recipe`; default
True, the behaviour above). The
environment never stops an episode itself: :meth:`envs.reaching.ReachEnv.step` only *reports*
``done = 1`` at a collision, and it is this module that freezes the episode. Without the cut the
episode simply keeps being stepped for the full horizon: obstacles are not in the MJX model, so
the arm passes through them (the data is then like D4RL's halfcheetah, thesis §8.4.1: every
episode has the same length). A colliding step keeps the environment's reward (its obstacle
penalty, averaged up to the first colliding substep), the collision is recorded in the
``collision`` rollout array and the per-episode ``collided`` / ``safe`` / ``success`` (and the
metadata's ``safe_pct``) — never as a terminal. Only a **non-finite** state still ends an
episode (a terminal, as with the cut): it cannot be continued. Such datasets have
``metadata["cut_at_collision"] = False`` (the key is absent from default datasets, so read it
as ``metadata.get("cut_at_collision", True)``).

**Recorded action.** The action stored is the one the environment actually applied: the policy's
output with NaNs replaced by 0 and clipped to ``±action_limit`` — exactly what
:meth:`envs.reaching.ReachEnv.step` does before integrating. For the noisy expert the Gaussian
noise is added to the (already clipped) expert action and the sum is clipped, so recorded noisy
actions always lie in the action box and equal ``clip(expert + σ·ε)``, not ``expert + σ·ε``.
For a PPO policy of kind ``rmp_residual_env`` (whose environment action is a residual RMP) the
recorded action is the joint acceleration RMP² resolved from it, clipped: every dataset of an
environment shares one action space (joint accelerations) and one observation layout (the
environment's default observation; the ``residual_rmp`` variant's extra entries, which extend it,
are cut off).


Expert, noisy and random episodes run through one compiled program (per environment, horizon
and batch size), parameterised per episode by ``(σ, uniform?)``; every PPO checkpoint of one run
shares a second program (parameters are arguments, not constants). Programs are cached, so
collecting several sources of one recipe compiles at most twice.

"""

from __future__ import annotations

import json
import os
import zlib
from collections.abc import Callable, Mapping
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

import envs as envs_pkg
import mjxrmp  # noqa: F401  (XLA:CPU flags before JAX initialises)
from agents.run.loading import load_run, policy_params
from envs.evaluate import hand_designed_policy
from offline.data import dataset as odata
from offline.data.behaviours import Behaviour

#: How the recorded action relates to the policy output (stored in the metadata).
ACTION_NOTE = ("actions are those the environment applied: policy output with NaN -> 0, clipped "
               "to +-action_limit (noise is added before the clip); joint accelerations")



_ENVS: dict[tuple, Any] = {}
_PROGRAMS: dict[tuple, tuple[Any, Callable]] = {}
_RUNS: dict[tuple, Any] = {}


def _kwargs_key(env_kwargs: Mapping[str, Any] | None) -> str:
    return json.dumps(dict(env_kwargs or {}), sort_keys=True)


def make_env(env_name: str, env_kwargs: Mapping[str, Any] | None = None, *,
             observation: str | None = None, rmp_in_env: bool = False) -> Any:
    """The (cached) environment ``envs.make(env_name, rmp_in_env=rmp_in_env, **env_kwargs)``
    (``observation`` added to the arguments when given); unknown names raise ``ValueError``
    listing the valid ones."""
    kwargs = dict(env_kwargs or {})
    if observation is not None:
        kwargs["observation"] = observation
    key = (env_name, _kwargs_key(kwargs), rmp_in_env)
    if key not in _ENVS:
        _ENVS[key] = envs_pkg.make(env_name, rmp_in_env=rmp_in_env, **kwargs)
    return _ENVS[key]


def _executed(env, raw: jax.Array) -> jax.Array:
    """The action :meth:`ReachEnv.step` applies for ``raw`` (NaN → 0, clipped)."""
    a = jnp.where(jnp.isfinite(raw), raw, 0.0)
    return jnp.clip(a, -env.action_limit, env.action_limit).astype(jnp.float32)


def _rollout_fn(env, horizon: int, act: Callable, obs_size: int, params_axes: Any = 0,
                cut_at_collision: bool = True) -> Callable:
    """``jit(vmap(episode))(keys (B, 2), params) -> (traj, per_episode)``, time-major traj.

    ``act(state, key, params) -> (raw_action, base_action)`` for one episode: the joint
    acceleration the policy asks for (before the environment's clip) and its noise-free part;
    ``params_axes`` is the ``in_axes`` of ``params`` (None for parameters shared by all).
    An episode is frozen after ``done`` (``cut_at_collision``) or only after a non-finite
    state (module docstring, "Datasets without length bias").
    """

    def ended(state):
        return state.done if cut_at_collision else state.metrics["nonfinite"]

    def episode(key, params):
        k_reset, k_act = jax.random.split(key)
        state0 = env.reset(k_reset)

        def step(state, t):
            raw, base = act(state, jax.random.fold_in(k_act, t), params)
            executed = _executed(env, raw)
            new = env.step(state, executed)
            valid = ended(state) == 0
            new = jax.tree.map(lambda a, b: jnp.where(valid, a, b), new, state)
            out = {
                "observations": state.obs[:obs_size],
                "actions": executed,
                "raw_actions": raw,
                "base_actions": base,
                "rewards": new.reward,
                "next_observations": new.obs[:obs_size],
                "dones": jnp.where(valid, ended(new), 0.0),
                "valid": valid,
                "collision": jnp.where(valid, new.metrics["collision"], 0.0),
                "nonfinite": jnp.where(valid, new.metrics["nonfinite"], 0.0),
            }
            return new, out

        final, traj = jax.lax.scan(step, state0, jnp.arange(horizon))
        info = final.info
        safe = (info["episode_collided"] == 0) & (info["episode_nonfinite"] == 0)
        dist = final.metrics["goal_distance"]
        ep = {
            "return": info["episode_return"],
            "length": info["episode_length"],
            "collided": info["episode_collided"],
            "nonfinite": info["episode_nonfinite"],
            "safe": safe,
            "success": safe & (dist < env.success_radius),
            "final_goal_distance": dist,
            "final_observation": final.obs[:obs_size],
        }
        return traj, ep

    @jax.jit
    def rollout(keys, params):
        traj, ep = jax.vmap(episode, in_axes=(0, params_axes))(keys, params)
        traj = jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), traj)  # (T, B, ...)
        return traj, ep

    return rollout


def _scripted_program(env_name: str, env_kwargs, horizon: int, batch: int,
                      cut_at_collision: bool = True):
    """Program for expert / noisy / random; params = (sigma (B,), uniform (B,))."""
    env = make_env(env_name, env_kwargs)
    key = ("scripted", env_name, _kwargs_key(env_kwargs), horizon, batch, cut_at_collision)
    if key not in _PROGRAMS:
        policy = hand_designed_policy(env)
        lim, size = env.action_limit, env.action_size

        def act(state, k, params):
            sigma, uniform = params
            k_noise, k_unif = jax.random.split(k)
            base = policy(state)
            noisy = base + sigma * jax.random.normal(k_noise, (size,), jnp.float32)
            rand = jax.random.uniform(k_unif, (size,), jnp.float32, -lim, lim)
            return jnp.where(uniform, rand, noisy), base

        _PROGRAMS[key] = (env, _rollout_fn(env, horizon, act, env.observation_size,
                                           cut_at_collision=cut_at_collision))
    return _PROGRAMS[key]


def _load(run_dir: str, step: int | None):
    key = (os.path.abspath(run_dir), step)
    if key not in _RUNS:
        _RUNS[key] = load_run(run_dir, step)
    return _RUNS[key]


def _ppo_program(env_name: str, env_kwargs, horizon: int, batch: int, loaded,
                 cut_at_collision: bool = True):
    """Program for a PPO policy; params = (PolicyParams, stochastic (B,))."""
    spec = loaded.spec
    if spec.env != env_name:
        raise ValueError(f"PPO run {loaded.run_dir!r} was trained on {spec.env!r}; it cannot "
                         f"collect data on {env_name!r} (observation layouts differ)")
    data_env = make_env(env_name, env_kwargs)
    kind = spec.policy
    variant = "residual_rmp" if kind == "rmp_residual_env" else None
    base_env = make_env(env_name, env_kwargs, observation=variant)
    module = loaded.policy_module
    key = ("ppo", env_name, _kwargs_key(env_kwargs), horizon, batch, kind, id(module),
           cut_at_collision)
    if key not in _PROGRAMS:
        data_layout = data_env.observation_layout()
        pol_layout = base_env.observation_layout()
        if any(pol_layout.get(k) != v for k, v in data_layout.items()):
            raise ValueError(f"policy observation layout {pol_layout} does not extend the data "
                             f"layout {data_layout}")
        rmp_env = (make_env(env_name, env_kwargs, observation=variant, rmp_in_env=True)
                   if kind == "rmp_residual_env" else None)

        def act(state, k, params):
            p, stochastic = params
            mean, log_std = module.apply(p.params, state.obs, p.norm)
            eps = jax.random.normal(k, mean.shape, mean.dtype)
            raw = mean + jnp.where(stochastic, jnp.exp(log_std) * eps, 0.0)
            if rmp_env is not None:  # residual RMP -> joint acceleration
                return (rmp_env.joint_acceleration(state, raw),
                        rmp_env.joint_acceleration(state, mean))
            return raw, mean

        _PROGRAMS[key] = (module, _rollout_fn(base_env, horizon, act,
                                              data_env.observation_size, (None, 0),
                                              cut_at_collision))
    return _PROGRAMS[key]


def clear_caches() -> None:
    """Forget cached environments, compiled programs and loaded PPO runs."""
    _ENVS.clear()
    _PROGRAMS.clear()
    _RUNS.clear()


def source_key(seed: int | jax.Array, role: str, name: str) -> jax.Array:
    """The key of a recipe source: ``fold_in(PRNGKey(seed), crc32(f"{role}:{name}"))``."""
    root = jax.random.PRNGKey(seed) if isinstance(seed, int | np.integer) else seed
    return jax.random.fold_in(root, zlib.crc32(f"{role}:{name}".encode()) & 0x7FFFFFFF)


def rollout(env_name: str, behaviour: Behaviour, num_episodes: int, key: jax.Array, *,
            env_kwargs: Mapping[str, Any] | None = None, horizon: int | None = None,
            batch_size: int | None = None,
            progress: Callable[[str], None] | None = None,
            cut_at_collision: bool = True) -> dict[str, Any]:
    """Raw rollout arrays (NumPy) of ``num_episodes`` episodes of ``behaviour``.

    Returns a dict with time-major ``(T, B, ...)`` arrays ``observations``, ``actions``
    (executed: ``raw_actions`` with NaN → 0, clipped), ``raw_actions`` (the policy's output:
    expert + noise, the uniform sample, the PPO mean or sample), ``base_actions`` (its
    noise-free part: the expert's clipped action for scripted behaviours — also for ``random``,
    where it is unused —, the Gaussian mean for PPO; for ``rmp_residual_env`` both are the joint
    accelerations RMP² resolves), ``rewards``, ``next_observations``, ``dones``, ``valid``,
    ``collision``,
    ``nonfinite`` and ``episode`` (per-episode ``(B,)`` arrays: ``return``, ``length``,
    ``collided``, ``nonfinite``, ``safe``, ``success``, ``final_goal_distance``,
    ``final_observation``). Episodes run ``batch_size`` at a time (default: all at once; the
    last chunk is padded and the padding dropped) in one compiled program per batch size.
    ``cut_at_collision=False`` keeps colliding episodes running to the horizon (module
    docstring, "Datasets without length bias"): ``dones`` then marks non-finite states only.
    """
    if not isinstance(cut_at_collision, bool):
        raise ValueError(f"cut_at_collision must be a bool, got {cut_at_collision!r}")
    if not isinstance(num_episodes, int | np.integer) or num_episodes < 1:
        raise ValueError(f"num_episodes must be a positive integer, got {num_episodes!r}")
    env = make_env(env_name, env_kwargs)
    horizon = env.horizon if horizon is None else int(horizon)
    if horizon < 1:
        raise ValueError(f"horizon must be >= 1, got {horizon}")
    batch = int(num_episodes if batch_size is None else batch_size)
    if batch < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size!r}")
    n = int(num_episodes)
    keys = jax.vmap(lambda i: jax.random.fold_in(key, i))(jnp.arange(n))

    if behaviour.kind == "ppo":
        loaded = _load(behaviour.run_dir, behaviour.step)
        _, fn = _ppo_program(env_name, env_kwargs, horizon, batch, loaded, cut_at_collision)
        pparams = policy_params(loaded, behaviour.seed_index)

        def params_for(b):
            return pparams, jnp.full((b,), behaviour.stochastic)
    else:
        _, fn = _scripted_program(env_name, env_kwargs, horizon, batch, cut_at_collision)
        sigma = behaviour.sigma if behaviour.kind == "noisy" else 0.0
        uniform = behaviour.kind == "random"

        def params_for(b):
            return jnp.full((b,), sigma, jnp.float32), jnp.full((b,), uniform)

    chunks = []
    for start in range(0, n, batch):
        stop = min(start + batch, n)
        k = keys[start:stop]
        if stop - start < batch:  # pad with copies of the last key, dropped below
            k = jnp.concatenate([k, jnp.repeat(k[-1:], batch - (stop - start), axis=0)])
        traj, ep = jax.device_get(fn(k, params_for(batch)))
        m = stop - start
        chunks.append(({k: v[:, :m] for k, v in traj.items()},
                       {k: v[:m] for k, v in ep.items()}))
        if progress is not None:
            progress(f"  {behaviour.name}: {stop}/{n} episodes")
    traj = {k: np.concatenate([c[0][k] for c in chunks], axis=1) for k in chunks[0][0]}
    traj["episode"] = {k: np.concatenate([c[1][k] for c in chunks]) for k in chunks[0][1]}
    return traj


def environment_metadata(env_name: str, env_kwargs: Mapping[str, Any] | None = None,
                         horizon: int | None = None) -> dict[str, Any]:
    """What a dataset records about its environment."""
    env = make_env(env_name, env_kwargs)
    return {
        "env": env_name,
        "env_kwargs": dict(env_kwargs or {}),
        "horizon": int(env.horizon if horizon is None else horizon),
        "action_limit": float(env.action_limit),
        "reward_range": [float(env.reward_min), float(env.reward_max)],
        "observation_layout": {k: [s.start, s.stop]
                               for k, s in env.observation_layout().items()},
        "action_note": ACTION_NOTE,
    }


def to_dataset(traj: Mapping[str, Any], metadata: Mapping[str, Any] | None = None
               ) -> odata.Dataset:
    """The :class:`offline.data.dataset.Dataset` of :func:`rollout` arrays (frozen steps dropped,
    collisions as terminals, episodes still running at the horizon as timeouts)."""
    return odata.from_transitions(traj["observations"], traj["actions"], traj["rewards"],
                                  traj["dones"], None,
                                  next_observations=traj["next_observations"],
                                  valid=traj["valid"], unfinished="timeout", metadata=metadata)



__all__ = [
    "ACTION_NOTE",
    "clear_caches",
    "environment_metadata",
    "make_env",
    "rollout",
    "source_key",
    "to_dataset",
]
