"""The auto-reset computed only when an episode ended (envs.wrappers.AutoResetWrapper.step, a
``lax.cond``; docs/design.md §5.7) gives the states of a reset computed and selected at every
step, and stays a real branch under a ``vmap`` that names its axis. The conditional is what
``step`` does on the CPU (``CONDITIONAL_RESET_BACKENDS``), where these tests run.

Tolerance: both paths run the same float32 operations on the same keys; on this CPU they agree
bit for bit, but XLA may fuse the reset differently inside a conditional, so 1e-6 is allowed.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from envs.wrappers import CONDITIONAL_RESET_BACKENDS, wrap

TOL = 1e-6
AXIS = "seeds"
pytestmark = pytest.mark.skipif(jax.default_backend() not in CONDITIONAL_RESET_BACKENDS,
                                reason="the auto-reset is conditional on the CPU only")


def _runs(env, episode_length: int, steps: int, batch: int = 4):
    """``steps`` steps of a constant action from the same start, with the conditional reset
    and with the reference; both final states and per-step done flags."""
    w = wrap(env, episode_length)
    state = jax.jit(w.reset)(jax.random.split(jax.random.PRNGKey(3), batch))
    action = 0.3 * jnp.ones((batch, env.action_size), jnp.float32)

    def run(step):
        def body(s, _):
            s = step(s)
            return s, s.done
        return jax.lax.scan(body, state, None, length=steps)

    return jax.jit(lambda: (run(lambda s: w.step(s, action)),
                            run(lambda s: w.step_resetting_always(s, action))))()


@pytest.mark.parametrize("robot", [
    "three_link/env3",
    # robot-independent wrapper code; the Franka repeats it on the larger physics state
    pytest.param("franka", marks=pytest.mark.slow),
])
def test_conditional_reset_equals_a_reset_every_step(robot):
    """Episodes of 5 steps over 12 steps: two restarts per environment, at steps 5 and 10, and
    steps without any; states, observations, rewards and episode info equal the reference."""
    (s_cond, d_cond), (s_ref, d_ref) = _runs(envs.make(robot), 5, 12)
    d = np.asarray(d_cond)
    assert d.sum() == 2 * 4 and (d.sum(axis=1) == 0).sum() == 10
    np.testing.assert_array_equal(d, np.asarray(d_ref))
    for a, b in zip(jax.tree.leaves((s_cond.pipeline_state.qpos, s_cond.pipeline_state.qvel,
                                     s_cond.obs, s_cond.reward, s_cond.info)),
                    jax.tree.leaves((s_ref.pipeline_state.qpos, s_ref.pipeline_state.qvel,
                                     s_ref.obs, s_ref.reward, s_ref.info)), strict=True):
        np.testing.assert_allclose(np.asarray(a, np.float64), np.asarray(b, np.float64),
                                   rtol=TOL, atol=TOL)


def test_the_reset_stays_a_branch_under_a_named_vmap():
    """Under ``vmap`` with the axis passed on, the predicate is reduced over the rows and the
    reset remains a ``cond``; under an unnamed ``vmap`` JAX turns it into a select of both."""
    w = wrap(envs.make("three_link/env3"), 5)
    keys = jax.random.split(jax.random.PRNGKey(0), 2 * 3).reshape(2, 3, 2)
    states = jax.eval_shape(jax.vmap(w.reset), keys)  # shapes only: the jaxprs are compared
    action = jnp.zeros((2, 3, 3), jnp.float32)
    named = jax.make_jaxpr(jax.vmap(lambda s, a: w.step(s, a, axis_name=AXIS),
                                    axis_name=AXIS))(states, action)
    unnamed = jax.make_jaxpr(jax.vmap(w.step))(states, action)
    assert "cond[" in str(named) and "pmax" in str(named)
    assert "cond[" not in str(unnamed)
