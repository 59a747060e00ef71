"""Where a control step's time goes: each phase of a reaching environment's control step timed
alone at one batch size, against the physics floor (docs/reports/performance.md).

Phases, each a compiled ``lax.scan`` over ``steps`` control steps of ``batch`` environments and
reported per control step:

* ``physics`` — raw ``mjx.step`` × ``substeps`` with the servo targets held (substeps unrolled
  and mass-matrix solves written out where the environment does so), on the model as
  generated (:data:`PHYSICS_VARIANTS` ``as_is``), with the constraint, contact, equality,
  friction-loss and limit stages disabled (``contact_free``), and the same with one solver
  iteration (``contact_free_1iter``): the floor the environment is compared with;
* ``env_step_raw`` — the environment's own ``step`` (PD scheme, geometry, reward, observation)
  with a zero action, no wrappers;
* ``env_step`` — the training ``envs.wrappers.wrap`` step (episode limit and auto-reset: on the
  CPU computed only at steps where an episode ended, elsewhere at every step and selected);
* ``env_step_reset_always`` — where the auto-reset is conditional (the CPU), the same with the
  reset computed for every environment at every step and selected where an episode ended;
* ``env_step_pooled`` — the same, restarting from reset pools made every
  :data:`agents.ppo.rollout.POOL_BLOCK` steps, as the PPO rollout does;
* ``reset`` — one full ``reset`` of every environment (scene sampling with rejection);
* ``observe`` — geometry, observation and goal metrics alone;
* ``rmp2_policy`` — the hand-designed RMP² policy's forward alone;
* ``ppo_rollout`` — the PPO trainer's rollout as training runs it (:data:`PPO_POLICY`, the
  thesis preset, the batch split over :data:`PPO_SEEDS` vmapped seeds): environment step with
  auto-reset, the policy's forward (RMP² included), sampling and the stored transitions.

:func:`limit_excursions` rolls the hand-designed policy out with the model as generated and with
the contact-free one from the same scenes: how far joint limits are exceeded under each and how
far the trajectories drift apart (the check before a stage may be dropped).
"""

from __future__ import annotations

import functools
import statistics
import time
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx

import envs
from agents.ppo.rollout import POOL_DEPTH, pool_block
from agents.run.program import SEED_AXIS, build, seed_keys
from agents.run.spec import RunSpec, preset
from envs.evaluate import hand_designed_policy
from envs.physics import set_constraint_stages, written_out_mass_solves
from envs.wrappers import CONDITIONAL_RESET_BACKENDS, wrap

#: The MJX model variants timed as the physics floor.
PHYSICS_VARIANTS = ("as_is", "contact_free", "contact_free_1iter")
#: The policy kind and the vmapped seeds of the ``ppo_rollout`` phase (the thesis runs: 4 seeds
#: × 128 environments = 512).
PPO_POLICY, PPO_SEEDS = "rmp_residual", 4

def physics_model(mj_model: mujoco.MjModel, variant: str) -> mjx.Model:
    """The MJX model of ``mj_model`` in :data:`PHYSICS_VARIANTS` ``variant``: ``as_is`` with
    MuJoCo's constraint pipeline on (the MJCF as generated), ``contact_free`` with it off (what
    the environments run, docs/design.md §5.8), ``contact_free_1iter`` also with one solver
    iteration."""
    if variant not in PHYSICS_VARIANTS:
        raise ValueError(f"variant must be one of {PHYSICS_VARIANTS}, got {variant!r}")
    m = set_constraint_stages(mj_model, variant == "as_is")
    if variant == "contact_free_1iter":
        m.opt.iterations = 1
    return mjx.put_model(m)


def time_phase(fn: Callable[[], Any], steps: int, repeats: int) -> dict[str, float]:
    """Compile time and the median (min, max) wall time per control step of ``fn``."""
    t0 = time.perf_counter()
    jax.block_until_ready(fn())
    compile_s = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        times.append((time.perf_counter() - t0) / steps)
    return {"per_step_s": statistics.median(times), "min_s": min(times), "max_s": max(times),
            "compile_s": compile_s}


def _data_like(model: mjx.Model, data: mjx.Data, batch: int) -> mjx.Data:
    """A batch of ``model``'s data (its constraint arrays sized for it) with the joint state and
    controls of ``data``."""
    fresh = jax.vmap(lambda _: mjx.make_data(model))(jnp.arange(batch))
    return fresh.replace(qpos=data.qpos, qvel=data.qvel, ctrl=data.ctrl)


def _scan(body: Callable[[Any], Any], steps: int) -> Callable[[Any], Any]:
    """``carry -> carry`` after ``steps`` applications of ``body``, jitted."""
    return jax.jit(lambda c: jax.lax.scan(lambda c, _: (body(c), None), c, None,
                                          length=steps)[0])


def _fed_back(fn: Callable[[Any], Any], state: Any, steps: int) -> Callable[[], Any]:
    """``steps`` evaluations of ``fn(state)``, each output fed back into the joint positions at
    1e-9 scale so that no evaluation is loop-invariant (XLA would hoist it out of the loop)."""
    def body(s):
        y = jnp.mean(jnp.concatenate([jnp.ravel(x) for x in jax.tree.leaves(fn(s))]))
        data = s.pipeline_state
        return s.replace(pipeline_state=data.replace(qpos=data.qpos + 1e-9 * jnp.tanh(y)))

    program = _scan(body, steps)
    return lambda: program(state)


def phase_programs(env_name: str, batch: int, steps: int, key: jax.Array
              ) -> dict[str, Callable[[], Any]]:
    """``{phase: fn}``: the programs of the module docstring, each a call ``fn()`` of ``steps``
    control steps of ``batch`` environments, closed over its input."""
    base = envs.make(env_name)
    wrapped = wrap(base)
    keys = jax.random.split(key, batch)
    state = jax.jit(jax.vmap(base.reset))(keys)
    wstate = jax.jit(wrapped.reset)(keys)
    zero = jnp.zeros((batch, base.action_size), jnp.float32)
    data = state.pipeline_state
    out: dict[str, Callable[[], Any]] = {}
    for variant in PHYSICS_VARIANTS:
        model = physics_model(base.mj_model, variant)
        # the substeps looped and the mass-matrix solves traced as the environment does them
        def substeps(d: mjx.Data, m: mjx.Model = model) -> mjx.Data:
            with written_out_mass_solves(base.written_out_solves):
                return jax.lax.scan(lambda d, _: (mjx.step(m, d), None), d, None,
                                    length=base.substeps, unroll=base.substep_unroll)[0]

        sub = jax.vmap(substeps)
        out[f"physics_{variant}"] = functools.partial(_scan(sub, steps),
                                                      _data_like(model, data, batch))
    raw = _scan(lambda s: jax.vmap(base.step)(s, zero), steps)
    out["env_step_raw"] = lambda: raw(state)
    stepped = _scan(lambda s: wrapped.step(s, zero), steps)
    out["env_step"] = lambda: stepped(wstate)
    if jax.default_backend() in CONDITIONAL_RESET_BACKENDS:  # else env_step is this program
        always = _scan(lambda s: wrapped.step_resetting_always(s, zero), steps)
        out["env_step_reset_always"] = lambda: always(wstate)
    block = pool_block(steps) or steps

    def pooled_block(s):
        def body(c, _):
            return wrapped.step_from_pool(c[0], zero, c[1]), None
        return jax.lax.scan(body, (s, wrapped.reset_pool(s, POOL_DEPTH)), None,
                            length=block)[0][0]

    pooled = jax.jit(lambda s: jax.lax.scan(lambda c, _: (pooled_block(c), None), s, None,
                                            length=steps // block)[0])
    out["env_step_pooled"] = lambda: pooled(wstate)
    # reset stores the next key in info["rng"]: each call draws new scenes (nothing to hoist)
    resets = _scan(lambda s: jax.vmap(base.reset)(s.info["rng"]), steps)
    out["reset"] = lambda: resets(state)

    def observe(s):
        q, qd, goal, obs = base.policy_inputs(s)
        o = base.observe(q, qd, goal, obs)
        return o, base._goal_metrics(q, goal)["goal_distance"] + base._robot_clearance(q, obs)

    out["observe"] = _fed_back(jax.vmap(observe), state, steps)
    out["rmp2_policy"] = _fed_back(jax.vmap(hand_designed_policy(base)), state, steps)
    out["ppo_rollout"] = ppo_rollout(env_name, batch, steps)
    return out


def ppo_rollout(env_name: str, batch: int, steps: int) -> Callable[[], Any]:
    """A call of ``steps`` control steps of the PPO trainer's rollout (:data:`PPO_POLICY`,
    thesis preset) over ``batch`` environments, split over :data:`PPO_SEEDS` vmapped seeds
    (one seed where ``batch`` does not split), from the run's initial state; the program is
    built at the first call."""
    seeds = PPO_SEEDS if batch % PPO_SEEDS == 0 else 1
    # the rollout does not depend on the update's settings: one minibatch fits any batch
    spec = RunSpec(env=env_name, policy=PPO_POLICY, seeds=tuple(range(seeds)),
                   ppo=preset("thesis", num_envs=batch // seeds, rollout_length=steps,
                              num_minibatches=1))

    @functools.cache
    def program() -> Callable[[], Any]:
        prog = build(spec)
        state = prog.initial_state(seed_keys(spec.seeds))
        keys = jax.vmap(jax.random.PRNGKey)(jnp.arange(seeds))
        rollout = jax.jit(jax.vmap(prog.trainer.rollout, axis_name=SEED_AXIS))
        return functools.partial(rollout, state, keys)

    return lambda: program()()


def limit_excursions(env_name: str, episodes: int, steps: int, key: jax.Array,
                     policy: Callable[[Any], jax.Array] | None = None) -> dict[str, float]:
    """``policy`` (a function of the environment state; default the hand-designed RMP² policy)
    over ``episodes`` scenes × ``steps`` control steps, with MuJoCo's constraint pipeline on
    (``as_is``) and off (``contact_free``, what the environment runs), from the same scenes
    without auto-reset: ``max_excess_<variant>`` (rad beyond a joint limit, 0 if never),
    ``max_abs_dq`` (largest joint-position difference between the two runs),
    ``final_abs_dq_p99`` (its 99th percentile over episodes at the last step) and
    ``repeat_max_abs_dq`` (the same difference between two runs of ``as_is``: 0 on a
    deterministic device, the device's own run-to-run spread on a GPU)."""
    base = envs.make(env_name)
    policy = policy if policy is not None else hand_designed_policy(base)
    lo = jnp.where(jnp.isfinite(base._q_lower), base._q_lower, -jnp.inf)
    hi = base._q_upper
    keys = jax.random.split(key, episodes)

    def program(model: mjx.Model) -> Callable[[jax.Array], Any]:
        data0 = mjx.make_data(model)

        def one(k):
            s = base.reset(k)
            s = s.replace(pipeline_state=data0.replace(
                qpos=s.pipeline_state.qpos, qvel=s.pipeline_state.qvel,
                ctrl=s.pipeline_state.ctrl))

            def body(s, _):
                s = base.step(s, policy(s))
                q = s.pipeline_state.qpos
                return s, (q, jnp.max(jnp.maximum(q - hi, lo - q)))
            return jax.lax.scan(body, s, None, length=steps)[1]
        return jax.jit(jax.vmap(one))

    own = base.mjx_model
    try:
        base.mjx_model = physics_model(base.mj_model, "as_is")
        run_as_is = program(base.mjx_model)
        q_a, ex_a = run_as_is(keys)
        q_r, _ = run_as_is(keys)
        base.mjx_model = physics_model(base.mj_model, "contact_free")
        q_f, ex_f = program(base.mjx_model)(keys)
    finally:
        base.mjx_model = own
    dq = jnp.max(jnp.abs(q_a - q_f), axis=-1)
    return {"episodes": episodes, "steps": steps,
            "max_excess_as_is": float(jnp.maximum(jnp.max(ex_a), 0.0)),
            "max_excess_contact_free": float(jnp.maximum(jnp.max(ex_f), 0.0)),
            "max_abs_dq": float(jnp.max(dq)),
            "final_abs_dq_p99": float(jnp.percentile(dq[:, -1], 99)),
            "repeat_max_abs_dq": float(jnp.max(jnp.abs(q_a - q_r)))}


__all__ = ["PHYSICS_VARIANTS", "PPO_POLICY", "PPO_SEEDS", "limit_excursions", "phase_programs",
           "physics_model", "ppo_rollout", "time_phase"]
