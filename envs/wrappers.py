"""Wrappers: an auto-reset that re-samples goal and obstacles, the training ``wrap`` and RMP²
inside the environment (:class:`RMPInEnv`).

brax's own ``AutoResetWrapper`` restores each batch slot's cached *first* ``pipeline_state`` and
``obs`` and keeps ``state.info``. The environments are built for that: everything a step reads
lives in ``pipeline_state`` (the virtual velocity is the velocity half of ``ctrl``,
:meth:`envs.reaching.ReachEnv.virtual_velocity`) or is fixed for the episode in ``state.info``
(goal, obstacles), and the per-episode accumulators restart by themselves
(:func:`envs.base.accumulate_episode`); so brax restarts a slot's first episode exactly, scene
included (docs/design.md §5.3). :class:`AutoResetWrapper` here instead calls ``reset`` with the
fresh key the environment stored in ``state.info["rng"]`` at its last reset, so every reset
inside the compiled graph samples a *new* scene. Use :func:`wrap` (vmap → episode limit → this
auto-reset) for training; brax's ``brax.envs.wrappers.training.wrap``, its ``EvalWrapper`` and
its PPO trainer (:mod:`agents.brax_compat`) also run the environments correctly, re-using the
first scene of each batch slot.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from brax.envs.base import Env, State, Wrapper
from brax.envs.wrappers.training import EpisodeWrapper, VmapWrapper

from envs.base import check_action
from mjxrmp import policies

#: ``state.info`` entries owned by brax's ``EpisodeWrapper``: kept across an automatic reset.
EPISODE_KEYS = ("steps", "truncation", "episode_done", "episode_metrics")


def where_done(done: jax.Array, new: Any, old: Any) -> Any:
    """``new`` where ``done > 0`` and ``old`` elsewhere, leaf by leaf, for pytrees batched over
    environments (``done`` of shape ``(N,)`` broadcast over each leaf's trailing axes)."""

    def sel(x, y):
        d = jnp.reshape(done, done.shape + (1,) * (x.ndim - done.ndim)) > 0
        return jnp.where(d, x, y)

    return jax.tree.map(sel, new, old)


#: Backends on which :meth:`AutoResetWrapper.step` computes the reset only when an episode ended
#: (a conditional; on a GPU its per-step predicate read-back made PPO rollouts slower: H100,
#: three_link/env3 0.39 s against 0.28 s per 512-step rollout).
CONDITIONAL_RESET_BACKENDS = ("cpu",)


class ResetPool(NamedTuple):
    """The next ``depth`` episode starts of every environment, computed ahead
    (:meth:`AutoResetWrapper.reset_pool`): ``starts`` has leading axes ``(depth, B)``;
    ``taken (B,)`` counts the starts each environment has used and ``overflow`` is True once an
    environment finished more episodes than the pool held (its restart is then wrong and the
    steps since the pool was made must be redone with :meth:`AutoResetWrapper.step`)."""

    starts: State
    taken: jax.Array
    overflow: jax.Array


class AutoResetWrapper(Wrapper):
    """Resets done episodes with a *new* scene (goal, obstacles, initial state).

    Apply it outermost (after the vmap and episode wrappers). At each step every finished
    episode gets ``env.reset(state.info["rng"])`` (of its own scene, ``state.info["scene"]``,
    for environments that keep one: :meth:`envs.reaching.ReachEnv.reset`): pipeline state,
    observation and the environment's own ``info`` entries (goal, obstacles, key, per-episode
    accumulators) are replaced; brax's episode bookkeeping (:data:`EPISODE_KEYS`), ``reward``,
    ``done`` and ``metrics`` of the terminal step are kept, as in brax.

    :meth:`step` computes a reset for every environment and selects it where an episode ended.
    On backends in :data:`CONDITIONAL_RESET_BACKENDS` (the CPU) it computes that reset only at
    steps where some environment finished (a ``lax.cond`` on "any episode ended"; with
    ``axis_name``, the name of an enclosing ``vmap``, over all of its rows too, so the
    conditional stays a branch instead of becoming a select of both sides). On a GPU a
    conditional reads its predicate back to the host at every step, which costs more than the
    reset (docs/design.md §5.7). The key of an environment's next episode
    is fixed when its current episode starts, so its next starts can also be computed ahead,
    once for many steps (:meth:`reset_pool`), and taken in turn by :meth:`step_from_pool`: the
    same states (docs/design.md §5.7).
    """

    def _advance(self, state: State, action: jax.Array) -> State:
        """The wrapped step, with brax's step counter of finished episodes restarted."""
        if "steps" in state.info:
            steps = jnp.where(state.done > 0, jnp.zeros_like(state.info["steps"]),
                              state.info["steps"])
            state.info.update(steps=steps)
        state = state.replace(done=jnp.zeros_like(state.done))
        return self.env.step(state, action)

    @staticmethod
    def _restart(state: State, fresh: State) -> State:
        """``state`` with every done environment replaced by its slot of ``fresh``."""
        done = state.done
        info = dict(state.info)
        for k, v in fresh.info.items():
            if k not in EPISODE_KEYS:
                info[k] = where_done(done, v, state.info[k])
        return state.replace(
            pipeline_state=where_done(done, fresh.pipeline_state, state.pipeline_state),
            obs=where_done(done, fresh.obs, state.obs),
            info=info,
        )

    def reset(self, rng: jax.Array, scene: dict[str, jax.Array] | None = None) -> State:
        """The batch's first episodes (``rng`` of shape ``(B, 2)``); with ``scene`` (leaves with
        a leading ``B`` axis) each environment samples from its own scene parameters
        (:meth:`envs.reaching.ReachEnv.default_scene`), which its later episodes keep."""
        state = self.env.reset(rng)
        if scene is None:
            return state
        # of ``state`` only brax's bookkeeping (zeros) is used: under jit the rest is dropped
        fresh = self._fresh(rng, scene)
        return fresh.replace(info={**fresh.info,
                                   **{k: state.info[k] for k in EPISODE_KEYS}})

    def _fresh(self, rng: jax.Array, scene: dict[str, jax.Array] | None) -> State:
        """New episodes of the batch from the keys ``rng``: the wrapped environment's reset,
        or, for environments that keep their scene in ``info["scene"]``, the base
        environment's reset of each row's own scene (the wrappers in between — vmap, episode
        limit — add only :data:`EPISODE_KEYS`, which a restart keeps from the old state)."""
        if scene is None:
            return self.env.reset(rng)
        return jax.vmap(self.env.unwrapped.reset)(rng, scene)

    def _reset_done(self, state: State) -> State:
        return self._restart(state, self._fresh(state.info["rng"], state.info.get("scene")))

    def step(self, state: State, action: jax.Array, axis_name: str | None = None) -> State:
        """Step every environment; finished episodes restart from a freshly sampled scene (on
        the CPU computed only when an episode ended in the batch or, with ``axis_name``, in any
        row of the enclosing ``vmap`` of that name)."""
        if jax.default_backend() not in CONDITIONAL_RESET_BACKENDS:
            return self.step_resetting_always(state, action)
        state = self._advance(state, action)
        ended = jnp.any(state.done > 0)
        if axis_name is not None:
            ended = jax.lax.pmax(ended, axis_name)
        return jax.lax.cond(ended, self._reset_done, lambda s: s, state)

    def step_resetting_always(self, state: State, action: jax.Array) -> State:
        """:meth:`step` with the reset computed for every environment at every step and selected
        where an episode ended (the same states; the reference the conditional is measured and
        tested against)."""
        return self._reset_done(self._advance(state, action))

    def reset_pool(self, state: State, depth: int) -> ResetPool:
        """The next ``depth`` episode starts of every environment of ``state``: the first from
        ``state.info["rng"]`` (what :meth:`step` would reset to), each further one from the key
        its predecessor stores."""
        if depth < 1:
            raise ValueError(f"depth must be a positive integer, got {depth}")

        scene = state.info.get("scene")

        def following(rng, _):
            start = self._fresh(rng, scene)
            return start.info["rng"], start

        _, starts = jax.lax.scan(following, state.info["rng"], None, length=depth)
        taken = jnp.zeros(state.done.shape, jnp.int32)
        return ResetPool(starts, taken, jnp.zeros((), bool))

    def step_from_pool(self, state: State, action: jax.Array, pool: ResetPool
                       ) -> tuple[State, ResetPool]:
        """:meth:`step` with each finished episode restarted from the environment's next unused
        start in ``pool`` instead of a reset computed now (equal while ``pool.overflow`` stays
        False)."""
        state = self._advance(state, action)
        depth = jax.tree.leaves(pool.starts)[0].shape[0]
        fresh = jax.tree.map(lambda x: x[depth - 1], pool.starts)
        for j in reversed(range(depth - 1)):
            fresh = where_done((pool.taken == j).astype(jnp.float32),
                                jax.tree.map(lambda x, j=j: x[j], pool.starts), fresh)
        taken = pool.taken + (state.done > 0).astype(jnp.int32)
        overflow = pool.overflow | jnp.any(taken > depth)
        return self._restart(state, fresh), ResetPool(pool.starts, taken, overflow)


def wrap(env: Env, episode_length: int | None = None, action_repeat: int = 1) -> Wrapper:
    """Training wrapper: ``VmapWrapper`` → ``EpisodeWrapper`` → :class:`AutoResetWrapper`.

    ``episode_length`` defaults to the environment's ``horizon`` (600 control steps). ``reset``
    takes a batch of keys ``(B, 2)``.
    """
    if episode_length is None:
        episode_length = int(getattr(env.unwrapped, "horizon", 1000))
    env = VmapWrapper(env)
    env = EpisodeWrapper(env, episode_length, action_repeat)
    return AutoResetWrapper(env)


class RMPInEnv(Wrapper):
    """RMP² inside the environment (thesis §6.1.1, §6.2.2): the action is a residual RMP.

    For an end effector of dimension ``m`` the action has ``m·m + m`` entries: the raw
    metric-root residual ``A_r`` (row-major) and the raw acceleration residual ``a_r``, squashed
    as ``A_r = √5·tanh(·)`` and ``a_r = tanh(·)`` (docs/design.md §4.4). With the hand-designed
    target RMP ``(M_h, a_h)`` of the ``residual_rmp`` preset, the learned end-effector leaf is
    ``M = (A_r + chol(M_h))(A_r + chol(M_h))ᵀ``, ``a = a_r + a_h``; it replaces the target leaf
    and is combined with the other hand-designed leaves by RMP². The resulting joint
    acceleration goes to the wrapped environment (which clips it and runs the PD scheme).

    A zero action reproduces the ``residual_rmp`` base policy. Wrap a single (un-vmapped)
    environment; build it with ``observation="residual_rmp"`` to give the network
    ``[x, ẋ, g, {o_i}]`` (goal, end-effector position/velocity are appended to the observation).
    """

    def __init__(self, env: Env, variant: str = "residual_rmp"):
        super().__init__(env)
        if variant != "residual_rmp":
            raise ValueError(f"RMPInEnv supports variant='residual_rmp' only, got {variant!r}")
        base = env.unwrapped
        self.robot = base.robot
        self.m = self.robot.workspace_dim
        self.policy_config = policies.default_config(base.robot_name, variant)

    @property
    def action_size(self) -> int:
        """``m·m + m``: the raw metric-root and acceleration residuals."""
        return self.m * self.m + self.m

    def squash(self, action: jax.Array) -> tuple[jax.Array, jax.Array]:
        """``(A_r (m, m), a_r (m,))`` from a raw action."""
        m = self.m
        A_r = math.sqrt(5.0) * jnp.tanh(action[: m * m]).reshape(m, m)
        a_r = jnp.tanh(action[m * m :])
        return A_r, a_r

    def joint_acceleration(self, state: State, action: jax.Array) -> jax.Array:
        """Joint acceleration of the combined RMP² policy for a raw residual action."""
        cfg = self.policy_config
        A_r, a_r = self.squash(jnp.where(jnp.isfinite(action), action, 0.0))
        q, qd, goal, obstacles = self.env.unwrapped.policy_inputs(state)
        return policies.residual_rmp_acceleration(cfg, q, qd, goal, obstacles, A_r, a_r)

    def step(self, state: State, action: jax.Array) -> State:
        """Step the wrapped environment with the RMP² acceleration of the residual action."""
        check_action(action, self.action_size)
        return self.env.step(state, self.joint_acceleration(state, action))


__all__ = ["CONDITIONAL_RESET_BACKENDS", "EPISODE_KEYS", "AutoResetWrapper", "RMPInEnv",
           "ResetPool", "where_done", "wrap"]
