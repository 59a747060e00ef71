"""MAHALO (offline/learners/mahalo.py, thesis Algorithm 3) and the RP / UDS / Oracle baselines
(offline/learners/plfo_baselines.py, §7.4).

* MAHALO with reward data = all the dynamics data (true rewards) matches ATAC with the true
  rewards (critic values, actions), and its reward network recovers the rewards; trained vmapped
  over (seed, β) pairs.
* RP's regression recovers the rewards; UDS labels exactly the shared transitions per scenario;
  Oracle reads hidden rewards that ATAC refuses; errors.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from offline.data import dataset as odata
from offline.data import scenarios
from offline.learners import atac, mahalo, plfo_baselines
from offline.learners.networks import QEnsemble, StateNet

FAST = {"xla_backend_optimization_level": 0}
HIDDEN = (16, 16)
N = 600
B_S = np.array([0.2, -0.1, 0.1])     # r(s) = b_s, a function of the state only
C_S = np.array([-0.5, 0.6, 0.3])
META = {"action_limit": 1.0, "reward_range": [-1.0, 1.0]}


def fast_jit(f, **kw):
    return jax.jit(f, compiler_options=FAST, **kw)


def state_reward_dataset(seed: int = 0) -> odata.Dataset:
    """3 one-hot states, every transition to state 2, r = b_s, behaviour a ~ N(c_s, 0.4)."""
    rng = np.random.default_rng(seed)
    s = np.arange(N) % 3
    eye = np.eye(3, dtype=np.float32)
    a = np.clip(rng.normal(C_S[s], 0.4), -0.99, 0.99)[:, None].astype(np.float32)
    return odata.create(eye[s], a, B_S[s].astype(np.float32), eye[np.full(N, 2)], np.zeros(N),
                        np.zeros(N), np.zeros(N), META)


ATAC_CFG = atac.ATACConfig(hidden_sizes=HIDDEN, batch_size=64, warmstart_steps=200,
                           num_steps=1500, critic_lr=2e-3, actor_lr=1e-3, bc_lr=2e-3,
                           discount=0.9, tau=0.05)
REWARD_CFG = mahalo.RewardNetConfig(hidden_sizes=HIDDEN, lr=3e-3, batch_size=64)
KEYS = jax.random.split(jax.random.key(0), 2)
BETAS = jnp.array([3.0, 30.0])


@pytest.fixture(scope="module")
def paired_runs():
    ds = state_reward_dataset()
    rd = scenarios.reward_data(ds)
    m_tr = mahalo.make_train(ds.replace(metadata=ds.metadata.updated(rewards_visible=False)),
                             mahalo.MAHALOConfig(atac=ATAC_CFG, reward=REWARD_CFG),
                             reward_data=rd)
    a_tr = atac.make_train(ds, ATAC_CFG)
    m_state, m_metrics = fast_jit(jax.vmap(m_tr.train))(KEYS, BETAS)
    a_state, _ = fast_jit(jax.vmap(a_tr.train))(KEYS, BETAS)
    return ds, m_tr, m_state, m_metrics, a_state


def test_mahalo_matches_atac_with_true_rewards(paired_runs):
    ds, m_tr, m_state, _, a_state = paired_runs
    critic = fast_jit(QEnsemble(2, HIDDEN).apply)
    obs = jnp.eye(3, dtype=jnp.float32)
    qs = {}
    for name, st in (("mahalo", m_state), ("atac", a_state)):
        for i in range(2):
            p = jax.tree.map(lambda x, i=i: x[i], st.params)
            qs[name, i] = np.asarray(critic(p["critic"], ds.observations, ds.actions))
            qs[name, "act", i] = np.asarray(m_tr.act(p["actor"], obs))
    for i in range(2):
        diff = np.mean(np.abs(qs["mahalo", i] - qs["atac", i]))
        # What a different β changes, for scale: MAHALO must be much closer to ATAC than that.
        other = np.mean(np.abs(qs["atac", 1 - i] - qs["atac", i]))
        assert diff < 0.1 * other and diff < 0.05 * np.mean(np.abs(qs["atac", i])), (diff, other)
        np.testing.assert_allclose(qs["mahalo", "act", i], qs["atac", "act", i], atol=0.03)
        assert np.max(np.abs(qs["atac", "act", 1 - i] - qs["atac", "act", i])) > 0.1


def test_reward_network_recovers_rewards(paired_runs):
    ds, _, m_state, m_metrics, _ = paired_runs
    net = mahalo.RewardNetConfig(hidden_sizes=HIDDEN)
    g = mahalo.make_reward_net(scenarios.reward_data(ds), net, observation_size=3,
                               remove_terminals=False, learner="test")
    for i in range(2):
        params = jax.tree.map(lambda x, i=i: x[i], m_state.params["reward"])
        pred = np.asarray(g.predict(params, ds))
        np.testing.assert_allclose(pred, np.asarray(ds.rewards), atol=0.02)
    assert np.all(np.asarray(m_metrics["reward_fit"])[:, -50:].mean(1) < 1e-3)


def test_max_reward_label_and_clip():
    ds = state_reward_dataset(1)
    rd = scenarios.reward_data(ds, reward=0.7)
    prepared = mahalo.prepare_reward_data(rd, remove_terminals=False, max_reward_label=True)
    np.testing.assert_array_equal(np.asarray(prepared.rewards), 1.0)
    cfg = mahalo.RewardNetConfig(hidden_sizes=(4,), max_reward_label=True)
    g = mahalo.make_reward_net(rd, cfg, observation_size=3, remove_terminals=False,
                               learner="test")
    assert g.bounds == (0.0, 1.0)
    params = jax.tree.map(lambda x: 50.0 * x, g.init(jax.random.key(0)))
    raw = np.asarray(StateNet(1, (4,)).apply(params, mahalo.reward_features(ds)))
    assert raw.min() < 0.0 or raw.max() > 1.0
    np.testing.assert_allclose(np.asarray(g.predict(params, ds)), np.clip(raw, 0.0, 1.0))


def test_rp_regression_recovers_rewards():
    ds = state_reward_dataset(2)
    rd = scenarios.reward_data(ds)
    cfg = plfo_baselines.RPConfig(atac=ATAC_CFG, reward=REWARD_CFG, reward_steps=1500)
    tr = plfo_baselines.make_train_rp(ds.replace(metadata=ds.metadata.updated(
        rewards_visible=False)), cfg, reward_data=rd)
    state = fast_jit(tr.init)(jax.random.key(3))
    g = mahalo.make_reward_net(rd, REWARD_CFG, observation_size=3, remove_terminals=False,
                               learner="test")
    np.testing.assert_allclose(np.asarray(g.predict(state.params["reward"], ds)),
                               np.asarray(ds.rewards), atol=0.02)


# --------------------------------------------------------------------------------------------
# UDS labels per scenario (host-side) and Oracle


def episodes_dataset(num_episodes: int, reward: float, seed: int) -> odata.Dataset:
    rng = np.random.default_rng(seed)
    n = 5 * num_episodes
    obs = rng.normal(size=(n, 2)).astype(np.float32)
    return odata.create(obs, rng.uniform(-1, 1, (n, 1)).astype(np.float32),
                        np.full(n, reward, np.float32) + rng.uniform(0, 0.1, n).astype(
                            np.float32), obs + 1, np.zeros(n), np.arange(n) % 5 == 4,
                        np.arange(n) // 5, {**META, "reward_range": [-0.5, 1.0]})


@pytest.fixture(scope="module")
def mixed_expert():
    return episodes_dataset(6, 0.2, 0), episodes_dataset(2, 0.9, 1)


def test_uds_labels_il_and_rl_expert(mixed_expert):
    mixed, expert = mixed_expert
    for name, expert_reward in (("IL", 1.0), ("RL-expert", None)):
        dyn, rd = scenarios.make(name, mixed, expert)
        out = plfo_baselines.uds_relabel(dyn, rd, -0.5)
        r = np.asarray(out.rewards)
        np.testing.assert_array_equal(r[:mixed.size], -0.5)
        want = (np.full(expert.size, expert_reward) if expert_reward is not None
                else np.asarray(expert.rewards))
        np.testing.assert_allclose(r[mixed.size:], want, rtol=1e-6)
        assert out.metadata["uds"]["labelled"] == expert.size
        plfo_baselines.make_train_uds(dyn, plfo_baselines.UDSConfig(atac=ATAC_CFG),
                                      reward_data=rd)


def test_uds_labels_rl_sample_and_refuses_ilfo(mixed_expert):
    mixed, expert = mixed_expert
    dyn, rd = scenarios.make("RL-sample", mixed, key=jax.random.key(4))
    out = plfo_baselines.uds_relabel(dyn, rd, -0.5)
    labelled = np.isin(np.asarray(dyn.episode_ids), np.asarray(rd.episode_ids))
    assert 0 < labelled.sum() < dyn.size
    np.testing.assert_array_equal(np.asarray(out.rewards)[~labelled], -0.5)
    np.testing.assert_array_equal(np.asarray(out.rewards)[labelled],
                                  np.asarray(dyn.rewards)[labelled])
    for name in ("ILfO", "RLfO"):
        dyn, rd = scenarios.make(name, mixed, expert)
        with pytest.raises(ValueError, match="shared transitions"):
            plfo_baselines.make_train_uds(dyn, plfo_baselines.UDSConfig(atac=ATAC_CFG),
                                          reward_data=rd)


def test_oracle_reads_hidden_rewards(mixed_expert):
    mixed, expert = mixed_expert
    dyn, rd = scenarios.make("RLfO", mixed, expert)
    with pytest.raises(ValueError, match="rewards_visible"):
        atac.make_train(dyn, ATAC_CFG)
    tr = plfo_baselines.make_train_oracle(dyn, ATAC_CFG)
    assert tr.num_steps == ATAC_CFG.num_steps
    with pytest.raises(ValueError, match="reward_data"):
        plfo_baselines.make_train_oracle(dyn, ATAC_CFG, reward_data=rd)


# --------------------------------------------------------------------------------------------
# Errors


def test_missing_or_bad_reward_data_and_configs(mixed_expert):
    mixed, expert = mixed_expert
    dyn, rd = scenarios.make("RLfO", mixed, expert)
    cfg = mahalo.MAHALOConfig(atac=ATAC_CFG, reward=REWARD_CFG)
    with pytest.raises(ValueError, match="MAHALO needs reward_data"):
        mahalo.make_train(dyn, cfg)
    with pytest.raises(ValueError, match="RP needs reward_data"):
        plfo_baselines.make_train_rp(dyn, plfo_baselines.RPConfig(atac=ATAC_CFG))
    with pytest.raises(ValueError, match="UDS needs reward_data"):
        plfo_baselines.make_train_uds(dyn, plfo_baselines.UDSConfig(atac=ATAC_CFG))
    with pytest.raises(ValueError, match="RewardData"):
        mahalo.make_train(dyn, cfg, reward_data=dyn)
    no_range = rd.replace(metadata=odata.Metadata({}))
    with pytest.raises(ValueError, match="reward_range"):
        mahalo.make_train(dyn, cfg, reward_data=no_range)
    other = scenarios.reward_data(state_reward_dataset())
    with pytest.raises(ValueError, match="observation size"):
        mahalo.make_train(dyn, cfg, reward_data=other)
    with pytest.raises(TypeError, match="MAHALOConfig"):
        mahalo.make_train(dyn, ATAC_CFG, reward_data=rd)
    for bad in ({"reward_weight": -1.0}, {"atac": {"beta": 1}}, {"reward": None}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            mahalo.MAHALOConfig(**bad)
    for bad in ({"hidden_sizes": ()}, {"lr": 0.0}, {"batch_size": 0},
                {"reward_range": (1.0, 0.0)}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            mahalo.RewardNetConfig(**bad)
    with pytest.raises(ValueError, match="reward_steps"):
        plfo_baselines.RPConfig(reward_steps=0)
    with pytest.raises(ValueError, match="min_reward"):
        plfo_baselines.UDSConfig(min_reward=float("inf"))
