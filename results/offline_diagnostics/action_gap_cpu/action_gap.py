"""One-step action gap of the expert's Q (session 12; environment and control rate added in
session 13).

From 64 scenes: the expert for T0 steps, then one control step of the expert's action, its
negation, zero, +1 or -1 on every joint, then the expert for 400 steps; discounted returns
(gamma 0.99) of the five branches. Usage: python action_gap.py T0 [ENV] [SUBSTEPS]
(default three_link/env3 at the environment's 3 substeps, 80 Hz; 24 substeps is 10 Hz with the
same 7.5 s episodes).
"""
import sys

import jax
import jax.numpy as jnp
import numpy as np
from offline.sweep import control_rate_kwargs

from envs.evaluate import hand_designed_policy
from offline import collect

ENV_NAME = sys.argv[2] if len(sys.argv) > 2 else "three_link/env3"
SUBSTEPS = int(sys.argv[3]) if len(sys.argv) > 3 else None
ENV = collect.make_env(ENV_NAME, control_rate_kwargs(ENV_NAME, SUBSTEPS))
EXPERT = hand_designed_policy(ENV)
GAMMA, HORIZON = 0.99, 400


def expert_action(state):
    return jnp.clip(EXPERT(state), -1.0, 1.0)


def branches(key, t0):
    state = ENV.reset(key)
    state = jax.lax.fori_loop(0, t0, lambda i, s: ENV.step(s, expert_action(s)), state)
    a_ex = expert_action(state)

    def discounted_return(a0):
        s1 = ENV.step(state, a0)

        def body(carry, t):
            st, acc = carry
            nxt = ENV.step(st, expert_action(st))
            nxt = jax.tree.map(lambda x, y: jnp.where(st.done > 0, y, x), nxt, st)
            return (nxt, acc + jnp.where(st.done > 0, 0.0, nxt.reward) * GAMMA ** (t + 1)), None

        (_, acc), _ = jax.lax.scan(body, (s1, s1.reward), jnp.arange(HORIZON))
        return acc

    ones = jnp.ones_like(a_ex)
    return jnp.stack([discounted_return(a) for a in (a_ex, -a_ex, 0 * ones, ones, -ones)])


def main() -> None:
    t0 = int(sys.argv[1])
    keys = jax.random.split(jax.random.PRNGKey(3), 64)
    q = np.asarray(jax.jit(jax.vmap(lambda k: branches(k, t0)))(keys))
    print(f"{ENV_NAME} substeps {SUBSTEPS or 3} T0 {t0} Q(expert) mean {q[:, 0].mean():.3f} "
          f"|Q(ex)-Q(-ex)| mean {np.abs(q[:, 0] - q[:, 1]).mean():.4f} "
          f"|Q(ex)-Q(0)| {np.abs(q[:, 0] - q[:, 2]).mean():.4f} "
          f"|Q(+1)-Q(-1)| {np.abs(q[:, 3] - q[:, 4]).mean():.4f} "
          f"max over actions - min: {(q.max(1) - q.min(1)).mean():.4f}")


if __name__ == "__main__":
    main()
