"""The NN-RESIDUAL actor's RMP² base alone, scored like a learner (session 14).

Every chapter-7 learner with ``--actor nn_residual`` acts ``a_max·tanh(μ(s) + b(s))``
(offline.residual_actor); with a zero network mean that is the base policy, the ``residual_base``
RMP² preset clipped to the action limit. This evaluates it as reproduce_ch7.py evaluates a
learner (64 episodes, key 10 000, at 10 Hz), with the hand-designed expert (100) and uniform
random (0) as references. Usage: python base_score.py ENV [SUBSTEPS]
"""
import sys

import jax
import jax.numpy as jnp
from agents.policies import ObservationSpec
from offline.residual_actor import BASE_VARIANT, base_pre_tanh
from offline.sweep import control_rate_kwargs

from mjxrmp import policies as rmp_policies
from offline import evaluate

ENV = sys.argv[1]
SUBSTEPS = int(sys.argv[2]) if len(sys.argv) > 2 else 24


def main() -> None:
    ev = evaluate.make_evaluator(ENV, 64, env_kwargs=control_rate_kwargs(ENV, SUBSTEPS))
    spec = ObservationSpec.from_env(ev.env)
    cfg = rmp_policies.default_config(spec.robot, BASE_VARIANT)
    a_max = float(ev.env.action_limit)

    def act(params, obs):
        del params
        return a_max * jnp.tanh(base_pre_tanh(spec, cfg, a_max, obs))

    res = ev.evaluate(act, None, jax.random.PRNGKey(10_000))
    print(f"{ENV}, {SUBSTEPS} substeps: base '{BASE_VARIANT}' alone: score "
          f"{float(res['normalized_score']):.1f}, safe {float(res['safe_pct']):.1f} %, success "
          f"{float(res['success_pct']):.1f} %, final goal distance "
          f"{float(res['mean_final_goal_distance']):.3f} m; reference {ev.reference}", flush=True)


if __name__ == "__main__":
    main()
