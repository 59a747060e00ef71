"""Dropping MuJoCo's constraint pipeline (envs.physics, docs/design.md §5.8): the environments
run without it by default, ``constraint_stages=True`` restores the model as generated, the
trajectories of both agree (3-link exactly, Franka to float rounding), and the joint-limit
check of agents.bench.phases takes any policy, trained runs included. Unrolling the physics
substeps (docs/design.md §5.9) and writing out MJX's mass-matrix solves (§5.10) change no
trajectory."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from env_rollouts import random_action_qpos

import envs
from agents.bench.phases import limit_excursions
from agents.bench.profile import limit_checks
from agents.run.spec import RunSpec, preset
from agents.run.training import run_training
from envs.physics import (
    CONSTRAINT_STAGES,
    constraint_stages_on,
    set_constraint_stages,
    written_out_mass_solves,
)
from mjxrmp.core import linalg


def test_environments_drop_the_constraint_pipeline_by_default():
    """Every flag of CONSTRAINT_STAGES is set in the default model and cleared with
    ``constraint_stages=True``; set_constraint_stages copies and round-trips."""
    for name in ("three_link/env3", "franka"):
        off, on = envs.make(name), envs.make(name, constraint_stages=True)
        assert not off.constraint_stages and on.constraint_stages
        for flag in CONSTRAINT_STAGES:
            bit = int(getattr(mujoco.mjtDisableBit, flag))
            assert off.mj_model.opt.disableflags & bit
            assert not on.mj_model.opt.disableflags & bit
        assert not constraint_stages_on(off.mj_model) and constraint_stages_on(on.mj_model)
        back = set_constraint_stages(set_constraint_stages(on.mj_model, False), True)
        assert back.opt.disableflags == on.mj_model.opt.disableflags
        assert not constraint_stages_on(off.mj_model)  # the copy left the original alone
    with pytest.raises(ValueError, match="constraint_stages"):
        envs.make("franka", constraint_stages="yes")


@functools.cache
def _rollout_of(name: str, **env_kwargs: bool) -> np.ndarray:
    """:func:`random_action_qpos` of ``envs.make(name, **env_kwargs)`` (40 steps × 4
    environments), computed once per module (the CPU-default model's rollout is the reference
    of every check below)."""
    return random_action_qpos(envs.make(name, **env_kwargs), 40, 4)


@pytest.mark.parametrize("name,tol", [("three_link/env3", 0.0), ("franka", 1e-5)])
def test_trajectories_with_and_without_the_constraint_pipeline_agree(name, tol):
    """Random actions, 40 control steps × 4 environments: the joint positions agree exactly for
    the 3-link (no limited joints) and to 1e-5 rad for the Franka (float rounding of the
    solver's unconstrained pass; no limit is touched)."""
    off = _rollout_of(name, written_out_solves=False, unroll_substeps=False)
    on = _rollout_of(name, constraint_stages=True, written_out_solves=False,
                     unroll_substeps=False)
    assert np.isfinite(off).all()
    np.testing.assert_allclose(off, on, rtol=0, atol=tol)


@pytest.mark.parametrize("name", ["three_link/env3", "franka"])
def test_substep_unroll_is_the_gpu_default(name):
    """Unrolling the physics substeps (docs/design.md §5.9) is on by default on a GPU only and
    ``unroll_substeps=True`` writes every substep out."""
    looped = envs.make(name)
    assert looped.substep_unroll == (looped.substeps if jax.default_backend() == "gpu" else 1)
    written = envs.make(name, unroll_substeps=True)
    assert written.substep_unroll == written.substeps
    with pytest.raises(ValueError, match="unroll_substeps"):
        envs.make(name, unroll_substeps=1)


def test_unrolled_substeps_give_the_same_trajectories():
    """The physics substeps written out and looped give the same joint trajectories (40
    random-action control steps × 4 environments, to float rounding; the Franka's are checked
    with both GPU defaults together below)."""
    name = "three_link/env3"
    np.testing.assert_allclose(_rollout_of(name, written_out_solves=False, unroll_substeps=True),
                               _rollout_of(name, written_out_solves=False, unroll_substeps=False),
                               rtol=0, atol=1e-6)


def _primitives(env) -> set[str]:
    """The primitives of one traced control step of ``env`` (nested jaxprs included)."""
    state = jax.eval_shape(env.reset, jax.random.PRNGKey(0))  # shapes only: nothing runs
    text = str(jax.make_jaxpr(env.step)(state, jnp.zeros(env.action_size)))
    return {name for name in ("cholesky", "triangular_solve") if name in text}


@pytest.mark.parametrize("name", ["three_link/env3", "franka"])
def test_written_out_mass_solves_leave_no_library_factorisation(name):
    """MJX's mass-matrix factorisations and solves written out (``written_out_solves=True``,
    docs/design.md §5.10) leave no library Cholesky or triangular solve in the control step;
    the default is on a GPU only; the context restores JAX's functions, also after an error."""
    assert _primitives(envs.make(name, written_out_solves=True)) == set()
    assert _primitives(envs.make(name, written_out_solves=False)) == {"cholesky",
                                                                      "triangular_solve"}
    assert envs.make(name).written_out_solves == (jax.default_backend() == "gpu")
    library = jax.scipy.linalg.cho_factor, jax.scipy.linalg.cho_solve
    with pytest.raises(RuntimeError, match="inside"), written_out_mass_solves():
        assert jax.scipy.linalg.cho_factor is linalg.cho_factor
        raise RuntimeError("inside")
    with written_out_mass_solves(False):
        assert (jax.scipy.linalg.cho_factor, jax.scipy.linalg.cho_solve) == library
    assert (jax.scipy.linalg.cho_factor, jax.scipy.linalg.cho_solve) == library
    with pytest.raises(ValueError, match="written_out_solves must be a bool or None"):
        envs.make(name, written_out_solves=1)


def test_written_out_mass_solves_give_the_same_trajectories():
    """With MJX's mass-matrix solves written out the joint trajectories equal the library's (40
    random-action control steps × 4 environments) to float rounding."""
    name = "three_link/env3"
    np.testing.assert_allclose(_rollout_of(name, written_out_solves=True, unroll_substeps=False),
                               _rollout_of(name, written_out_solves=False, unroll_substeps=False),
                               rtol=0, atol=1e-6)


def test_gpu_default_physics_gives_the_franka_the_same_trajectories():
    """The Franka with both GPU defaults (substeps written out, mass-matrix solves written out)
    against the CPU default (looped, library solves): the same joint trajectories to float
    rounding (40 random-action control steps × 4 environments). Each option alone is checked
    on the 3-link above; neither has code of its own per robot."""
    np.testing.assert_allclose(_rollout_of("franka", written_out_solves=True, unroll_substeps=True),
                               _rollout_of("franka", written_out_solves=False,
                                           unroll_substeps=False),
                               rtol=0, atol=1e-6)


def test_limit_check_takes_any_policy():
    """limit_excursions with a policy that drives every joint at full acceleration: finite
    figures, a same-model repeat that is exactly 0 on the CPU, and the 3-link (no limits)
    never exceeds one."""
    env = envs.make("three_link/env3")

    def full_speed(state):
        return jnp.ones((env.action_size,))

    lim = limit_excursions("three_link/env3", 3, 5, jax.random.PRNGKey(0), full_speed)
    assert lim["episodes"] == 3 and lim["steps"] == 5
    assert lim["max_excess_as_is"] == lim["max_excess_contact_free"] == 0.0
    assert lim["repeat_max_abs_dq"] == 0.0
    assert lim["max_abs_dq"] == 0.0


@pytest.mark.slow  # the same API is checked by test_limit_check_takes_any_policy
def test_limit_check_of_a_trained_run(tmp_path):
    """limit_checks loads a trained run's first seed and checks it beside the hand-designed
    policy; a run of another environment is refused."""
    spec = RunSpec(env="three_link/env3", policy="nn", seeds=(0,), log_every=1,
                   checkpoint_every=1,
                   ppo=preset("cpu", num_envs=4, rollout_length=8, num_minibatches=2,
                              update_epochs=1, total_iterations=1))
    run_training(spec, str(tmp_path), progress=False)
    out = limit_checks("three_link/env3", 2, 4, jax.random.PRNGKey(0), str(tmp_path))
    assert set(out) == {"hand_designed", "trained"}
    assert out["trained"]["run"].startswith("nn, 1 iterations")
    assert np.isfinite(out["trained"]["max_abs_dq"])
    with pytest.raises(ValueError, match="trained on"):
        limit_checks("three_link/env1", 2, 4, jax.random.PRNGKey(0), str(tmp_path))
