"""Offline data collection inside one compiled graph (thesis chapters 7–8, docs/design.md §2.4).

:func:`collect` rolls out a behaviour policy on a reaching environment (:func:`envs.make` name)
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
:func:`collect` and :func:`collect_recipe`; default True, the behaviour above). The
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

**Behaviour policies** (:class:`Behaviour`):

==========================  =================================================================
constructor                 action
==========================  =================================================================
:func:`expert`              hand-designed RMP² (:func:`envs.evaluate.hand_designed_policy`)
:func:`noisy_expert`        expert + ``N(0, σ²)`` per component, then clipped (σ ∈ {0.1, 0.5,
                            1.0} in the recipes: ``noisy-0.1`` …)
:func:`uniform_random`      i.i.d. ``U[−action_limit, action_limit]`` per component
:func:`ppo_policy`          a PPO checkpoint (:func:`agents.run.loading.load_run`): its Gaussian mean
                            (``stochastic=False``) or a sample ``mean + exp(log_std)·ε``
                            (``stochastic=True``, as during training); the environment clips
==========================  =================================================================

Expert, noisy and random episodes run through one compiled program (per environment, horizon
and batch size), parameterised per episode by ``(σ, uniform?)``; every PPO checkpoint of one run
shares a second program (parameters are arguments, not constants). Programs are cached, so
collecting several sources of one recipe compiles at most twice.

**Determinism.** Episode ``i`` of a source uses the key ``fold_in(source_key, i)``, split into a
reset key (scene) and an action key (``fold_in(action_key, t)`` at step ``t`` for the noise).
A source's key is ``fold_in(PRNGKey(seed), crc32(role:name))``. The data therefore depend only
on the seed, the source and the episode index — not on the batch size, the chunking, or which
other sources a recipe has — and a larger ``scale`` extends a dataset (its first episodes are
those of the smaller one).

**Recipes** (:func:`collect_recipe`, in the spirit of D4RL; ``n = scale`` episodes per source):

=================  ============================================  ==============================
recipe             sources with a PPO run (``ppo_run``)          without a PPO run (FALLBACK)
=================  ============================================  ==============================
``random``         ``random`` ×n                                 same
``medium``         ``ppo-medium`` ×n                             ``noisy-0.5`` ×n as "medium"
``medium-replay``  the run's checkpoints up to the medium one    ``random``, ``noisy-1.0``,
                   (``ppo-replay-<step>``, stochastic), n split  ``noisy-0.5`` (n split evenly,
                   evenly over them, earliest first              in that order)
``medium-expert``  medium ×n + ``expert`` ×n                     ``noisy-0.5`` ×n +
                                                                 ``expert`` ×n
``expert``         ``expert`` ×n                                 same
``mixed``          ``random``, ``noisy-1.0``, ``noisy-0.5``,     ``random``, ``noisy-1.0``,
                   ``noisy-0.1``, ``ppo-low``, ``ppo-medium``    ``noisy-0.5``, ``noisy-0.1``
                   ×n each + medium-replay (n split)             ×n each (no PPO sources)
=================  ============================================  ==============================

Splitting n over k parts gives the first ``n mod k`` parts one episode more. Sources appear in
the dataset in the order listed; a source's episodes are identical in every recipe that has it
(same seed, role and behaviour), e.g. ``expert`` in ``expert`` and ``medium-expert``.

* ``ppo-medium`` is the run's checkpoint ``ppo_step`` (default: its newest), ``ppo-low`` its
  earliest checkpoint; both act stochastically unless ``ppo_stochastic=False``; medium-replay
  always samples (it stands for the data PPO collected while training). "Medium" quality is
  whatever checkpoint is passed: choose one whose return is well below the expert's. A run keeps
  only its 3 newest checkpoints unless it was trained with ``scripts/train.py
  --keep-checkpoints 0`` (``RunSpec.keep_checkpoints=None``), so train it that way for a
  medium-replay dataset that covers the whole run.
* ``mixed`` is the union of every non-expert source: random, the noisy experts (the thesis'
  Meta-World mixed data, §7.4.2) and the PPO snapshots (the D4RL mixed data, §7.4.1).
* **Fallback — read this.** Without a PPO run, ``medium`` / ``medium-expert`` /
  ``medium-replay`` contain *no PPO data*: "medium" is the expert with Gaussian noise σ = 0.5 and
  "medium-replay" the sequence random → σ 1.0 → σ 0.5; ``mixed`` simply lacks the PPO sources.
  The dataset's ``metadata["fallback"]`` says so in words (``None`` when no fallback was used),
  :func:`collect_recipe` emits a ``UserWarning`` and ``scripts/collect.py`` prints a warning.
* **The noisy experts are not much worse than the expert.** Measured on the same 128 scenes
  (seed 0, 600 steps, CPU): mean return expert / σ 0.1 / σ 0.5 / σ 1.0 / random = 243.6 /
  243.0 / 236.0 / 207.0 / −6.8 on 3-link env3 (safe 100 / 100 / 100 / 97.7 / 79.7 %), 278.4 /
  277.7 / 272.6 / 254.3 / −3.6 on env1. The σ = 0.5 "medium" stand-in thus reaches ~97 % of
  the expert's return — far above D4RL's "medium" (about a third of expert); the quality gap
  in fallback data is between random and everything else.

Every dataset's metadata records the environment (name, constructor arguments, horizon, action
limit, reward range, observation layout), the seed, the recipe and for each source its role,
behaviour, episode count, the episode-id range it occupies and its summary statistics (mean
return, terminals, timeouts, safe % and success %).
"""

from __future__ import annotations

import dataclasses
import json
import os
import warnings
import zlib
from collections.abc import Callable, Mapping
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

import envs as envs_pkg
import mjxrmp  # noqa: F401  (XLA:CPU flags before JAX initialises)
from envs.evaluate import hand_designed_policy
from offline.data import dataset as odata

#: Recipe names accepted by :func:`collect_recipe` (see the module docstring).
RECIPES = ("random", "medium", "medium-replay", "medium-expert", "expert", "mixed")
#: Noise levels of the noisy expert (thesis §7.4.2).
NOISE_LEVELS = (0.1, 0.5, 1.0)
#: σ of the noisy expert that stands in for "medium" without a PPO run.
FALLBACK_MEDIUM_SIGMA = 0.5
BEHAVIOUR_KINDS = ("expert", "noisy", "random", "ppo")
#: How the recorded action relates to the policy output (stored in the metadata).
ACTION_NOTE = ("actions are those the environment applied: policy output with NaN -> 0, clipped "
               "to +-action_limit (noise is added before the clip); joint accelerations")


# --------------------------------------------------------------------------------------------
# Behaviour policies


@dataclasses.dataclass(frozen=True)
class Behaviour:
    """A behaviour policy (build one with :func:`expert`, :func:`noisy_expert`,
    :func:`uniform_random` or :func:`ppo_policy`)."""

    name: str
    kind: str
    sigma: float = 0.0
    run_dir: str | None = None
    step: int | None = None
    seed_index: int = 0
    stochastic: bool = False

    def __post_init__(self):
        if self.kind not in BEHAVIOUR_KINDS:
            raise ValueError(f"unknown behaviour kind={self.kind!r}; valid kinds are "
                             f"{BEHAVIOUR_KINDS}")
        if not (np.isfinite(self.sigma) and self.sigma >= 0):
            raise ValueError(f"sigma must be finite and >= 0, got {self.sigma!r}")
        if self.kind == "ppo" and self.run_dir is None:
            raise ValueError("a 'ppo' behaviour needs run_dir")

    def describe(self) -> dict[str, Any]:
        """JSON description stored in the dataset metadata."""
        d: dict[str, Any] = {"name": self.name, "kind": self.kind}
        if self.kind == "noisy":
            d["sigma"] = float(self.sigma)
        if self.kind == "ppo":
            d.update(run_dir=os.fspath(self.run_dir), step=self.step,
                     seed_index=self.seed_index, stochastic=self.stochastic)
        return d


def expert() -> Behaviour:
    """The hand-designed RMP² policy (deterministic)."""
    return Behaviour("expert", "expert")


def noisy_expert(sigma: float) -> Behaviour:
    """The expert plus i.i.d. Gaussian noise of standard deviation ``sigma`` on every action
    component, then clipped to the action box (name ``noisy-<σ>``)."""
    sigma = float(sigma)
    return Behaviour(f"noisy-{sigma!r}", "noisy", sigma=sigma)


def uniform_random() -> Behaviour:
    """Uniform random actions in the action box ``[−action_limit, action_limit]^A``."""
    return Behaviour("random", "random")


def ppo_policy(run_dir: str | os.PathLike, step: int | None = None, *, seed_index: int = 0,
               stochastic: bool = False, name: str | None = None) -> Behaviour:
    """Checkpoint ``step`` (default: newest) of training seed ``seed_index`` of the run in
    ``run_dir``: the Gaussian mean (``stochastic=False``) or a sample of the Gaussian."""
    if name is None:
        name = f"ppo-step{step if step is not None else 'latest'}"
    return Behaviour(name, "ppo", run_dir=os.fspath(run_dir), step=step,
                     seed_index=int(seed_index), stochastic=bool(stochastic))


# --------------------------------------------------------------------------------------------
# Environments and compiled programs (cached)

_ENVS: dict[tuple, Any] = {}
_PROGRAMS: dict[tuple, tuple[Any, Callable]] = {}
_RUNS: dict[tuple, Any] = {}


def _kwargs_key(env_kwargs: Mapping[str, Any] | None) -> str:
    return json.dumps(dict(env_kwargs or {}), sort_keys=True)


def make_env(env_name: str, env_kwargs: Mapping[str, Any] | None = None, *,
             observation: str | None = None):
    """The (cached) environment ``env_name`` built with ``env_kwargs``; unknown names raise
    ``ValueError`` listing the valid ones."""
    kwargs = dict(env_kwargs or {})
    if observation is not None:
        kwargs["observation"] = observation
    key = (env_name, _kwargs_key(kwargs))
    if key not in _ENVS:
        _ENVS[key] = envs_pkg.make(env_name, **kwargs)
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
    from agents.run.loading import load_run

    key = (os.path.abspath(run_dir), step)
    if key not in _RUNS:
        _RUNS[key] = load_run(run_dir, step)
    return _RUNS[key]


def _ppo_program(env_name: str, env_kwargs, horizon: int, batch: int, loaded,
                 cut_at_collision: bool = True):
    """Program for a PPO policy; params = (PolicyParams, stochastic (B,))."""
    from envs.wrappers import RMPInEnv

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
        rmp_env = RMPInEnv(base_env) if kind == "rmp_residual_env" else None

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


# --------------------------------------------------------------------------------------------
# Collection


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
        from agents.run.loading import policy_params

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


def _cut_metadata(cut_at_collision: bool) -> dict[str, Any]:
    """``{"cut_at_collision": False}`` for uncut data, nothing for the default."""
    return {} if cut_at_collision else {"cut_at_collision": False}


def _source_summary(ds: odata.Dataset, ep: Mapping[str, np.ndarray]) -> dict[str, Any]:
    _, s = odata.episode_statistics(ds)
    return {
        "episodes": s["num_episodes"],
        "transitions": s["num_transitions"],
        "return_mean": s["return_mean"],
        "return_std": s["return_std"],
        "length_mean": s["length_mean"],
        "terminals": s["num_terminals"],
        "timeouts": s["num_timeouts"],
        "safe_pct": 100.0 * float(np.mean(ep["safe"])),
        "success_pct": 100.0 * float(np.mean(ep["success"])),
        "nonfinite_episodes": int(np.sum(ep["nonfinite"] > 0)),
    }


def to_dataset(traj: Mapping[str, Any], metadata: Mapping[str, Any] | None = None
               ) -> odata.Dataset:
    """The :class:`offline.data.dataset.Dataset` of :func:`rollout` arrays (frozen steps dropped,
    collisions as terminals, episodes still running at the horizon as timeouts)."""
    return odata.from_transitions(traj["observations"], traj["actions"], traj["rewards"],
                                  traj["dones"], None,
                                  next_observations=traj["next_observations"],
                                  valid=traj["valid"], unfinished="timeout", metadata=metadata)


def collect(env_name: str, behaviour: Behaviour, num_episodes: int, *, seed: int = 0,
            key: jax.Array | None = None, env_kwargs: Mapping[str, Any] | None = None,
            horizon: int | None = None, batch_size: int | None = None,
            metadata: Mapping[str, Any] | None = None,
            progress: Callable[[str], None] | None = None,
            cut_at_collision: bool = True) -> odata.Dataset:
    """A :class:`offline.data.dataset.Dataset` of ``num_episodes`` episodes of ``behaviour`` on
    ``env_name`` (see the module docstring). ``key`` (default ``PRNGKey(seed)``) drives scenes
    and noise; ``metadata`` entries are added to the recorded ones. ``cut_at_collision=False``
    gives full-horizon episodes without collision terminals (no length bias, thesis §8.3.3;
    module docstring) and records ``metadata["cut_at_collision"] = False``."""
    if key is None:
        key = jax.random.PRNGKey(seed)
    traj = rollout(env_name, behaviour, num_episodes, key, env_kwargs=env_kwargs,
                   horizon=horizon, batch_size=batch_size, progress=progress,
                   cut_at_collision=cut_at_collision)
    meta = {**environment_metadata(env_name, env_kwargs, horizon), "seed": int(seed),
            "behaviour": behaviour.describe(), "num_episodes": int(num_episodes),
            **_cut_metadata(cut_at_collision)}
    ds = to_dataset(traj, meta)
    summary = _source_summary(ds, traj["episode"])
    return ds.replace(metadata=ds.metadata.updated(summary=summary, **dict(metadata or {})))


# --------------------------------------------------------------------------------------------
# Recipes


@dataclasses.dataclass(frozen=True)
class Source:
    """One part of a recipe: ``episodes`` episodes of ``behaviour`` in the role ``role``
    (``"random"``, ``"medium"``, ``"medium-replay"``, ``"expert"``, ``"noisy"``, ``"low"``);
    ``fallback`` marks a stand-in for missing PPO data."""

    role: str
    behaviour: Behaviour
    episodes: int
    fallback: bool = False


def _split(n: int, k: int) -> list[int]:
    return [n // k + (1 if i < n % k else 0) for i in range(k)]


def recipe_sources(recipe: str, scale: int, *, ppo_run: str | os.PathLike | None = None,
                   ppo_step: int | None = None, ppo_seed_index: int = 0,
                   ppo_stochastic: bool = True) -> tuple[list[Source], str | None]:
    """``(sources, fallback)`` of ``recipe`` with ``scale`` episodes per source (the table of
    the module docstring); ``fallback`` is a sentence saying what stands in for missing PPO
    data, or None. Sources with zero episodes are left out."""
    if recipe not in RECIPES:
        raise ValueError(f"unknown recipe={recipe!r}; valid recipes are {list(RECIPES)}")
    if not isinstance(scale, int | np.integer) or scale < 1:
        raise ValueError(f"scale must be a positive integer, got {scale!r}")
    n = int(scale)
    fallback = None
    if ppo_run is not None:
        from agents.run.loading import checkpoint_steps

        steps = checkpoint_steps(ppo_run)
        if not steps:
            raise FileNotFoundError(f"PPO run {os.fspath(ppo_run)!r} has no checkpoint")
        medium_step = steps[-1] if ppo_step is None else int(ppo_step)
        if medium_step not in steps:
            raise ValueError(f"ppo_step={ppo_step!r} is not a checkpoint of {ppo_run!r}; "
                             f"available steps are {steps}")
        run = os.fspath(ppo_run)
        medium = [Source("medium", ppo_policy(run, medium_step, seed_index=ppo_seed_index,
                                              stochastic=ppo_stochastic,
                                              name=f"ppo-medium-step{medium_step}"), n)]
        low = [Source("low", ppo_policy(run, steps[0], seed_index=ppo_seed_index,
                                        stochastic=ppo_stochastic,
                                        name=f"ppo-low-step{steps[0]}"), n)]
        replay_steps = [s for s in steps if s <= medium_step]
        replay = [Source("medium-replay",
                         ppo_policy(run, s, seed_index=ppo_seed_index, stochastic=True,
                                    name=f"ppo-replay-step{s}"), m)
                  for s, m in zip(replay_steps, _split(n, len(replay_steps)), strict=True)]
    else:
        medium = [Source("medium", noisy_expert(FALLBACK_MEDIUM_SIGMA), n, fallback=True)]
        low = []
        replay = [Source("medium-replay", b, m, fallback=True)
                  for b, m in zip((uniform_random(), noisy_expert(1.0),
                                   noisy_expert(FALLBACK_MEDIUM_SIGMA)), _split(n, 3),
                                  strict=True)]
    exp = [Source("expert", expert(), n)]
    rand = [Source("random", uniform_random(), n)]
    noisy = [Source("noisy", noisy_expert(s), n) for s in sorted(NOISE_LEVELS, reverse=True)]
    table = {
        "random": rand,
        "medium": medium,
        "medium-replay": replay,
        "medium-expert": medium + exp,
        "expert": exp,
        "mixed": rand + noisy + (low + medium + replay if ppo_run is not None else []),
    }
    sources = [s for s in table[recipe] if s.episodes > 0]
    if ppo_run is None and recipe in ("medium", "medium-replay", "medium-expert"):
        what = {"medium": f"'medium' is the expert with Gaussian action noise sigma="
                          f"{FALLBACK_MEDIUM_SIGMA}",
                "medium-expert": f"its 'medium' half is the expert with Gaussian action noise "
                                 f"sigma={FALLBACK_MEDIUM_SIGMA}",
                "medium-replay": "'medium-replay' is random -> noisy expert sigma=1.0 -> "
                                 f"sigma={FALLBACK_MEDIUM_SIGMA}"}[recipe]
        fallback = f"FALLBACK: no PPO run given, this dataset contains no PPO data; {what}"
    elif ppo_run is None and recipe == "mixed":
        fallback = ("FALLBACK: no PPO run given, 'mixed' has no PPO sources (random and the "
                    "noisy experts only)")
    return sources, fallback


def collect_recipe(env_name: str, recipe: str, scale: int, *, seed: int = 0,
                   ppo_run: str | os.PathLike | None = None, ppo_step: int | None = None,
                   ppo_seed_index: int = 0, ppo_stochastic: bool = True,
                   env_kwargs: Mapping[str, Any] | None = None, horizon: int | None = None,
                   batch_size: int | None = None,
                   progress: Callable[[str], None] | None = None,
                   cut_at_collision: bool = True) -> odata.Dataset:
    """The dataset of ``recipe`` (module docstring table) with ``scale`` episodes per source.

    Sources are concatenated in table order (episode ids ``0 … K−1``);
    ``metadata["sources"]`` lists each with its role, behaviour, episode count,
    ``episode_ids`` range ``[start, stop)`` and summary; ``metadata["fallback"]`` is None or the
    sentence saying what stands in for missing PPO data (also emitted as a ``UserWarning``).
    ``batch_size`` defaults to ``scale``; every source runs in chunks of exactly that many
    episodes (smaller sources are padded), so all scripted sources share one compiled program
    and all PPO checkpoints of the run another. ``cut_at_collision=False``: every source is
    collected without collision cuts (:func:`collect`).
    """
    sources, fallback = recipe_sources(recipe, scale, ppo_run=ppo_run, ppo_step=ppo_step,
                                       ppo_seed_index=ppo_seed_index,
                                       ppo_stochastic=ppo_stochastic)
    if fallback is not None:
        warnings.warn(fallback, UserWarning, stacklevel=2)
    batch = int(scale if batch_size is None else batch_size)
    parts, described, start = [], [], 0
    for src in sources:
        if progress is not None:
            progress(f"[{recipe}] source {src.behaviour.name} ({src.role}): "
                     f"{src.episodes} episodes")
        ds = collect(env_name, src.behaviour, src.episodes,
                     key=source_key(seed, src.role, src.behaviour.name), seed=seed,
                     env_kwargs=env_kwargs, horizon=horizon, batch_size=batch,
                     progress=progress, cut_at_collision=cut_at_collision)
        parts.append(ds)
        described.append({"role": src.role, "behaviour": src.behaviour.describe(),
                          "episodes": src.episodes, "fallback": src.fallback,
                          "episode_ids": [start, start + src.episodes],
                          "summary": ds.metadata["summary"]})
        start += src.episodes
    meta = {**environment_metadata(env_name, env_kwargs, horizon), "seed": int(seed),
            "recipe": recipe, "scale": int(scale), "num_episodes": start,
            "ppo_run": None if ppo_run is None else os.fspath(ppo_run),
            "fallback": fallback, "sources": described, **_cut_metadata(cut_at_collision)}
    ds = odata.concatenate(*parts, metadata=meta)
    _, summary = odata.episode_statistics(ds)
    return ds.replace(metadata=ds.metadata.updated(summary=summary))


def source_of_episodes(dataset: odata.Dataset) -> np.ndarray:
    """Per-transition index into ``metadata["sources"]`` of a recipe dataset (host-side)."""
    ids = np.asarray(dataset.episode_ids)
    out = np.full(ids.shape, -1, np.int64)
    for i, s in enumerate(dataset.metadata["sources"]):
        lo, hi = s["episode_ids"]
        out[(ids >= lo) & (ids < hi)] = i
    return out


__all__ = [
    "ACTION_NOTE",
    "BEHAVIOUR_KINDS",
    "FALLBACK_MEDIUM_SIGMA",
    "NOISE_LEVELS",
    "RECIPES",
    "Behaviour",
    "Source",
    "clear_caches",
    "collect",
    "collect_recipe",
    "environment_metadata",
    "expert",
    "make_env",
    "noisy_expert",
    "ppo_policy",
    "recipe_sources",
    "rollout",
    "source_key",
    "source_of_episodes",
    "to_dataset",
    "uniform_random",
]
