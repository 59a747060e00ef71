"""Tabular survival-instinct experiment (offline/survival/gridworld.py and tabular.py, thesis §8.3.1
Fig. 8.2): PEVI's pessimism (lower bound on its own policy's true value), PEVI vs BC with wrong
rewards, exact evaluation vs brute-force enumeration in float64, the length bias of the data, bad
inputs."""

import itertools

import jax
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from offline.survival import gridworld as gw
from offline.survival import tabular as tb

WORLD = gw.GridWorld()
SMALL = gw.GridWorld(layout=("S.L", ".#K", "..."), horizon=4)


@pytest.fixture(scope="module")
def data():
    return tb.collect(WORLD, tb.DataConfig(), seed=0)


def _pevi_reference(data, penalty, r_min=-1.0, r_max=1.0):
    """Float64 loop implementation of the PEVI recursion (module docstring)."""
    horizon, num_s, num_a = data.counts.shape
    v = np.zeros((horizon + 1, num_s))
    for h in reversed(range(horizon)):
        left = horizon - h
        for s in range(num_s):
            q = np.empty(num_a)
            for a in range(num_a):
                n = data.counts[h, s, a]
                if n == 0:
                    q[a] = left * r_min
                    continue
                p = data.transition_counts[h, s, a] / n
                q_bar = data.reward_sums[h, s, a] / n + p @ v[h + 1] - penalty / np.sqrt(n)
                q[a] = min(max(q_bar, left * r_min), left * r_max)
            v[h, s] = q.max()
    return v


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 10_000), penalty=st.floats(0.0, 3.0),
       kind=st.sampled_from(tb.REWARDS))
def test_pevi_value_lower_bounds_true_value_of_its_policy(seed, penalty, kind):
    data = tb.collect(WORLD, tb.DataConfig(num_trajectories=60), seed)
    table = tb.reward_table(WORLD, kind, seed)
    out = tb.pevi(tb.relabel(data, table, kind), tb.PEVIConfig(penalty=penalty))
    v_true, _ = WORLD.true_values(np.asarray(out.policy), table)
    v_star = WORLD.optimal_values(table)[0]
    np.testing.assert_array_less(np.asarray(out.values) - 1e-4, np.asarray(v_true))
    np.testing.assert_array_less(np.asarray(v_true) - 1e-4, np.asarray(v_star))


def test_pevi_matches_float64_reference(data):
    for kind in tb.REWARDS:
        relabelled = tb.relabel(data, tb.reward_table(WORLD, kind, 0), kind)
        out = tb.pevi(relabelled, tb.PEVIConfig(penalty=0.7))
        np.testing.assert_allclose(out.values, _pevi_reference(relabelled, 0.7), atol=1e-4)
        q = np.asarray(out.q)
        chosen = np.take_along_axis(q, np.asarray(out.policy)[..., None], -1)[..., 0]
        np.testing.assert_array_equal(chosen, q.max(-1))


def test_unseen_actions_get_the_lowest_return(data):
    out = tb.pevi(data, tb.PEVIConfig())
    unseen = data.counts == 0
    lowest = -np.arange(WORLD.horizon, 0, -1.0)[:, None, None] * np.ones_like(unseen)
    np.testing.assert_allclose(np.asarray(out.q)[unseen], lowest[unseen])
    # Lava is never acted in: its value is the lowest return of the remaining steps.
    lava = np.flatnonzero(WORLD.terminal)
    np.testing.assert_allclose(np.asarray(out.values)[:-1, lava],
                               -np.arange(WORLD.horizon, 0, -1.0)[:, None] * np.ones(len(lava)))


@pytest.mark.parametrize("seed", range(4))
def test_pevi_reaches_key_with_every_reward_while_bc_touches_lava(seed):
    data = tb.collect(WORLD, tb.DataConfig(), seed)
    bc = gw.rollout(WORLD, tb.behaviour_cloning(data))
    assert bc.touched_lava and not bc.reached_key and bc.return_ == -1.0
    optimal = float(WORLD.optimal_values()[0][0, WORLD.start])
    for kind in tb.REWARDS:
        out = tb.pevi(tb.relabel(data, tb.reward_table(WORLD, kind, seed), kind),
                      tb.PEVIConfig())
        roll = gw.rollout(WORLD, np.asarray(out.policy))
        assert roll.reached_key and not roll.touched_lava, kind
        assert roll.return_ == optimal == 1.0


def _enumerate_values(world, probs, reward):
    """V_0(s) for every s by enumerating all action sequences (float64)."""
    num_a = len(gw.ACTIONS)
    values = np.zeros(world.num_states)
    for s0 in range(world.num_states):
        for seq in itertools.product(range(num_a), repeat=world.horizon):
            s, weight, ret = s0, 1.0, 0.0
            for h, a in enumerate(seq):
                weight *= probs[h, s, a]  # after lava the suffix weights still sum to 1
                if not world.terminal[s]:
                    ret += reward[s, a]
                    s = world.next_state[s, a]
            values[s0] += weight * ret
    return values


def test_exact_evaluation_matches_enumeration():
    rng = np.random.default_rng(0)
    probs = rng.dirichlet(np.ones(4), size=(SMALL.horizon, SMALL.num_states))
    reward = rng.uniform(-1, 1, (SMALL.num_states, 4))
    with jax.enable_x64(True):
        v, _ = SMALL.true_values(probs, reward)
        v_star = SMALL.optimal_values(reward)[0]
    v, v_star = np.asarray(v), np.asarray(v_star)
    np.testing.assert_allclose(v[0], _enumerate_values(SMALL, probs, reward), rtol=1e-10)
    best = np.full(SMALL.num_states, -np.inf)
    for seq in itertools.product(range(4), repeat=SMALL.horizon):
        open_loop = np.zeros((SMALL.horizon, SMALL.num_states, 4))
        open_loop[np.arange(SMALL.horizon), :, seq] = 1.0
        best = np.maximum(best, _enumerate_values(SMALL, open_loop, reward))
    # Deterministic dynamics: the best action sequence per start state is optimal.
    np.testing.assert_allclose(v_star[0], best, rtol=1e-10)
    assert np.all(SMALL.terminal <= (v[0] == 0))


def test_rollout_return_equals_exact_value_and_true_reward_layout():
    pi = WORLD.optimal_values()[2]
    roll = gw.rollout(WORLD, np.asarray(pi))
    assert roll.reached_key and not roll.touched_lava
    value = float(WORLD.true_values(np.asarray(pi))[0][0, WORLD.start])
    assert roll.return_ == pytest.approx(value)
    assert WORLD.reward.max() == 1.0 and WORLD.reward.min() == -1.0
    assert np.all(WORLD.next_state[WORLD.key] == WORLD.key)


def test_data_has_length_bias_and_lava_episodes_are_cut(data):
    by = {o: [t for t in data.trajectories if t.outcome == o] for o in tb.OUTCOMES}
    assert all(len(v) > 10 for v in by.values())
    config = tb.DataConfig()
    for t in by["lava"]:
        assert WORLD.terminal[t.states[-1]] and not WORLD.terminal[t.states[:-1]].any()
        assert len(t.actions) <= config.episode_length and t.rewards[-1] == -1.0
    assert all(len(t.actions) == config.episode_length and WORLD.key not in t.states
               for t in by["timeout"])
    assert all(len(t.actions) == WORLD.horizon and t.states[-1] == WORLD.key for t in by["key"])
    mean = {o: np.mean([len(t.actions) for t in v]) for o, v in by.items()}
    assert mean["key"] > max(mean["lava"], mean["timeout"])
    # Only the absorbing key is seen beyond the episode length.
    late = data.counts[config.episode_length:].sum(axis=(0, 2))
    assert late.sum() > 0 and np.flatnonzero(late).tolist() == [WORLD.key]
    assert data.counts.sum() == sum(len(t.actions) for t in data.trajectories)
    np.testing.assert_array_equal(data.transition_counts.sum(-1), data.counts)
    assert data.state_visits.sum() == sum(len(t.states) for t in data.trajectories)


def test_relabelling(data):
    seen = data.counts > 0
    for kind in tb.REWARDS:
        table = tb.reward_table(WORLD, kind, 3)
        r_hat = tb.relabel(data, table, kind).reward_sums[seen] / data.counts[seen]
        np.testing.assert_allclose(r_hat, np.broadcast_to(table, data.counts.shape)[seen])
    random = tb.reward_table(WORLD, "random", 3)
    assert random.min() >= 0 and random.max() <= 1
    np.testing.assert_array_equal(random, tb.reward_table(WORLD, "random", 3))
    np.testing.assert_array_equal(tb.reward_table(WORLD, "negated"), -WORLD.reward)
    np.testing.assert_allclose(data.reward_sums, data.counts * WORLD.reward)


@pytest.mark.parametrize(("make", "match"), [
    (lambda: tb.PEVIConfig(penalty=-0.1), "penalty"),
    (lambda: tb.PEVIConfig(reward_range=(1.0, -1.0)), "reward_range"),
    (lambda: gw.GridWorld(horizon=0), "horizon"),
    (lambda: gw.GridWorld(layout=("S..", "...")), "key"),
    (lambda: gw.GridWorld(layout=("S.K", "..")), "same length"),
    (lambda: gw.GridWorld(layout=("S.K", ".x.")), "layout"),
    (lambda: tb.DataConfig(noise=1.5), "noise"),
    (lambda: tb.DataConfig(num_trajectories=0), "num_trajectories"),
    (lambda: tb.collect(WORLD, tb.DataConfig(episode_length=WORLD.horizon), 0), "episode_length"),
    (lambda: tb.reward_table(WORLD, "ones"), "kind"),
    (lambda: gw.rollout(WORLD, np.zeros(3, np.int32)), "policy"),
    (lambda: WORLD.true_values(np.zeros((2, 4))), "policy"),
])
def test_bad_inputs_raise(make, match):
    with pytest.raises(ValueError, match=match):
        make()
