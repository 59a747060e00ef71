"""Scene parameters as data (envs.reaching.ReachEnv.default_scene): a setup is its scene
sampler's parameters, so environments that share a model (the three_link setups; env1 has
three obstacle slots, one active) run in one program, each environment with its own scene,
through resets and automatic resets."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import envs
from envs.evaluate import frozen_step, hand_designed_policy
from envs.three_link import ThreeLinkReach
from envs.wrappers import wrap


@pytest.fixture(scope="module")
def setups():
    return {name: envs.make(f"three_link/{name}") for name in ("env1", "env2", "env3")}


def _equal(a, b) -> None:
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_a_reset_of_another_setups_scene_is_that_setups_reset(setups):
    """env2 given env3's scene parameters samples exactly env3's episodes (same keys)."""
    keys = jax.random.split(jax.random.PRNGKey(7), 16)
    env2, env3 = setups["env2"], setups["env3"]
    ours = jax.jit(jax.vmap(lambda k: env2.reset(k, env3.default_scene())))(keys)
    theirs = jax.jit(jax.vmap(env3.reset))(keys)
    _equal(ours, theirs)
    # and the scenes really differ: env2's own goals lie in a narrower annulus
    own = jax.jit(jax.vmap(env2.reset))(keys)
    assert not np.array_equal(np.asarray(own.info["goal"]), np.asarray(theirs.info["goal"]))


def test_which_setups_share_a_model(setups):
    assert setups["env2"].shares_model(setups["env3"])
    assert setups["env1"].shares_model(setups["env2"])  # one obstacle active of three slots
    assert not envs.make("three_link/env1", num_obstacles=1).shares_model(setups["env1"])
    assert not setups["env3"].shares_model(ThreeLinkReach("env3", obstacle_sampler="original"))
    assert not setups["env3"].shares_model(envs.make("franka"))
    assert envs.make("franka").shares_model(envs.make("franka"))


def test_padded_env1_runs_the_unpadded_episodes(setups):
    """env1's two inactive obstacle slots change nothing the robot meets: from the same keys the
    padded and the thesis's unpadded env1 (``num_obstacles=1``) sample the same goal and
    obstacle, and the hand-designed policy drives the same joint trajectory (20 control steps
    × 4 environments, to float rounding) with the same rewards."""
    keys = jax.random.split(jax.random.PRNGKey(3), 4)

    def run(env):
        step = jax.vmap(frozen_step(env, hand_designed_policy(env)))

        def body(s, _):
            s = step(s)
            return s, (s.pipeline_state.qpos, s.reward)

        first = jax.vmap(env.reset)(keys)
        return first, jax.lax.scan(lambda s, x: body(s, x), first, None, length=20)[1]

    padded, unpadded = setups["env1"], envs.make("three_link/env1", num_obstacles=1)
    p0, (pq, pr) = jax.jit(lambda: run(padded))()
    u0, (uq, ur) = jax.jit(lambda: run(unpadded))()
    _equal(p0.info["goal"], u0.info["goal"])
    _equal(p0.info["obstacles"].center[:, :1], u0.info["obstacles"].center)
    assert np.all(np.asarray(p0.info["obstacles"].active) == [1.0, 0.0, 0.0])
    np.testing.assert_allclose(np.asarray(pq), np.asarray(uq), rtol=0, atol=1e-5)
    np.testing.assert_allclose(np.asarray(pr), np.asarray(ur), rtol=1e-5, atol=1e-6)


@settings(max_examples=15, deadline=None)
@given(r_min=st.floats(0.1, 0.4), width=st.floats(0.05, 0.3), centre=st.floats(0.0, 6.28),
       spread=st.floats(0.1, 3.14), radius=st.floats(0.03, 0.08), seed=st.integers(0, 2**30),
       count=st.integers(0, 3))
def test_episodes_are_sampled_from_the_given_scene(setups, r_min, width, centre, spread,
                                                   radius, seed, count):
    """Property: goals lie in the scene's annular sector, obstacle radii in its range and
    obstacle centres in its annulus, the first ``obstacle_count`` slots active, for any scene
    parameters."""
    env = setups["env3"]
    scene = {"goal_region": jnp.asarray([r_min, r_min + width, centre, spread], jnp.float32),
             "obstacle_region": jnp.asarray([0.5, 0.8], jnp.float32),
             "obstacle_radius": jnp.asarray([radius, radius + 0.02], jnp.float32),
             "obstacle_count": jnp.asarray(count, jnp.float32)}
    state = _reset_many(env, jax.random.split(jax.random.PRNGKey(seed), 8), scene)
    goal = np.asarray(state.info["goal"], np.float64)
    r = np.linalg.norm(goal, axis=-1)
    assert np.all((r >= r_min - 1e-5) & (r <= r_min + width + 1e-5))
    off = np.abs((np.arctan2(goal[:, 1], goal[:, 0]) - centre + math.pi) % (2 * math.pi)
                 - math.pi)
    assert np.all(off <= spread / 2 + 1e-4)
    obstacles = state.info["obstacles"]
    np.testing.assert_array_equal(np.asarray(obstacles.active), np.tile(np.arange(3) < count,
                                                                        (8, 1)))
    rad = np.asarray(obstacles.radius)
    assert np.all((rad >= radius - 1e-6) & (rad <= radius + 0.02 + 1e-6))
    rc = np.linalg.norm(np.asarray(obstacles.center, np.float64)[..., :2], axis=-1)
    assert np.all((rc >= 0.5 - 1e-5) & (rc <= 0.8 + 1e-5))
    _equal(state.info["scene"], jax.tree.map(lambda x: jnp.broadcast_to(x, (8, *x.shape)), scene))


_reset_many = jax.jit(lambda env, keys, scene: jax.vmap(env.reset, in_axes=(0, None))(
    keys, scene), static_argnums=0)


def _mixed_batch(setups, batch: int = 6):
    """env2's wrapper over a batch whose first half samples env2's scene, the second env3's."""
    w = wrap(setups["env2"], 20)
    scenes = [setups["env2"].default_scene()] * (batch // 2) + [
        setups["env3"].default_scene()] * (batch - batch // 2)
    scene = jax.tree.map(lambda *xs: jnp.stack(xs), *scenes)
    keys = jax.random.split(jax.random.PRNGKey(11), batch)
    return w, jax.jit(w.reset)(keys, scene), keys


def test_every_environment_keeps_its_scene_through_automatic_resets(setups):
    """A mixed batch: each half's first episodes equal its setup's own, and after 100 steps
    (episodes of 20 steps) every environment's goals stayed in its setup's region."""
    w, state, keys = _mixed_batch(setups)
    _equal(state.pipeline_state, jax.tree.map(lambda a, b: jnp.concatenate([a[:3], b[3:]]),
                                              jax.jit(wrap(setups["env2"], 20).reset)(keys),
                                              jax.jit(wrap(setups["env3"], 20).reset)(keys))
           .pipeline_state)
    step = jax.jit(w.step_resetting_always)
    goals = []
    for _ in range(100):
        state = step(state, jnp.zeros((6, 3)))
        goals.append(np.asarray(state.info["goal"]))
    r = np.linalg.norm(np.stack(goals), axis=-1)
    assert all(len(np.unique(r[:, i])) >= 5 for i in range(6))  # a new goal per episode
    assert r[:, :3].min() >= 0.275 - 1e-5 and r[:, :3].max() <= 0.475 + 1e-5
    assert r[:, 3:].min() < 0.275 or r[:, 3:].max() > 0.475  # env3's wider annulus is used
    assert r[:, 3:].min() >= 0.125 - 1e-5 and r[:, 3:].max() <= 0.625 + 1e-5


def test_reset_pools_start_episodes_of_each_environments_scene(setups):
    """The pool's starts are each environment's next episodes of its own scene."""
    w, state, _ = _mixed_batch(setups)
    pool = jax.jit(w.reset_pool, static_argnums=1)(state, 2)
    first = jax.tree.map(lambda x: x[0], pool.starts)
    expected = jax.jit(jax.vmap(lambda k, s: setups["env2"].reset(k, s)))(
        state.info["rng"], state.info["scene"])
    _equal(first.info["goal"], expected.info["goal"])
    _equal(first.info["scene"], state.info["scene"])
