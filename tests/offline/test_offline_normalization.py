"""Optional observation standardisation of the offline learners (``normalize_observations``,
:class:`offline.learners.base.ObservationNormalizer`).

* The statistics equal float64 NumPy's (population std, floored at ``STD_FLOOR``).
* Off (the default everywhere), data and actions are untouched: the prepared observations are the
  raw ones, and a BC run equals the run with the option spelled out as False.
* On, BC is invariant to a per-feature affine change of the observations (``A·o + b``, diagonal
  scales 1e-2 … 1e2): trained on the changed data it acts on changed inputs as the original does
  on the original ones; ``act`` takes raw observations.
* MAHALO's reward network sees the reward data standardised with the *dynamics* statistics;
  MAHALO and BCO train with finite losses; AP / ATAC of :func:`offline.experiment.run.build` use
  ``D_A``'s statistics; a traced-reward build (the chapter-8 sweep) works; bad input → ValueError.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from offline.data import dataset as odata
from offline.data import scenarios
from offline.experiment import run as experiment
from offline.learners import atac, bc, cql, iql, mahalo, registry
from offline.learners.base import (
    STD_FLOOR,
    ObservationNormalizer,
    action_scale,
    actor_params,
    normalized_dataset,
    policy_act,
)
from offline.learners.inverse_dynamics import InverseDynamicsConfig
from offline.learners.tanh_gaussian import TanhGaussianPolicy
from offline.survival import sweep

FAST = {"xla_backend_optimization_level": 0}
HIDDEN = (16, 16)
META = {"env": "three_link/env3", "action_limit": 2.0, "reward_range": [-1.0, 1.0]}
#: The per-feature affine change A·o + b (A diagonal, 1e-2 … 1e2).
SCALES = np.array([1e-2, 1.0, 1e2], np.float64)
SHIFTS = np.array([3.0, -7.0, 50.0], np.float64)


def _dataset(obs: np.ndarray, next_obs: np.ndarray, actions: np.ndarray, n_episodes: int = 4,
             reward: float = 0.0, first_id: int = 0) -> odata.Dataset:
    n = obs.shape[0]
    length = n // n_episodes
    ids = np.repeat(np.arange(first_id, first_id + n_episodes), length)
    timeouts = np.tile(np.arange(length) == length - 1, n_episodes)
    return odata.create(obs.astype(np.float32), actions.astype(np.float32),
                        np.full(n, reward, np.float32), next_obs.astype(np.float32),
                        np.zeros(n), timeouts, ids, META)


def _affine_pair(n: int = 200, seed: int = 0) -> tuple[odata.Dataset, odata.Dataset]:
    """A dataset with a = f(o) and the same transitions with observations ``A·o + b``."""
    rng = np.random.default_rng(seed)
    obs = rng.normal(size=(n, 3))
    nxt = obs + 0.1 * rng.normal(size=(n, 3))
    actions = 1.8 * np.tanh(obs[:, :2] - 0.5 * obs[:, 2:])
    return (_dataset(obs, nxt, actions),
            _dataset(obs * SCALES + SHIFTS, nxt * SCALES + SHIFTS, actions))


def test_statistics_match_float64_numpy_and_the_identity_is_a_no_op():
    obs = np.array([[1.0, 5.0, 2.0], [3.0, 5.0, -4.0], [-2.0, 5.0, 0.5], [6.0, 5.0, 1.0]])
    ds = _dataset(obs, obs[::-1].copy(), np.zeros((4, 1)), n_episodes=1)
    norm = ObservationNormalizer.fit(ds)
    np.testing.assert_allclose(norm.mean, obs.mean(axis=0), rtol=1e-7)
    ref_std = np.sqrt(np.mean((obs - obs.mean(axis=0)) ** 2, axis=0))  # population std
    ref_std[1] = STD_FLOOR  # the constant feature
    np.testing.assert_allclose(norm.std, ref_std, rtol=1e-7)
    assert norm.mean.dtype == norm.std.dtype == np.float32 and norm.enabled
    np.testing.assert_allclose(norm.apply(obs), (obs - obs.mean(0)) / ref_std, rtol=1e-6)
    # normalized_dataset standardises observations and next_observations with those statistics.
    data, scale, fitted = normalized_dataset(ds, normalize_observations=True)
    assert scale == 2.0
    np.testing.assert_array_equal(fitted.mean, norm.mean)
    np.testing.assert_array_equal(fitted.std, norm.std)
    np.testing.assert_allclose(data.next_observations, (obs[::-1] - obs.mean(0)) / ref_std,
                               rtol=1e-6)
    # Off: the identity; the prepared observations are the raw ones, bit for bit.
    identity = ObservationNormalizer()
    assert not identity.enabled and identity.apply(obs) is obs and identity.apply_states(ds) is ds
    off, _, norm_off = normalized_dataset(ds)
    assert not norm_off.enabled
    np.testing.assert_array_equal(off.observations, ds.observations)
    np.testing.assert_array_equal(atac.prepare_dataset(ds, False).next_observations,
                                  ds.next_observations)
    rd = mahalo.prepare_reward_data(scenarios.reward_data(ds), remove_terminals=False,
                                    max_reward_label=False)
    np.testing.assert_array_equal(rd.observations, ds.observations)


def test_defaults_are_off_and_a_default_run_equals_the_explicitly_off_one():
    for cfg in (atac.ATACConfig(), bc.BCConfig(), InverseDynamicsConfig(), iql.IQLConfig(),
                cql.CQLConfig(), registry.Budget()):
        assert cfg.normalize_observations is False, type(cfg).__name__
    ds, _ = _affine_pair()
    base = bc.BCConfig(hidden_sizes=HIDDEN, batch_size=32, num_steps=3)
    outs = []
    for cfg in (base, dataclasses.replace(base, normalize_observations=False)):
        tr = bc.make_train(ds, cfg)
        state, metrics = jax.jit(tr.train, compiler_options=FAST)(jax.random.key(0))
        outs.append(jax.tree.leaves((state.params, metrics, tr.act(actor_params(state),
                                                                   ds.observations[:5]))))
    for a, b in zip(*outs, strict=True):
        np.testing.assert_array_equal(a, b)


def test_bc_with_standardisation_is_invariant_to_per_feature_affine_rescaling():
    ds, moved = _affine_pair()
    cfg = bc.BCConfig(hidden_sizes=HIDDEN, batch_size=32, num_steps=50, learning_rate=3e-3,
                      normalize_observations=True)
    probe = np.random.default_rng(1).normal(size=(20, 3))
    acts = []
    for data, x in ((ds, probe), (moved, probe * SCALES + SHIFTS)):
        tr = bc.make_train(data, cfg)
        state, metrics = jax.jit(tr.train, compiler_options=FAST)(jax.random.key(3))
        assert np.isfinite(metrics["bc_loss"]).all()
        acts.append(np.asarray(tr.act(actor_params(state), jnp.asarray(x, jnp.float32))))
        # act takes raw observations and standardises them itself.
        norm = ObservationNormalizer.fit(data)
        policy = TanhGaussianPolicy(2, HIDDEN)
        manual = 2.0 * policy.apply(actor_params(state), norm.apply(x.astype(np.float32))).mode()
        np.testing.assert_allclose(acts[-1], manual, rtol=1e-5, atol=1e-6)
    assert np.abs(acts[0]).max() > 0.1  # the policy is not trivially zero
    np.testing.assert_allclose(acts[1], acts[0], atol=2e-4)


def test_mahalo_and_bco_train_with_dynamics_statistics():
    ds, _ = _affine_pair(n=120)
    expert = _affine_pair(n=40, seed=5)[1]  # other states (A·o + b): statistics must differ
    expert = expert.replace(episode_ids=expert.episode_ids + 10)
    rd = scenarios.reward_data(expert)
    norm = ObservationNormalizer.fit(ds)
    # The reward network's data are standardised with the dynamics statistics, not its own.
    g = mahalo.make_reward_net(rd, mahalo.RewardNetConfig(hidden_sizes=HIDDEN, batch_size=8),
                               observation_size=3, remove_terminals=False, learner="t",
                               normalizer=norm)
    params = g.init(jax.random.key(0))
    net = mahalo.StateNet(1, hidden_sizes=HIDDEN)
    batch = odata.sample(jax.device_put(rd), jax.random.key(1), 8)
    x = np.concatenate([norm.apply(np.asarray(batch.observations)),
                        norm.apply(np.asarray(batch.next_observations)),
                        np.asarray(batch.terminals, np.float32)[:, None]], axis=1)
    ref = np.mean((np.asarray(net.apply(params, x)) - np.asarray(batch.rewards)) ** 2)
    np.testing.assert_allclose(g.mse(params, jax.random.key(1)), ref, rtol=1e-5)

    steps = 4
    atac_cfg = atac.ATACConfig(hidden_sizes=HIDDEN, batch_size=16, warmstart_steps=2,
                               num_steps=steps, normalize_observations=True)
    hidden_rewards = ds.replace(metadata=ds.metadata.updated(rewards_visible=False))
    m = mahalo.make_train(hidden_rewards, mahalo.MAHALOConfig(
        atac=atac_cfg, reward=mahalo.RewardNetConfig(hidden_sizes=HIDDEN, batch_size=16)),
        reward_data=rd)
    state, metrics = jax.jit(m.train, compiler_options=FAST)(jax.random.key(0))
    for name in ("critic_loss", "actor_loss", "reward_loss"):
        assert metrics[name].shape == (steps,) and np.isfinite(metrics[name]).all(), name
    assert m.act(actor_params(state), expert.observations[:7]).shape == (7, 2)

    bco = bc.make_train(ds, bc.BCOConfig(
        bc=bc.BCConfig(hidden_sizes=HIDDEN, batch_size=16, num_steps=steps,
                       normalize_observations=True),
        inverse=InverseDynamicsConfig(hidden_sizes=HIDDEN, batch_size=16, num_steps=steps,
                                      normalize_observations=True)), reward_data=rd)
    state, metrics = jax.jit(bco.train, compiler_options=FAST)(jax.random.key(0))
    assert state.labels.shape == (rd.size, 2) and np.isfinite(state.labels).all()
    assert metrics["bc_loss"].shape == (steps,) and np.isfinite(metrics["bc_loss"]).all()
    assert np.isfinite(bco.act(actor_params(state), expert.observations)).all()


def test_experiment_uses_dynamics_statistics_and_supports_traced_rewards():
    mixed, _ = _affine_pair(n=60)
    expert = _affine_pair(n=20, seed=7)[1]
    expert = odata.create(expert.observations, expert.actions, np.ones(20, np.float32),
                          expert.next_observations, expert.terminals, expert.timeouts,
                          expert.episode_ids + 100, META)
    budget = registry.Budget(steps=10, hidden=HIDDEN, batch=8, normalize_observations=True)
    dyn, rd = scenarios.make("IL", mixed, expert, key=jax.random.PRNGKey(0))
    tr = experiment.build("ATAC", dyn, rd, budget, "IL")  # trains on the shared episodes only
    params = actor_params(jax.jit(tr.init)(jax.random.key(0)))
    norm = ObservationNormalizer.fit(dyn)  # D_A's, not the shared episodes'
    obs = np.asarray(mixed.observations[:5])
    ref = policy_act(TanhGaussianPolicy(2, HIDDEN), action_scale(dyn), norm)(params, obs)
    np.testing.assert_allclose(tr.act(params, obs), ref, rtol=1e-6)
    # The chapter-8 sweep builds IQL inside a traced function of the rewards.
    base = mixed.replace(metadata=mixed.metadata.updated(rewards_visible=True))
    batched = sweep.reward_batched("IQL", base, budget)
    rows = np.stack([np.zeros(base.size, np.float32), np.ones(base.size, np.float32)])
    out = jax.eval_shape(jax.vmap(batched.init), sweep.reward_seed_keys(rows, [0]))
    assert out.rewards.shape == (2, base.size)


def test_bad_input_names_the_argument():
    with pytest.raises(ValueError, match="normalize_observations"):
        registry.Budget(steps=10, normalize_observations=1)
    for cls in (atac.ATACConfig, bc.BCConfig, InverseDynamicsConfig, iql.IQLConfig,
                cql.CQLConfig):
        with pytest.raises(ValueError, match="normalize_observations"):
            cls(normalize_observations="yes")
    ds, _ = _affine_pair(n=8)
    norm = ObservationNormalizer.fit(ds)
    with pytest.raises(ValueError, match="normalize_observations is False"):
        normalized_dataset(ds, normalizer=norm)
    with pytest.raises(ValueError, match="normalizer"):
        normalized_dataset(ds, normalize_observations=True,
                           normalizer=ObservationNormalizer(norm.mean[:2], norm.std[:2]))
    with pytest.raises(ValueError, match="concrete"):
        jax.jit(lambda o: ObservationNormalizer.fit(ds.replace(observations=o)).mean)(
            ds.observations)
