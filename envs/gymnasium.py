"""Gymnasium 1.x interfaces to the MJX environments (docs/design.md §2.2).

* :func:`make_vec` — a ``gymnasium.vector.VectorEnv`` of ``num_envs`` copies of a registered
  environment (:func:`envs.make`), stepped together by one jitted, vmapped function;
* :func:`make` — the single-environment ``gymnasium.Env`` (passes
  ``gymnasium.utils.env_checker.check_env``);
* :func:`register_gymnasium` (run on import) — the ids ``mjxrmp/<brax name>-v0``
  (``mjxrmp/three_link_env3-v0``, …, ``mjxrmp/franka_reach-v0``) for ``gymnasium.make`` and
  ``gymnasium.make_vec``.

Conventions (Gymnasium 1.x):

* spaces: ``single_observation_space`` is ``Box(−inf, inf, (observation_size,), float32)``,
  ``single_action_space`` ``Box(±action_limit, (action_size,), float32)`` (the environment clips
  actions to that limit, docs/design.md §4.3; the raw residual of ``rmp_in_env=True`` is
  unbounded); ``observation_space``/``action_space`` are their ``batch_space``;
* ``terminated`` is the environment's ``done`` (collision or a non-finite state); ``truncated``
  is the episode limit ``env.horizon`` (600 control steps unless ``horizon=`` is given), set when
  the episode's step count reaches it, as Gymnasium's ``TimeLimit`` does;
* auto-reset ``AutoresetMode.NEXT_STEP`` (``metadata["autoreset_mode"]``): the step after a
  sub-environment's ``terminated or truncated`` ignores its action and returns the first
  observation of a new episode (a freshly sampled scene), reward 0, ``terminated`` and
  ``truncated`` False and the reset's infos;
* infos: a dict of ``(num_envs,)`` arrays ``goal_distance``, ``success``, ``collision``,
  ``nonfinite`` (the step's metrics, docs/design.md §2.2) with the boolean masks ``_goal_distance``
  … that Gymnasium's vector infos carry (all True: every sub-environment reports every key at
  every step); the single environment returns the same keys as Python floats;
* rewards are float64 arrays (as Gymnasium's ``SyncVectorEnv``), observations float32;
* seeding: ``reset(seed=s)`` seeds the environment's ``np_random`` and the JAX key of every
  sub-environment's episode is drawn from it, so ``reset(seed=s)`` is reproducible and
  ``reset()`` continues the sequence; ``make_vec(seed=...)`` seeds the first ``reset()``;
  ``options`` of ``reset`` are accepted and not used.

The batched step, auto-reset bookkeeping included, is one compiled function; a step moves the
actions to the device and its results back in one transfer each.
"""

from __future__ import annotations

from typing import Any, ClassVar, NamedTuple

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from brax.envs.base import State
from gymnasium.utils import seeding
from gymnasium.vector.utils import batch_space

from envs.registry import BRAX_NAMES
from envs.registry import make as make_brax
from envs.wrappers import RMPInEnv, where_done
from mjxrmp.config import check_int

#: Per-step metrics returned as infos.
INFO_KEYS = ("goal_distance", "success", "collision", "nonfinite")

__all__ = ["INFO_KEYS", "MJXEnv", "MJXVectorEnv", "gymnasium_id", "make", "make_vec",
           "register_gymnasium"]


class _Carry(NamedTuple):
    """Device state between steps: the batched brax state, each episode's step count and the
    sub-environments to restart at the next step."""

    state: State
    steps: jax.Array
    autoreset: jax.Array


class _Batched:
    """A brax environment from :func:`envs.make` reset and stepped over a batch by jitted,
    vmapped functions, with the episode limit as truncation and (``autoreset``) the
    ``NEXT_STEP`` restart of finished episodes (module docstring)."""

    def __init__(self, name: str, env_kwargs: dict[str, Any], autoreset: bool):
        self.env = make_brax(name, **env_kwargs)
        self.horizon = int(self.env.unwrapped.horizon)
        self.autoreset = autoreset
        self.action_shape = (self.env.action_size,)
        limit = np.inf if isinstance(self.env, RMPInEnv) else self.env.unwrapped.action_limit
        self.observation_space = gymnasium.spaces.Box(
            -np.inf, np.inf, (self.env.observation_size,), np.float32)
        self.action_space = gymnasium.spaces.Box(-limit, limit, self.action_shape, np.float32)
        self._template = jax.eval_shape(self.env.reset, jax.random.PRNGKey(0))
        self.step = jax.jit(self._step)

    @staticmethod
    def _info(state: State) -> dict[str, jax.Array]:
        return {k: state.metrics[k] for k in INFO_KEYS}

    def reset(self, keys: jax.Array) -> tuple[_Carry, tuple]:
        """New episodes from ``keys (B, 2)`` through the auto-reset path of :meth:`step` (one
        compiled function): a zero placeholder state holding ``keys`` and marked for restart is
        stepped, so the result is each reset's observation, reward 0, not done, and its infos."""
        b = keys.shape[0]
        state = jax.tree.map(lambda s: np.zeros((b, *s.shape), s.dtype), self._template)
        state = state.replace(info={**state.info, "rng": keys})
        carry = _Carry(state, np.zeros((b,), np.int32), np.ones((b,), bool))
        return self.step(carry, np.zeros((b, *self.action_shape), np.float32))

    def _step(self, carry: _Carry, actions: jax.Array) -> tuple[_Carry, tuple]:
        stepped = jax.vmap(self.env.step)(carry.state, actions)
        restart = carry.autoreset
        fresh = jax.lax.cond(jnp.any(restart),
                             lambda s: jax.vmap(self.env.reset)(s.info["rng"]),
                             lambda s: s, carry.state)
        state = where_done(restart, fresh, stepped)
        steps = jnp.where(restart, 0, carry.steps + 1)
        terminated = (stepped.done > 0) & ~restart
        truncated = (steps >= self.horizon) & ~restart
        reward = jnp.where(restart, 0.0, stepped.reward)
        finished = (terminated | truncated) & self.autoreset
        return (_Carry(state, steps, finished),
                (state.obs, reward, terminated, truncated, self._info(state)))

    def actions(self, actions: Any, shape: tuple[int, ...]) -> jax.Array:
        """``actions`` as a float32 device array, refused unless its shape is ``shape``."""
        try:
            a = np.asarray(actions, dtype=np.float32)
        except (TypeError, ValueError) as e:
            raise ValueError(f"actions must be a float array of shape {shape}: {e}") from None
        if a.shape != shape:
            raise ValueError(f"actions must have shape {shape}, got {a.shape}")
        return jnp.asarray(a)


def _keys(rng: np.random.Generator, n: int) -> jax.Array:
    """``n`` JAX keys drawn from a Gymnasium ``np_random``."""
    return jax.random.split(jax.random.PRNGKey(int(rng.integers(2**31))), n)


def _not_started(carry: _Carry | None) -> None:
    if carry is None:
        raise RuntimeError("call reset() before step()")


class MJXVectorEnv(gymnasium.vector.VectorEnv):
    """``num_envs`` copies of an MJX environment as a Gymnasium vector environment with
    ``NEXT_STEP`` auto-reset (module docstring; build it with :func:`make_vec`)."""

    metadata: ClassVar[dict[str, Any]] = {
        "autoreset_mode": gymnasium.vector.AutoresetMode.NEXT_STEP, "render_modes": []}

    def __init__(self, name: str, num_envs: int, seed: int = 0, **env_kwargs):
        self.num_envs = check_int(num_envs, "num_envs")
        self._core = _Batched(name, env_kwargs, autoreset=True)
        self.horizon = self._core.horizon  # the episode limit (truncation)
        self.single_observation_space = self._core.observation_space
        self.single_action_space = self._core.action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._np_random, self._np_random_seed = seeding.np_random(seed)
        self._carry: _Carry | None = None

    def _infos(self, info: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        masks = {f"_{k}": np.ones(self.num_envs, bool) for k in info}
        return {**info, **masks}

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Start a new episode in every sub-environment: ``(observations, infos)``."""
        super().reset(seed=seed, options=options)
        self._carry, out = self._core.reset(_keys(self.np_random, self.num_envs))
        obs, *_, info = jax.device_get(out)
        return obs, self._infos(info)

    def step(self, actions: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                          dict[str, np.ndarray]]:
        """One control step of every sub-environment: ``(observations, rewards, terminations,
        truncations, infos)``; finished sub-environments restart at the next step."""
        _not_started(self._carry)
        a = self._core.actions(actions, (self.num_envs, *self._core.action_shape))
        self._carry, out = self._core.step(self._carry, a)
        obs, reward, terminated, truncated, info = jax.device_get(out)
        return obs, reward.astype(np.float64), terminated, truncated, self._infos(info)

    def close_extras(self, **kwargs) -> None:
        """Drop the device state."""
        self._carry = None


class MJXEnv(gymnasium.Env):
    """One MJX environment as a ``gymnasium.Env`` (module docstring; build it with :func:`make`):
    no auto-reset, call ``reset`` after ``terminated or truncated``."""

    metadata: ClassVar[dict[str, Any]] = {"render_modes": []}

    def __init__(self, name: str, **env_kwargs):
        self._core = _Batched(name, env_kwargs, autoreset=False)
        self.horizon = self._core.horizon  # the episode limit (truncation)
        self.observation_space = self._core.observation_space
        self.action_space = self._core.action_space
        self._carry: _Carry | None = None

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, float]]:
        """Start a new episode: ``(observation, info)``."""
        super().reset(seed=seed, options=options)
        self._carry, out = self._core.reset(_keys(self.np_random, 1))
        obs, *_, info = jax.device_get(out)
        return obs[0], {k: float(v[0]) for k, v in info.items()}

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, float]]:
        """One control step: ``(observation, reward, terminated, truncated, info)``."""
        _not_started(self._carry)
        a = self._core.actions(action, self._core.action_shape)
        self._carry, out = self._core.step(self._carry, a[None])
        obs, reward, terminated, truncated, info = jax.device_get(out)
        return (obs[0], float(reward[0]), bool(terminated[0]), bool(truncated[0]),
                {k: float(v[0]) for k, v in info.items()})

    def close(self) -> None:
        """Drop the device state."""
        self._carry = None


def make_vec(name: str, num_envs: int, seed: int = 0, **env_kwargs) -> MJXVectorEnv:
    """A Gymnasium vector environment of ``num_envs`` copies of ``envs.make(name,
    **env_kwargs)`` with ``NEXT_STEP`` auto-reset (module docstring, docs/design.md §2.2)."""
    return MJXVectorEnv(name, num_envs, seed, **env_kwargs)


def make(name: str, **env_kwargs) -> MJXEnv:
    """``envs.make(name, **env_kwargs)`` as a single ``gymnasium.Env`` (module docstring,
    docs/design.md §2.2)."""
    return MJXEnv(name, **env_kwargs)


def gymnasium_id(brax_name: str) -> str:
    """The Gymnasium id ``mjxrmp/<brax name>-v0`` of an environment (``envs.BRAX_NAMES``)."""
    return f"mjxrmp/{brax_name}-v0"


def register_gymnasium() -> None:
    """Register every environment with Gymnasium's registry (idempotent; done on import), so
    that ``gymnasium.make("mjxrmp/three_link_env3-v0", **env_kwargs)`` builds :func:`make` and
    ``gymnasium.make_vec("mjxrmp/three_link_env3-v0", num_envs, **env_kwargs)`` builds
    :func:`make_vec` (its ``vector_entry_point``); no ``TimeLimit`` is added: the environments
    truncate at their ``horizon`` themselves."""
    for brax_name, name in BRAX_NAMES.items():
        env_id = gymnasium_id(brax_name)
        if env_id not in gymnasium.registry:
            gymnasium.register(env_id, entry_point=make, vector_entry_point=make_vec,
                               kwargs={"name": name})


register_gymnasium()
