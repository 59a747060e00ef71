"""Chapter-8 data (offline/survival/rewards.py) and datasets without length bias
(``offline.data.collect`` with ``cut_at_collision=False``).

The collected data: 8 episodes of the noisy expert (σ = 3) on 3-link env3 with a 150-step
horizon, seed 2 — one episode collides (at step 94), the others time out. Each cut mode
compiles one program (batch 8), shared by :func:`collect`, :func:`rollout` and the recipe.
"""

from __future__ import annotations

import math

import jax
import numpy as np
import pytest

import mjxrmp  # noqa: F401  (XLA flags first)
from offline.data import behaviours, rollouts
from offline.data import collect as oc
from offline.data import dataset as odata
from offline.survival import rewards as sv

ENV, HORIZON, BATCH, SEED = "three_link/env3", 150, 8, 2
BEHAVIOUR = behaviours.noisy_expert(3.0)


def _handmade() -> odata.Dataset:
    """Episodes of lengths 1, 3, 2 (ids 0, 5, 7): a terminal, a timeout, a terminal."""
    rewards = np.array([0.5, 1.0, -2.0, 0.25, 3.0, -1.0], np.float32)
    term = np.array([1, 0, 0, 0, 0, 1], bool)
    tout = np.array([0, 0, 0, 1, 0, 0], bool)
    ids = np.array([0, 5, 5, 5, 7, 7])
    obs = np.arange(12, dtype=np.float32).reshape(6, 2)
    return odata.create(obs, obs[:, :1] * 0.5, rewards, obs + 1.0, term, tout, ids,
                        metadata={"recipe": "handmade"})


@pytest.fixture(scope="module")
def collected():
    key = jax.random.PRNGKey(SEED)
    out = {}
    for cut in (True, False):
        ds = oc.collect(ENV, BEHAVIOUR, BATCH, key=key, seed=SEED, horizon=HORIZON,
                        batch_size=BATCH, cut_at_collision=cut)
        traj = rollouts.rollout(ENV, BEHAVIOUR, BATCH, key, horizon=HORIZON, batch_size=BATCH,
                          cut_at_collision=cut)
        out[cut] = (ds, traj)
    return out


def test_variants_rewards_flags_and_metadata():
    ds = _handmade()
    key = jax.random.PRNGKey(3)
    got = dict(sv.variants(ds, key))
    assert list(got) == [f"{r}-{t}" for r in sv.REWARD_VARIANTS for t in sv.TERMINAL_MODES]
    r64 = np.asarray(ds.rewards, np.float64)
    expected_random = np.asarray(jax.random.uniform(key, (ds.size,)), np.float64)
    expected = {"original": r64, "zero": np.zeros(6), "negated": -r64, "random": expected_random}
    term, tout = np.asarray(ds.terminals), np.asarray(ds.timeouts)
    for name, v in got.items():
        reward, terminals = name.split("-")
        odata.validate(v)
        np.testing.assert_array_equal(np.asarray(v.rewards, np.float64), expected[reward])
        assert v.rewards.dtype == ds.rewards.dtype
        if terminals == "keep":
            np.testing.assert_array_equal(v.terminals, term)
            np.testing.assert_array_equal(v.timeouts, tout)
        else:
            assert not np.asarray(v.terminals).any()
            np.testing.assert_array_equal(v.timeouts, term | tout)
            assert v.metadata["terminals_as_timeouts"] is True
        assert v.metadata["survival_variant"] == {"name": name, "reward": reward,
                                                  "terminals": terminals}
        assert v.metadata.get("reward_relabel", []) == ([] if reward == "original" else [reward])
        assert v.metadata["recipe"] == "handmade"
        for f in ("observations", "actions", "next_observations", "episode_ids"):
            np.testing.assert_array_equal(getattr(v, f), getattr(ds, f))
    assert ((expected_random >= 0) & (expected_random < 1)).all()
    # Both terminal modes of "random" share the rewards.
    np.testing.assert_array_equal(got["random-keep"].rewards, got["random-remove"].rewards)


def test_variant_errors_and_grid():
    ds = _handmade()
    with pytest.raises(ValueError, match="reward must be one of"):
        sv.variant(ds, "inverted", "keep")
    with pytest.raises(ValueError, match="terminals must be one of"):
        sv.variant(ds, "zero", "drop")
    with pytest.raises(ValueError, match="PRNG key"):
        sv.variant(ds, "random", "keep")
    key = jax.random.PRNGKey(0)
    grid = list(sv.variant_grid({"a": ds, "b": ds}, key))
    assert [(r, n) for r, n, _ in grid] == [(r, f"{w}-{t}") for r in "ab"
                                            for w in sv.REWARD_VARIANTS for t in sv.TERMINAL_MODES]
    rand = {r: np.asarray(d.rewards) for r, n, d in grid if n == "random-keep"}
    assert not np.array_equal(rand["a"], rand["b"])  # independent keys per recipe
    alone = dict((n, d) for _, n, d in sv.variant_grid({"b": ds}, key))
    np.testing.assert_array_equal(alone["random-keep"].rewards, rand["b"])


def test_goal_oriented_form_shifts_the_true_reward_and_makes_its_negation_non_negative():
    """Thesis §7.4.2 / §8.4.1: the goal-oriented true reward is ``r − r_max ≤ 0`` and its
    negation ``r_max − r ≥ 0``; zero and random rewards are the same under either form."""
    ds = _handmade()
    ds = ds.replace(metadata=ds.metadata.updated(reward_range=[-5.0, 3.0]))
    goal = sv.goal_oriented(ds)
    expected = np.array([-2.5, -2.0, -5.0, -2.75, 0.0, -4.0], np.float32)
    np.testing.assert_array_equal(goal.rewards, expected)
    assert goal.rewards.dtype == ds.rewards.dtype
    assert goal.metadata["reward_form"] == {"form": "goal", "reward_max": 3.0}
    np.testing.assert_array_equal(sv.variant(goal, "negated", "keep").rewards, -expected)
    assert (np.asarray(sv.variant(goal, "negated", "keep").rewards) >= 0).all()
    key = jax.random.PRNGKey(1)
    for reward in ("zero", "random"):
        np.testing.assert_array_equal(sv.variant(goal, reward, "keep", key).rewards,
                                      sv.variant(ds, reward, "keep", key).rewards)
    for f in ("observations", "actions", "terminals", "timeouts", "episode_ids"):
        np.testing.assert_array_equal(getattr(goal, f), getattr(ds, f))
    np.testing.assert_array_equal(sv.goal_oriented(_handmade(), reward_max=4.0).rewards,
                                  np.asarray(_handmade().rewards) - 4.0)
    with pytest.raises(ValueError, match="no reward_range"):
        sv.goal_oriented(_handmade())
    with pytest.raises(ValueError, match="above reward_max"):
        sv.goal_oriented(ds, reward_max=2.0)
    with pytest.raises(ValueError, match="finite"):
        sv.goal_oriented(ds, reward_max=float("nan"))
    with pytest.raises(ValueError, match="relabelled"):
        sv.goal_oriented(sv.variant(ds, "negated", "keep"))
    with pytest.raises(ValueError, match="already"):
        sv.goal_oriented(goal)


@pytest.mark.parametrize("scores, expected", [
    ({"zero": 50.0, "random": 80.0, "negated": 60.0}, 100.0 / 50.0),
    ({"zero": 0.0, "random": 0.0, "negated": 0.0, "original": 90.0}, 1.0),
    ({"zero": -20.0, "random": 100.0, "negated": 95.0}, 100.0 / 120.0),
    ({"zero": 100.0, "random": 100.0, "negated": 100.0}, math.inf),
    ({"zero": 120.0, "random": 101.0, "negated": 150.0}, math.inf),
    ({"zero": 99.0, "random": 100.0, "negated": 99.5}, 100.0),
])
def test_positive_data_bias_hand_computed(scores, expected):
    got = sv.positive_data_bias(scores)
    assert got == pytest.approx(expected, rel=1e-12) if math.isfinite(expected) else got == expected


def test_positive_data_bias_errors_and_optimal():
    assert sv.positive_data_bias({"zero": 1.0, "random": 2.0, "negated": 3.0},
                                 optimal=4.0) == pytest.approx(4.0 / 3.0)
    with pytest.raises(ValueError, match=r"lacks the wrong-reward score\(s\) \['negated'\]"):
        sv.positive_data_bias({"zero": 1.0, "random": 2.0, "negative": 3.0})
    with pytest.raises(ValueError, match="finite"):
        sv.positive_data_bias({"zero": float("nan"), "random": 2.0, "negated": 3.0})
    with pytest.raises(ValueError, match="optimal"):
        sv.positive_data_bias({"zero": 1.0, "random": 2.0, "negated": 3.0}, optimal=0.0)
    with pytest.raises(ValueError, match="mapping"):
        sv.positive_data_bias([1.0, 2.0, 3.0])


def test_length_bias_statistics_hand_computed():
    ds = _handmade()
    s = sv.length_bias_statistics(ds)
    lengths, returns = np.array([1.0, 3.0, 2.0]), np.array([0.5, -0.75, 2.0])
    assert s["episode_ids"] == [0, 5, 7] and s["lengths"] == [1, 3, 2]
    np.testing.assert_allclose(s["returns"], returns, rtol=1e-6)
    dl, dr = lengths - lengths.mean(), returns - returns.mean()
    corr = (dl @ dr) / math.sqrt((dl @ dl) * (dr @ dr))
    assert s["length_return_correlation"] == pytest.approx(corr, rel=1e-6)
    assert s["cut_fraction"] == pytest.approx(2.0 / 3.0)
    # Quantile 0.75 of (−0.75, 0.5, 2.0) = 0.5 + 0.5·(2.0 − 0.5) = 1.25: only episode 7 wins.
    assert s["success_source"] == "top_return_quantile"
    assert s["success_threshold"] == pytest.approx(1.25, rel=1e-6)
    assert s["num_success"] == 1
    assert s["mean_length_success"] == 2.0 and s["mean_length_failure"] == 2.0
    given = sv.length_bias_statistics(ds, success=np.array([False, True, True]))
    assert given["success_source"] == "given" and given["success_threshold"] is None
    assert given["mean_length_success"] == 2.5 and given["mean_length_failure"] == 1.0
    none = sv.length_bias_statistics(ds, success=np.zeros(3, bool))
    assert math.isnan(none["mean_length_success"]) and none["mean_length_failure"] == 2.0
    with pytest.raises(ValueError, match="success must be a boolean array"):
        sv.length_bias_statistics(ds, success=np.array([1, 0, 1]))
    with pytest.raises(ValueError, match="relabelled"):
        sv.length_bias_statistics(sv.variant(ds, "zero", "keep"))
    with pytest.raises(ValueError, match="success_quantile"):
        sv.length_bias_statistics(ds, success_quantile=1.5)
    # Equal lengths: the correlation is undefined (no length bias to measure).
    equal = ds.replace(episode_ids=np.array([0, 0, 1, 1, 2, 2], np.int32),
                       terminals=np.array([0, 1, 0, 0, 0, 1], bool),
                       timeouts=np.array([0, 0, 0, 1, 0, 0], bool))
    assert math.isnan(sv.length_bias_statistics(equal)["length_return_correlation"])


def test_cut_dataset_has_variable_lengths_and_collision_terminals(collected):
    ds, traj = collected[True]
    ep = traj["episode"]
    assert "cut_at_collision" not in ds.metadata  # default datasets are unchanged
    per, _ = odata.episode_statistics(ds)
    assert 0 < (ep["collided"] > 0).sum() < BATCH, "the seed must give collisions and timeouts"
    np.testing.assert_array_equal(per.terminated, ep["collided"] > 0)
    assert per.lengths.min() < HORIZON == per.lengths.max()
    np.testing.assert_array_equal(per.lengths[~per.terminated], HORIZON)
    s = sv.length_bias_statistics(ds, success=ep["success"].astype(bool))
    assert s["cut_fraction"] == pytest.approx((ep["collided"] > 0).mean())


def test_uncut_dataset_has_full_horizon_episodes_and_no_terminals(collected):
    (cut, cut_traj), (ds, traj) = collected[True], collected[False]
    ep = traj["episode"]
    assert ds.metadata["cut_at_collision"] is False
    per, _ = odata.episode_statistics(ds)
    np.testing.assert_array_equal(per.lengths, HORIZON)
    assert not np.asarray(ds.terminals).any() and per.timed_out.all()
    assert ds.size == BATCH * HORIZON
    # Collisions are still recorded (per step and per episode), not as terminals.
    collided = ep["collided"] > 0
    np.testing.assert_array_equal(collided, cut_traj["episode"]["collided"] > 0)
    assert ((traj["collision"] > 0).any(axis=0) == collided).all()
    assert not (ep["safe"][collided]).any()
    s = sv.length_bias_statistics(ds)
    assert s["cut_fraction"] == 0.0 and math.isnan(s["length_return_correlation"])
    # Up to the collision the episodes are the cut ones, transition for transition (to float32
    # rounding: the two collections are different programs, and XLA may contract the RMP²
    # resolve's written-out arithmetic differently in each, docs/design.md §5.10).
    cut_per, _ = odata.episode_statistics(cut)
    starts = np.concatenate([[0], np.cumsum(cut_per.lengths)[:-1]])
    for i, (start, n) in enumerate(zip(starts, cut_per.lengths, strict=True)):
        rows = slice(i * HORIZON, i * HORIZON + n)
        for f in ("observations", "actions", "rewards", "next_observations"):
            np.testing.assert_allclose(np.asarray(getattr(ds, f))[rows],
                                       np.asarray(getattr(cut, f))[start:start + n],
                                       rtol=0, atol=1e-4)
    # The recipe passes the flag through (same compiled program: batch = scale = 8).
    rec = oc.collect_recipe(ENV, "random", BATCH, seed=SEED, horizon=HORIZON,
                            cut_at_collision=False)
    assert rec.metadata["cut_at_collision"] is False
    np.testing.assert_array_equal(odata.episode_statistics(rec)[0].lengths, HORIZON)
    with pytest.raises(ValueError, match="cut_at_collision must be a bool"):
        rollouts.rollout(ENV, BEHAVIOUR, 1, jax.random.PRNGKey(0), cut_at_collision=0)


def _goal_dataset(distances: list[list[float]], ends: list[str]) -> odata.Dataset:
    """Episodes whose next-observation goal distance follows ``distances`` (one list per
    episode, ids 10, 11, …), ending with a ``"terminal"`` or ``"timeout"``; the layout puts
    ``g − x`` at columns 1–2 (the distance along the first axis)."""
    rows, ids, term, tout = [], [], [], []
    for e, (ds_, end) in enumerate(zip(distances, ends, strict=True)):
        for t, d in enumerate(ds_):
            rows.append([float(t), d, 0.0])
            ids.append(10 + e)
            last = t == len(ds_) - 1
            term.append(last and end == "terminal")
            tout.append(last and end == "timeout")
    nxt = np.asarray(rows, np.float32)
    n = len(rows)
    return odata.create(nxt - 1.0, np.zeros((n, 1), np.float32), np.ones(n, np.float32), nxt,
                        np.asarray(term), np.asarray(tout), np.asarray(ids),
                        metadata={"observation_layout": {"goal_minus_x": [1, 3]}})


def test_cut_before_goal_hand_computed():
    # Deadline 3, radius 0.05: episode 10 arrives at its 3rd transition (kept whole), 11 never
    # arrives (cut to 3, last a terminal), 12 arrives only at its 5th (cut), 13 is shorter than
    # the deadline (kept, its collision terminal too).
    ds = _goal_dataset([[0.5, 0.2, 0.04, 0.3, 0.3], [0.5, 0.4, 0.3, 0.2, 0.1, 0.1],
                        [0.5, 0.4, 0.3, 0.2, 0.01], [0.5, 0.4]],
                       ["timeout", "timeout", "timeout", "terminal"])
    np.testing.assert_allclose(sv.goal_distances(ds)[:3], [0.5, 0.2, 0.04], rtol=1e-6)
    out = sv.cut_before_goal(ds, deadline=3)
    per, _ = odata.episode_statistics(out)
    assert per.episode_ids.tolist() == [10, 11, 12, 13]
    assert per.lengths.tolist() == [5, 3, 3, 2]
    assert per.terminated.tolist() == [False, True, True, True]
    assert per.timed_out.tolist() == [True, False, False, False]
    assert int(np.asarray(out.terminals).sum()) == 3 and int(np.asarray(out.timeouts).sum()) == 1
    assert out.metadata["goal_deadline"] == {"deadline": 3, "radius": 0.05, "cut_episodes": 2}
    # The kept transitions are the first three of each cut episode, unchanged.
    np.testing.assert_array_equal(np.asarray(out.next_observations)[5:8],
                                  np.asarray(ds.next_observations)[5:8])
    # With radius 0.35 episodes 11 and 12 arrive at their 3rd transition (0.3): nothing is cut.
    assert sv.cut_before_goal(ds, deadline=3, radius=0.35).metadata["goal_deadline"][
        "cut_episodes"] == 0
    for bad in (0, 2.5, True):
        with pytest.raises(ValueError, match="deadline must be an integer"):
            sv.cut_before_goal(ds, deadline=bad)
    with pytest.raises(ValueError, match="radius must be a positive"):
        sv.cut_before_goal(ds, deadline=3, radius=0.0)
    with pytest.raises(ValueError, match="observation_layout"):
        sv.cut_before_goal(ds.replace(metadata=odata.Metadata({})), deadline=3)


def test_absorbing_goal_hand_computed():
    # Episode 10 ends at the goal (0.04 < 0.05): its last transition becomes a terminal. 11 ends
    # away from it with a timeout, 13 with a collision terminal: both end with timeouts. 12
    # passes the goal (0.01) but leaves it (0.2): a timeout. Nothing else changes.
    ds = _goal_dataset([[0.5, 0.2, 0.04], [0.5, 0.4], [0.3, 0.01, 0.2], [0.5, 0.4]],
                       ["timeout", "timeout", "timeout", "terminal"])
    out = sv.absorbing_goal(ds)
    per, _ = odata.episode_statistics(out)
    assert per.lengths.tolist() == [3, 2, 3, 2]
    assert per.terminated.tolist() == [True, False, False, False]
    assert per.timed_out.tolist() == [False, True, True, True]
    assert np.asarray(out.terminals).tolist() == [False, False, True] + [False] * 7
    assert out.metadata["absorbing_goal"] == {"radius": 0.05, "episodes_at_goal": 1,
                                              "at_arrival": False}
    for field in ("observations", "actions", "rewards", "next_observations", "episode_ids"):
        np.testing.assert_array_equal(np.asarray(getattr(out, field)),
                                      np.asarray(getattr(ds, field)))
    # The -goal data of reproduce_ch8: after the deadline cut, the failures' terminals move to
    # the successes (same transitions, only the end flags differ).
    # Deadline 2 cuts episode 10 (not yet at the goal) with a terminal, which becomes a
    # timeout; deadline 3 cuts nothing and episode 10 keeps its goal terminal.
    cut = sv.cut_before_goal(ds, deadline=2)
    assert odata.episode_statistics(cut)[0].terminated.tolist() == [True, False, False, True]
    assert not odata.episode_statistics(sv.absorbing_goal(cut))[0].terminated.any()
    kept = sv.absorbing_goal(sv.cut_before_goal(ds, deadline=3))
    assert odata.episode_statistics(kept)[0].terminated.tolist() == [True, False, False, False]
    assert sv.absorbing_goal(ds, radius=0.3).metadata["absorbing_goal"]["episodes_at_goal"] == 2
    for bad in (0.0, -1.0, True):
        with pytest.raises(ValueError, match="radius must be a positive"):
            sv.absorbing_goal(ds, radius=bad)


def test_absorbing_goal_at_arrival_hand_computed():
    # at_arrival: an episode ends at its first transition into the goal region. Episode 10
    # arrives at its last transition (unchanged, terminal); 12 arrives at its 2nd (0.01) and
    # loses its 3rd (0.2), which left the goal; 11 and 13 never arrive and end in timeouts.
    ds = _goal_dataset([[0.5, 0.2, 0.04], [0.5, 0.4], [0.3, 0.01, 0.2], [0.5, 0.4]],
                       ["timeout", "timeout", "timeout", "terminal"])
    out = sv.absorbing_goal(ds, at_arrival=True)
    per, _ = odata.episode_statistics(out)
    assert per.lengths.tolist() == [3, 2, 2, 2]
    assert per.terminated.tolist() == [True, False, True, False]
    assert per.timed_out.tolist() == [False, True, False, True]
    np.testing.assert_allclose(sv.goal_distances(out), [0.5, 0.2, 0.04, 0.5, 0.4, 0.3, 0.01,
                                                        0.5, 0.4], atol=1e-6)
    assert out.metadata["absorbing_goal"] == {"radius": 0.05, "episodes_at_goal": 2,
                                              "at_arrival": True}
    keep = np.array([True] * 7 + [False] + [True] * 2)
    for field in ("observations", "actions", "rewards", "next_observations", "episode_ids"):
        np.testing.assert_array_equal(np.asarray(getattr(out, field)),
                                      np.asarray(getattr(ds, field))[keep])
    # An episode inside the goal region from its first transition ends right there.
    first = _goal_dataset([[0.01, 0.02, 0.3]], ["timeout"])
    arrived = sv.absorbing_goal(first, at_arrival=True)
    assert odata.episode_statistics(arrived)[0].lengths.tolist() == [1]


def test_goal_deadline_gives_collected_data_a_length_bias(collected):
    # On real env3 data (uncut at collisions), the goal distance from the observation is the
    # environment's, and a deadline makes the failures short.
    ds, traj = collected[False]
    d = np.asarray(sv.goal_distances(ds)).reshape(BATCH, HORIZON)
    np.testing.assert_allclose(d[:, -1], np.asarray(traj["episode"]["final_goal_distance"]),
                               rtol=1e-5, atol=1e-6)
    # The radius between the episodes' closest approaches in their first 50 steps: some arrive.
    first = np.asarray(sv.goal_distances(ds)).reshape(BATCH, HORIZON)[:, :50].min(axis=1)
    radius = float(np.sort(first)[BATCH // 2])
    out = sv.cut_before_goal(ds, deadline=50, radius=radius)
    per, _ = odata.episode_statistics(out)
    cut = out.metadata["goal_deadline"]["cut_episodes"]
    assert 0 < cut < per.episode_ids.size, "the noisy behaviour must both miss and reach"
    assert per.terminated.sum() == cut and (per.lengths[per.terminated] == 50).all()
    assert (per.lengths[~per.terminated] == HORIZON).all()
