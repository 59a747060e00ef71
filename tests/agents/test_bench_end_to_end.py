"""Training timed end to end (agents.bench.end_to_end): a failing command is reported with its
exit status, the study validates and renders, a new measurement replaces only its own
rows, and (slow) a real tiny measurement runs
scripts/train.py five times."""

from __future__ import annotations

import pytest

from agents.bench.end_to_end import (
    COLUMNS,
    _kept,
    _median,
    measure_training_speed,
    run_training_speed,
    timed_train,
    write_training_speed,
)
from mjxrmp.results.summary import load_summary, run_record


def test_a_failing_training_command_is_reported(tmp_path):
    """An unknown environment makes train.py exit 2; timed_train names the status and shows
    the script's own message."""
    with pytest.raises(RuntimeError, match=r"exited 2:(.|\n)*unknown --env"):
        timed_train(["--env", "nowhere"], str(tmp_path / "cache"))


def _result(env: str, device: str, first: bool = True, full: bool = True) -> dict:
    times = {"wall_s": 40.0, "compile_s": 20.0, "train_s": 15.0, "steps_per_s": 1e4}
    record = run_record("python x.py", device=device)
    return {"env": env, "policy": "nn", "seeds": [0, 1], "iterations": 5, "preset": "cpu",
            "full": times if full else None,
            "first_cold": {**times, "wall_s": 30.0} if first else None,
            "first_warm": {**times, "wall_s": 9.0, "first_chunk_s": 6.5} if first else None,
            "run": f"{env}_{device}", "record": record}


def test_training_speed_study_validates(tmp_path):
    """One measurement with the one-iteration command and one without: three headline rows,
    one table row per run (dashes where not measured), one run record each, the CSV."""
    summary = load_summary(write_training_speed(
        [_result("three_link/env3", "GPU"), _result("franka", "GPU", first=False)], tmp_path))
    assert summary["study"] == "training_speed"
    assert [r["cells"][2] for r in summary["headline"]["rows"]] == [
        "40 s (20 s, 15 s)", "30.0 s / 9.0 s (6.5 s)", "40 s (20 s, 15 s)"]
    rows = summary["tables"]["runs"]["rows"]
    assert rows[0][7] == "3.000"  # 15 s / 5 iterations
    assert rows[1][9:] == ["—", "—", "—", "—"]
    assert sorted(summary["runs"]) == ["franka_GPU", "three_link/env3_GPU"]
    assert (tmp_path / "table.csv").read_text().splitlines()[0] == ",".join(COLUMNS)


def test_a_first_iteration_only_measurement_renders_without_the_whole_run(tmp_path):
    """--first-iteration-only: headline rows of the repeated and the resumed command, dashes
    for the whole run."""
    result = {**_result("point2d", "GPU", full=False),
              "resumed": {"wall_s": 9.5, "compile_s": 0.1, "train_s": 0.5, "steps_per_s": 1e4,
                          "first_chunk_s": 7.25}}
    summary = load_summary(write_training_speed([result], tmp_path))
    assert [r["cells"][2] for r in summary["headline"]["rows"]] == [
        "30.0 s / 9.0 s (6.5 s)", "7.2 s"]
    assert summary["tables"]["runs"]["rows"][0][4:] == ["—"] * 5 + ["30.0", "9.0", "6.5", "7.2"]
    with pytest.raises(ValueError, match="first=True or full=True"):
        measure_training_speed("point2d", "nn", [0], 1, "cpu", tmp_path, first=False,
                               full=False)
    with pytest.raises(ValueError, match="warm_runs must be an integer >= 1"):
        measure_training_speed("point2d", "nn", [0], 1, "cpu", tmp_path, warm_runs=0)


def test_a_new_measurement_replaces_only_its_own_rows(tmp_path):
    """_kept drops the earlier results of the pairs measured again on the same device and keeps
    every other row: other pairs, and the same pair measured on another device."""
    write_training_speed([_result("three_link/env3", "GPU"), _result("franka", "GPU"),
                          _result("point2d", "CPU"), _result("franka", "CPU")], tmp_path)
    kept = _kept(tmp_path, "GPU", [("franka", "nn")])
    assert [(r["env"], r["record"]["device"]) for r in kept] == [
        ("three_link/env3", "GPU"), ("point2d", "CPU"), ("franka", "CPU")]
    assert _kept(tmp_path / "none", "GPU", []) == []


@pytest.mark.slow  # five train.py processes with compiles; the pieces are tested above
def test_training_speed_measures_real_runs(tmp_path):
    """One iteration of the CPU preset: the whole run, then a cold and a warm repeat and a
    resumed command."""
    path = run_training_speed([("three_link/env3", "nn")], [0], 1, "cpu", tmp_path / "work",
                              tmp_path / "out", "python scripts/bench_training.py")
    raw = load_summary(path)["raw"][0]
    assert all(raw[k]["wall_s"] > raw[k]["compile_s"] >= 0
               for k in ("full", "first_cold", "first_warm", "resumed"))
    assert 0 < raw["first_warm"]["first_chunk_s"] < raw["first_warm"]["wall_s"]


def test_the_median_run_is_the_middle_one_by_first_iteration_time():
    """The repeated and the resumed command report the run of median launch-to-first-iteration
    time (the lower middle of an even count); nothing measured gives None."""
    runs = [{"first_chunk_s": t, "wall_s": 10 + t} for t in (5.5, 4.2, 4.9, 6.1)]
    assert _median(runs)["first_chunk_s"] == 4.9
    assert _median(runs[:3])["first_chunk_s"] == 4.9
    assert _median([]) is None
