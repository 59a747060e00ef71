"""Sim-to-sim (:mod:`agents.run.sim2sim`, :mod:`agents.run.sim2sim_mujoco`) on CPU.

The hand-designed RMP² policy of ``three_link/env3``, exported like any policy, runs 2 scenes in
MuJoCo C and in MJX: for the first 20 control steps the trajectories, observations and returns
agree to float32 rounding (MuJoCo C computes in float64, MJX in float32; measured differences
≤ 1e-7 in ``q``, so :data:`TOL` leaves a margin of about 100). The study's summary has the
documented fields, and bad arguments (also ``--viewer`` without a display) are refused naming
what is wrong.
"""

from __future__ import annotations

import csv
import json

import jax
import mujoco
import numpy as np
import pytest

import envs
from agents.run import sim2sim as s2s
from agents.run.export import export_run, load_export
from agents.run.sim2sim_mujoco import MujocoScenes, decorate, scenes_of
from mjxrmp.results.summary import load_summary

ENV = "three_link/env3"
SCENES, STEPS = 2, 20
#: Largest MuJoCo-vs-MJX difference accepted in q (rad), the observation and the return.
TOL = 1e-5


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    path = tmp_path_factory.mktemp("sim2sim") / "hand_designed.jaxexport"
    export_run(path, env_name=ENV, kind="hand_designed", platforms=("cpu",))
    exported, manifest = load_export(path)
    return envs.make(ENV), path, exported, manifest


def test_short_episode_matches_mjx(setup):
    """MuJoCo C and MJX trajectories of the same exported policy agree step by step; the
    viewer's decoration of the scene (obstacles and goal) builds without a window."""
    env, _, exported, _ = setup
    call = jax.jit(exported.call)

    @jax.jit
    def mjx_trajectory(keys):
        def body(s, _):
            s = jax.vmap(env.step)(s, exported.call(s.obs))
            return s, (s.pipeline_state.qpos, env.virtual_velocity(s), s.obs)

        s0 = jax.vmap(env.reset)(keys)
        s, traj = jax.lax.scan(body, s0, None, length=STEPS)
        return s0, s, traj

    first, last, (qs, qvs, obs) = mjx_trajectory(jax.random.split(jax.random.PRNGKey(0), SCENES))
    sim = MujocoScenes(env, scenes_of(first))
    np.testing.assert_allclose(sim.observe(), first.obs, atol=TOL)
    for t in range(STEPS):
        sim.step(np.asarray(call(sim.observe())))
        np.testing.assert_allclose(np.stack([d.qpos for d in sim.data]), qs[t], atol=TOL)
        np.testing.assert_allclose(sim.qv, qvs[t], atol=TOL)
        np.testing.assert_allclose(sim.observe(), obs[t], atol=TOL)
    np.testing.assert_allclose(sim.stats["return"], last.info["episode_return"], atol=TOL)
    np.testing.assert_allclose(sim.goal_distance, last.metrics["goal_distance"], atol=TOL)
    assert np.abs(qs[-1] - first.pipeline_state.qpos).max() > 0.01  # the arms moved
    scn = mujoco.MjvScene(env.mj_model, maxgeom=100)  # what --viewer draws, without a window
    decorate(scn, sim)
    assert scn.ngeom == env.num_obstacles + 1
    types = [scn.geoms[i].type for i in range(scn.ngeom)]
    assert types == [mujoco.mjtGeom.mjGEOM_CYLINDER] * 3 + [mujoco.mjtGeom.mjGEOM_SPHERE]


def test_summary_has_the_documented_fields(setup, tmp_path):
    """:func:`sim2sim` records and the study files :func:`write_results` writes."""
    env, path, _, _ = setup
    records = s2s.sim2sim(ENV, [path], num_scenes=SCENES, horizon=STEPS)
    (r,) = records
    assert (r["env"], r["policy"], r["kind"], r["scenes"], r["horizon"]) == (
        ENV, "hand_designed", "hand_designed", SCENES, STEPS)
    assert r["model"] == {"integrator": "implicitfast", "timestep": env.sim_dt, "substeps": 3,
                          "constraint_stages": False, "mujoco_float": "float64",
                          "mjx_float": "float32"}
    for side in ("mujoco", "mjx"):
        assert set(r[side]) == {"mean_return", "success_pct", "safe_pct",
                                "mean_final_goal_distance", "seconds"}
        assert all(np.isfinite(v) for v in r[side].values())
    assert set(r["diff"]) == {"success_pp", "safe_pp", "success_flips", "safety_flips",
                              "max_abs_final_distance_diff", "median_abs_final_distance_diff",
                              "max_abs_return_diff"}
    assert r["diff"]["max_abs_final_distance_diff"] < TOL
    assert abs(r["mujoco"]["mean_return"] - r["mjx"]["mean_return"]) < TOL
    out = s2s.write_results(tmp_path, records, "python scripts/sim2sim.py --env three_link/env3")
    summary = load_summary(out)
    assert summary["study"] == "sim2sim" and list(summary["runs"]) == [ENV]
    assert summary["raw"][0]["diff"] == json.loads(json.dumps(r["diff"]))
    with open(tmp_path / "table.csv") as f:
        rows = list(csv.reader(f))
    assert rows[0] == s2s.COLUMNS and len(rows) == 2


def test_bad_arguments_are_refused(setup, tmp_path, monkeypatch):
    """Unknown environment, missing file, another environment's export, unsupported kind,
    nothing to run, and the viewer without a display."""
    env, path, _, manifest = setup
    with pytest.raises(ValueError, match=r"unknown env='point2d'.*valid names"):
        s2s.sim2sim("point2d", [path])
    with pytest.raises(FileNotFoundError, match=r"nope\.jaxexport"):
        s2s.sim2sim(ENV, [tmp_path / "nope.jaxexport"])
    with pytest.raises(ValueError, match=r"--policy.*or --hand-designed"):
        s2s.sim2sim(ENV)
    with pytest.raises(ValueError, match="num_scenes must be an integer >= 1"):
        s2s.sim2sim(ENV, [path], num_scenes=0)
    with pytest.raises(ValueError, match=r"exported for env 'three_link/env3'.*'three_link/env1'"):
        s2s.sim2sim("three_link/env1", [path])
    other = {**manifest, "metadata": {**manifest["metadata"], "env": "franka"}}
    with pytest.raises(ValueError, match="exported for env 'franka', not the requested"):
        s2s.check_manifest(other, env, ENV, "p.jaxexport")
    kind = {**manifest, "metadata": {**manifest["metadata"], "policy": "rmp_residual_env"}}
    with pytest.raises(ValueError, match=r"rmp_residual_env.*joint-acceleration policies"):
        s2s.check_manifest(kind, env, ENV, "p.jaxexport")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(RuntimeError, match="--viewer needs a display"):
        s2s.view(ENV)
