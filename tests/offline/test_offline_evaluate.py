"""In-graph evaluation of offline policies (offline/experiment/evaluate.py) on the 3-link env3
task."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from envs.evaluate import make_rollout
from offline.experiment.evaluate import make_evaluator

ENV = "three_link/env3"
REF_EPISODES = 64


@pytest.fixture(scope="module")
def ev():
    return make_evaluator(ENV, 16, reference_episodes=REF_EPISODES)


def test_reference_returns_match_envs_evaluate(ev):
    """J_expert is the hand-designed policy's mean return of envs.evaluate on the same
    (reference) episodes; J_random is far below it."""
    per = make_rollout(ev.env, REF_EPISODES)(jax.random.PRNGKey(0))
    ref = ev.reference
    # two separately compiled programs: rounding differences grow along 600 chaotic steps
    np.testing.assert_allclose(ref["expert_return"], np.mean(np.asarray(per["return"],
                                                                        np.float64)),
                               rtol=1e-3)
    np.testing.assert_allclose(ref["expert_safe_pct"], 100 * np.mean(per["safe"]))
    np.testing.assert_allclose(ref["expert_success_pct"], 100 * np.mean(per["success"]))
    assert ref["episodes"] == REF_EPISODES and ref["seed"] == 0
    assert ref["expert_return"] > ref["random_return"] + 100
    assert ref["random_safe_pct"] < ref["expert_safe_pct"]


def test_expert_scores_100_and_random_0_on_other_episodes(ev):
    key = jax.random.PRNGKey(123)
    expert = ev.evaluate_baseline("expert", key)
    random = ev.evaluate_baseline("random", key)
    # the score on the reference episodes is 100 / 0 by construction; on other episodes it
    # differs by sampling noise only (SE of 64 episodes: ~3 points for the expert, <1 random)
    assert abs(float(expert["normalized_score"]) - 100.0) < 15.0
    assert abs(float(random["normalized_score"])) < 5.0
    assert float(expert["success_pct"]) > 50.0 and float(random["success_pct"]) == 0.0
    np.testing.assert_allclose(float(ev.normalized_score(ev.reference["expert_return"])), 100.0,
                               rtol=1e-6)
    np.testing.assert_allclose(float(ev.normalized_score(ev.reference["random_return"])), 0.0,
                               atol=1e-6)
    with pytest.raises(ValueError, match="valid names"):
        ev.evaluate_baseline("oracle", key)


def test_vmap_over_parameter_sets(ev):
    """Two linear tanh policies evaluated in one vmapped program; swapping the parameter sets
    swaps the results exactly, and the score follows the reference returns."""

    def act(w, obs):
        return jnp.tanh(obs @ w)

    w = jax.random.normal(jax.random.PRNGKey(1), (2, ev.env.observation_size,
                                                  ev.env.action_size)) * 0.5
    key = jax.random.PRNGKey(7)
    program = jax.jit(jax.vmap(lambda p: ev.evaluate(act, p, key)))
    out, swapped = program(w), program(w[::-1])
    assert set(out) == {"mean_return", "normalized_score", "safe_pct", "success_pct",
                        "mean_final_goal_distance", "mean_length"}
    for k, v in out.items():
        assert v.shape == (2,) and np.all(np.isfinite(v))
        np.testing.assert_array_equal(v, swapped[k][::-1])
    assert out["mean_return"][0] != out["mean_return"][1]
    ref = ev.reference
    np.testing.assert_allclose(
        out["normalized_score"],
        100 * (out["mean_return"] - ref["random_return"])
        / (ref["expert_return"] - ref["random_return"]), rtol=1e-5)
    assert np.all(out["mean_return"] < ref["expert_return"])


def test_the_same_arguments_return_the_cached_evaluator(ev):
    """make_evaluator builds an evaluator once per process and arguments (reference returns
    and compiled programs shared)."""
    again = make_evaluator(ENV, 16, reference_episodes=REF_EPISODES, reference_seed=0)
    assert again is ev and again.reference == ev.reference


def test_bad_arguments_are_refused(ev):
    with pytest.raises(ValueError, match="valid names"):
        make_evaluator("three_link/env9", 4)
    with pytest.raises(ValueError, match="num_episodes"):
        make_evaluator(ENV, 0)
    with pytest.raises(ValueError, match="reference_episodes"):
        make_evaluator(ENV, 4, reference_episodes=-1)
    with pytest.raises(ValueError, match="act"):
        ev.evaluate(None, {}, jax.random.PRNGKey(0))
