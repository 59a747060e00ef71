"""The Gymnasium 1.x adapter :mod:`envs.gymnasium` on ``three_link/env3`` (docs/design.md §2.2).

* the single-environment form passes ``gymnasium.utils.env_checker.check_env`` and truncates at
  the horizon without resetting itself;
* the vector form has Gymnasium's spaces, dtypes, infos (with ``_key`` masks) and
  ``NEXT_STEP`` auto-reset, checked step by step on a 3-step horizon;
* ``reset(seed=...)`` is reproducible; bad arguments raise errors that name them;
* ``gymnasium.make``/``gymnasium.make_vec`` build them from the ``mjxrmp/...-v0`` ids.

Each environment is built once (one compiled step each); episodes are 3 control steps long.
"""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import envs.gymnasium as gym_envs

NAME, NUM_ENVS, HORIZON = "three_link/env3", 2, 3
OBS_SIZE, ACTION_SIZE = 26, 3


@pytest.fixture(scope="module")
def single():
    env = gym_envs.make(NAME, horizon=HORIZON)
    yield env
    env.close()


@pytest.fixture(scope="module")
def vec():
    env = gym_envs.make_vec(NAME, NUM_ENVS, seed=0, horizon=HORIZON)
    yield env
    env.close()


def _actions(rng: np.random.Generator, n: int = NUM_ENVS) -> np.ndarray:
    return rng.uniform(-1.0, 1.0, (n, ACTION_SIZE)).astype(np.float32)


@pytest.mark.filterwarnings("ignore:.*Box observation space m")  # unbounded observations
def test_single_env_passes_the_gymnasium_checker(single):
    assert isinstance(single.unwrapped, gymnasium.Env)
    check_env(single.unwrapped, skip_render_check=True)


def test_single_env_truncates_at_the_horizon_and_does_not_reset_itself(single):
    obs, info = single.reset(seed=1)
    assert obs.shape == (OBS_SIZE,) and obs.dtype == np.float32
    assert set(info) == set(gym_envs.INFO_KEYS)
    rng = np.random.default_rng(0)
    for t in range(1, HORIZON + 2):
        obs, reward, terminated, truncated, info = single.step(_actions(rng, 1)[0])
        assert isinstance(reward, float) and reward != 0.0 and not terminated
        assert truncated == (t >= HORIZON), t
    goal_minus_x = obs[3 * ACTION_SIZE:3 * ACTION_SIZE + 2]
    assert np.isclose(np.linalg.norm(goal_minus_x), info["goal_distance"], atol=1e-5)


def test_vector_spaces_shapes_and_dtypes(vec):
    assert vec.num_envs == NUM_ENVS
    assert vec.metadata["autoreset_mode"] is gymnasium.vector.AutoresetMode.NEXT_STEP
    box = gymnasium.spaces.Box
    assert vec.single_observation_space == box(-np.inf, np.inf, (OBS_SIZE,), np.float32)
    assert vec.single_action_space == box(-1.0, 1.0, (ACTION_SIZE,), np.float32)
    assert vec.observation_space.shape == (NUM_ENVS, OBS_SIZE)
    assert vec.action_space.shape == (NUM_ENVS, ACTION_SIZE)
    obs, infos = vec.reset(seed=0)
    assert obs in vec.observation_space and obs.dtype == np.float32
    obs, rewards, terminated, truncated, infos = vec.step(vec.action_space.sample())
    assert obs in vec.observation_space
    assert rewards.shape == (NUM_ENVS,) and rewards.dtype == np.float64
    assert terminated.dtype == truncated.dtype == np.bool_
    for key in gym_envs.INFO_KEYS:
        assert infos[key].shape == (NUM_ENVS,) and np.all(np.isfinite(infos[key]))
        assert infos[f"_{key}"].dtype == np.bool_ and infos[f"_{key}"].all()
    residual = gym_envs.make_vec(NAME, 1, rmp_in_env=True)  # built only, never compiled
    assert residual.single_action_space == box(-np.inf, np.inf, (6,), np.float32)


def test_registered_with_gymnasium():
    """``gymnasium.make``/``make_vec`` build the adapters from the ids (built, never compiled)."""
    env = gymnasium.make("mjxrmp/three_link_env3-v0", horizon=HORIZON)
    assert isinstance(env.unwrapped, gym_envs.MJXEnv)
    assert env.unwrapped.horizon == HORIZON
    vec = gymnasium.make_vec("mjxrmp/franka_reach-v0", num_envs=2)
    assert isinstance(vec, gym_envs.MJXVectorEnv) and vec.num_envs == 2 and vec.horizon == 600
    assert vec.single_action_space.shape == (7,)
    gym_envs.register_gymnasium()  # idempotent


def _episode_pattern(vec, seed: int, reset_action: np.ndarray):
    """Observations, rewards and flags of 2 × (HORIZON + 1) steps; ``reset_action`` is taken at
    each step after a truncation (which NEXT_STEP auto-reset must ignore)."""
    rng = np.random.default_rng(seed)
    first, _ = vec.reset(seed=seed)
    out = [(first, np.zeros(NUM_ENVS), np.zeros(NUM_ENVS, bool), np.zeros(NUM_ENVS, bool))]
    for t in range(1, 2 * (HORIZON + 1) + 1):
        actions = reset_action if t % (HORIZON + 1) == 0 else _actions(rng)
        obs, rewards, terminated, truncated, _ = vec.step(actions)
        out.append((obs, rewards, terminated, truncated))
    return out


def test_vector_next_step_autoreset(vec):
    steps = _episode_pattern(vec, 4, np.ones((NUM_ENVS, ACTION_SIZE), np.float32))
    qd = slice(2 * ACTION_SIZE, 3 * ACTION_SIZE)
    scene = slice(OBS_SIZE - 9, OBS_SIZE)  # the obstacles (centre, radius): fixed per episode
    for t, (obs, rewards, terminated, truncated) in enumerate(steps):
        assert not terminated.any(), t
        in_episode = t % (HORIZON + 1)
        assert truncated.all() == (in_episode == HORIZON) and truncated.any() == truncated.all()
        if t > 0 and in_episode == 0:  # the step after the truncation: a new episode starts
            assert np.all(rewards == 0.0), t
            assert np.all(np.abs(obs[:, qd]) <= 0.005), t  # at rest, as after a reset
            assert not np.allclose(obs[:, scene], steps[t - 1][0][:, scene]), t  # new scene
        elif t > 0:
            assert np.all(rewards != 0.0), t
            np.testing.assert_array_equal(obs[:, scene], steps[t - 1][0][:, scene])
    other = _episode_pattern(vec, 4, -np.ones((NUM_ENVS, ACTION_SIZE), np.float32))
    for a, b in zip(steps, other, strict=True):  # the action at an auto-reset step is ignored
        for x, y in zip(a, b, strict=True):
            np.testing.assert_array_equal(x, y)


def test_vector_reset_seed_is_reproducible(vec):
    a, _ = vec.reset(seed=3)
    a_next, _ = vec.reset()
    b, _ = vec.reset(seed=3)
    b_next, _ = vec.reset()
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a_next, b_next)
    assert not np.array_equal(a, a_next)
    assert not np.array_equal(a[0], a[1])  # the sub-environments get different scenes


def test_bad_arguments_are_named(vec, single):
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match="num_envs"):
            gym_envs.make_vec(NAME, bad)
    with pytest.raises(ValueError, match="name"):
        gym_envs.make_vec("three_link/env9", 2)
    with pytest.raises(RuntimeError, match="reset"):
        gym_envs.make_vec(NAME, 1).step(np.zeros((1, ACTION_SIZE)))
    vec.reset(seed=0)
    with pytest.raises(ValueError, match=r"actions must have shape \(2, 3\)"):
        vec.step(np.zeros((NUM_ENVS, ACTION_SIZE + 1)))
    with pytest.raises(ValueError, match=r"actions must have shape \(2, 3\)"):
        vec.step(np.zeros(ACTION_SIZE))
    with pytest.raises(ValueError, match=r"actions must be a float array of shape \(2, 3\)"):
        vec.step([["a"] * ACTION_SIZE] * NUM_ENVS)
    single.reset(seed=0)
    with pytest.raises(ValueError, match=r"actions must have shape \(3,\)"):
        single.step(np.zeros((1, ACTION_SIZE)))
