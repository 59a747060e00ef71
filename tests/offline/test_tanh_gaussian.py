"""offline.learners.tanh_gaussian: change-of-variables log-probability, density checks, module
output."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from offline.learners.tanh_gaussian import TanhGaussian, TanhGaussianPolicy, tanh_log_det_jacobian


def _reference_log_prob(u, mean, log_std):
    """float64 NumPy: log N(u; mean, std) − Σ log(1 − tanh(u)²), summed over the last axis."""
    u, mean, log_std = (np.asarray(x, np.float64) for x in (u, mean, log_std))
    std = np.exp(log_std)
    gauss = -0.5 * ((u - mean) / std) ** 2 - log_std - 0.5 * math.log(2 * math.pi)
    jac = np.log(1.0 - np.tanh(u) ** 2)
    return np.sum(gauss - jac, axis=-1)


def test_log_prob_matches_float64_change_of_variables():
    key_m, key_s, key_x = jax.random.split(jax.random.key(0), 3)
    mean = jax.random.normal(key_m, (64, 3))
    log_std = jax.random.uniform(key_s, (64, 3), minval=-1.5, maxval=0.3)
    dist = TanhGaussian(mean, log_std)
    actions, logp = dist.sample(key_x)
    u = np.asarray(dist.sample_pre_tanh(key_x))  # the same pre-squash draw (float32)
    np.testing.assert_allclose(actions, np.tanh(u), rtol=1e-6, atol=1e-7)
    ref = _reference_log_prob(u, mean, log_std)
    np.testing.assert_allclose(logp, ref, rtol=1e-5, atol=1e-5)
    # scoring the sampled actions gives the log-probability returned by sample (atanh of a
    # float32 action amplifies its rounding where the action is near ±1)
    np.testing.assert_allclose(dist.log_prob(actions), logp, rtol=1e-4, atol=2e-5)
    # the Jacobian term matters (it is not a plain Gaussian log-density)
    no_jac = ref + np.sum(np.log(1.0 - np.tanh(u.astype(np.float64)) ** 2), axis=-1)
    assert np.min(np.abs(np.asarray(logp) - no_jac)) > 1e-3
    # the stable Jacobian formula agrees with the naive one where both are accurate, and stays
    # finite where the naive one overflows (tanh(u) == 1 in float32)
    us = np.linspace(-6.0, 6.0, 101)
    np.testing.assert_allclose(tanh_log_det_jacobian(jnp.asarray(us, jnp.float32)),
                               np.log(1.0 - np.tanh(us) ** 2), rtol=1e-5, atol=1e-5)
    far = tanh_log_det_jacobian(jnp.array([-40.0, 40.0]))
    np.testing.assert_allclose(far, 2 * (math.log(2) - 40.0), rtol=1e-6)


def test_density_integrates_to_one_and_matches_samples_1d():
    dist = TanhGaussian(jnp.array([0.4]), jnp.array([math.log(0.9)]))
    # numeric integration over (−1, 1) on a fine grid (the density vanishes at both ends)
    a = np.linspace(-1.0, 1.0, 200_001)[1:-1]
    dens = np.exp(np.asarray(dist.log_prob(jnp.asarray(a[:, None], jnp.float32)), np.float64))
    assert np.trapezoid(dens, a) == pytest.approx(1.0, abs=2e-3)
    # Monte-Carlo: histogram of 200k samples vs the density integrated over each bin
    n = 200_000
    samples, _ = dist.sample(jax.random.key(1), (n,))
    edges = np.linspace(-1.0, 1.0, 41)
    counts, _ = np.histogram(np.asarray(samples[:, 0]), edges)
    bin_of = np.clip(np.searchsorted(edges, a) - 1, 0, 39)
    prob = np.bincount(bin_of, weights=dens * (a[1] - a[0]), minlength=40)
    sigma = np.sqrt(n * prob * (1 - prob)) + 1.0
    assert np.all(np.abs(counts - n * prob) < 5 * sigma)
    # entropy estimate vs −∫ p log p
    h_true = -np.trapezoid(dens * np.log(np.maximum(dens, 1e-300)), a)
    h_est = float(dist.entropy(jax.random.key(2), num_samples=20_000)[()])
    assert h_est == pytest.approx(h_true, abs=0.03)


def test_policy_module_shapes_mode_and_log_std_clip():
    policy = TanhGaussianPolicy(action_size=2, hidden_sizes=(16, 16))
    obs = jax.random.normal(jax.random.key(0), (5, 4))
    params = policy.init(jax.random.key(1), obs)
    dist = policy.apply(params, obs)
    assert dist.mean.shape == (5, 2) and dist.log_std.shape == (5, 2)
    action, logp = jax.jit(lambda p, o, k: policy.apply(p, o).sample(k))(
        params, obs, jax.random.key(2))
    assert action.shape == (5, 2) and logp.shape == (5,)
    assert np.all(np.abs(np.asarray(action)) < 1) and np.all(np.isfinite(np.asarray(logp)))
    np.testing.assert_allclose(dist.mode(), np.tanh(np.asarray(dist.mean)), rtol=1e-6)
    single = policy.apply(params, obs[0])
    assert single.mean.shape == (2,)
    # push the log-std outputs far out of range: they are clipped to [−5, 2]
    out = params["params"]["mlp"]["out"]
    for bias, bound in ((100.0, 2.0), (-100.0, -5.0)):
        b = out["bias"].at[2:].set(bias)
        p = {"params": {"mlp": {**params["params"]["mlp"], "out": {**out, "bias": b}}}}
        np.testing.assert_array_equal(policy.apply(p, obs).log_std, bound)
    # gradients flow to the parameters through the reparameterised sample
    def loss(p):
        return policy.apply(p, obs).sample(jax.random.key(3))[1].sum()

    grads = jax.jit(jax.grad(loss))(params)
    assert all(np.all(np.isfinite(np.asarray(g))) for g in jax.tree.leaves(grads))
    with pytest.raises(ValueError, match="log_std_min"):
        TanhGaussianPolicy(action_size=2, log_std_min=1.0, log_std_max=0.0).init(
            jax.random.key(0), obs)


def test_extreme_pre_tanh_values_stay_finite():
    dist = TanhGaussian(jnp.array([[30.0, -30.0]]), jnp.array([[-5.0, -5.0]]))
    action, logp = dist.sample(jax.random.key(0))
    np.testing.assert_array_equal(np.abs(np.asarray(action)), 1.0)  # tanh saturated
    assert np.all(np.isfinite(np.asarray(logp)))
    assert np.all(np.isfinite(np.asarray(dist.log_prob(jnp.array([[1.0, -1.0]])))))
