"""Survival instinct on a tabular grid world: PEVI vs behaviour cloning with wrong rewards
(thesis §8.3.1, Fig. 8.2; §8.3.2 Proposition 8.3.1; §8.3.3 length bias; docs/design.md §2.4).

The world is :class:`offline.survival.gridworld.GridWorld` (deterministic grid, lava terminal,
the key absorbing; values are finite-horizon sums up to its ``horizon`` ``H``).

**The data** (:func:`collect`) comes from a suboptimal behaviour policy that heads straight for
the key (columns first) ignoring the lava, with ``ε``-uniform action noise. As in §8.3.1, episodes
that touch the lava are *cut* there; the others run until the data's episode length ``T``
(:attr:`DataConfig.episode_length`) and time out, except those that reach the absorbing key: they
are recorded as absorbing (a terminal with an unbounded continuation, §8.4 "Goal-oriented problems
have data bias"), which we unroll to the planning horizon ``H > T``. Hence the *length bias* of
§8.3.3: the longest trajectories are exactly those that reach the key. Counts are kept per step
``h`` (the episodic setting of PEVI [Jin et al., 2021]): ``n_h(s, a)``, ``n_h(s, a, s')`` and the
recorded reward sums.

**Wrong rewards** (§8.1, Fig. 8.1): :func:`reward_table` gives the true reward or the relabellings
``zero``, ``random`` (``U[0, 1]`` per ``(s, a)``, fixed seed) and ``negated``;
:func:`relabel` writes one into the data.

**PEVI** (:func:`pevi`; Jin et al. 2021, Algorithm 1 in the tabular case) is pessimistic value
iteration on the empirical MDP, backwards over ``h = H−1 … 0``::

    Q̄_h(s, a) = r̂_h(s, a) + Σ_s' P̂_h(s'|s, a) V̂_{h+1}(s') − Γ_h(s, a),   Γ_h(s, a) = c / √n_h(s, a)
    Q̂_h(s, a) = clip(Q̄_h(s, a), (H−h)·r_min, (H−h)·r_max)   if n_h(s, a) > 0
    Q̂_h(s, a) = (H−h)·r_min                                 if n_h(s, a) = 0
    π̂_h(s) = argmax_a Q̂_h(s, a),   V̂_h(s) = max_a Q̂_h(s, a),   V̂_H = 0,

with ``[r_min, r_max]`` the reward class range (``[−1, 1]``, §8.2). The second line is the
*pessimistic value initialisation* of §8.3.1: an action the data never took at step ``h`` is worth
the lowest return of the remaining ``H − h`` steps, so a data trajectory that stops before the
horizon (cut at the lava, timed out at ``T``) continues, for PEVI, with the lowest return; the
``−Γ`` term is the instantaneous ``O(−1/√n(s, a))`` penalty. Because the grid is deterministic,
``P̂`` and ``r̂`` are exact where ``n > 0``, and induction over ``h`` gives ``V̂_h ≤ V_h^{π̂}``
(the learned value lower-bounds the true one, §8.3.1) for every ``c ≥ 0``.

**BC** (:func:`behaviour_cloning`) takes the most frequent data action in each state (pooled over
steps; ties and unseen states go to the lowest action index);
:func:`offline.survival.gridworld.rollout` runs a policy in the true MDP.

PEVI is jitted JAX (one compile per shape; the penalty and the reward range are traced
arguments); the data collection runs on the host in NumPy.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from offline.data.dataset import RELABELLINGS
from offline.survival.gridworld import ACTIONS, GridWorld

#: Rewards :func:`reward_table` knows: the true one and the wrong ones of thesis §8.1.
REWARDS = ("true", *RELABELLINGS)
#: Trajectory outcomes recorded by :func:`collect`.
OUTCOMES = ("key", "lava", "timeout")

def behaviour_policy(world: GridWorld, noise: float) -> np.ndarray:
    """(S, A) probabilities of the suboptimal data-collection policy of §8.3.1: head for the
    key's column, then its row (ignoring lava) with probability ``1 − noise``, else a uniformly
    random action."""
    if not 0.0 <= noise <= 1.0:
        raise ValueError(f"noise must lie in [0, 1], got {noise!r}")
    cols = world.shape[1]
    key_r, key_c = divmod(world.key, cols)
    probs = np.full((world.num_states, len(ACTIONS)), noise / len(ACTIONS))
    for s in range(world.num_states):
        r, c = divmod(s, cols)
        preferred = (1 if c < key_c else 3) if c != key_c else (2 if r < key_r else 0)
        probs[s, preferred] += 1.0 - noise
    return probs


@dataclasses.dataclass(frozen=True)
class DataConfig:
    """Offline data collection: ``num_trajectories`` episodes of the behaviour policy with action
    noise ``noise``, cut at lava, timed out after ``episode_length`` ``T`` steps unless at the
    absorbing key (then unrolled to the world's horizon ``H``, which must exceed ``T``)."""

    num_trajectories: int = 300
    episode_length: int = 14
    noise: float = 0.5

    def __post_init__(self) -> None:
        for name in ("num_trajectories", "episode_length"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
        if not 0.0 <= self.noise <= 1.0:
            raise ValueError(f"noise must lie in [0, 1], got {self.noise!r}")


class Trajectory(NamedTuple):
    """One data episode: visited states ``(L+1,)``, actions ``(L,)``, rewards ``(L,)`` (true
    reward) and how it ended (one of :data:`OUTCOMES`)."""

    states: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    outcome: str


@dataclasses.dataclass(frozen=True, eq=False)
class OfflineData:
    """Per-step counts of an offline dataset (episodic setting, step ``h = 0 … H−1``).

    ``counts`` ``n_h(s, a)`` ``(H, S, A)``, ``transition_counts`` ``n_h(s, a, s')``
    ``(H, S, A, S)``, ``reward_sums`` ``(H, S, A)`` (sum of the recorded rewards, so
    ``r̂_h = reward_sums / n_h``), the ``trajectories`` and the ``reward`` name they carry.
    """

    counts: np.ndarray
    transition_counts: np.ndarray
    reward_sums: np.ndarray
    trajectories: tuple[Trajectory, ...]
    reward: str = "true"

    @property
    def state_visits(self) -> np.ndarray:
        """(S,) how often each state occurs in the data (the opacity of Fig. 8.2)."""
        visits = np.zeros(self.counts.shape[1], dtype=np.int64)
        for trajectory in self.trajectories:
            np.add.at(visits, trajectory.states, 1)
        return visits


def collect(world: GridWorld, config: DataConfig, seed: int) -> OfflineData:
    """Roll the behaviour policy (:func:`behaviour_policy`) out from the start: episodes touching
    lava are cut there, others time out after ``T`` steps, those at the absorbing key continue to
    ``H`` — the length bias of §8.3.3. Returns the per-step counts and the trajectories."""
    if config.episode_length >= world.horizon:
        raise ValueError(f"episode_length ({config.episode_length}) must be smaller than the "
                         f"world's horizon ({world.horizon}): only the absorbing key is seen "
                         f"beyond the episode length")
    rng = np.random.default_rng(seed)
    cumulative = np.cumsum(behaviour_policy(world, config.noise), axis=1)
    num_s, num_a, horizon = world.num_states, len(ACTIONS), world.horizon
    counts = np.zeros((horizon, num_s, num_a), dtype=np.int64)
    transition_counts = np.zeros((horizon, num_s, num_a, num_s), dtype=np.int64)
    reward_sums = np.zeros((horizon, num_s, num_a))
    trajectories = []
    uniforms = rng.random((config.num_trajectories, horizon))
    for i in range(config.num_trajectories):
        states, actions, outcome = [world.start], [], "timeout"
        for h in range(horizon):
            s = states[-1]
            if s == world.key:
                outcome = "key"
            elif h >= config.episode_length:
                break
            a = min(int(np.searchsorted(cumulative[s], uniforms[i, h], side="right")), num_a - 1)
            s_next = int(world.next_state[s, a])
            counts[h, s, a] += 1
            transition_counts[h, s, a, s_next] += 1
            reward_sums[h, s, a] += world.reward[s, a]
            states.append(s_next)
            actions.append(a)
            if world.terminal[s_next]:
                outcome = "lava"
                break
        else:
            outcome = "key" if states[-1] == world.key else outcome
        states_arr, actions_arr = np.array(states), np.array(actions, dtype=np.int64)
        trajectories.append(Trajectory(states_arr, actions_arr,
                                       world.reward[states_arr[:-1], actions_arr], outcome))
    return OfflineData(counts, transition_counts, reward_sums, tuple(trajectories))


def reward_table(world: GridWorld, kind: str, seed: int = 0) -> np.ndarray:
    """(S, A) reward: ``true`` (§8.3.1) or a wrong one of §8.1 — ``zero``, ``random`` (``U[0, 1]``
    per ``(s, a)`` from ``seed``) or ``negated`` (the true reward's negation)."""
    if kind not in REWARDS:
        raise ValueError(f"kind must be one of {list(REWARDS)}, got {kind!r}")
    shape = world.reward.shape
    if kind == "zero":
        return np.zeros(shape)
    if kind == "random":
        return np.random.default_rng(seed).uniform(0.0, 1.0, shape)
    return -world.reward if kind == "negated" else world.reward.copy()


def relabel(data: OfflineData, table: np.ndarray, name: str) -> OfflineData:
    """The dataset with every transition's reward replaced by ``table[s, a]`` (§8.2, D̃)."""
    if np.shape(table) != data.counts.shape[1:]:
        raise ValueError(f"table must have shape (S, A) = {data.counts.shape[1:]}, got "
                         f"{np.shape(table)}")
    trajectories = tuple(t._replace(rewards=np.asarray(table)[t.states[:-1], t.actions])
                         for t in data.trajectories)
    return dataclasses.replace(data, reward_sums=data.counts * np.asarray(table),
                               trajectories=trajectories, reward=name)


@dataclasses.dataclass(frozen=True)
class PEVIConfig:
    """PEVI: penalty scale ``c ≥ 0`` in ``Γ_h(s, a) = c / √n_h(s, a)`` and the reward class range
    ``[r_min, r_max]`` (§8.2: ``R̃ ∈ [−1, 1]``) fixing the clip bounds and the pessimistic
    initialisation ``(H − h)·r_min``."""

    penalty: float = 0.1
    reward_range: tuple[float, float] = (-1.0, 1.0)

    def __post_init__(self) -> None:
        if not (np.isfinite(self.penalty) and self.penalty >= 0.0):
            raise ValueError(f"penalty must be a finite number >= 0, got {self.penalty!r}")
        low, high = self.reward_range
        if not (np.isfinite(low) and np.isfinite(high) and low < high):
            raise ValueError(f"reward_range must be finite (r_min, r_max) with r_min < r_max, "
                             f"got {self.reward_range!r}")


class PEVIResult(NamedTuple):
    """PEVI's pessimistic ``values`` ``V̂`` ``(H+1, S)``, ``q`` ``Q̂`` ``(H, S, A)`` and greedy
    ``policy`` ``(H, S)``."""

    values: jax.Array
    q: jax.Array
    policy: jax.Array


def pevi(data: OfflineData, config: PEVIConfig) -> PEVIResult:
    """Pessimistic value iteration (Jin et al. 2021; thesis §8.3.1) on the empirical MDP of
    ``data`` with the rewards it carries (see the module docstring for the recursion)."""
    counts = jnp.asarray(data.counts, dtype=jnp.result_type(float))
    low, high = config.reward_range
    return _pevi(counts, jnp.asarray(data.transition_counts, counts.dtype),
                 jnp.asarray(data.reward_sums, counts.dtype), config.penalty, low, high)


@jax.jit
def _pevi(counts: jax.Array, transition_counts: jax.Array, reward_sums: jax.Array,
          penalty: jax.Array, r_min: jax.Array, r_max: jax.Array) -> PEVIResult:
    horizon = counts.shape[0]
    seen = counts > 0
    n = jnp.maximum(counts, 1.0)
    reward_hat = reward_sums / n
    transition_hat = transition_counts / n[..., None]
    bonus = penalty / jnp.sqrt(n)
    remaining = jnp.arange(horizon, 0, -1, dtype=counts.dtype)

    def backup(v_next, step):
        r_h, p_h, gamma_h, seen_h, steps_left = step
        lowest, highest = steps_left * r_min, steps_left * r_max
        q_bar = r_h + p_h @ v_next - gamma_h
        q = jnp.where(seen_h, jnp.clip(q_bar, lowest, highest), lowest)
        return jnp.max(q, axis=-1), (jnp.max(q, axis=-1), q, jnp.argmax(q, axis=-1))

    v_end = jnp.zeros(counts.shape[1], counts.dtype)
    _, (v, q, pi) = jax.lax.scan(
        backup, v_end, (reward_hat, transition_hat, bonus, seen, remaining), reverse=True)
    return PEVIResult(jnp.concatenate([v, v_end[None]]), q, pi.astype(jnp.int32))


def behaviour_cloning(data: OfflineData) -> np.ndarray:
    """(S,) the most frequent data action per state, pooled over steps (lowest index on ties and
    in unseen states): the BC agent of Fig. 8.2."""
    return np.argmax(data.counts.sum(axis=0), axis=1).astype(np.int32)


__all__ = [
    "OUTCOMES",
    "REWARDS",
    "DataConfig",
    "OfflineData",
    "PEVIConfig",
    "PEVIResult",
    "Trajectory",
    "behaviour_cloning",
    "behaviour_policy",
    "collect",
    "pevi",
    "relabel",
    "reward_table",
]
