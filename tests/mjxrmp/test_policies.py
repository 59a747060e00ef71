"""Hand-designed RMP² policies of both robots against the float64 reference, and their behaviour."""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from rmp_reference import reference_pullback, reference_resolve, rel_err

from mjxrmp import policies
from mjxrmp.core import rmp2
from mjxrmp.geometry import make_obstacles
from mjxrmp.robots import get


def random_context(robot_name, rng):
    robot = get(robot_name)
    if robot_name == "three_link":
        q = rng.uniform(-np.pi, np.pi, size=3)
        goal = rng.uniform(-0.6, 0.6, size=2)
        centers = rng.uniform(-0.6, 0.6, size=(3, 2))
    else:
        lo, hi = np.array(robot.q_lower), np.array(robot.q_upper)
        q = np.array(robot.default_q) + rng.uniform(-0.6, 0.6, size=7)
        q = np.clip(q, lo + 0.05, hi - 0.05)
        goal = rng.uniform([0.2, -0.5, 0.1], [0.7, 0.5, 0.8])
        centers = rng.uniform([0.1, -0.6, 0.0], [0.8, 0.6, 1.0], size=(3, 3))
    qd = rng.uniform(-1.0, 1.0, size=robot.dof)
    radii = rng.uniform(0.05, 0.1, size=3)
    return q, qd, goal, centers, radii


@pytest.mark.parametrize("robot_name", ["three_link", "franka"])
def test_policy_pullback_matches_float64_reference(robot_name):
    rng = np.random.default_rng(42)
    cfg = policies.default_config(robot_name)
    # compiled once per robot (RMP² run op by op costs several times its compile)
    pullback = jax.jit(functools.partial(rmp2.pullback, policies.task_map, policies.leaf_rmps))
    acceleration = jax.jit(policies.acceleration)
    with jax.enable_x64(True):
        for _ in range(3):
            q, qd, goal, centers, radii = random_context(robot_name, rng)
            obs = make_obstacles(jnp.asarray(centers), jnp.asarray(radii))
            args = (jnp.asarray(goal), obs, cfg)
            root = pullback(jnp.asarray(q), jnp.asarray(qd), *args)
            M_ref, f_ref = reference_pullback(policies.task_map, policies.leaf_rmps, q, qd, *args)
            assert rel_err(root.M, M_ref) <= 1e-6
            assert rel_err(root.f, f_ref) <= 1e-6
            qdd = acceleration(cfg, jnp.asarray(q), jnp.asarray(qd), jnp.asarray(goal), obs)
            assert rel_err(qdd, reference_resolve(M_ref, f_ref)) <= 1e-6


@pytest.mark.parametrize("robot_name", ["three_link", "franka"])
def test_policy_float32_agrees_with_float64(robot_name):
    rng = np.random.default_rng(7)
    cfg = policies.default_config(robot_name)
    states = [random_context(robot_name, rng) for _ in range(4)]

    @jax.jit
    def root_and_qdd(*context):
        root = policies.root(*context)
        return root, rmp2.resolve(root)

    def run(dtype):
        out = []
        for q, qd, goal, centers, radii in states:
            obs = make_obstacles(jnp.asarray(centers, dtype), jnp.asarray(radii, dtype))
            root, qdd = root_and_qdd(cfg, jnp.asarray(q, dtype), jnp.asarray(qd, dtype),
                                     jnp.asarray(goal, dtype), obs)
            assert qdd.dtype == dtype
            out.append((root.M, root.f, qdd))
        return out

    out32 = run(jnp.float32)
    with jax.enable_x64(True):
        out64 = run(jnp.float64)
    for a, b in zip(out32, out64, strict=True):
        for x32, x64 in zip(a, b, strict=True):
            assert rel_err(x32, x64) <= 1e-4


def test_gradient_wrt_policy_parameters_matches_finite_difference():
    rng = np.random.default_rng(3)
    cfg = policies.three_link_config()
    with jax.enable_x64(True):
        q, qd, goal, centers, radii = (jnp.asarray(a) for a in random_context("three_link", rng))
        obs = make_obstacles(centers, radii)

        @jax.jit
        def loss(c):
            return jnp.sum(policies.acceleration(c, q, qd, goal, obs) ** 2)

        grads = jax.jit(jax.grad(loss))(cfg)
        for leaf, field in (("target", "k_p"), ("damping", "damping_gain"),
                            ("collision", "repulsion_std")):
            g = getattr(getattr(grads, leaf), field)
            base = getattr(getattr(cfg, leaf), field)
            h = 1e-3 * base  # the loss is smooth; a larger step keeps roundoff small

            def shifted(delta, leaf=leaf, field=field, base=base):
                params = dataclasses.replace(getattr(cfg, leaf), **{field: base + delta})
                return loss(dataclasses.replace(cfg, **{leaf: params}))

            fd = (shifted(h) - shifted(-h)) / (2 * h)
            assert np.isfinite(g)
            assert abs(g - fd) <= 1e-5 * max(1.0, abs(fd)), (leaf, field, g, fd)


def test_inactive_obstacles_are_ignored():
    rng = np.random.default_rng(5)
    cfg = policies.franka_config()
    q, qd, goal, centers, radii = (jnp.asarray(a, jnp.float32)
                                   for a in random_context("franka", rng))
    centers = centers.at[2].set(jnp.array([0.4, 0.0, 0.5]))  # close to the arm: matters if active
    masked = make_obstacles(centers, radii, active=jnp.array([1.0, 1.0, 0.0]))
    two = make_obstacles(centers[:2], radii[:2])
    acceleration = jax.jit(policies.acceleration)
    np.testing.assert_allclose(acceleration(cfg, q, qd, goal, masked),
                               acceleration(cfg, q, qd, goal, two), rtol=1e-5, atol=1e-5)


def test_context_is_validated():
    cfg = policies.franka_config()
    q = jnp.zeros(7)
    obs = make_obstacles(jnp.zeros((3, 3)), jnp.full((3,), 0.05))
    with pytest.raises(ValueError, match=r"goal must have shape \(3,\) for franka"):
        policies.acceleration(cfg, q, q, jnp.zeros(2), obs)
    with pytest.raises(ValueError, match=r"obstacles.center must have shape \(O, 3\)"):
        policies.acceleration(cfg, q, q, jnp.zeros(3), make_obstacles(jnp.zeros((3, 2)),
                                                                       jnp.ones(3)))
    with pytest.raises(ValueError, match="radius must have shape"):
        make_obstacles(jnp.zeros((3, 3)), jnp.ones(2))
    with pytest.raises(ValueError, match="unknown robot name='ur5'"):
        policies.PolicyConfig(robot="ur5", damping=policies.DampingParams())
    with pytest.raises(ValueError, match="joint_limit_buffers must have 7 entries"):
        policies.PolicyConfig(robot="franka", joint_limit=policies.JointLimitParams())
    with pytest.raises(ValueError, match="variant must be one of"):
        policies.franka_config("expert")


def _rollout(cfg, q0, goal, obs, steps, dt=1.0 / 80.0):
    """Double-integrator closed loop with the environment's ±1 acceleration clip."""

    def step(carry, _):
        q, qd = carry
        qdd = jnp.clip(policies.acceleration(cfg, q, qd, goal, obs), -1.0, 1.0)
        qd = qd + dt * qdd
        q = q + dt * qd
        return (q, qd), q

    return jax.lax.scan(step, (q0, jnp.zeros_like(q0)), None, length=steps)


def test_three_link_policy_reaches_free_goal_and_never_collides():
    cfg = policies.three_link_config()
    robot = get("three_link")
    q0 = jnp.array([0.05, -0.05, 0.05])
    goal = jnp.array([-0.1, 0.55])
    far = make_obstacles(jnp.array([[5.0, 5.0]]), jnp.array([0.08]))
    blocking = make_obstacles(jnp.array([[0.45, 0.3]]), jnp.array([0.06]))
    rollouts = jax.jit(jax.vmap(lambda o: _rollout(cfg, q0, goal, o, 600)))
    stacked = jax.tree.map(lambda *a: jnp.stack(a), far, blocking)
    (q, _), qs = rollouts(stacked)
    dist = jnp.linalg.norm(jax.vmap(robot.end_effector)(q) - goal, axis=-1)
    assert float(dist[0]) < 0.01  # free space: converges to the goal
    start = float(jnp.linalg.norm(robot.end_effector(q0) - goal))
    assert float(dist[1]) < 0.5 * start  # with an obstacle in the way: still makes progress
    pts = jax.vmap(robot.control_points)(qs[1])
    clearance = jnp.linalg.norm(pts - blocking.center[0], axis=-1) - 0.025 - blocking.radius[0]
    assert float(clearance.min()) > 0.0  # ... and never touches it


def test_residual_rmp_acceleration_matches_float64_reference():
    """The residual end-effector RMP (§6.2.2) composed in NumPy, through the FD reference."""
    rng = np.random.default_rng(11)
    cfg = policies.three_link_config("residual_rmp")
    with jax.enable_x64(True):
        q, qd, goal, centers, radii = (jnp.asarray(a) for a in random_context("three_link", rng))
        obs = make_obstacles(centers, radii)
        A_r = jnp.asarray(rng.normal(size=(2, 2)))
        a_r = jnp.asarray(rng.uniform(-1, 1, size=2))

        def leaves_np(x, xd, goal_, obstacles_, cfg_):
            out = policies.leaf_rmps(x, xd, goal_, obstacles_, cfg_)
            M_h, f_h = (np.asarray(v[0]) for v in out["target"])
            B = np.asarray(A_r) + np.linalg.cholesky(M_h)
            M = B @ B.T
            f = M @ (np.asarray(a_r) + np.linalg.solve(M_h, f_h))
            out["target"] = (M[None], f[None])
            return out

        M_ref, f_ref = reference_pullback(policies.task_map, leaves_np, q, qd, goal, obs, cfg,
                                          jit_leaves=False)
        residual = jax.jit(policies.residual_rmp_acceleration)
        got = residual(cfg, q, qd, goal, obs, A_r, a_r)
        assert rel_err(got, reference_resolve(M_ref, f_ref)) <= 1e-6
        zero = residual(cfg, q, qd, goal, obs, 0 * A_r, 0 * a_r)
        np.testing.assert_allclose(zero, jax.jit(policies.acceleration)(cfg, q, qd, goal, obs),
                                   rtol=1e-9)
