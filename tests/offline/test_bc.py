"""BC, BCO and the inverse-dynamics model (offline/learners/bc.py,
offline/learners/inverse_dynamics.py) on tiny synthetic datasets whose answers are known in closed
form."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from offline.data import dataset as odata
from offline.data import scenarios
from offline.learners import bc
from offline.learners.base import actor_params
from offline.learners.inverse_dynamics import (
    InverseDynamicsConfig,
    label_actions,
    make_inverse_dynamics,
)

LIMIT = 2.0  # action_limit recorded in the metadata: learners must divide and multiply by it
DT = 0.1
OBS, ACT, EPISODES, LENGTH = 2, 2, 16, 32
W_TRUE = np.array([[-0.8, 0.5], [-0.3, -0.9]])  # a contraction: expert states stay bounded
SMALL = dict(hidden_sizes=(32, 32), learning_rate=3e-3, batch_size=128)


def expert_action(s):
    """The deterministic mapping to clone (environment units, inside the box)."""
    return LIMIT * 0.8 * np.tanh(s @ W_TRUE)


def _episodes(rng, policy):
    """Episodes of the linear system s' = s + a·dt from uniform starts."""
    obs, act, nxt, ids = [], [], [], []
    for e in range(EPISODES):
        s = rng.uniform(-1.0, 1.0, OBS)
        for _ in range(LENGTH):
            a = policy(s)
            obs.append(s)
            act.append(a)
            s = s + a * DT
            nxt.append(s)
            ids.append(e)
    n = len(ids)
    timeouts = np.zeros(n, bool)
    timeouts[LENGTH - 1::LENGTH] = True
    return odata.create(np.float32(obs), np.float32(act), np.zeros(n, np.float32),
                        np.float32(nxt), np.zeros(n, bool), timeouts, np.int32(ids),
                        {"action_limit": LIMIT})


@pytest.fixture(scope="module")
def expert_data():
    return _episodes(np.random.default_rng(0), expert_action)


@pytest.fixture(scope="module")
def random_data():
    rng = np.random.default_rng(1)
    return _episodes(rng, lambda s: rng.uniform(-LIMIT, LIMIT, ACT))


@pytest.fixture(scope="module")
def test_states(expert_data):
    """Expert states (BC's guarantee is on the data distribution)."""
    idx = np.random.default_rng(2).choice(expert_data.size, 256, replace=False)
    return np.asarray(expert_data.observations)[idx]


@pytest.fixture(scope="module")
def bc_trainer(expert_data):
    return bc.make_train(expert_data, bc.BCConfig(num_steps=600, **SMALL))


def test_bc_recovers_the_mapping_and_a_random_actor_does_not(bc_trainer, test_states):
    train = jax.jit(bc_trainer.train)
    state, metrics = train(jax.random.PRNGKey(0))
    assert metrics["bc_loss"].shape == (600,)
    assert float(metrics["bc_loss"][-50:].mean()) < float(metrics["bc_loss"][:50].mean()) - 2
    truth = expert_action(test_states.astype(np.float64))
    err = np.abs(np.asarray(bc_trainer.act(actor_params(state), test_states)) - truth)
    assert err.max() < 0.1 * LIMIT, err.max()
    untrained = jax.jit(bc_trainer.init)(jax.random.PRNGKey(0))
    err0 = np.abs(np.asarray(bc_trainer.act(actor_params(untrained), test_states)) - truth)
    assert err0.max() > 0.1 * LIMIT and err0.mean() > 5 * err.mean()
    # act accepts a single observation and returns environment units
    one = bc_trainer.act(actor_params(state), test_states[0])
    assert one.shape == (ACT,) and np.abs(np.asarray(one) - truth[0]).max() < 0.1 * LIMIT


def test_run_split_equals_one_call_and_vmap_equals_separate_runs(bc_trainer):
    run = jax.jit(bc_trainer.run, static_argnums=1)
    init = jax.jit(bc_trainer.init)
    s0 = init(jax.random.PRNGKey(3))
    whole, m_whole = run(s0, 20)
    part, m1 = run(s0, 10)
    part, m2 = run(part, 10)
    jax.tree.map(np.testing.assert_array_equal, whole, part)
    np.testing.assert_array_equal(m_whole["bc_loss"],
                                  np.concatenate([m1["bc_loss"], m2["bc_loss"]]))

    keys = jax.random.split(jax.random.PRNGKey(4), 2)
    both, _ = jax.jit(jax.vmap(lambda k: bc_trainer.run(bc_trainer.init(k), 20)))(keys)
    for i in range(2):
        single, _ = run(init(keys[i]), 20)
        jax.tree.map(lambda a, b, i=i: np.testing.assert_allclose(a[i], b, rtol=1e-5,
                                                                  atol=1e-6),
                     both.params, single.params)


def test_bc_configs_and_data_selection(expert_data, random_data):
    with pytest.raises(ValueError, match="hidden_sizes"):
        bc.BCConfig(hidden_sizes=(16, 0))
    with pytest.raises(ValueError, match="learning_rate"):
        bc.BCConfig(learning_rate=-1.0)
    with pytest.raises(ValueError, match="data"):
        bc.BCConfig(data="expert")
    with pytest.raises(ValueError, match=r"bc\.data"):
        bc.BCOConfig(bc=bc.BCConfig(data="reward_episodes"))
    with pytest.raises(ValueError, match="config"):
        bc.make_train(expert_data, InverseDynamicsConfig())
    mixed = odata.concatenate(random_data, expert_data, metadata={"action_limit": LIMIT})
    _, rd = scenarios.make("IL", random_data, expert_data, max_reward=1.0)
    with pytest.raises(ValueError, match="uses no reward data"):
        bc.make_train(mixed, bc.BCConfig(**SMALL), reward_data=rd)
    with pytest.raises(ValueError, match="needs reward_data"):
        bc.make_train(mixed, bc.BCConfig(data="reward_episodes", **SMALL))
    with pytest.raises(ValueError, match="needs reward_data"):
        bc.make_train(mixed, bc.BCOConfig())
    # ILfO's reward data does not overlap the dynamics data
    dyn, rd_ilfo = scenarios.make("ILfO", random_data, expert_data, max_reward=1.0)
    with pytest.raises(ValueError, match="no dynamics episode id"):
        bc.make_train(dyn, bc.BCConfig(data="reward_episodes"), reward_data=rd_ilfo)


@pytest.fixture(scope="module")
def bco_setup(random_data, expert_data):
    dynamics, rd = scenarios.make("ILfO", random_data, expert_data, max_reward=1.0)
    dynamics = dynamics.replace(metadata=dynamics.metadata.updated(action_limit=LIMIT))
    inverse = InverseDynamicsConfig(num_steps=500, **SMALL)
    config = bc.BCOConfig(bc=bc.BCConfig(num_steps=500, **SMALL), inverse=inverse)
    return dynamics, rd, config


def test_inverse_dynamics_labels_the_linear_system(bco_setup, expert_data):
    dynamics, rd, config = bco_setup
    inv = make_inverse_dynamics(dynamics, config.inverse)
    state, metrics = jax.jit(inv.train)(jax.random.PRNGKey(0))
    assert float(metrics["loss"][-50:].mean()) < 0.01
    labelled = label_actions(inv.model(state), rd)
    assert isinstance(labelled, odata.Dataset)
    assert labelled.metadata["action_labels"] == "inverse_dynamics"
    odata.validate(jax.device_get(labelled))
    # a = (s' - s)/dt exactly
    truth = (np.asarray(rd.next_observations, np.float64)
             - np.asarray(rd.observations, np.float64)) / DT
    np.testing.assert_allclose(truth, np.asarray(expert_data.actions), atol=1e-4)
    err = np.abs(np.asarray(labelled.actions) - truth)
    assert np.quantile(err, 0.95) < 0.1 * LIMIT, np.quantile(err, 0.95)
    # vmappable over models (seeds): a stack of the trained model and a perturbed copy
    model = inv.model(state)
    other = jax.tree.map(lambda p: 1.1 * p, model)
    models = jax.tree.map(lambda a, b: jnp.stack([a, b]), model, other)
    batch = jax.vmap(label_actions, in_axes=(0, None))(models, rd)
    assert batch.actions.shape == (2, rd.size, ACT)
    np.testing.assert_allclose(batch.actions[0], labelled.actions, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(batch.actions[1], label_actions(other, rd).actions, rtol=1e-5,
                               atol=1e-6)


def test_bco_recovers_the_expert_from_observations_only(bco_setup, test_states):
    dynamics, rd, config = bco_setup
    trainer = bc.make_train(dynamics, config, reward_data=rd)
    state, _ = jax.jit(trainer.train)(jax.random.PRNGKey(0))
    assert set(state.params) == {"actor", "inverse"}
    truth = expert_action(test_states.astype(np.float64))
    err = np.abs(np.asarray(trainer.act(actor_params(state), test_states)) - truth)
    assert err.mean() < 0.05 * LIMIT and err.max() < 0.25 * LIMIT, (err.mean(), err.max())
