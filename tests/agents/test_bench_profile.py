"""The control-step profile (agents.bench.phases, agents.bench.profile): every phase runs and
is reported against the physics floor, the contact-free model really drops the constraint
stages, the Perfetto kernel count reads GPU stream events only, and the study validates."""

from __future__ import annotations

import gzip
import json

import jax
import mujoco
import numpy as np
import pytest

import envs
from agents.bench.kernels import gpu_kernel_events, summarise
from agents.bench.phases import PHYSICS_VARIANTS, physics_model
from agents.bench.profile import kept_profiles, profile_env, write_profile
from mjxrmp.results.summary import load_summary, run_record


def test_contact_free_model_disables_the_constraint_stages():
    """``contact_free`` sets the five disable flags (and one solver iteration for
    ``contact_free_1iter``) and ``as_is`` clears them, on a copy; the environment's own model
    is left alone."""
    env = envs.make("franka")
    before = env.mj_model.opt.disableflags
    free = physics_model(env.mj_model, "contact_free")
    one = physics_model(env.mj_model, "contact_free_1iter")
    for flag in ("mjDSBL_CONSTRAINT", "mjDSBL_CONTACT", "mjDSBL_LIMIT"):
        assert free.opt.disableflags & int(getattr(mujoco.mjtDisableBit, flag))
    assert int(one.opt.iterations) == 1
    assert not physics_model(env.mj_model, "as_is").opt.disableflags & int(
        mujoco.mjtDisableBit.mjDSBL_LIMIT)
    assert env.mj_model.opt.disableflags == before
    with pytest.raises(ValueError, match="variant must be one of"):
        physics_model(env.mj_model, "fast")


#: Every phase :func:`profile_env` times by default.
ALL_PHASES = {f"physics_{v}" for v in PHYSICS_VARIANTS} | {
    "env_step_raw", "env_step", "env_step_reset_always", "env_step_pooled", "reset", "observe",
    "rmp2_policy", "ppo_rollout"}


def _profile_is_written_as_a_study(tmp_path, phases: set[str] | None) -> None:
    """A tiny profile on this CPU of ``phases`` (None: all): every phase asked for timed
    (positive, finite), kernels absent without a GPU, the joint-limit check finite (2 episodes
    × 4 steps, the size of tests/agents/test_limit_check.py), and the study validates."""
    r = profile_env("three_link/env3", batch=2, steps=2, repeats=1, episodes=2, horizon=4,
                    key=jax.random.PRNGKey(0), phases=None if phases is None else sorted(phases))
    names = ALL_PHASES if phases is None else phases
    assert set(r["phases"]) == names
    assert all(0 < t["per_step_s"] < 10 for t in r["phases"].values())
    assert all(k is None for k in r["kernels"].values())
    lim = r["limits"]["hand_designed"]
    assert lim["max_excess_as_is"] >= 0 and np.isfinite(lim["max_abs_dq"])
    record = run_record("python scripts/profile_step.py", device="CPU (test)")
    path = write_profile({"three_link/env3": {**r, "record": record}}, tmp_path)
    summary = load_summary(path)
    assert len(summary["tables"]["phases"]["rows"]) == len(names)
    assert summary["headline"]["rows"][0]["cells"][0].startswith("three_link/env3, 2 environ")
    assert (tmp_path / "table.csv").read_text().startswith("environment,phase")
    # another environment measured by another command on another device joins the study,
    # each keeping its own run record; a re-run of one environment keeps only the other
    other = {**next(iter(summary["runs"].values())), "device": "NVIDIA H200",
             "command": "python scripts/profile_step.py --envs franka", "date": "2026-11-28"}
    both = {**summary["raw"], "franka": {**summary["raw"]["three_link/env3"], "record": other}}
    joined = load_summary(write_profile(both, tmp_path))
    assert sorted(joined["runs"].values(), key=str) == sorted([record, other], key=str)
    assert len(joined["tables"]["phases"]["rows"]) == 2 * len(names)
    assert list(kept_profiles(tmp_path, ["three_link/env3"])) == ["franka"]
    assert kept_profiles(tmp_path, ["three_link/env3"])["franka"]["record"] == other
    assert kept_profiles(tmp_path / "none", ["franka"]) == {}


def test_profile_of_a_subset_of_phases_is_written_as_a_study(tmp_path):
    """The quick check of :func:`test_profile_of_every_phase_is_written_as_a_study`: the floor
    and four phases, the PPO rollout among them (the other phases' programs are never
    compiled)."""
    _profile_is_written_as_a_study(tmp_path, {"physics_contact_free", "reset", "observe",
                                              "rmp2_policy", "ppo_rollout"})


@pytest.mark.slow
def test_profile_of_every_phase_is_written_as_a_study(tmp_path):
    """Every phase (the default) profiled and written; the default suite checks a subset
    (:func:`test_profile_of_a_subset_of_phases_is_written_as_a_study`)."""
    _profile_is_written_as_a_study(tmp_path, None)


def test_kernel_count_reads_gpu_stream_events_only(tmp_path):
    """Only complete events on a GPU process's stream threads count (host threads and CPU
    processes do not); per step they are counted, timed, spanned and split by kind."""
    events = [
        {"ph": "M", "name": "process_name", "pid": 1, "args": {"name": "/device:GPU:0"}},
        {"ph": "M", "name": "process_name", "pid": 2, "args": {"name": "/host:CPU"}},
        {"ph": "M", "name": "thread_name", "pid": 1, "tid": 7,
         "args": {"name": "Stream #14(Compute)"}},
        {"ph": "M", "name": "thread_name", "pid": 1, "tid": 8, "args": {"name": "launcher"}},
        {"ph": "X", "pid": 1, "tid": 7, "ts": 0, "dur": 2.0, "name": "gemm_fusion_dot.3"},
        {"ph": "X", "pid": 1, "tid": 7, "ts": 3, "dur": 1.5, "name": "input_reduce_fusion"},
        {"ph": "X", "pid": 1, "tid": 7, "ts": 5, "dur": 0.5, "name": "loop_add_fusion"},
        {"ph": "X", "pid": 1, "tid": 8, "ts": 0, "dur": 9.0},
        {"ph": "X", "pid": 2, "tid": 7, "ts": 0, "dur": 9.0},
    ]
    path = tmp_path / "t.trace.json.gz"
    with gzip.open(path, "wt") as f:
        json.dump({"traceEvents": events}, f)
    kernels = gpu_kernel_events(str(path))
    assert [e["name"] for e in kernels] == ["gemm_fusion_dot.3", "input_reduce_fusion",
                                            "loop_add_fusion"]
    per_step = summarise(kernels, steps=2)
    assert per_step["kernels_per_step"] == 1.5 and per_step["busy_us_per_step"] == 2.0
    assert per_step["span_us_per_step"] == 2.75  # 0 → 5.5 µs over 2 steps
    assert per_step["by_kind"] == {
        "matrix products": {"kernels_per_step": 0.5, "busy_us_per_step": 1.0},
        "reductions": {"kernels_per_step": 0.5, "busy_us_per_step": 0.75},
        "other": {"kernels_per_step": 0.5, "busy_us_per_step": 0.25}}
