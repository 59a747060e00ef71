"""Policy evaluation inside the compiled graph for the offline learners (thesis §7.4, §8.4;
docs/design.md §2.4).

:func:`make_evaluator` builds an :class:`Evaluator` for one reaching environment
(:func:`envs.make` name) and a number of episodes. ``evaluator.evaluate(act, params, key)``
rolls out the deterministic policy ``act(params, obs)`` (a learner's
:attr:`offline.learners.base.Trainer.act`, actions in environment units) for ``num_episodes``
vmapped episodes with :func:`envs.evaluate.make_rollout` (no auto-reset: each episode is frozen
once it ends, so returns are exact) and returns scalars:

* ``mean_return`` ``J`` — mean undiscounted return;
* ``normalized_score`` — ``100·(J − J_random)/(J_expert − J_random)``, the D4RL-style score the
  thesis reports (Tables 7.3, Figs 8.4 and 8.7; docs/design.md §4.5: "expert 100, random 0"), with
  ``J_random`` the return of uniformly random actions in the action box and ``J_expert`` that of
  the hand-designed RMP² expert (:func:`envs.evaluate.hand_designed_policy`);
* ``safe_pct`` (episodes without collision or non-finite state), ``success_pct`` (safe and the
  goal within the environment's success radius at the end), ``mean_final_goal_distance``,
  ``mean_length``.

``evaluate`` is jittable and vmappable over ``params`` (seeds) and ``key``:
``jax.vmap(lambda p: ev.evaluate(act, p, key))(stacked_params)`` evaluates every seed's policy
on the same episodes in one program. One compiled program per ``act`` is cached on the
evaluator, and :func:`make_evaluator` returns the evaluator it built before for the same
arguments (the same reference returns and compiled programs; results are unchanged).

**Reference returns.** ``J_expert`` and ``J_random`` are computed once, when the evaluator is
built, on ``reference_episodes`` (default 256) episodes drawn with the fixed key
``PRNGKey(reference_seed)``; both policies see the same scenes. They are exposed as
``evaluator.reference`` (a dict of floats, also holding their safe and success percentages).
The expert and the random policy share one compiled program (the random actions of step ``t``
come from ``fold_in(state.info["rng"], t)``, the per-episode key the environment keeps);
:meth:`Evaluator.evaluate_baseline` runs it on other keys. A normalised score is therefore 100
for the expert and 0 for the random policy on the reference episodes, and close to those (up to
sampling noise) on others.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from envs.evaluate import hand_designed_policy, make_rollout
from envs.reaching import ReachEnv
from mjxrmp.config import check_int
from offline.data.rollouts import make_env

#: Default number of episodes of the reference returns.
REFERENCE_EPISODES = 256
#: Baselines that define the normalised score.
BASELINES = ("expert", "random")
#: The evaluators :func:`make_evaluator` built in this process, by their arguments.
_EVALUATORS: dict[tuple, Evaluator] = {}


def normalized_score(returns: Any, expert_return: float, random_return: float) -> Any:
    """``100·(J − J_random)/(J_expert − J_random)`` (expert 100, random 0; thesis §7.4 and
    §8.4, D4RL normalisation); works on floats and arrays, inside traced code too."""
    return 100.0 * (returns - random_return) / (expert_return - random_return)


def uniform_random_policy(env: ReachEnv) -> Callable[[Any], jax.Array]:
    """``policy(state)``: i.i.d. ``U[−action_limit, action_limit]`` actions; step ``t``'s key is
    ``fold_in(state.info["rng"], t)`` (the per-episode key :meth:`ReachEnv.reset` stores)."""
    lim, size = env.action_limit, env.action_size

    def policy(state):
        t = state.info["episode_length"].astype(jnp.int32)
        k = jax.random.fold_in(state.info["rng"], t)
        return jax.random.uniform(k, (size,), jnp.float32, -lim, lim)

    return policy


def _summary(per_episode: Mapping[str, jax.Array],
             reference: Mapping[str, float]) -> dict[str, jax.Array]:
    """Episode means of :func:`envs.evaluate.make_rollout`'s output (in the graph), with the
    normalised score once ``reference`` holds both reference returns."""
    j = jnp.mean(per_episode["return"])
    out = {
        "mean_return": j,
        "safe_pct": 100.0 * jnp.mean(per_episode["safe"]),
        "success_pct": 100.0 * jnp.mean(per_episode["success"]),
        "mean_final_goal_distance": jnp.mean(per_episode["final_goal_distance"]),
        "mean_length": jnp.mean(per_episode["length"]),
    }
    if "expert_return" in reference and "random_return" in reference:
        out["normalized_score"] = normalized_score(j, reference["expert_return"],
                                                   reference["random_return"])
    return out


@dataclasses.dataclass(frozen=True, eq=False)
class Evaluator:
    """Built by :func:`make_evaluator` (see the module docstring)."""

    env_name: str
    env: ReachEnv
    num_episodes: int
    horizon: int
    reference_episodes: int
    reference_seed: int
    reference: dict[str, float] = dataclasses.field(default_factory=dict)
    _programs: dict = dataclasses.field(default_factory=dict, repr=False)

    def _baseline_program(self) -> Callable:
        """``program(is_random, key) -> per-episode dict`` for the expert (``is_random``
        False) or the uniform random policy (True) on ``reference_episodes`` episodes."""
        if "baselines" not in self._programs:
            env, n, horizon = self.env, self.reference_episodes, self.horizon
            expert, rand = hand_designed_policy(env), uniform_random_policy(env)

            @jax.jit
            def program(is_random, key):
                def policy(state):
                    return jnp.where(is_random, rand(state), expert(state))

                return make_rollout(env, n, horizon, policy)(key)

            self._programs["baselines"] = program
        return self._programs["baselines"]

    def _act_program(self, act: Callable) -> Callable:
        """Cached ``program(params, key) -> summary`` for the learner policy ``act``."""
        if act not in self._programs:
            env, n, horizon = self.env, self.num_episodes, self.horizon

            @jax.jit
            def program(params, key):
                def policy(state):
                    return act(params, state.obs)

                per_episode = make_rollout(env, n, horizon, policy)(key)
                return _summary(per_episode, self.reference)

            self._programs[act] = program
        return self._programs[act]

    def evaluate(self, act: Callable[[Any, jax.Array], jax.Array], params: Any,
                 key: jax.Array) -> dict[str, jax.Array]:
        """Scalars of ``num_episodes`` episodes of ``act(params, obs)`` (module docstring):
        ``mean_return``, ``normalized_score``, ``safe_pct``, ``success_pct``,
        ``mean_final_goal_distance``, ``mean_length``. Jittable, vmappable over ``params``."""
        if not callable(act):
            raise ValueError(f"act must be a callable act(params, obs), got {type(act).__name__}")
        return self._act_program(act)(params, key)

    def evaluate_baseline(self, name: str, key: jax.Array) -> dict[str, jax.Array]:
        """The summary of :meth:`evaluate` for the ``"expert"`` or ``"random"`` policy on
        ``reference_episodes`` episodes drawn with ``key`` (the reference program)."""
        if name not in BASELINES:
            raise ValueError(f"unknown baseline name={name!r}; valid names are {list(BASELINES)}")
        per_episode = self._baseline_program()(name == "random", key)
        return _summary(per_episode, self.reference)

    def normalized_score(self, returns: Any) -> Any:
        """:func:`normalized_score` with this evaluator's reference returns."""
        return normalized_score(returns, self.reference["expert_return"],
                                self.reference["random_return"])


def make_evaluator(env_name: str, num_episodes: int, *, horizon: int | None = None,
                   env_kwargs: Mapping[str, Any] | None = None,
                   reference_episodes: int = REFERENCE_EPISODES,
                   reference_seed: int = 0) -> Evaluator:
    """An :class:`Evaluator` of ``num_episodes`` episodes on environment ``env_name`` (built by
    :func:`envs.make` with ``env_kwargs``; unknown names raise ``ValueError`` listing the valid
    ones), ``horizon`` control steps per episode (default: the environment's, 600).

    Computes the reference returns (thesis §7.4 normalisation; module docstring) on
    ``reference_episodes`` episodes with key ``PRNGKey(reference_seed)``; raises
    ``ValueError`` if the expert does not beat the random policy there (e.g. a horizon too
    short for the expert to reach the goal), where the normalised score is meaningless.
    """
    num_episodes = check_int(num_episodes, "num_episodes")
    reference_episodes = check_int(reference_episodes, "reference_episodes")
    if isinstance(reference_seed, bool) or not isinstance(reference_seed, int | np.integer):
        raise ValueError(f"reference_seed must be an integer, got {reference_seed!r}")
    if env_kwargs is not None and not isinstance(env_kwargs, Mapping):
        raise ValueError(f"env_kwargs must be a mapping or None, got {type(env_kwargs).__name__}")
    if horizon is not None:
        horizon = check_int(horizon, "horizon")
    args = (env_name, num_episodes, horizon, env_kwargs, reference_episodes, int(reference_seed))
    key = (*args[:3], _kwargs_key(env_kwargs), *args[4:])
    try:
        hash(key)
    except TypeError:  # an unhashable environment argument: built, not cached
        return _build_evaluator(*args)
    if key not in _EVALUATORS:
        _EVALUATORS[key] = _build_evaluator(*args)
    return _EVALUATORS[key]


def _kwargs_key(env_kwargs: Mapping[str, Any] | None) -> tuple | None:
    """``env_kwargs`` as a tuple of items (a cache key; unhashable values make it unhashable)."""
    return None if env_kwargs is None else tuple(sorted(env_kwargs.items()))


def _build_evaluator(env_name: str, num_episodes: int, horizon: int | None,
                     env_kwargs: Mapping[str, Any] | None, reference_episodes: int,
                     reference_seed: int) -> Evaluator:
    """The :class:`Evaluator` of :func:`make_evaluator` with its reference returns (checked
    arguments; not cached)."""
    env = make_env(env_name, env_kwargs)
    if not isinstance(env, ReachEnv):
        raise ValueError(f"env_name={env_name!r} is not a reaching environment with a "
                         f"hand-designed expert (envs.reaching.ReachEnv); the normalised score "
                         f"needs one")
    horizon = env.horizon if horizon is None else horizon
    ev = Evaluator(env_name, env, num_episodes, horizon, reference_episodes, reference_seed)
    key = jax.random.PRNGKey(reference_seed)
    for name in BASELINES:
        s = ev.evaluate_baseline(name, key)
        ev.reference.update({f"{name}_return": float(s["mean_return"]),
                             f"{name}_safe_pct": float(s["safe_pct"]),
                             f"{name}_success_pct": float(s["success_pct"])})
    ev.reference.update(episodes=reference_episodes, seed=reference_seed)
    if not ev.reference["expert_return"] > ev.reference["random_return"]:
        raise ValueError(f"the expert's mean return {ev.reference['expert_return']:.4g} does not "
                         f"exceed the random policy's {ev.reference['random_return']:.4g} on "
                         f"{env_name!r} with horizon={horizon}; the normalised score is "
                         f"undefined (use a longer horizon)")
    return ev


__all__ = [
    "BASELINES",
    "REFERENCE_EPISODES",
    "Evaluator",
    "make_evaluator",
    "normalized_score",
    "uniform_random_policy",
]
