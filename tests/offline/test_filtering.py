"""Collision-margin filtering (offline/survival/filtering.py, thesis §8.4.2) against an independent
float64 NumPy computation of the planar 3-link clearance."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from mjxrmp.geometry import Obstacles
from offline.data import dataset as odata
from offline.data.rollouts import make_env
from offline.survival.filtering import filter_collision_margin, observation_clearance

ENV = "three_link/env3"


def reference_clearance(q: np.ndarray, centers: np.ndarray, radii: np.ndarray) -> float:
    """3 links of 0.25 m from the origin, 5 control points of radius 0.025 per link at
    fractions 0.2 … 1.0; circles (centre, radius); radius ≤ 0 means no obstacle."""
    angles = np.cumsum(q)
    joints = np.concatenate([[[0.0, 0.0]], np.cumsum(
        0.25 * np.stack([np.cos(angles), np.sin(angles)], -1), axis=0)])
    t = np.arange(1, 6) / 5.0
    pts = np.concatenate([joints[k] + t[:, None] * (joints[k + 1] - joints[k])
                          for k in range(3)])
    best = np.inf
    for c, r in zip(centers, radii, strict=True):
        if r > 0:
            best = min(best, float(np.min(np.linalg.norm(pts - c, axis=1) - 0.025 - r)))
    return best


def observation(q: np.ndarray, centers: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """An env3 observation by hand (layout of thesis §6.2.2); the unused parts are noise."""
    rng = np.random.default_rng(0)
    return np.concatenate([np.sin(q), np.cos(q), rng.normal(size=3), rng.normal(size=2),
                           rng.normal(size=6),
                           np.concatenate([centers, radii[:, None]], 1).reshape(-1)])


def random_scene(rng: np.random.Generator, pad: bool) -> tuple[np.ndarray, ...]:
    q = rng.uniform(-4.0, 4.0, 3)  # outside (−π, π] too: atan2 recovers it modulo 2π
    centers = rng.uniform(-0.6, 0.6, (3, 2))
    radii = rng.uniform(0.05, 0.10, 3)
    if pad:
        centers[2], radii[2] = 0.0, -1.0
    return q, centers, radii


@pytest.fixture(scope="module")
def env():
    return make_env(ENV)


def test_clearance_matches_numpy_reference(env):
    rng = np.random.default_rng(1)
    scenes = [random_scene(rng, pad=i % 4 == 0) for i in range(64)]
    obs = np.stack([observation(*s) for s in scenes]).astype(np.float32)
    got = np.asarray(observation_clearance(env, obs))
    want = np.array([reference_clearance(*s) for s in scenes])
    assert (want < 0).any() and (want > 0).any()  # both sides of the collision surface
    np.testing.assert_allclose(got, want, atol=2e-5)
    # leading axes are kept
    assert observation_clearance(env, obs.reshape(8, 8, -1)).shape == (8, 8)


def test_clearance_matches_the_environment_observation(env):
    rng = np.random.default_rng(2)
    for _ in range(4):
        q, centers, radii = random_scene(rng, pad=False)
        obst = Obstacles(jnp.asarray(centers, jnp.float32), jnp.asarray(radii, jnp.float32),
                         jnp.ones(3, jnp.float32))
        q = jnp.asarray(q, jnp.float32)
        obs = env.observe(q, jnp.zeros(3), jnp.zeros(2), obst)
        want = env._robot_clearance(q, obst)
        np.testing.assert_allclose(observation_clearance(env, obs), want, atol=1e-5)


def _dataset(obs: np.ndarray, next_obs: np.ndarray) -> odata.Dataset:
    n = len(obs)
    term = np.zeros(n, bool)
    term[-1] = True
    return odata.create(obs, np.zeros((n, 3), np.float32), np.arange(n, dtype=np.float32),
                        next_obs, term, np.zeros(n, bool), np.zeros(n, np.int32),
                        metadata={"env": ENV})


def test_filter_removes_transitions_near_obstacles(env):
    rng = np.random.default_rng(3)
    scenes = [random_scene(rng, pad=False) for _ in range(41)]
    obs_all = np.stack([observation(*s) for s in scenes]).astype(np.float32)
    ref = np.array([reference_clearance(*s) for s in scenes])
    ds = _dataset(obs_all[:-1], obs_all[1:])  # one episode: s_t, s_{t+1}
    margin = 0.05
    keep = np.minimum(ref[:-1], ref[1:]) >= margin
    assert 0 < keep.sum() < keep.size
    out = filter_collision_margin(ds, ENV, margin)
    np.testing.assert_array_equal(out.rewards, np.arange(40, dtype=np.float32)[keep])
    np.testing.assert_array_equal(out.observations, obs_all[:-1][keep])
    assert out.metadata["collision_filter"] == {"env": ENV, "margin": margin,
                                                "removed": int((~keep).sum()),
                                                "kept": int(keep.sum())}
    # a negative margin keeps everything whose clearance exceeds it; a huge one removes all
    assert filter_collision_margin(ds, ENV, -10.0).size == ds.size
    assert filter_collision_margin(ds, ENV, 10.0).size == 0


def test_filter_rejects_bad_input(env):
    obs = np.zeros((2, 26), np.float32)
    ds = _dataset(obs, obs)
    with pytest.raises(ValueError, match="margin"):
        filter_collision_margin(ds, ENV, float("nan"))
    small = _dataset(np.zeros((2, 5), np.float32), np.zeros((2, 5), np.float32))
    with pytest.raises(ValueError, match="observation size"):
        filter_collision_margin(small, ENV, 0.0)
    with pytest.raises(ValueError, match="at least"):
        observation_clearance(env, np.zeros((3, 5), np.float32))
