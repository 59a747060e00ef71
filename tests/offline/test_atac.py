"""ATAC / PSPI (offline/learners/atac.py; thesis §7.3.3, eqs 7.2 and 7.11, docs/design.md §4.5).

* loss terms against float64 NumPy references on a hand-made batch;
* relative pessimism on a 3-state MDP whose values are known in closed form: the critic's
  relative evaluation of the (frozen) actor is below the true one and the gap closes as β grows;
* β = 0 reproduces behaviour cloning;
* after the BC warm start the game phase moves the actor to the best action of a bandit;
* mechanics: warm-start switch, ``run`` split, vmap over seeds, Frobenius projection, errors.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from offline_bandit import LIMIT, make_bandit, mean_reward

from offline.data import dataset as odata
from offline.learners import atac, atac_losses
from offline.learners.base import actor_params
from offline.learners.tanh_gaussian import TanhGaussianPolicy

#: Compile fast (XLA backend optimisation off): these programs run for well under a second.
FAST = {"xla_backend_optimization_level": 0}
HIDDEN = (16, 16)


def fast_jit(f, **kw):
    return jax.jit(f, compiler_options=FAST, **kw)


# --------------------------------------------------------------------------------------------
# Loss terms vs float64 NumPy


def np_dqra(q, qn, qt, r, d, g, w):
    cont = g * (1.0 - d)
    y_t = r + cont * qt
    y_r = r[:, None] + cont[:, None] * qn
    return w * np.mean((q - y_t[:, None]) ** 2, 0) + (1 - w) * np.mean((q - y_r) ** 2, 0)


@pytest.fixture(scope="module")
def hand_batch():
    rng = np.random.default_rng(3)
    b, k = 7, 2
    return dict(q=rng.normal(size=(b, k)), qn=rng.normal(size=(b, k)), qt=rng.normal(size=b),
                r=rng.uniform(size=b), d=np.array([0, 1, 0, 0, 1, 0, 0], float),
                qpi=rng.normal(size=(b, k)))


def test_dqra_pessimism_combine_match_numpy(hand_batch):
    h = hand_batch
    with jax.enable_x64(True):
        for w in (0.0, 0.5, 0.8):
            got = atac_losses.dqra_loss(jnp.asarray(h["q"]), jnp.asarray(h["qn"]),
                                        jnp.asarray(h["qt"]), jnp.asarray(h["r"]),
                                        jnp.asarray(h["d"]), 0.9, w)
            np.testing.assert_allclose(got, np_dqra(h["q"], h["qn"], h["qt"], h["r"], h["d"],
                                                    0.9, w), rtol=1e-12)
        rel = atac_losses.pessimism_loss(jnp.asarray(h["qpi"]), jnp.asarray(h["q"]), True)
        np.testing.assert_allclose(rel, np.mean(h["qpi"] - h["q"], 0), rtol=1e-12)
        ab = atac_losses.pessimism_loss(jnp.asarray(h["qpi"]), jnp.asarray(h["q"]), False)
        np.testing.assert_allclose(ab, np.mean(h["qpi"], 0), rtol=1e-12)
        for w in (0.0, 0.3, 1.0, 16.0):
            ref = 2.0 / w + 5.0 if w > 1 else 2.0 + w * 5.0
            assert float(atac_losses.combine(2.0, 5.0, w)) == pytest.approx(ref, rel=1e-12)
        # β = 0: the unused branch must not poison the gradient.
        g = jax.grad(lambda b: atac_losses.combine(2.0 * b, 5.0, b))(0.0)
        assert np.isfinite(float(g))


def test_dqra_gradients_residual_and_target(hand_batch):
    """Gradient flows through f_i(s', a') (residual term) and not through the target term."""
    h = hand_batch
    g, w = 0.9, 0.5
    with jax.enable_x64(True):
        args = [jnp.asarray(h[k]) for k in ("q", "qn", "qt")]
        gq, gqn, gqt = jax.grad(lambda q, qn, qt: jnp.sum(atac_losses.dqra_loss(
            q, qn, qt, jnp.asarray(h["r"]), jnp.asarray(h["d"]), g, w)), argnums=(0, 1, 2))(*args)
    b = h["q"].shape[0]
    cont = g * (1 - h["d"])
    res = h["q"] - (h["r"][:, None] + cont[:, None] * h["qn"])
    tgt = h["q"] - (h["r"] + cont * h["qt"])[:, None]
    np.testing.assert_allclose(gq, 2 * (w * tgt + (1 - w) * res) / b, rtol=1e-12)
    np.testing.assert_allclose(gqn, -2 * (1 - w) * cont[:, None] * res / b, rtol=1e-12)
    np.testing.assert_allclose(gqt, 0.0, atol=0)


def test_value_bounds():
    assert atac_losses.value_bounds(0.0, 1.0, 0.99) == pytest.approx((-100.0, 200.0))
    assert atac_losses.value_bounds(-2.0, 0.1, 0.9) == pytest.approx((-40.0, 10.0))


# --------------------------------------------------------------------------------------------
# A 3-state MDP with known values: s ∈ {0, 1, 2} one-hot, a ∈ [−1, 1], every transition goes to
# state 2 (which loops on itself), r(s, a) = b_s + k_s·a with k_2 = 0. So
# Q^π(s, a) = r(s, a) + γ V^π(2), V^π(2) = b_2 / (1 − γ), and the true relative value of π is
# mean_D [Q^π(s, π) − Q^π(s, a)] = mean_D k_s (E_π[a | s] − a).

B_S = np.array([0.2, -0.1, 0.1])
K_S = np.array([0.5, -0.8, 0.0])
C_S = np.array([-0.5, 0.6, 0.3])  # behaviour means
GAMMA = 0.9
N = 600


def mdp_dataset(std: float, seed: int) -> odata.Dataset:
    rng = np.random.default_rng(seed)
    s = np.arange(N) % 3
    eye = np.eye(3, dtype=np.float32)
    a = np.clip(rng.normal(C_S[s], std), -0.99, 0.99)[:, None].astype(np.float32)
    r = (B_S[s] + K_S[s] * a[:, 0]).astype(np.float32)
    return odata.create(eye[s], a, r, eye[np.full(N, 2)], np.zeros(N), np.zeros(N),
                        np.zeros(N), {"action_limit": 1.0})


PESS_BETAS = np.array([1.0, 10.0, 100.0, 3000.0], np.float32)


@pytest.fixture(scope="module")
def pessimism_runs():
    ds = mdp_dataset(0.6, 0)
    cfg = atac.ATACConfig(hidden_sizes=HIDDEN, batch_size=64, warmstart_steps=0,
                          num_steps=2000, critic_lr=2e-3, actor_lr=1e-9, discount=GAMMA,
                          tau=0.05)
    tr = atac.make_train(ds, cfg)
    state, metrics = fast_jit(jax.vmap(tr.train, in_axes=(None, 0)))(
        jax.random.key(0), jnp.asarray(PESS_BETAS))
    return ds, state, metrics


def np_mlp(layers, x):
    """float64 NumPy forward pass of agents.ppo.networks.MLP (ReLU hidden layers, linear output)."""
    h = np.asarray(x, np.float64)
    hidden = sorted(k for k in layers if k.startswith("hidden_"))
    for name in hidden:
        h = np.maximum(h @ np.asarray(layers[name]["kernel"], np.float64)
                       + np.asarray(layers[name]["bias"], np.float64), 0.0)
    return h @ np.asarray(layers["out"]["kernel"], np.float64) + np.asarray(
        layers["out"]["bias"], np.float64)


def np_critics(critic_params, obs, act):
    """``(N, K)`` values of the Q ensemble, member by member, in float64."""
    layers = critic_params["params"]["critics"]
    x = np.concatenate([obs, act], -1)
    k = layers["out"]["bias"].shape[0]
    return np.stack([np_mlp(jax.tree.map(lambda v, i=i: np.asarray(v)[i], layers), x)[:, 0]
                     for i in range(k)], -1)


def test_relative_pessimism_and_gap_closing_with_beta(pessimism_runs):
    ds, state, _ = pessimism_runs
    s = np.argmax(np.asarray(ds.observations), 1)
    a = np.asarray(ds.actions, np.float64)
    eye = np.eye(3)
    x, wts = np.polynomial.hermite_e.hermegauss(80)
    wts = wts / wts.sum()
    gaps = []
    for i, _ in enumerate(PESS_BETAS):
        p = jax.tree.map(lambda v, i=i: np.asarray(v)[i], state.params)
        out = np_mlp(p["actor"]["params"]["mlp"], eye)
        mean, log_std = out[:, 0], np.clip(out[:, 1], -5.0, 2.0)
        acts = np.tanh(mean[:, None] + np.exp(log_std)[:, None] * x[None])  # (3, nodes)
        e_a = acts @ wts                                   # E_π[a | s] by Gauss-Hermite
        true_rel = np.mean(K_S[s] * (e_a[s] - a[:, 0]))
        f_nodes = np_critics(p["critic"], np.repeat(eye, len(x), 0), acts.reshape(-1, 1))
        f_pi = np.einsum("snk,n->sk", f_nodes.reshape(3, len(x), -1), wts)
        f_data = np_critics(p["critic"], np.asarray(ds.observations), a)
        est_rel = np.mean(f_pi[s] - f_data, 0)             # per critic
        gaps.append(true_rel - est_rel)
    gaps = np.array(gaps)                                  # (betas, K)
    # Pessimistic: the critic never over-estimates the relative value (up to optimisation noise).
    assert np.all(gaps >= -0.02), gaps
    # Strongly pessimistic at small β, exact at large β, and monotone in between.
    assert np.all(gaps[0] > 0.5), gaps
    assert np.all(np.abs(gaps[-1]) < 0.02), gaps
    assert np.all(np.diff(gaps.mean(1)) < 0), gaps


def test_bellman_small_at_large_beta(pessimism_runs):
    _, _, metrics = pessimism_runs
    bell = np.asarray(metrics["bellman"])[:, -100:].mean(1)
    assert bell[-1] < 1e-3 and bell[0] > 10 * bell[-1], bell


# --------------------------------------------------------------------------------------------
# β = 0 (pessimism only) reproduces behaviour cloning


def test_beta_zero_reproduces_behaviour_cloning():
    ds = mdp_dataset(0.2, 1)
    cfg = atac.ATACConfig(hidden_sizes=HIDDEN, batch_size=64, warmstart_steps=0, num_steps=2000,
                          critic_lr=3e-3, actor_lr=3e-3, discount=GAMMA, tau=0.05, beta=0.0)
    tr = atac.make_train(ds, cfg)
    state, _ = fast_jit(tr.train)(jax.random.key(1))
    obs = jnp.eye(3, dtype=jnp.float32)
    atac_actions = np.asarray(tr.act(actor_params(state), obs))[:, 0]

    # Independent BC reference: maximum likelihood of the dataset actions, full batch.
    policy = TanhGaussianPolicy(1, HIDDEN)
    params = policy.init(jax.random.key(2), obs)
    random_actions = np.asarray(policy.apply(params, obs).mode())[:, 0]
    opt = optax.adam(3e-3)

    def bc_step(carry, _):
        p, o = carry
        g = jax.grad(lambda p: -jnp.mean(policy.apply(p, ds.observations).log_prob(
            ds.actions)))(p)
        u, o = opt.update(g, o)
        return (optax.apply_updates(p, u), o), None

    (params, _), _ = fast_jit(lambda p: jax.lax.scan(bc_step, (p, opt.init(p)), None,
                                                     length=2000))(params)
    bc_actions = np.asarray(policy.apply(params, obs).mode())[:, 0]
    np.testing.assert_allclose(bc_actions, C_S, atol=0.1)  # the reference itself is BC
    assert np.max(np.abs(atac_actions - bc_actions)) < 0.15, (atac_actions, bc_actions)
    assert np.max(np.abs(random_actions - bc_actions)) > 0.4, (random_actions, bc_actions)


# --------------------------------------------------------------------------------------------
# Mechanics on a tiny configuration (compiled once per module)

WARM = 2
TINY = atac.ATACConfig(hidden_sizes=(8, 8), batch_size=8, warmstart_steps=WARM, num_steps=4,
                       critic_lr=1e-2, actor_lr=1e-6, bc_lr=1e-3, alpha_lr=1e-2, tau=0.01,
                       norm_bound=1.0, clip_v=True)


@pytest.fixture(scope="module")
def tiny():
    ds = mdp_dataset(0.5, 2)
    ds = ds.replace(actions=ds.actions * 2.0, metadata=ds.metadata.updated(action_limit=2.0),
                    terminals=np.arange(N) % 5 == 4, episode_ids=(np.arange(N) // 5
                                                                  ).astype(np.int32))
    tr = atac.make_train(ds, TINY)
    init = fast_jit(tr.init)
    run = fast_jit(tr.run, static_argnums=1)
    keys = jax.random.split(jax.random.key(7), 2)
    batched = fast_jit(jax.vmap(tr.train))(keys)          # num_steps = 4, both seeds at once
    split = []
    for k in keys:                                        # each seed alone, as run(run(s, 2), 2)
        s0 = init(k)
        s2, m2 = run(s0, 2)
        s4, m4 = run(s2, 2)
        split.append(dict(s0=s0, s2=s2, s4=s4,
                          m4=jax.tree.map(lambda a, b: np.concatenate([a, b]), m2, m4)))
    return dict(tr=tr, batched=batched, split=split, **split[0])


def leaves_close(a, b, **kw):
    def arr(x):
        return jax.random.key_data(x) if jnp.issubdtype(x.dtype, jax.dtypes.prng_key) else x

    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_allclose(np.asarray(arr(x)), np.asarray(arr(y)), **kw)


def test_run_split_and_vmap_over_seeds_equal_one_call(tiny):
    """vmap(train)(keys)[i] (one scan of 4 steps, seeds batched) equals run(run(init(k_i), 2), 2)
    for each seed: the split is exact and batching over seeds changes nothing."""
    state, metrics = tiny["batched"]
    for i, one in enumerate(tiny["split"]):
        leaves_close(jax.tree.map(lambda x, i=i: x[i], state), one["s4"], rtol=1e-5, atol=1e-6)
        leaves_close(jax.tree.map(lambda x, i=i: x[i], metrics), one["m4"], rtol=1e-5,
                     atol=1e-6)
    assert not np.allclose(tiny["split"][0]["m4"]["critic_loss"],
                           tiny["split"][1]["m4"]["critic_loss"])


def test_warm_start_switch(tiny):
    s0, s2, s4, m4 = tiny["s0"], tiny["s2"], tiny["s4"], tiny["m4"]
    assert int(s2.step) == WARM and int(s4.step) == 4
    # Warm start: critic loss is the Bellman term only (summed over the 2 critics).
    np.testing.assert_allclose(m4["critic_loss"][:WARM], 2 * m4["bellman"][:WARM], rtol=1e-5)
    assert np.all(np.abs(m4["critic_loss"][WARM:] - 2 * m4["bellman"][WARM:]) > 1e-6)
    # Actor Adam state rebuilt at the switch (2 updates since), temperature reset.
    assert int(s2.opt_states["actor"].count) == WARM
    assert int(s4.opt_states["actor"].count) == 4 - WARM
    assert int(s4.opt_states["alpha"][0].count) == 4 - WARM
    assert abs(float(s4.params["log_alpha"])) <= (4 - WARM) * TINY.alpha_lr * 1.01
    assert abs(float(s2.params["log_alpha"])) > 0.5 * TINY.alpha_lr
    # Actor moves at bc_lr before the switch and at most actor_lr per step after it.
    def max_move(a, b):
        return max(float(jnp.max(jnp.abs(x - y))) for x, y in
                   zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True))
    assert max_move(s2.params["actor"], s0.params["actor"]) > 0.5 * TINY.bc_lr
    # (float32 rounding of parameters of size <= 2 adds < 4e-7)
    assert (max_move(s4.params["actor"], s2.params["actor"])
            <= (4 - WARM) * TINY.actor_lr * 1.01 + 4e-7)
    # Target critics kept (only Polyak-averaged), not reset to the online critics.
    tgt_move = max_move(s4.target_critic, s2.target_critic)
    assert tgt_move < 0.05 * max_move(s2.params["critic"], s2.target_critic)


def test_frobenius_projection_holds(tiny):
    norms = [float(jnp.linalg.norm(k[i]))
             for path, k in jax.tree_util.tree_leaves_with_path(tiny["s4"].params["critic"])
             if path[-1].key == "kernel" for i in range(k.shape[0])]
    assert max(norms) <= TINY.norm_bound * (1 + 1e-5)
    assert max(norms) >= TINY.norm_bound * (1 - 1e-4)  # the bound is active


def test_act_in_environment_units(tiny):
    obs = jnp.eye(3, dtype=jnp.float32)
    p = actor_params(tiny["s4"])
    a = tiny["tr"].act(p, obs)
    mode = TanhGaussianPolicy(1, (8, 8)).apply(p, obs).mode()
    np.testing.assert_allclose(a, 2.0 * mode, rtol=1e-6)
    assert tiny["tr"].act(p, obs[0]).shape == (1,)


# --------------------------------------------------------------------------------------------
# Errors


@pytest.mark.parametrize("field,value", [
    ("beta", -1.0), ("discount", 1.0), ("tau", 1.5), ("dqra_weight", -0.1),
    ("pessimism", "optimistic"), ("hidden_sizes", ()), ("batch_size", 0), ("critic_lr", 0.0),
    ("warmstart_steps", -1), ("num_critics", 0), ("target_entropy", float("nan")),
])
def test_bad_config_raises(field, value):
    with pytest.raises(ValueError, match=field):
        atac.ATACConfig(**{field: value})


def test_reward_data_and_hidden_rewards_rejected():
    ds = mdp_dataset(0.5, 3)
    cfg = dataclasses.replace(TINY)
    with pytest.raises(ValueError, match="reward_data"):
        atac.make_train(ds, cfg, reward_data=object())
    hidden = ds.replace(metadata=ds.metadata.updated(rewards_visible=False))
    with pytest.raises(ValueError, match="rewards_visible"):
        atac.make_train(hidden, cfg)
    with pytest.raises(TypeError, match="ATACConfig"):
        atac.make_train(ds, {"beta": 1.0})


def test_pspi_reward_fn_and_remove_terminals_build():
    """PSPI and a fixed reward model trace through the whole training program; terminals
    become timeouts with ``remove_terminals``."""
    ds = mdp_dataset(0.5, 4).replace(terminals=np.arange(N) == N - 1)
    pspi = atac.make_train(ds, dataclasses.replace(TINY, pessimism="absolute"))
    shapes = jax.eval_shape(pspi.train, jax.random.key(0))[1]
    assert shapes["pessimism"].shape == (TINY.num_steps,)
    hidden = ds.replace(metadata=ds.metadata.updated(rewards_visible=False))
    tr = atac.make_train(hidden, TINY, reward_fn=lambda b: jnp.zeros_like(b.rewards))
    jax.eval_shape(tr.train, jax.random.key(0))
    with pytest.raises(ValueError, match="reward_fn"):
        atac.make_train(hidden, TINY, reward_fn=1.0)
    kept = atac.prepare_dataset(ds, remove_terminals=False)
    gone = atac.prepare_dataset(ds, remove_terminals=True)
    assert bool(kept.terminals[-1]) and not bool(kept.timeouts[-1])
    assert not np.asarray(gone.terminals).any() and bool(gone.timeouts[-1])
    assert gone.actions.dtype == jnp.float32


@pytest.mark.parametrize("pessimism", atac.PESSIMISM)
def test_policy_moves_from_its_warm_start_to_the_bandit_optimum(pessimism):
    """Policy improvement where the data covers the best action: on the one-step bandit of
    ``offline_bandit`` (uniform actions, mean reward −4/3) the BC warm start ends near the
    behaviour's mean action 0 (reward 0 there), and the game phase (ATAC's relative or PSPI's
    absolute pessimism at the published β = 16) then moves the actor to the best action."""
    ds = make_bandit()
    cfg = atac.ATACConfig(hidden_sizes=(32, 32), batch_size=64, num_steps=600,
                          warmstart_steps=200, actor_lr=3e-3, critic_lr=3e-3,
                          pessimism=pessimism)
    trainer = atac.make_train(ds, cfg)
    run = fast_jit(trainer.run, static_argnums=1)
    warm, _ = run(trainer.init(jax.random.PRNGKey(0)), cfg.warmstart_steps)
    final, _ = run(warm, cfg.num_steps - cfg.warmstart_steps)
    obs = np.asarray(ds.observations[:64])

    def actions(state):
        return np.asarray(trainer.act(actor_params(state), obs))[:, 0] / LIMIT

    # the clone of uniform actions acts near their mean 0 (reward 0 there; the best is 1)
    assert abs(actions(warm).mean()) < 0.2 and mean_reward(actions(warm)) < 0.5
    assert mean_reward(actions(final)) > 0.9, actions(final).mean()
