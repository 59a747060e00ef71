"""Issue 27, case 5: leaf parameters, obstacles and configurations are validated by name: zero
is refused where a formula divides, concrete JAX arrays are checked like numbers, non-numbers
are refused, and debug mode catches a leaf metric that is not positive semi-definite."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjxrmp import policies
from mjxrmp.core import rmp2
from mjxrmp.core.rmp import RMP
from mjxrmp.geometry import make_obstacles
from mjxrmp.leaves import gds, hand_designed, point_robot
from mjxrmp.studies import ch3

DIVISORS = ("repulsion_std", "damping_std", "damping_eps", "velocity_gate_length",
            "modulation_radius", "metric_std", "metric_eps")


@pytest.mark.parametrize("field", DIVISORS)
def test_collision_divisor_zero_is_refused(field):
    """issue case 5: `CollisionParams` with `repulsion_std`, `damping_std`, `damping_eps`,
    `velocity_gate_length`, `modulation_radius`, `metric_std` or `metric_eps` = 0 passed
    validation and gave a NaN acceleration; now refused naming the field (as a float and as a
    concrete JAX array)."""
    match = rf"CollisionParams\.{field} must be >= 0 and non-zero \(a formula divides by it\)"
    with pytest.raises(ValueError, match=match):
        hand_designed.CollisionParams(**{field: 0.0})
    with pytest.raises(ValueError, match=match):
        hand_designed.CollisionParams(**{field: jnp.asarray(0.0)})


def _zero_states(m: int) -> tuple[jax.Array, jax.Array]:
    """Subtask states where a divisor of zero shows: at rest on the boundary, and moving."""
    x = jnp.stack([jnp.zeros(m), jnp.full(m, 0.3)])
    return x, jnp.stack([jnp.zeros(m), jnp.full(m, -0.2)])


def _leaf_outputs() -> dict[type, object]:
    """For each parameter class, ``params -> (M, f)`` of its leaf at :func:`_zero_states`."""
    x3, xd3 = _zero_states(3)
    x1, xd1 = _zero_states(1)
    x2, xd2 = _zero_states(2)
    hd = hand_designed
    return {
        hd.TargetParams: lambda p: hd.target_rmp(x3, xd3, jnp.zeros(3), p),
        hd.CollisionParams: lambda p: hd.collision_rmp(x1, xd1, p),
        hd.JointLimitParams: lambda p: hd.joint_limit_rmp(x1, xd1, p),
        hd.VelocityCapParams: lambda p: hd.velocity_cap_rmp(x1, xd1, p),
        hd.DampingParams: lambda p: hd.damping_rmp(x3, xd3, p),
        hd.CSpaceTargetParams: lambda p: hd.cspace_target_rmp(x3, xd3, p),
        point_robot.GoalAttractorParams:
            lambda p: gds.family(point_robot.goal_attractor(p))(x2, xd2),
        point_robot.CollisionParams:
            lambda p: gds.family(point_robot.collision_avoidance(p))(x1 + 0.5, xd1),
    }


def test_every_field_a_leaf_divides_by_refuses_zero():
    """issue case 5 (every leaf): set each parameter of each leaf to 0 (bypassing validation
    through the pytree) and evaluate the leaf; wherever that gives a non-finite RMP, the
    constructor must refuse 0 naming the field. The defaults and every preset still validate."""
    divisors = []
    for cls, leaf in _leaf_outputs().items():
        evaluate = jax.jit(leaf)
        default = cls()
        children, treedef = jax.tree.flatten(default)
        for i, field in enumerate(dataclasses.fields(cls)):
            zeroed = jax.tree.unflatten(treedef, [*children[:i], 0.0, *children[i + 1:]])
            if all(bool(jnp.all(jnp.isfinite(a))) for a in evaluate(zeroed)):
                continue
            divisors.append(f"{cls.__name__}.{field.name}")
            with pytest.raises(ValueError, match=rf"{cls.__name__}\.{field.name} must be >= 0 "
                                                 r"and non-zero"):
                cls(**{field.name: 0.0})
    assert {f"CollisionParams.{f}" for f in DIVISORS} - {"CollisionParams.velocity_gate_length",
                                                         "CollisionParams.modulation_radius"} \
        <= set(divisors), divisors
    for robot in ("three_link", "franka"):
        for variant in policies.VARIANTS:
            policies.default_config(robot, variant)
    assert ch3.SWAP_COLLISION.epsilon == 1e-8


def test_negative_nonnumeric_and_array_parameters_are_refused_by_name():
    """issue case 5: negative values given as concrete JAX arrays skipped validation, and
    `k_p='5'` failed without naming the field; both are refused by name now. Traced parameters
    (differentiated or jitted) are still accepted."""
    with pytest.raises(ValueError, match=r"TargetParams\.k_p must be a number or an array of "
                                         r"numbers, got '5'"):
        hand_designed.TargetParams(k_p="5")
    with pytest.raises(ValueError, match=r"CSpaceTargetParams\.k_d must be a number"):
        hand_designed.CSpaceTargetParams(k_d=None)
    with pytest.raises(ValueError, match=r"DampingParams\.damping_gain must be >= 0, got -1\.0"):
        hand_designed.DampingParams(damping_gain=jnp.asarray(-1.0))
    with pytest.raises(ValueError, match=r"TargetParams\.k_d must be >= 0, got -2\.0 at index "
                                         r"\(1,\)"):
        hand_designed.TargetParams(k_d=jnp.asarray([1.0, -2.0]))
    with pytest.raises(ValueError, match=r"GoalAttractorParams\.sigma must be finite, got nan"):
        point_robot.GoalAttractorParams(sigma=jnp.asarray(jnp.nan))
    grad = jax.grad(lambda k: hand_designed.TargetParams(k_p=k).k_p * 2.0)(1.0)
    assert grad == 2.0


def test_negative_obstacle_radius_is_refused():
    """issue case 5: negative obstacle radii were accepted; `make_obstacles` refuses them (and
    non-finite radii) naming the entry."""
    with pytest.raises(ValueError, match=r"radius must be finite and >= 0, got radius\[1\] = "
                                         r"-0\.05"):
        make_obstacles(jnp.zeros((2, 2)), jnp.asarray([0.05, -0.05]))
    with pytest.raises(ValueError, match=r"radius\[0\] = nan"):
        make_obstacles(jnp.zeros((1, 3)), jnp.asarray([jnp.nan]))
    assert make_obstacles(jnp.zeros((1, 2)), jnp.zeros(1)).radius.shape == (1,)


@pytest.fixture(scope="module")
def three_link():
    """A 3-link policy of the preset's target and velocity-cap leaves (a 2-D and a 1-D family);
    the full preset only adds compile time to debug mode."""
    preset = policies.three_link_config("hand_designed")
    cfg = policies.PolicyConfig(robot="three_link", target=preset.target,
                                velocity_cap=preset.velocity_cap, obstacle_shape="cylinder")
    q = jnp.asarray([0.3, -0.4, 0.5], jnp.float32)
    qd = jnp.asarray([0.2, 0.1, -0.3], jnp.float32)
    obstacles = make_obstacles(jnp.asarray([[0.4, 0.3]], jnp.float32),
                               jnp.asarray([0.05], jnp.float32))
    return cfg, q, qd, jnp.asarray([0.5, 0.2], jnp.float32), obstacles


def test_empty_configuration_is_refused_by_name(three_link):
    """issue case 5: `q` of shape `(0,)` failed deep inside; now refused at the entry."""
    cfg, _, _, goal, obstacles = three_link
    with pytest.raises(ValueError, match=r"q must have at least one coordinate, got shape \(0,\)"):
        policies.acceleration(cfg, jnp.zeros(0), jnp.zeros(0), goal, obstacles)


def test_debug_mode_names_a_leaf_with_a_negative_definite_metric(three_link):
    """issue case 5: a leaf with a negative-definite metric silently reversed the acceleration;
    debug mode now names the leaf and the member. Without debug mode the root is then not
    positive definite and its Cholesky resolve gives NaN, which the trainers stop on
    (docs/design.md §5.5, §5.10), instead of a number. Valid policies pass debug mode
    unchanged."""
    cfg, q, qd, goal, obstacles = three_link

    def reversed_target(x, xd, goal_, obstacles_, cfg_):
        out = policies.leaf_rmps(x, xd, goal_, obstacles_, cfg_)
        out["target"] = RMP(-out["target"].M, out["target"].f)
        return out

    args = (q, qd, goal, obstacles, cfg)
    # the plain (non-debug) calls compiled; debug mode raises here, before returning
    plain = jax.jit(rmp2.acceleration, static_argnums=(0, 1))(policies.task_map,
                                                               reversed_target, *args)
    assert not np.all(np.isfinite(plain))  # without debug mode: NaN, not a wrong number
    with pytest.raises(Exception, match=r"leaf_fn output\['target'\]: metric M is not positive "
                                        r"semi-definite; member 0 has minimum eigenvalue -"):
        rmp2.acceleration(policies.task_map, reversed_target, *args, debug=True)
    np.testing.assert_allclose(policies.acceleration(cfg, q, qd, goal, obstacles, debug=True),
                               jax.jit(policies.acceleration)(cfg, q, qd, goal, obstacles),
                               rtol=1e-5)
