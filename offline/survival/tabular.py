"""Survival instinct on a tabular grid world: PEVI vs behaviour cloning with wrong rewards
(thesis §8.3.1, Fig. 8.2; §8.3.2 Proposition 8.3.1; §8.3.3 length bias; docs/design.md §2.4).

**The world** (:class:`GridWorld`) is a deterministic grid given as text rows: ``S`` start,
``K`` key, ``L`` lava, ``#`` wall, ``.`` free. Four actions (up, right, down, left); moving into
a wall or off the grid stays put. The true reward (§8.3.1) is ``+1`` upon touching the key and
``−1`` upon touching the lava, ``0`` otherwise, as a function ``r(s, a)`` of the state and the
action (transitions are deterministic). Touching lava *ends the episode* (lava cells are terminal:
nothing is collected afterwards). The key is *absorbing*: every action keeps the agent there, so
it can stay forever, beyond the episode length. ``horizon`` ``H`` is the planning and evaluation
horizon; values are finite-horizon sums ``V_h^π(s) = E[Σ_{t=h}^{H−1} r(s_t, a_t)]``.

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
steps; ties and unseen states go to the lowest action index). :func:`rollout` runs a deterministic
policy in the true MDP; :func:`true_values` and :func:`optimal_values` are exact finite-horizon
policy evaluation and backward induction.

PEVI and the exact evaluations are jitted JAX (one compile per shape; the penalty and the reward
range are traced arguments); the data collection and rollouts run on the host in NumPy.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from offline.data.dataset import RELABELLINGS

#: Action names in index order; ``MOVES[a]`` is the (row, column) step of action ``a``.
ACTIONS = ("up", "right", "down", "left")
MOVES = ((-1, 0), (0, 1), (1, 0), (0, -1))
#: Rewards :func:`reward_table` knows: the true one and the wrong ones of thesis §8.1.
REWARDS = ("true", *RELABELLINGS)
#: Trajectory outcomes recorded by :func:`collect`.
OUTCOMES = ("key", "lava", "timeout")
_CELLS = frozenset("SKL#.")

#: The default layout: lava across the straight line from the start to the key.
DEFAULT_LAYOUT = (
    ".......",
    ".......",
    "S..LL.K",
    ".......",
    ".......",
)


@dataclasses.dataclass(frozen=True)
class GridWorld:
    """A deterministic, finite-horizon grid world with lava and an absorbing key (thesis Fig. 8.2).

    ``layout`` holds equally long text rows over ``SKL#.`` with exactly one start ``S`` and one
    key ``K``; ``horizon`` ``H ≥ 1`` is the planning/evaluation horizon. States are cells in
    row-major order (``s = row · width + column``).
    """

    layout: tuple[str, ...] = DEFAULT_LAYOUT
    horizon: int = 28

    def __post_init__(self) -> None:
        layout = tuple(self.layout)
        if not layout or not all(isinstance(row, str) and row for row in layout):
            raise ValueError(f"layout must be a non-empty sequence of non-empty strings, got "
                             f"{self.layout!r}")
        if len({len(row) for row in layout}) != 1:
            raise ValueError(f"layout rows must all have the same length, got lengths "
                             f"{[len(row) for row in layout]}")
        bad = set("".join(layout)) - _CELLS
        if bad:
            raise ValueError(f"layout may only contain {sorted(_CELLS)}, got {sorted(bad)}")
        for char, name in (("S", "start"), ("K", "key")):
            count = "".join(layout).count(char)
            if count != 1:
                raise ValueError(f"layout must contain exactly one {name} {char!r}, got {count}")
        if isinstance(self.horizon, bool) or not isinstance(self.horizon, int | np.integer) \
                or self.horizon < 1:
            raise ValueError(f"horizon must be an integer >= 1, got {self.horizon!r}")
        object.__setattr__(self, "layout", layout)
        object.__setattr__(self, "horizon", int(self.horizon))

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, columns) of the grid."""
        return len(self.layout), len(self.layout[0])

    @property
    def num_states(self) -> int:
        """Number of states (cells, walls included; walls are never entered)."""
        return self.shape[0] * self.shape[1]

    def _cells(self, char: str) -> np.ndarray:
        return np.array([c == char for row in self.layout for c in row])

    @property
    def start(self) -> int:
        """Index of the start state."""
        return int(np.flatnonzero(self._cells("S"))[0])

    @property
    def key(self) -> int:
        """Index of the (absorbing) key state."""
        return int(np.flatnonzero(self._cells("K"))[0])

    @functools.cached_property
    def terminal(self) -> np.ndarray:
        """(S,) bool: lava cells, where the episode ends."""
        return self._cells("L")

    @functools.cached_property
    def next_state(self) -> np.ndarray:
        """(S, A) int: the deterministic successor ``s'`` of ``(s, a)`` (the key and lava loop)."""
        rows, cols = self.shape
        wall = self._cells("#")
        nxt = np.zeros((self.num_states, len(MOVES)), dtype=np.int32)
        for s in range(self.num_states):
            r, c = divmod(s, cols)
            for a, (dr, dc) in enumerate(MOVES):
                r2, c2 = r + dr, c + dc
                inside = 0 <= r2 < rows and 0 <= c2 < cols
                absorbing = s == self.key or self.terminal[s]
                nxt[s, a] = s if absorbing or not inside or wall[r2 * cols + c2] else r2 * cols + c2
        return nxt

    @functools.cached_property
    def reward(self) -> np.ndarray:
        """(S, A) float: the true reward, +1 upon touching the key, −1 upon touching lava
        (§8.3.1)."""
        not_key = np.arange(self.num_states) != self.key
        touches_key = (self.next_state == self.key) & not_key[:, None]
        touches_lava = self.terminal[self.next_state] & ~self.terminal[:, None]
        return touches_key.astype(np.float64) - touches_lava.astype(np.float64)

    def true_values(self, policy: np.ndarray | jax.Array,
                    reward: np.ndarray | jax.Array | None = None) -> tuple[jax.Array, jax.Array]:
        """Exact finite-horizon policy evaluation (the Bellman equation of §8.2 with horizon H).

        ``policy``: action probabilities ``(H, S, A)`` or ``(S, A)`` (stationary), or a
        deterministic policy of action indices ``(H, S)`` or ``(S,)``. ``reward``: ``(S, A)``,
        the true reward by default. Returns ``V`` ``(H+1, S)`` and ``Q`` ``(H, S, A)`` with
        ``Q_h(s, a) = r(s, a) + V_{h+1}(s')``, ``V_h(s) = Σ_a π_h(a|s) Q_h(s, a)``, ``V_H = 0``
        and ``V_h = 0`` at terminal (lava) states.
        """
        probs = policy_probabilities(policy, self.horizon, self.num_states)
        return _evaluate(jnp.asarray(self.next_state), jnp.asarray(self.terminal),
                         self._reward_or_true(reward), probs)

    def optimal_values(self, reward: np.ndarray | jax.Array | None = None
                       ) -> tuple[jax.Array, jax.Array, jax.Array]:
        """Backward induction: optimal ``V*`` ``(H+1, S)``, ``Q*`` ``(H, S, A)`` and a greedy
        optimal policy ``(H, S)`` (lowest action index among ties) for ``reward`` (true by default).
        """
        return _optimal(jnp.asarray(self.next_state), jnp.asarray(self.terminal),
                        self._reward_or_true(reward), self.horizon)

    def _reward_or_true(self, reward: np.ndarray | jax.Array | None) -> jax.Array:
        reward = self.reward if reward is None else reward
        if np.shape(reward) != (self.num_states, len(ACTIONS)):
            raise ValueError(f"reward must have shape (S, A) = {(self.num_states, len(ACTIONS))}, "
                             f"got {np.shape(reward)}")
        return jnp.asarray(reward, dtype=jnp.result_type(float))


def policy_probabilities(policy: np.ndarray | jax.Array, horizon: int, num_states: int
                         ) -> jax.Array:
    """Action probabilities ``(H, S, A)`` of a policy given as probabilities ``(H, S, A)`` /
    ``(S, A)`` or as action indices ``(H, S)`` / ``(S,)`` (stationary ones are repeated)."""
    policy = jnp.asarray(policy)
    num_actions = len(ACTIONS)
    if jnp.issubdtype(policy.dtype, jnp.integer):
        if policy.shape not in ((num_states,), (horizon, num_states)):
            raise ValueError(f"a deterministic policy must have shape (S,) or (H, S) = "
                             f"{(horizon, num_states)}, got {policy.shape}")
        policy = jax.nn.one_hot(policy, num_actions)
    elif policy.shape not in ((num_states, num_actions), (horizon, num_states, num_actions)):
        raise ValueError(f"policy probabilities must have shape (S, A) or (H, S, A) = "
                         f"{(horizon, num_states, num_actions)}, got {policy.shape}")
    return jnp.broadcast_to(policy, (horizon, num_states, num_actions))


@jax.jit
def _evaluate(next_state: jax.Array, terminal: jax.Array, reward: jax.Array, probs: jax.Array
              ) -> tuple[jax.Array, jax.Array]:
    def backup(v_next, pi_h):
        q = reward + v_next[next_state]
        v = jnp.where(terminal, 0.0, jnp.sum(pi_h * q, axis=-1))
        return v, (v, q)

    v_end = jnp.zeros(terminal.shape, reward.dtype)
    _, (v, q) = jax.lax.scan(backup, v_end, probs.astype(reward.dtype), reverse=True)
    return jnp.concatenate([v, v_end[None]]), q


@functools.partial(jax.jit, static_argnames="horizon")
def _optimal(next_state: jax.Array, terminal: jax.Array, reward: jax.Array, horizon: int
             ) -> tuple[jax.Array, jax.Array, jax.Array]:
    def backup(v_next, _):
        q = reward + v_next[next_state]
        v = jnp.where(terminal, 0.0, jnp.max(q, axis=-1))
        return v, (v, q, jnp.argmax(q, axis=-1).astype(jnp.int32))

    v_end = jnp.zeros(terminal.shape, reward.dtype)
    _, (v, q, pi) = jax.lax.scan(backup, v_end, None, length=horizon, reverse=True)
    return jnp.concatenate([v, v_end[None]]), q, pi


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


class Rollout(NamedTuple):
    """A deterministic rollout in the true MDP: ``states`` visited (it stops at lava), the
    ``return_`` under the evaluated reward, and whether it reached the key / touched lava."""

    states: np.ndarray
    return_: float
    reached_key: bool
    touched_lava: bool


def rollout(world: GridWorld, policy: np.ndarray | jax.Array,
            reward: np.ndarray | None = None) -> Rollout:
    """Run a deterministic policy (action indices ``(H, S)`` or ``(S,)``) from the start for ``H``
    steps in the true MDP, the episode ending at lava; the return uses ``reward`` (true default)."""
    policy = np.asarray(policy)
    if not np.issubdtype(policy.dtype, np.integer) or policy.shape not in (
            (world.num_states,), (world.horizon, world.num_states)):
        raise ValueError(f"policy must hold action indices of shape (S,) or (H, S) = "
                         f"{(world.horizon, world.num_states)}, got {policy.dtype} {policy.shape}")
    policy = np.broadcast_to(policy, (world.horizon, world.num_states))
    reward = world.reward if reward is None else np.asarray(reward)
    states, total = [world.start], 0.0
    for h in range(world.horizon):
        s = states[-1]
        if world.terminal[s]:
            break
        a = int(policy[h, s])
        total += float(reward[s, a])
        states.append(int(world.next_state[s, a]))
    states_arr = np.array(states)
    return Rollout(states_arr, total, bool(np.any(states_arr == world.key)),
                   bool(np.any(world.terminal[states_arr])))
