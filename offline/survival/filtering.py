"""Safety from filtered data (thesis §8.4.2, Corollary 8.3.2): remove every transition that
comes close to an obstacle, then run an unmodified offline RL algorithm on what is left.

The thesis removes the transitions of offline SafetyGymnasium with non-zero cost. Our reaching
data have no cost signal, so the cost is geometric: a transition is *unsafe* when the robot's
clearance — the smallest exact surface distance between its collision control points and any
obstacle, :meth:`envs.reaching.ReachEnv.distances`, negative inside an obstacle — is below
``margin`` in its state ``s`` **or** its next state ``s'``.

The clearance is computed from the observation alone (:func:`observation_clearance`): the
default observation holds ``sin q`` and ``cos q`` (so ``q = atan2(sin q, cos q)``, exact
because the forward kinematics of revolute joints is 2π-periodic) and every obstacle's centre
and radius (padding obstacles have radius −1 and are ignored); the environment's own
:meth:`~envs.reaching.ReachEnv.distances` then gives the clearance, so the filter and the
environment's collision test (clearance < 0) use the same geometry. No extra data needs to be
recorded at collection time.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from mjxrmp.geometry import Obstacles
from offline.data import dataset as odata
from offline.data.rollouts import make_env


def observation_clearance(env: Any, observations: jax.Array) -> jax.Array:
    """The robot–obstacle clearance ``min_{i active, p} d(p, o_i)`` of each observation
    (``(..., O)`` → ``(...)``; thesis §8.4.2 cost, module docstring) of a reaching
    environment ``env`` (:func:`envs.make`), with the environment's exact surface distances
    (:meth:`envs.reaching.ReachEnv.distances`); ``+inf`` when no obstacle is active."""
    layout = env.observation_layout()
    dim = env.obs_dim
    obs = jnp.asarray(observations)
    if obs.shape[-1] < layout["obstacles"].stop:
        raise ValueError(f"observations must have at least {layout['obstacles'].stop} entries "
                         f"(the environment's observation layout), got shape {obs.shape}")

    def one(o: jax.Array) -> jax.Array:
        q = jnp.arctan2(o[layout["sin_q"]], o[layout["cos_q"]])
        block = o[layout["obstacles"]].reshape(env.num_obstacles, dim + 1)
        radius = block[:, dim]
        active = (radius > 0).astype(obs.dtype)
        d = env.distances(q, Obstacles(block[:, :dim], radius, active))
        return jnp.min(jnp.where(active[None, :] > 0, d, jnp.inf))

    flat = obs.reshape(-1, obs.shape[-1])
    return jax.jit(jax.vmap(one))(flat).reshape(obs.shape[:-1])


def transition_clearance(dataset: odata.Dataset, env_name: str) -> np.ndarray:
    """``min(clearance(s), clearance(s'))`` of every transition of ``dataset`` collected on
    ``env_name`` (:func:`observation_clearance`), as a float64 NumPy array ``(N,)``."""
    odata.validate(dataset)
    env = make_env(env_name)
    if dataset.observation_size != env.observation_size:
        raise ValueError(f"dataset has observation size {dataset.observation_size}, but "
                         f"env_name={env_name!r} has {env.observation_size}")
    both = np.stack([np.asarray(dataset.observations), np.asarray(dataset.next_observations)])
    return np.asarray(observation_clearance(env, both), np.float64).min(axis=0)


def filter_collision_margin(dataset: odata.Dataset, env_name: str,
                            margin: float) -> odata.Dataset:
    """``dataset`` without the transitions whose state or next state has clearance below
    ``margin`` (thesis §8.4.2's filtering: "remove all transitions with non-zero cost"; module
    docstring). ``margin = 0`` removes exactly the transitions that touch a collision.

    The kept transitions keep their order, episode ids and flags (host-side, like
    :func:`offline.data.dataset.filter_episodes`); an episode that lost transitions in its middle
    keeps its remaining ones adjacent, which the learners treat as independent transitions
    (each has its own true ``s'``). ``metadata["collision_filter"]`` records the margin and
    how many transitions were removed.
    """
    margin = float(margin)
    if not np.isfinite(margin):
        raise ValueError(f"margin must be a finite number (metres), got {margin!r}")
    keep = transition_clearance(dataset, env_name) >= margin
    out = jax.tree.map(lambda x: np.asarray(x)[keep], dataset)
    info = {"env": env_name, "margin": margin, "removed": int((~keep).sum()),
            "kept": int(keep.sum())}
    return odata.validate(out.replace(metadata=out.metadata.updated(collision_filter=info)))


__all__ = ["filter_collision_margin", "observation_clearance", "transition_clearance"]
