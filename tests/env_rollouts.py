"""Open-loop rollouts for trajectory comparisons: the same scenes and the same random actions,
so two variants of an environment (or two runs of one) can be compared joint by joint."""

import jax
import numpy as np


def random_action_qpos(env, steps: int, batch: int) -> np.ndarray:
    """Joint positions ``(steps, batch, nq)`` of ``batch`` environments reset from
    ``PRNGKey(0)`` and driven by uniform random actions in [-1, 1] from ``PRNGKey(1)``."""
    keys = jax.random.split(jax.random.PRNGKey(0), batch)
    actions = jax.random.uniform(jax.random.PRNGKey(1), (steps, batch, env.action_size),
                                 minval=-1.0, maxval=1.0)

    def body(s, a):
        s = jax.vmap(env.step)(s, a)
        return s, s.pipeline_state.qpos

    return np.asarray(jax.jit(lambda k: jax.lax.scan(body, jax.vmap(env.reset)(k),
                                                     actions)[1])(keys))
