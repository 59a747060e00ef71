"""IQL and CQL (offline/learners/iql.py, offline/learners/cql.py): losses against float64 NumPy
references, the learner-API contracts (split runs, vmap over seeds and β) and a one-step bandit
whose best action is known."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from offline_bandit import LIMIT, make_bandit, mean_reward

from offline.data.scenarios import reward_data
from offline.learners import cql, iql
from offline.learners.base import actor_params
from offline.learners.networks import QEnsemble
from offline.learners.tanh_gaussian import TanhGaussianPolicy

TINY = dict(hidden_sizes=(32, 32), batch_size=64, actor_lr=3e-3, critic_lr=3e-3)


@pytest.fixture(scope="module")
def bandit():
    """One-step episodes (all terminal): r = 1 − 4(a/limit − a*)², actions uniform."""
    return make_bandit()


# ------------------------------------------------------------------ IQL loss pieces


_expectile = jax.jit(iql.expectile_loss)
_awr = jax.jit(iql.awr_weights, static_argnums=2)


@settings(max_examples=25, deadline=None)
@given(arrays(np.float64, 16, elements=st.floats(-50, 50)), st.floats(0.05, 0.95))
def test_expectile_loss_matches_numpy(u, tau):
    ref = np.mean(np.where(u < 0, 1 - tau, tau) * u ** 2)
    got = float(_expectile(jnp.asarray(u, jnp.float32), tau))
    np.testing.assert_allclose(got, ref, rtol=1e-5, atol=1e-6)


def test_expectile_loss_minimiser_is_the_expectile():
    """The minimiser over a constant v of E[L_τ(x − v)] is the τ-expectile (above the mean
    for τ > 0.5), computed by a float64 fixed point."""
    x = np.random.default_rng(1).normal(size=400)
    grad = jax.jit(jax.grad(lambda v: iql.expectile_loss(jnp.asarray(x, jnp.float32) - v, 0.7)))
    v = 0.0
    for _ in range(400):
        v -= 0.5 * float(grad(v))
    e = 0.0
    for _ in range(100):  # e = Σ w x / Σ w with w = |τ − 1(x < e)|
        w = np.where(x < e, 0.3, 0.7)
        e = np.sum(w * x) / np.sum(w)
    assert e > x.mean() + 0.1
    np.testing.assert_allclose(v, e, atol=1e-4)


@settings(max_examples=25, deadline=None)
@given(arrays(np.float64, 16, elements=st.floats(-300, 300)), st.floats(0.1, 10.0))
def test_awr_weights_match_numpy(adv, temperature):
    with np.errstate(over="ignore"):
        ref = np.minimum(np.exp(temperature * adv), 100.0)
    got = np.asarray(_awr(jnp.asarray(adv, jnp.float32), temperature, 100.0))
    assert np.all(np.isfinite(got))
    np.testing.assert_allclose(got, ref, rtol=2e-4, atol=1e-30)


# ------------------------------------------------------------------ CQL penalty


def _numpy_q(params, obs, act):
    """Float64 NumPy forward pass of a QEnsemble (ReLU MLP per critic): ``(..., C)``."""
    layers = params["params"]["critics"]
    x = np.concatenate([obs, act], -1).astype(np.float64)
    outs = []
    for i in range(layers["out"]["kernel"].shape[0]):
        h = x
        for name in sorted(k for k in layers if k.startswith("hidden_")):
            h = np.maximum(h @ np.float64(layers[name]["kernel"][i])
                           + np.float64(layers[name]["bias"][i]), 0.0)
        outs.append(h @ np.float64(layers["out"]["kernel"][i]) + np.float64(
            layers["out"]["bias"][i]))
    return np.concatenate(outs, -1)


def test_cql_penalty_matches_numpy_logsumexp():
    b, o, a, k, c = 6, 3, 2, 4, 2
    rng = np.random.default_rng(2)
    obs, nxt = (rng.normal(size=(b, o)).astype(np.float32) for _ in range(2))
    act = rng.uniform(-1, 1, (b, a)).astype(np.float32)
    critic = QEnsemble(c, (16, 16))
    policy = TanhGaussianPolicy(a, (16, 16))

    @jax.jit
    def program(obs, nxt, act):
        # spread the Q-values (×3 weights) so the log-sum-exp is not dominated by one term
        cp = jax.tree.map(lambda x: 3.0 * x, critic.init(jax.random.PRNGKey(0), obs, act))
        ap = policy.init(jax.random.PRNGKey(1), obs)
        sampled, logd = cql.penalty_actions(policy, ap, obs, nxt, jax.random.PRNGKey(2), k)
        pen = cql.conservative_penalty(cql.sampled_q(critic, cp, obs, sampled), logd,
                                       critic.apply(cp, obs, act), temperature=0.7)
        return cp, sampled, logd, pen

    cp, sampled, logd, got = program(obs, nxt, act)
    assert sampled.shape == (3 * k, b, a) and logd.shape == (3 * k, b)
    np.testing.assert_allclose(logd[:k], -a * np.log(2.0))
    assert np.all(np.abs(np.asarray(sampled)) <= 1.0)

    q_s = _numpy_q(cp, np.broadcast_to(obs, (3 * k, b, o)), np.asarray(sampled, np.float64))
    z = (q_s - np.asarray(logd, np.float64)[..., None]) / 0.7
    m = z.max(0)
    lse = m + np.log(np.exp(z - m).sum(0))
    ref = 0.7 * lse.mean(0) - _numpy_q(cp, obs, act).mean(0)
    assert got.shape == (c,)
    np.testing.assert_allclose(np.asarray(got), ref, rtol=1e-4, atol=1e-4)
    # the penalty is ≥ the gap between the samples' soft maximum and the data's Q: positive
    # when the data actions are not preferred
    assert np.all(ref > 0)


# ------------------------------------------------------------------ learner contracts


@pytest.fixture(scope="module")
def programs(bandit):
    """Per learner: the trainer and its jitted init (compiled once for the module)."""
    trainers = {
        "iql": iql.make_train(bandit, iql.IQLConfig(num_steps=400, value_lr=3e-3, **TINY)),
        "cql": cql.make_train(bandit, cql.CQLConfig(num_steps=400, alpha_lr=3e-3, **TINY))}
    return {name: (t, jax.jit(t.init)) for name, t in trainers.items()}


@pytest.mark.parametrize("name", ["iql", "cql"])
def test_vmap_over_seeds_and_beta_and_the_bandit_optimum(programs, bandit, name):
    """A vmapped training over (seed, β) pairs equals each pair's own run (metrics of the
    first steps, where float32 reassociation has not yet been amplified by training; the
    exact split property of the shared scan is tested bit for bit in test_bc.py), and every
    policy moves from the behaviour's mean action 0 to the bandit's best action."""
    trainer, init = programs[name]
    run = jax.jit(lambda s: trainer.run(s, trainer.num_steps))
    keys = jax.random.split(jax.random.PRNGKey(1), 2)
    betas = jnp.array([0.5, 3.0])
    singles = [init(keys[i], betas[i]) for i in range(2)]
    stacked = jax.tree.map(lambda a, b: jnp.stack([a, b]), *singles)
    both, m = jax.jit(jax.vmap(lambda s: trainer.run(s, trainer.num_steps)))(stacked)
    np.testing.assert_array_equal(both.beta, betas)
    np.testing.assert_array_equal(both.step, [400, 400])
    assert all(v.shape == (2, 400) and np.all(np.isfinite(v)) for v in m.values())
    obs = np.asarray(bandit.observations[:64])
    for i in range(2):
        single, m_single = run(singles[i])
        for k in m:
            np.testing.assert_allclose(m[k][i, :10], m_single[k][:10], rtol=1e-4, atol=1e-5)
        for state in (single, jax.tree.map(lambda x, i=i: x[i], both)):
            a = np.asarray(trainer.act(actor_params(state), obs))[:, 0] / LIMIT
            assert mean_reward(a) > 0.75, (name, i, a.mean(), mean_reward(a))


def test_configs_and_reward_data_are_refused(bandit):
    with pytest.raises(ValueError, match="expectile"):
        iql.IQLConfig(expectile=1.0)
    with pytest.raises(ValueError, match="discount"):
        cql.CQLConfig(discount=1.5)
    with pytest.raises(ValueError, match="num_samples"):
        cql.CQLConfig(num_samples=0)
    with pytest.raises(ValueError, match="config"):
        iql.make_train(bandit, cql.CQLConfig())
    rd = reward_data(bandit)
    for mod, cfg in ((iql, iql.IQLConfig()), (cql, cql.CQLConfig())):
        with pytest.raises(ValueError, match="no reward_data"):
            mod.make_train(bandit, cfg, reward_data=rd)
