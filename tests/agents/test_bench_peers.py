"""The PPO peer comparison (agents.bench.peers): ours, brax's PPO and rejax's PPO each train
three_link/env3 at a tiny size and return a finite, well-formed row scored by our evaluator;
the study keeps the rows of other devices when a device writes its own. No speed is asserted."""

from __future__ import annotations

import importlib.util
import math

import pytest

from agents.bench.peer_common import PolicyNet
from agents.bench.peer_table import settings_table, write_peers
from agents.bench.peers import brax_kwargs, check_trainers, measure, plan
from agents.run.spec import preset
from mjxrmp.results.summary import load_summary

TINY = preset("thesis", num_envs=8, rollout_length=4, num_minibatches=2, update_epochs=1)
KEYS = {"trainer", "layout", "env", "seeds", "num_envs", "rollout_length", "iterations", "chunk",
        "env_steps", "policy_env_steps", "steps_per_s", "chunk_s", "wall_s", "compile_s",
        "chunks_s", "eval_episodes", "eval_return", "eval_success_pct", "compile_cache"}
HAVE_REJAX = all(importlib.util.find_spec(m) for m in ("rejax", "gymnax"))


def _tiny_row(trainer: str) -> dict:
    return measure(trainer, "thesis", TINY, seeds=1, iterations=1, chunk=1, episodes=2,
                   horizon=3, seed=0)


@pytest.fixture(scope="module")
def rows() -> dict[str, dict]:
    trainers = ["ours", "brax", *(["rejax"] if HAVE_REJAX else [])]
    return {t: _tiny_row(t) for t in trainers}


@pytest.mark.parametrize("trainer", ["ours", "brax", "rejax"])
def test_each_trainer_returns_a_finite_row(rows, trainer):
    if trainer not in rows:
        pytest.skip("rejax is not installed: the optional peers extra (pip install -e '.[peers]')")
    row = rows[trainer]
    assert set(row) == KEYS
    assert row["env_steps"] == row["policy_env_steps"] == 8 * 4
    for key in ("steps_per_s", "chunk_s", "wall_s", "eval_return"):
        assert math.isfinite(row[key]), key
    assert row["steps_per_s"] > 0 and row["wall_s"] >= row["compile_s"] >= 0
    assert row["eval_episodes"] == 2 and 0 <= row["eval_success_pct"] <= 100


def test_a_device_replaces_only_its_own_rows(rows, tmp_path):
    net = PolicyNet((256, 128), "relu", -1.0)
    settings = settings_table(TINY, net)
    write_peers(list(rows.values()), tmp_path, "python scripts/bench.py --peers", settings,
                device="CPU (test)")
    gpu = [{**rows["ours"], "steps_per_s": 2.0}, {**rows["brax"], "steps_per_s": 1.0}]
    path = write_peers(gpu, tmp_path, "python scripts/bench.py --peers", settings,
                       device="GPU (test)")
    again = write_peers(gpu, tmp_path, "python scripts/bench.py --peers", settings,
                        device="GPU (test)")
    summary = load_summary(again)
    assert path == again and sorted(summary["runs"]) == ["thesis_cpu_test", "thesis_gpu_test"]
    devices = [r["device"] for r in summary["raw"]["rows"]]
    assert devices.count("CPU (test)") == len(rows) and devices.count("GPU (test)") == 2
    gpu_headline = [h for h in summary["headline"]["rows"] if h["run"] == "thesis_gpu_test"]
    assert "2.00×" in gpu_headline[0]["cells"][2]
    assert gpu_headline[0]["cells"][1].endswith("(brax); not measured in this run: rejax")
    cpu_headline = [h for h in summary["headline"]["rows"] if h["run"] == "thesis_cpu_test"]
    assert ("not measured" in cpu_headline[0]["cells"][1]) == (not HAVE_REJAX)
    assert (tmp_path / "table.csv").read_text().count("\n") == len(devices) + 1


def test_layouts_and_settings_are_checked():
    assert plan(["gpu"], ["ours", "brax"]) == [("gpu", "ours", 64, 128), ("gpu", "ours", 1, 8192),
                                               ("gpu", "brax", 1, 8192)]
    with pytest.raises(ValueError, match="unknown layout 'huge'"):
        plan(["huge"], ["ours"])
    with pytest.raises(ValueError, match="unknown trainer 'sb3'"):
        check_trainers(["sb3"])
    odd = preset("thesis", num_envs=8, rollout_length=6, num_minibatches=3)
    with pytest.raises(ValueError, match="num_minibatches=3 must divide num_envs=8"):
        brax_kwargs(odd, PolicyNet((8,), "relu", -1.0), 2, 1, 0)
    kw = brax_kwargs(TINY, PolicyNet((8,), "relu", -1.0), 4, 2, 0)
    assert kw["batch_size"] * kw["num_minibatches"] == 8 and kw["num_evals"] == 3
    assert kw["unroll_length"] == 4 and kw["num_updates_per_batch"] == 1
