"""Offline diagnostics (offline/experiment/diagnostics.py): the action gap on toy dynamics with a
closed form, the ATAC-vs-BC learning curve and BC by data source on tiny synthetic data, and one
run of ``scripts/offline_diagnostics.py action-gap``."""

import json
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from script_main import load_script

from offline.data import dataset as odata
from offline.experiment import diagnostics
from offline.learners.registry import Budget

GAMMA = 0.9


class ToyState(NamedTuple):
    x: jax.Array
    reward: jax.Array
    done: jax.Array


class ToyEnv:
    """x' = x + a on two joints, reward sum(x'); done after the first step when ``stop``."""

    def __init__(self, stop: bool = False):
        self.stop = stop

    def reset(self, key):
        return ToyState(jnp.array([0.5, -0.25]), jnp.float32(0.0), jnp.float32(0.0))

    def step(self, state, action):
        x = state.x + action
        return ToyState(x, jnp.sum(x), jnp.float32(1.0 if self.stop else 0.0))


def _expert(state):
    return 2.0 * jnp.ones(2)  # clipped to +1 on both joints


def test_branch_returns_closed_form():
    """After t0 expert steps x = x0 + t0; the branch action a gives r_0 = sum(x + a) and the
    expert then adds 2 per step: Q(a) = Σ_{t=0}^{H} γ^t (r_0 + 2t)."""
    t0, horizon = 3, 7
    q = np.asarray(diagnostics.branch_returns(ToyEnv(), _expert, jax.random.PRNGKey(0), t0,
                                              gamma=GAMMA, horizon=horizon))
    base = 0.25 + 2 * t0
    t = np.arange(horizon + 1)
    expected = [np.sum(GAMMA ** t * (base + k + 2 * t)) for k in (2.0, -2.0, 0.0, 2.0, -2.0)]
    assert q.shape == (len(diagnostics.ACTION_BRANCHES),)
    np.testing.assert_allclose(q, expected, rtol=1e-5)


def test_branch_returns_stop_after_done():
    """A branch that ends the episode earns its one reward and nothing after."""
    q = np.asarray(diagnostics.branch_returns(ToyEnv(stop=True), _expert,
                                              jax.random.PRNGKey(0), 0, gamma=GAMMA,
                                              horizon=5))
    np.testing.assert_allclose(q, [2.25, -1.75, 0.25, 2.25, -1.75], rtol=1e-6)


def test_gap_summary_by_hand():
    q = np.array([[1.0, 0.0, 0.5, 2.0, -1.0], [3.0, 4.0, 3.0, 3.0, 3.0]])
    s = diagnostics.gap_summary(q)
    assert s == pytest.approx({"q_expert": 2.0, "expert_vs_negated": 1.0, "expert_vs_zero": 0.25,
                               "plus_vs_minus": 1.5, "range": 2.0})


# ---------------------------------------------------------------- learners on synthetic data

META = {"env": "three_link/env3", "action_limit": 1.0, "reward_range": [-1.0, 1.0]}
LENGTH = 5


def _mixed() -> odata.Dataset:
    """Two sources of three episodes each (rewards 0.1 and 0.9 per step), recipe metadata."""
    rng = np.random.default_rng(0)
    n_eps = 6
    n = n_eps * LENGTH
    obs = rng.normal(size=(n, 3)).astype(np.float32)
    rewards = np.repeat([0.1, 0.1, 0.1, 0.9, 0.9, 0.9], LENGTH).astype(np.float32)
    ids = np.repeat(np.arange(n_eps), LENGTH).astype(np.int32)
    timeouts = np.tile(np.arange(LENGTH) == LENGTH - 1, n_eps)
    sources = [{"behaviour": {"name": name}, "episode_ids": [lo, lo + 3],
                "summary": {"return_mean": r * LENGTH}}
               for name, lo, r in (("random", 0, 0.1), ("expert", 3, 0.9))]
    return odata.create(obs, rng.uniform(-1, 1, (n, 2)).astype(np.float32), rewards, obs + 0.1,
                        np.zeros(n, bool), timeouts, ids, {**META, "sources": sources})


class FakeEvaluator:
    """Scores a policy by how small its action is at one fixed state (jittable)."""

    def evaluate(self, act, params, key):
        a = act(params, jnp.ones(3))
        score = -jnp.sum(jnp.square(a))
        return {"normalized_score": score, "safe_pct": 100.0 + 0 * score,
                "success_pct": 0 * score}

    def normalized_score(self, returns):
        return 20.0 * returns


def test_top_episodes_keeps_best_half():
    top = diagnostics.top_episodes(_mixed(), 0.5)
    assert sorted(set(np.asarray(top.episode_ids).tolist())) == [3, 4, 5]


@pytest.mark.parametrize("program,runs", [("atac", 4), ("bc", 2), ("topbc", 2)])
def test_learning_curve_shapes(program, runs):
    r = diagnostics.learning_curve(program, _mixed(), FakeEvaluator(), steps=20, chunk=10,
                                   seeds=2, betas=[1.0, 16.0], warm=5, hidden=[8],
                                   actor="mlp")
    assert r["sources"] == pytest.approx({"random": 10.0, "expert": 90.0})
    assert [row["step"] for row in r["curve"]] == [10, 20]
    assert r["betas"] == ([1.0, 16.0, 1.0, 16.0] if program == "atac" else None)
    for row in r["curve"]:
        assert len(row["score"]) == runs and np.all(np.isfinite(row["score"]))
        assert all(np.all(np.isfinite(v)) for v in row["metrics"].values())
    json.dumps(r)


def test_bc_by_source_rows():
    rows = diagnostics.bc_by_source(_mixed(), FakeEvaluator(),
                                    Budget(steps=10, hidden=(8,)), [0, 1])
    assert [r["name"] for r in rows] == ["random", "expert", "all of mixed"]
    assert [r["transitions"] for r in rows] == [15, 15, 30]
    assert [r["behaviour"] for r in rows] == pytest.approx([10.0, 90.0, 50.0])
    for r in rows:
        assert len(r["bc"]["normalized_score"]) == 2 and np.isfinite(r["bc_mean"])
        assert np.isfinite(r["bc_sem"]) and r["safe_mean"] == 100.0


def test_mixed_file(tmp_path):
    (tmp_path / "franka_mixed_x400_s0_substeps_24.npz").touch()
    (tmp_path / "franka_mixed_x400_s0.npz").touch()
    assert diagnostics.mixed_file(tmp_path, "franka", 24).name.endswith("_substeps_24.npz")
    assert diagnostics.mixed_file(tmp_path, "franka", None).name == "franka_mixed_x400_s0.npz"
    with pytest.raises(FileNotFoundError):
        diagnostics.mixed_file(tmp_path, "three_link/env3", 24)


def test_script_action_gap(tmp_path):
    """The cheapest subcommand end to end on the real environment (2 scenes, 3 steps), through
    the script's ``main`` in this process."""
    out = tmp_path / "gap.jsonl"
    load_script("offline_diagnostics.py").main(["action-gap", "--scenes", "2", "--horizon", "3",
                                                "--out", str(out)])
    r = json.loads(out.read_text())
    q = np.asarray(r["q"])
    assert q.shape == (2, 5) and np.all(np.isfinite(q))
    assert r["args"]["command"] == "action-gap" and r["substeps"] == 3
    np.testing.assert_allclose(r["range"], np.mean(q.max(1) - q.min(1)), rtol=1e-9)
