"""The written-out SPD Cholesky and solve (mjxrmp.core.linalg) against numpy's LAPACK in
float64, their gradients against jnp.linalg's, their errors, and closed-loop trajectories of
the hand-designed policy against the LU resolve they replaced."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg
from hypothesis import given, settings
from hypothesis import strategies as st

import envs
from envs.evaluate import frozen_step, hand_designed_policy
from mjxrmp.core import rmp2
from mjxrmp.core.linalg import MAX_UNROLLED, cho_factor, cho_solve, cholesky, spd_solve


def _spd(rng: np.random.Generator, batch: int, n: int, floor: float = 1e-2) -> np.ndarray:
    A = rng.normal(size=(batch, n, n))
    return A @ np.swapaxes(A, -1, -2) + floor * np.eye(n)


@pytest.mark.parametrize("n", [1, 2, 3, 7, MAX_UNROLLED, MAX_UNROLLED + 1])
def test_float64_agrees_with_lapack(n):
    """Cholesky factor and solution equal numpy's (LAPACK) in float64, for the written-out
    sizes and the library fallback above MAX_UNROLLED."""
    rng = np.random.default_rng(n)
    M, f = _spd(rng, 6, n), rng.normal(size=(6, n))
    with jax.enable_x64(True):
        L = np.asarray(cholesky(jnp.asarray(M)))
        x = np.asarray(spd_solve(jnp.asarray(M), jnp.asarray(f)))
    np.testing.assert_allclose(L, np.linalg.cholesky(M), rtol=0, atol=1e-11)
    assert np.all(np.triu(L, 1) == 0.0)
    np.testing.assert_allclose(x, np.linalg.solve(M, f[..., None])[..., 0], rtol=1e-9, atol=1e-11)


@pytest.mark.parametrize("n", [1, 3, 9, MAX_UNROLLED + 1])
@pytest.mark.parametrize("lower", [True, False])
def test_cho_factor_and_cho_solve_agree_with_scipy(n, lower):
    """The ``(c, lower)`` pair and the solve as scipy.linalg computes them in float64: ``c``'s
    triangle equals scipy's factor, the other triangle is zero; one right-hand side is written
    out, several (``(n, k)``) and sizes above MAX_UNROLLED go to the library."""
    rng = np.random.default_rng(10 * n + lower)
    M, f, F = _spd(rng, 1, n)[0], rng.normal(size=n), rng.normal(size=(n, 2))
    ref = scipy.linalg.cho_factor(M, lower=lower)
    keep = np.tril if lower else np.triu
    with jax.enable_x64(True):
        c, low = cho_factor(jnp.asarray(M), lower=lower)
        x = np.asarray(cho_solve((c, low), jnp.asarray(f)))
        X = np.asarray(cho_solve((c, low), jnp.asarray(F)))
    assert low is lower
    np.testing.assert_allclose(np.asarray(c), keep(ref[0]), rtol=0, atol=1e-11)
    assert np.all(np.asarray(c) == keep(np.asarray(c)))
    np.testing.assert_allclose(x, scipy.linalg.cho_solve(ref, f), rtol=1e-9, atol=1e-11)
    np.testing.assert_allclose(X, scipy.linalg.cho_solve(ref, F), rtol=1e-9, atol=1e-11)


@settings(max_examples=40, deadline=None)
@given(n=st.integers(1, 7), seed=st.integers(0, 2**31 - 1),
       log_cond=st.floats(0.0, 5.0), scale=st.floats(1e-3, 1e3))
def test_properties_float64(n, seed, log_cond, scale):
    """For any SPD matrix (condition number up to 1e5, any scale): L is lower triangular with a
    positive diagonal, L Lᵀ = M, and M x = f, to float64 rounding times the conditioning."""
    rng = np.random.default_rng(seed)
    Q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    M = scale * (Q * np.logspace(0.0, log_cond, n)) @ Q.T
    f = rng.normal(size=n)
    with jax.enable_x64(True):
        L = np.asarray(cholesky(jnp.asarray(M)))
        x = np.asarray(spd_solve(jnp.asarray(M), jnp.asarray(f)))
    assert np.all(np.diag(L) > 0) and np.all(np.triu(L, 1) == 0.0)
    np.testing.assert_allclose(L @ L.T, M, atol=1e-12 * np.abs(M).max())
    np.testing.assert_allclose(M @ x, f, atol=1e-9 * 10.0**log_cond * np.abs(f).max())


def test_only_the_symmetric_part_is_read():
    """A matrix and its symmetric part give the same factor and solution (rounding of an
    RMP² pullback leaves M slightly asymmetric)."""
    rng = np.random.default_rng(3)
    M, f = _spd(rng, 4, 3), rng.normal(size=(4, 3))
    skew = rng.normal(size=(4, 3, 3))
    skew = skew - np.swapaxes(skew, -1, -2)
    with jax.enable_x64(True):
        for fn, args in ((cholesky, ()), (spd_solve, (jnp.asarray(f),))):
            a = np.asarray(fn(jnp.asarray(M + 1e-3 * skew), *args))
            b = np.asarray(fn(jnp.asarray(M), *args))
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-14)


def test_float32_within_the_conditioning_of_the_rmp2_root():
    """In float32 the solve of a regularised RMP² root (entries ≤ 100 after scaling, 1e-3·I
    added: condition ≤ 1e5) is as accurate as LAPACK's LU (jnp.linalg.solve) against float64."""
    rng = np.random.default_rng(4)
    A = rng.normal(size=(256, 7, 3))
    M = 100.0 * A @ np.swapaxes(A, -1, -2) / np.abs(A @ np.swapaxes(A, -1, -2)).max(
        axis=(-1, -2), keepdims=True) + 1e-3 * np.eye(7)  # rank 3 + regulariser
    f = rng.normal(size=(256, 7))
    exact = np.linalg.solve(M, f[..., None])[..., 0]
    ours = np.asarray(spd_solve(jnp.asarray(M, jnp.float32), jnp.asarray(f, jnp.float32)))
    lu = np.asarray(jnp.linalg.solve(jnp.asarray(M, jnp.float32),
                                     jnp.asarray(f, jnp.float32)[..., None]))[..., 0]
    err = np.abs(ours - exact).max(axis=-1) / np.abs(exact).max(axis=-1)
    err_lu = np.abs(lu - exact).max(axis=-1) / np.abs(exact).max(axis=-1)
    assert np.all(np.isfinite(ours))
    assert np.median(err) <= 3.0 * np.median(err_lu) + 1e-6
    assert err.max() <= 3.0 * err_lu.max() + 1e-6


def test_gradients_equal_the_library_solve():
    """Reverse-mode gradients of a loss through spd_solve and cholesky, and spd_solve's
    forward-mode derivative, equal those through jnp.linalg in float64 (the PPO update
    differentiates through the resolve)."""
    rng = np.random.default_rng(5)
    M, f, w = _spd(rng, 3, 4), rng.normal(size=(3, 4)), rng.normal(size=(3, 4))
    with jax.enable_x64(True):
        M, f, w = map(jnp.asarray, (M, f, w))

        def loss(solve, chol, M, f):
            return jnp.sum(w * solve(M, f)) + jnp.sum(jnp.tril(chol(M)) ** 3)

        def lib_solve(M, f):
            return jnp.linalg.solve(M, f[..., None])[..., 0]

        def lib_chol(M):
            return jnp.linalg.cholesky(0.5 * (M + jnp.swapaxes(M, -1, -2)))

        g = jax.grad(lambda M, f: loss(spd_solve, cholesky, M, f), argnums=(0, 1))(M, f)
        g_lib = jax.grad(lambda M, f: loss(lib_solve, lib_chol, M, f), argnums=(0, 1))(M, f)
        sym = [0.5 * (x + jnp.swapaxes(x, -1, -2)) for x in (g[0], g_lib[0])]
        np.testing.assert_allclose(sym[0], sym[1], rtol=1e-9, atol=1e-11)
        np.testing.assert_allclose(g[1], g_lib[1], rtol=1e-9, atol=1e-11)
        dM = jnp.asarray(rng.normal(size=M.shape))
        dM = dM + jnp.swapaxes(dM, -1, -2)
        t = jax.jvp(spd_solve, (M, f), (dM, w))[1]
        t_lib = jax.jvp(lib_solve, (M, f), (dM, w))[1]
        np.testing.assert_allclose(t, t_lib, rtol=1e-9, atol=1e-11)


def test_not_positive_definite_gives_nan_and_bad_shapes_raise():
    """An indefinite matrix gives NaN (as jnp.linalg.cholesky), never a silent number; shapes
    are checked with the argument named."""
    M = jnp.asarray([[1.0, 2.0], [2.0, 1.0]])
    assert np.isnan(np.asarray(cholesky(M))).any()
    assert np.isnan(np.asarray(spd_solve(M, jnp.ones(2)))).any()
    with pytest.raises(ValueError, match="spd_solve: M must be square"):
        spd_solve(jnp.ones((2, 3)), jnp.ones(3))
    with pytest.raises(ValueError, match="spd_solve: f must have shape"):
        spd_solve(jnp.eye(3), jnp.ones(2))
    with pytest.raises(ValueError, match="cholesky: M must be square"):
        cholesky(jnp.ones(3))


def _lu_resolve(M, f):
    """The resolve before the written-out solve: LAPACK/cuSOLVER LU at full precision."""
    with jax.default_matmul_precision("highest"):
        return jnp.linalg.solve(M, f[..., None])[..., 0]


def _hand_designed_qpos(name: str, steps: int, episodes: int) -> np.ndarray:
    env = envs.make(name)
    step = frozen_step(env, hand_designed_policy(env))

    def body(state, _):
        state = step(state)
        return state, state.pipeline_state.qpos

    def episode(key):
        return jax.lax.scan(body, env.reset(key), None, length=steps)[1]

    keys = jax.random.split(jax.random.PRNGKey(7), episodes)
    return np.asarray(jax.jit(jax.vmap(episode))(keys))


@pytest.mark.parametrize("name,tol", [
    ("three_link/env3", 1e-4),
    # The resolve has no code of its own per robot (sizes 1-13 are checked above): the
    # Franka's closed loop (two 12 s compiles of its RMP² tree) runs with -m slow.
    pytest.param("franka", 1e-4, marks=pytest.mark.slow)])
def test_closed_loop_trajectories_match_the_lu_resolve(name, tol, monkeypatch):
    """The hand-designed RMP² policy in closed loop (4 episodes × 40 control steps, float32,
    this CPU): joint trajectories with the written-out resolve stay within ``tol`` rad of those
    with the LU solve it replaced (rounding of two exact methods, amplified by the loop)."""
    ours = _hand_designed_qpos(name, 40, 4)
    monkeypatch.setattr(rmp2, "spd_solve", _lu_resolve)
    lu = _hand_designed_qpos(name, 40, 4)
    assert np.all(np.isfinite(ours))
    assert np.abs(ours - lu).max() <= tol
    assert np.abs(ours[:, -1] - ours[:, 0]).max() > 100 * tol  # the arm moved
