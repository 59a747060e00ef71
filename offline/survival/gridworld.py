"""The grid world of the tabular survival-instinct experiment (thesis §8.3.1, Fig. 8.2;
docs/design.md §2.4), its exact finite-horizon evaluations and deterministic rollouts.

**The world** (:class:`GridWorld`) is a deterministic grid given as text rows: ``S`` start,
``K`` key, ``L`` lava, ``#`` wall, ``.`` free. Four actions (up, right, down, left); moving into
a wall or off the grid stays put. The true reward (§8.3.1) is ``+1`` upon touching the key and
``−1`` upon touching the lava, ``0`` otherwise, as a function ``r(s, a)`` of the state and the
action (transitions are deterministic). Touching lava *ends the episode* (lava cells are terminal:
nothing is collected afterwards). The key is *absorbing*: every action keeps the agent there, so
it can stay forever, beyond the episode length. ``horizon`` ``H`` is the planning and evaluation
horizon; values are finite-horizon sums ``V_h^π(s) = E[Σ_{t=h}^{H−1} r(s_t, a_t)]``.

:meth:`GridWorld.true_values` and :meth:`GridWorld.optimal_values` are exact finite-horizon
policy evaluation and backward induction (jitted JAX, one compile per shape); :func:`rollout`
runs a deterministic policy in the true MDP on the host.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

#: Action names in index order; ``MOVES[a]`` is the (row, column) step of action ``a``.
ACTIONS = ("up", "right", "down", "left")
MOVES = ((-1, 0), (0, 1), (1, 0), (0, -1))
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


__all__ = [
    "ACTIONS",
    "DEFAULT_LAYOUT",
    "MOVES",
    "GridWorld",
    "Rollout",
    "policy_probabilities",
    "rollout",
]
