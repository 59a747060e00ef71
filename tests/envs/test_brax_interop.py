"""brax's own wrappers and PPO trainer on ``three_link/env3`` (issue case 8; docs/design.md §5.3).

* brax's ``EvalWrapper`` over brax's training ``wrap`` runs and reports finite episode metrics,
  ``reward`` included, that agree with the environment's own accumulators;
* brax's ``AutoResetWrapper``: the state an episode restarts from is the cached first reset
  state (virtual velocity included), the accumulators restart, and the second episode repeats
  the first bit for bit under a deterministic policy;
* brax's PPO (``brax.training.agents.ppo.train``) trains for a tiny budget through
  :func:`agents.brax_compat.train_with_brax_ppo` on current JAX.

Batches, episodes and networks are tiny; each compiled function is built once.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.envs.wrappers import training as brax_training
from brax.training.agents.ppo import networks as brax_ppo_networks

import envs
from agents.brax_compat import train_with_brax_ppo
from envs import evaluate

ENV = envs.make("three_link/env3")
POLICY = jax.vmap(evaluate.hand_designed_policy(ENV))
BATCH, EPISODE = 2, 4
ACCUMULATORS = ("episode_return", "episode_length", "episode_collided", "episode_nonfinite")


@pytest.fixture(scope="module")
def brax_unroll():
    """``(first state, stacked states after each of EPISODE + 2 steps)`` of the hand-designed
    policy (deterministic) under brax's ``EvalWrapper(wrap(env))`` (vmap, episode limit,
    brax's auto-reset)."""
    env = brax_training.EvalWrapper(brax_training.wrap(ENV, episode_length=EPISODE))

    def run(key):
        state = env.reset(jax.random.split(key, BATCH))

        def body(s, _):
            s = env.step(s, POLICY(s))
            return s, s

        return state, jax.lax.scan(body, state, None, length=EPISODE + 2)[1]

    return jax.device_get(jax.jit(run)(jax.random.PRNGKey(1)))


def _at(tree, i):
    return jax.tree.map(lambda x: x[i], tree)


def _assert_same(a, b, what):
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_array_equal(x, y, err_msg=what)


def test_brax_eval_wrapper_reports_finite_episode_metrics(brax_unroll):
    first, states = brax_unroll
    last = _at(states, EPISODE - 1)
    ev = last.info["eval_metrics"]
    assert set(ev.episode_metrics) == set(first.metrics) and "reward" in first.metrics
    for name, value in ev.episode_metrics.items():
        assert np.all(np.isfinite(np.asarray(value))), name
    assert np.all(np.asarray(ev.active_episodes) == 0)  # every episode ended by the limit
    np.testing.assert_array_equal(ev.episode_steps, EPISODE)
    # brax's sum of rewards equals the environment's own accumulator of the finished episode.
    np.testing.assert_allclose(ev.episode_metrics["reward"], last.info["episode_return"],
                               rtol=1e-6)


def test_brax_auto_reset_restarts_from_the_first_state_with_fresh_accumulators(brax_unroll):
    first, states = brax_unroll
    assert np.all(np.asarray(states.done[EPISODE - 1]) == 1)
    restarted = _at(states, EPISODE - 1)  # brax swapped in the cached first reset state
    _assert_same(restarted.pipeline_state, first.pipeline_state, "pipeline_state")
    np.testing.assert_array_equal(restarted.obs, first.obs)
    np.testing.assert_array_equal(ENV.virtual_velocity(restarted), ENV.virtual_velocity(first))
    np.testing.assert_array_equal(restarted.info["episode_length"], EPISODE)  # not restarted yet
    # The next episode repeats the first one: same state, reward, metrics and accumulators.
    for k in (0, 1):
        one, again = _at(states, k), _at(states, EPISODE + k)
        _assert_same(one.pipeline_state, again.pipeline_state, f"pipeline_state, step {k}")
        np.testing.assert_array_equal(one.obs, again.obs)
        np.testing.assert_array_equal(one.reward, again.reward)
        _assert_same({n: one.info[n] for n in ACCUMULATORS},
                     {n: again.info[n] for n in ACCUMULATORS}, f"accumulators, step {k}")
        _assert_same(one.metrics, again.metrics, f"metrics, step {k}")
    np.testing.assert_array_equal(states.info["episode_length"][EPISODE], 1.0)


@pytest.fixture(scope="module")
def brax_ppo_run():
    progress = []
    network_factory = functools.partial(
        brax_ppo_networks.make_ppo_networks, policy_hidden_layer_sizes=(8,),
        value_hidden_layer_sizes=(8,))
    out = train_with_brax_ppo(
        "three_link/env3", num_timesteps=640, num_envs=4, episode_length=16, unroll_length=5,
        batch_size=4, num_minibatches=2, num_updates_per_batch=1, num_evals=1, num_eval_envs=4,
        network_factory=network_factory, seed=0,
        progress_fn=lambda step, metrics: progress.append((step, metrics)))
    return out, progress


def test_brax_ppo_trains_through_the_helper(brax_ppo_run):
    (make_policy, params, metrics), progress = brax_ppo_run
    assert len(progress) == 1 and progress[0][0] >= 640  # one evaluation, after training
    assert all(np.all(np.isfinite(np.asarray(x))) for x in jax.tree.leaves(params))
    for name in ("eval/episode_reward", "eval/episode_goal_distance"):
        assert np.isfinite(float(metrics[name])), name
    obs = jnp.zeros((ENV.observation_size,), jnp.float32)
    action, _ = make_policy(params, deterministic=True)(obs, jax.random.PRNGKey(3))
    assert action.shape == (ENV.action_size,) and bool(jnp.all(jnp.isfinite(action)))
    assert not hasattr(jax, "device_put_replicated")  # the stand-in was removed again
