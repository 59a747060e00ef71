"""The scaling study's measurements run at a tiny size and render a well-formed study (no speed
is asserted)."""

from __future__ import annotations

import math

import pytest

from agents.bench.scaling import (
    measure_data_parallel,
    measure_sweep,
    write_part,
    write_scaling_study,
)
from mjxrmp.results.summary import load_summary, run_record

TINY = dict(num_envs=8, rollout_length=16, num_minibatches=2, update_epochs=1)


def test_sweep_part_measures_and_renders_the_study(tmp_path):
    sweep = measure_sweep("three_link/env3", "nn", 2, 1, "cpu", seeds=1, **TINY)
    assert sweep["points"] == 2 and sweep["env_steps"] == 2 * 8 * 16
    assert math.isfinite(sweep["steps_per_s"]) and sweep["steps_per_s"] > 0
    write_part(tmp_path, "sweeps", [sweep], run_record("test sweeps"))
    summary = load_summary(write_scaling_study(tmp_path))
    assert [r[0] for r in summary["tables"]["scaling"]["rows"]] == ["packed sweep"]
    assert summary["headline"]["rows"][0]["run"] == "sweeps"
    assert (tmp_path / "table.csv").read_text().count("\n") == 2
    with pytest.raises(ValueError, match="multiple of seeds × setups"):
        measure_sweep("three_link/env3", "nn", 3, 1, "cpu", seeds=2)
    with pytest.raises(FileNotFoundError):
        write_scaling_study(tmp_path / "empty")


def test_setups_part_packs_setups_and_renders_the_study(tmp_path):
    one = measure_sweep("three_link/env3", "nn", 1, 1, "cpu", seeds=1, **TINY)
    packed = measure_sweep("three_link/env1", "nn", 2, 1, "cpu", seeds=1,
                           setups=("three_link/env2", "three_link/env3"), **TINY)
    assert packed["points"] == 1 and packed["env"] == "three_link/env2"
    assert packed["env_steps"] == 2 * 8 * 16 and packed["steps_per_s"] > 0
    write_part(tmp_path, "setups", [one, packed], run_record("test setups"))
    summary = load_summary(write_scaling_study(tmp_path))
    assert [r[0] for r in summary["tables"]["scaling"]["rows"]] == [
        "one setup (env3)", "setups packed (env2+env3)"]
    assert "2 runs of 2 setups in one program vs 1 of one" in str(summary["headline"])


@pytest.mark.slow
def test_data_parallel_part_measures_and_renders_the_study(tmp_path):
    dp = measure_data_parallel("three_link/env3", "nn", [1], 8, 8, 1, 1, "cpu")
    assert [r["devices"] for r in dp] == [1] and dp[0]["mode"] == "weak"
    write_part(tmp_path, "data_parallel", dp, run_record("test dp"))
    summary = load_summary(write_scaling_study(tmp_path))
    assert summary["tables"]["scaling"]["rows"][0][:2] == ["data parallel", "1"]
