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

import jax
import jax.numpy as jnp
from brax.envs.base import Env, State, Wrapper
from brax.envs.wrappers.training import EpisodeWrapper, VmapWrapper

from envs.base import check_action
from mjxrmp import policies

#: ``state.info`` entries owned by brax's ``EpisodeWrapper``: kept across an automatic reset.
EPISODE_KEYS = ("steps", "truncation", "episode_done", "episode_metrics")


def _where_done(done: jax.Array, new, old):
    def sel(x, y):
        d = jnp.reshape(done, done.shape + (1,) * (x.ndim - done.ndim)) > 0
        return jnp.where(d, x, y)

    return jax.tree.map(sel, new, old)


class AutoResetWrapper(Wrapper):
    """Resets done episodes with a *new* scene (goal, obstacles, initial state).

    Apply it outermost (after the vmap and episode wrappers). At each step every finished
    episode gets ``env.reset(state.info["rng"])``: pipeline state, observation and the
    environment's own ``info`` entries (goal, obstacles, key, per-episode accumulators) are
    replaced; brax's episode bookkeeping (:data:`EPISODE_KEYS`), ``reward``,
    ``done`` and ``metrics`` of the terminal step are kept, as in brax.
    """

    def step(self, state: State, action: jax.Array) -> State:
        """Step every environment; finished episodes restart from a freshly sampled scene."""
        if "steps" in state.info:
            steps = jnp.where(state.done > 0, jnp.zeros_like(state.info["steps"]),
                              state.info["steps"])
            state.info.update(steps=steps)
        state = state.replace(done=jnp.zeros_like(state.done))
        state = self.env.step(state, action)
        fresh = self.env.reset(state.info["rng"])
        done = state.done
        info = dict(state.info)
        for k, v in fresh.info.items():
            if k not in EPISODE_KEYS:
                info[k] = _where_done(done, v, state.info[k])
        return state.replace(
            pipeline_state=_where_done(done, fresh.pipeline_state, state.pipeline_state),
            obs=_where_done(done, fresh.obs, state.obs),
            info=info,
        )


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


__all__ = ["EPISODE_KEYS", "AutoResetWrapper", "RMPInEnv", "wrap"]
