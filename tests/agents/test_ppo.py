"""PPO (agents/ppo/): GAE and loss against float64 NumPy references, seed-vmapping, learning.

Small configurations, the pure-JAX ``point2d`` environment and a 1-D toy environment only (no
MJX), so the whole module compiles and runs in well under a minute on 2 CPU cores.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.envs.base import Env, State

import envs
from agents.ppo import (
    GaussianPolicy,
    PPOConfig,
    ValueMLP,
    gae,
    make_train,
    make_trainer,
    ppo_loss,
)


class MoveToZero(Env):
    """1-D toy: ``x ← x + 0.2·clip(a, −1, 1)``, reward ``−|x|``; |x| > 2 ends it as a collision."""

    horizon = 16

    @property
    def observation_size(self) -> int:
        return 1

    @property
    def action_size(self) -> int:
        return 1

    @property
    def backend(self) -> str:
        return "jax"

    def reset(self, rng):
        k_x, k_next = jax.random.split(rng)
        x = jax.random.uniform(k_x, (1,), minval=-1.0, maxval=1.0)
        z = jnp.zeros((), jnp.float32)
        info = {"rng": k_next, "episode_return": z, "episode_collided": z}
        return State(x, x, z, z, {"collision": z}, info)

    def step(self, state, action):
        x = state.pipeline_state + 0.2 * jnp.clip(action, -1.0, 1.0)
        collided = (jnp.abs(x[0]) > 2.0).astype(jnp.float32)
        reward = -jnp.abs(x[0])
        info = dict(state.info)
        info["episode_return"] = info["episode_return"] + reward
        info["episode_collided"] = jnp.maximum(info["episode_collided"], collided)
        return state.replace(pipeline_state=x, obs=x, reward=reward, done=collided,
                             metrics={"collision": collided}, info=info)


# --------------------------------------------------------------------------------- references


def gae_reference(rewards, values, dones, truncs, last_value, gamma, lam):
    """Plain float64 loop; truncated steps bootstrap from V(s_t) (module docstring)."""
    rewards, values, dones, truncs = (np.asarray(a, np.float64)
                                      for a in (rewards, values, dones, truncs))
    T = rewards.shape[0]
    adv = np.zeros_like(rewards)
    nxt = np.zeros_like(np.asarray(last_value, np.float64))
    for t in reversed(range(T)):
        next_v = np.asarray(last_value, np.float64) if t == T - 1 else values[t + 1]
        out = np.empty_like(nxt)
        for b in range(rewards.shape[1]):
            ended = dones[t, b] > 0 or truncs[t, b] > 0
            if truncs[t, b] > 0:
                boot = values[t, b]
            elif dones[t, b] > 0:
                boot = 0.0
            else:
                boot = next_v[b]
            delta = rewards[t, b] + gamma * boot - values[t, b]
            out[b] = delta + (0.0 if ended else gamma * lam * nxt[b])
        adv[t] = out
        nxt = out
    return adv, adv + values


#: ``ppo_loss`` compiled (the apply functions and the normalisation flag static), so the tests
#: below do not run it op by op.
PPO_LOSS = jax.jit(ppo_loss, static_argnames=("policy_apply", "value_apply",
                                              "normalize_advantages"))


def loss_reference(W, b, log_std, v_w, v_b, batch, clip, vf, ent, normalize):
    obs = np.asarray(batch["obs"], np.float64)
    act = np.asarray(batch["actions"], np.float64)
    mean = obs @ W + b
    std = np.exp(log_std)
    logp = np.sum(-0.5 * ((act - mean) / std) ** 2 - log_std - 0.5 * math.log(2 * math.pi),
                  axis=-1)
    ratio = np.exp(logp - np.asarray(batch["log_probs"], np.float64))
    adv = np.asarray(batch["advantages"], np.float64)
    if normalize:
        adv = (adv - adv.mean()) / (adv.std() + 1e-8)
    pg = -np.mean(np.minimum(ratio * adv, np.clip(ratio, 1 - clip, 1 + clip) * adv))
    v = obs @ v_w + v_b
    vl = 0.5 * np.mean((v - np.asarray(batch["returns"], np.float64)) ** 2)
    entropy = np.sum(log_std + 0.5 * (math.log(2 * math.pi) + 1.0))
    return pg + vf * vl - ent * entropy, pg, vl, entropy, np.mean(np.abs(ratio - 1) > clip)


# ---------------------------------------------------------------------------------------- tests


def test_gae_matches_numpy_reference():
    rng = np.random.default_rng(0)
    T, B = 9, 4
    rewards = rng.normal(size=(T, B))
    values = rng.normal(size=(T, B))
    last_value = rng.normal(size=(B,))
    dones = np.zeros((T, B))
    truncs = np.zeros((T, B))
    dones[2, 0] = 1  # termination
    dones[5, 1] = truncs[5, 1] = 1  # time limit
    dones[3, 2] = 1  # termination, then a time limit in the same column
    dones[7, 2] = truncs[7, 2] = 1
    dones[T - 1, 3] = truncs[T - 1, 3] = 1  # time limit on the last step
    gamma, lam = 0.97, 0.9
    ref_adv, ref_ret = gae_reference(rewards, values, dones, truncs, last_value, gamma, lam)
    with jax.enable_x64(True):
        adv, ret = gae(*(jnp.asarray(a, jnp.float64) for a in
                         (rewards, values, dones, truncs, last_value)), gamma, lam)
        np.testing.assert_allclose(adv, ref_adv, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(ret, ref_ret, rtol=1e-12, atol=1e-12)
    adv32, _ = gae(*(jnp.asarray(a, jnp.float32) for a in
                     (rewards, values, dones, truncs, last_value)), gamma, lam)
    np.testing.assert_allclose(adv32, ref_adv, rtol=1e-5, atol=1e-5)
    # Explicit terminal values replace V(s_t) in the bootstrap of truncated steps only.
    term = values + 1.0
    adv_t, _ = gae(*(jnp.asarray(a, jnp.float32) for a in
                     (rewards, values, dones, truncs, last_value)), gamma, lam,
                   terminal_values=jnp.asarray(term, jnp.float32))
    np.testing.assert_allclose(adv_t[5, 1] - adv32[5, 1], gamma, rtol=1e-5)
    np.testing.assert_allclose(adv_t[:, 0], adv32[:, 0], rtol=1e-6)


def test_gae_without_episode_ends_is_discounted_td_sum():
    # λ = 1, no ends: advantage = Σ γ^k r_{t+k} + γ^{T-t} V_last − V_t.
    T = 6
    r = np.arange(1.0, T + 1)[:, None]
    v = np.linspace(-1, 1, T)[:, None]
    z = np.zeros((T, 1))
    with jax.enable_x64(True):
        adv, _ = gae(jnp.asarray(r), jnp.asarray(v), jnp.asarray(z), jnp.asarray(z),
                     jnp.asarray([2.0]), 0.9, 1.0)
    expect = [sum(0.9**k * r[t + k, 0] for k in range(T - t)) + 0.9 ** (T - t) * 2.0 - v[t, 0]
              for t in range(T)]
    np.testing.assert_allclose(np.asarray(adv)[:, 0], expect, rtol=1e-12)


@pytest.mark.parametrize("normalize", [True, False])
def test_ppo_loss_matches_numpy_reference(normalize):
    rng = np.random.default_rng(1)
    N, O, A = 12, 3, 2
    W, b = rng.normal(size=(O, A)), rng.normal(size=(A,))
    log_std = np.array([-1.0, -0.3])
    v_w, v_b = rng.normal(size=(O,)), 0.4
    obs = rng.normal(size=(N, O))
    mean = obs @ W + b
    actions = mean + np.exp(log_std) * rng.normal(size=(N, A))
    # Old log-probs perturbed so that some ratios fall outside [1 − ε, 1 + ε].
    old = np.sum(-0.5 * ((actions - mean) / np.exp(log_std)) ** 2 - log_std
                 - 0.5 * math.log(2 * math.pi), axis=-1) + rng.normal(scale=0.3, size=N)
    batch = {"obs": obs, "actions": actions, "log_probs": old,
             "advantages": rng.normal(size=N), "returns": rng.normal(size=N)}
    clip, vf, ent = 0.2, 0.7, 0.01
    ref = loss_reference(W, b, log_std, v_w, v_b, batch, clip, vf, ent, normalize)
    assert 0 < ref[4] < 1  # clipping is exercised

    def policy_apply(p, o):
        return o @ p["W"] + p["b"], p["log_std"]

    def value_apply(p, o):
        return o @ p["w"] + p["b"]

    with jax.enable_x64(True):
        params = {"policy": {"W": jnp.asarray(W), "b": jnp.asarray(b),
                             "log_std": jnp.asarray(log_std)},
                  "value": {"w": jnp.asarray(v_w), "b": jnp.asarray(v_b)}}
        jb = {k: jnp.asarray(v) for k, v in batch.items()}
        loss, m = PPO_LOSS(params, jb, policy_apply, value_apply, clip, vf, ent, normalize)
        np.testing.assert_allclose(loss, ref[0], rtol=1e-10)
        np.testing.assert_allclose(m["policy_loss"], ref[1], rtol=1e-10)
        np.testing.assert_allclose(m["value_loss"], ref[2], rtol=1e-10)
        np.testing.assert_allclose(m["entropy"], ref[3], rtol=1e-10)
        np.testing.assert_allclose(m["clip_fraction"], ref[4], rtol=1e-10)
        # The gradient is finite and reaches both networks.
        g = jax.jit(jax.grad(lambda p: PPO_LOSS(p, jb, policy_apply, value_apply, clip, vf,
                                                ent, normalize)[0]))(params)
        assert all(bool(jnp.all(jnp.isfinite(x))) for x in jax.tree.leaves(g))
        assert float(jnp.abs(g["value"]["w"]).sum()) > 0


def test_networks_initialisation():
    pol = GaussianPolicy(3, hidden_sizes=(8,), activation="elu")
    p = pol.init(jax.random.PRNGKey(0), jnp.zeros(5))
    mean, log_std = pol.apply(p, jnp.ones((4, 5)))
    assert mean.shape == (4, 3) and log_std.shape == (3,)
    np.testing.assert_allclose(log_std, -1.0)
    # normc output init at scale 0.1: every output unit's weight vector has norm 0.1.
    k = p["params"]["mean"]["out"]["kernel"]
    np.testing.assert_allclose(jnp.linalg.norm(k, axis=0), 0.1, rtol=1e-5)
    val = ValueMLP()
    vp = val.init(jax.random.PRNGKey(1), jnp.zeros(5))
    assert [vp["params"]["mlp"][f"hidden_{i}"]["kernel"].shape[1] for i in range(2)] == [256, 128]
    assert val.apply(vp, jnp.ones((4, 5))).shape == (4,)


def test_config_validation_and_thesis_preset():
    cfg = PPOConfig.thesis()
    assert cfg.learning_rate == 5e-5 and cfg.clip_eps == 0.2 and cfg.gae_lambda == 0.99
    assert cfg.minibatch_size == 4096 and cfg.total_iterations == 500
    assert abs(cfg.batch_size - 67_312) / 67_312 < 0.03
    assert cfg.value_hidden_sizes == (256, 128) and cfg.value_activation == "tanh"
    assert cfg.log_std_init == -1.0 and cfg.policy_out_scale == 0.1
    hash(cfg)
    with pytest.raises(ValueError, match="num_minibatches"):
        PPOConfig(num_envs=3, rollout_length=5, num_minibatches=2)
    with pytest.raises(ValueError, match="learning_rate"):
        PPOConfig(learning_rate=-1.0)
    with pytest.raises(ValueError, match="gae_lambda"):
        PPOConfig(gae_lambda=1.5)
    with pytest.raises(ValueError, match="policy_activation"):
        PPOConfig(policy_activation="sigmoidish")
    with pytest.raises(ValueError, match="num_envs"):
        PPOConfig(num_envs=0)


TINY = PPOConfig(num_envs=4, rollout_length=8, num_minibatches=2, update_epochs=2,
                 total_iterations=2, policy_hidden_sizes=(8,), value_hidden_sizes=(8,),
                 episode_length=6)


def test_vmap_over_seeds_equals_separate_runs():
    train = make_train(envs.make("point2d"), config=TINY)
    keys = jnp.stack([jax.random.PRNGKey(3), jax.random.PRNGKey(4)])
    params_v, metrics_v = jax.jit(jax.vmap(train))(keys)
    single = jax.jit(train)
    for i in range(2):
        params_i, metrics_i = single(keys[i])
        for a, b in zip(jax.tree.leaves(params_i), jax.tree.leaves(params_v), strict=True):
            np.testing.assert_allclose(a, b[i], rtol=2e-4, atol=1e-6)
        for k, v in metrics_i.items():
            np.testing.assert_allclose(v, metrics_v[k][i], rtol=2e-3, atol=1e-6,
                                       equal_nan=True, err_msg=k)
    assert metrics_v["mean_reward"].shape == (2, TINY.total_iterations)
    # Episodes of length 6 in 8-step rollouts: every iteration finishes some.
    assert np.all(np.asarray(metrics_v["episodes"]) > 0)
    assert np.all(np.isfinite(np.asarray(metrics_v["mean_episode_return"])))
    np.testing.assert_allclose(metrics_v["safe_fraction"], 1.0)  # 1 obstacle, tiny moves


def test_update_metrics_are_the_means_over_every_minibatch_step():
    """The update's loss metrics are the means over its 3 epochs × 4 minibatch steps: at a
    vanishing learning rate the parameters stay put and (advantages not normalised per
    minibatch) that mean is the metric of the whole batch, computed here in one call."""
    cfg = dataclasses.replace(TINY, num_minibatches=4, update_epochs=3, learning_rate=1e-12,
                              normalize_advantages=False, normalize_observations=False)
    trainer = make_trainer(envs.make("point2d"), config=cfg)
    ts, tr = jax.jit(trainer.rollout)(jax.jit(trainer.init)(jax.random.PRNGKey(0)),
                                      jax.random.PRNGKey(1))
    _, metrics = jax.jit(trainer.update)(ts, tr, jax.random.PRNGKey(2))
    value = lambda p, o: trainer.value_net.apply(p, o)  # noqa: E731

    @jax.jit
    def whole_batch(ts, tr):
        adv, ret = gae(tr.rewards, tr.values, tr.dones, tr.truncations,
                       value(ts.params["value"], ts.env_state.obs), cfg.gamma, cfg.gae_lambda)
        return jax.tree.map(lambda x: x.reshape((-1, *x.shape[2:])), {
            "obs": tr.obs, "actions": tr.actions, "log_probs": tr.log_probs,
            "advantages": adv, "returns": ret})

    whole = whole_batch(ts, tr)
    _, want = PPO_LOSS(ts.params, whole, trainer.policy.apply, value, cfg.clip_eps,
                       cfg.vf_coef, cfg.ent_coef, normalize_advantages=False)
    for k, v in want.items():
        np.testing.assert_allclose(metrics[k], v, rtol=1e-5, atol=1e-7, err_msg=k)


def test_training_improves_on_move_to_zero():
    cfg = PPOConfig(num_envs=16, rollout_length=16, num_minibatches=2, update_epochs=4,
                    total_iterations=40, learning_rate=3e-3, gamma=0.9, gae_lambda=0.9,
                    policy_hidden_sizes=(16,), value_hidden_sizes=(16,), episode_length=16)
    _, m = jax.jit(make_train(MoveToZero(), config=cfg))(jax.random.PRNGKey(0))
    r = np.asarray(m["mean_reward"])
    first, last = r[:3].mean(), r[-5:].mean()
    # Random policy: E|x| ≈ 0.5 (x0 ~ U[−1, 1], std-0.37 noise); moving at 0.2/step towards 0
    # reaches |x| < 0.2 within 5 of 16 steps.
    # (Over 8 seeds: first ∈ [−0.54, −0.39], last ∈ [−0.077, −0.063].)
    assert first < -0.3, first
    assert last > -0.15, (first, last)
    assert last > first + 0.2
    # Finished episodes are time limits only (no collision): return = 16 × mean reward.
    np.testing.assert_allclose(m["safe_fraction"], 1.0)
    np.testing.assert_allclose(m["mean_episode_return"][-1] / 16, r[-1], atol=0.05)
