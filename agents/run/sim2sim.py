"""Sim-to-sim: an exported policy in MuJoCo's own simulator next to its MJX evaluation.

Robotics users check an MJX-trained policy in MuJoCo proper before trusting it. For each exported
policy (a :mod:`agents.run.export` blob; the hand-designed RMP² policy is exported the same way,
kind ``hand_designed``) :func:`sim2sim` runs the same scenes (``reset`` of ``split(PRNGKey(seed),
scenes)``) twice:

* **MuJoCo**: :func:`agents.run.sim2sim_mujoco.run_episodes`: ``mujoco.mj_step`` on the MJCF
  the environment simulates, float64, with the observation, control, reward and collision
  computed in numpy from ``MjData``; the exported function is called once per control step on
  the whole batch (mujoco, numpy and jax only);
* **MJX**: :func:`envs.evaluate.make_rollout`, the project's evaluation, with the same exported
  function as the policy (a ``custom_vmap`` turns the per-episode calls into one batched call).

Per policy it reports mean return, success % and safe % on both sides and the per-scene
differences: success and safety flips, the largest and median ``|Δ final goal distance|`` and
the largest ``|Δ return|``. :func:`write_results` adds the records to
``results/sim2sim/summary.json`` and ``table.csv`` (records of other environments are kept, so
one command per environment fills one study).
"""

from __future__ import annotations

import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import IO

import jax
import mujoco
import numpy as np
from jax import export as jax_export

import envs
from agents.run.export import EXPORTABLE_ENVS, export_run, load_export
from agents.run.logs import ProgressBar
from agents.run.sim2sim_mujoco import (
    Scenes,
    require_display,
    run_episodes,
    sample_scenes,
    view_scene,
)
from envs.evaluate import make_rollout
from mjxrmp.config import check_int
from mjxrmp.results.summary import load_summary, run_record, write_study

#: The study folder and the name of its table.
STUDY = "sim2sim"
#: Columns of the sim-to-sim table (``table.csv``).
COLUMNS = ["env", "policy", "scenes", "MuJoCo return", "MJX return", "MuJoCo success %",
           "MJX success %", "MuJoCo safe %", "MJX safe %", "success flips", "safety flips",
           "max |Δ final dist| (m)", "median |Δ final dist| (m)", "MuJoCo s", "MJX s"]
#: Policy kinds whose exported action is not a joint acceleration of the plain environment.
UNSUPPORTED_KINDS = ("rmp_residual_env",)
HEAD = {"study": STUDY, "title": "Sim-to-sim: MuJoCo vs MJX",
        "report": "docs/reports/sim2sim.md"}


def env_name_of(name: str) -> str:
    """The registry name of ``name`` (brax names accepted); ``ValueError`` listing the valid ones
    for anything but a reaching environment."""
    name = envs.BRAX_NAMES.get(name, name)
    if name not in EXPORTABLE_ENVS:
        raise ValueError(f"unknown env={name!r} for sim-to-sim; valid names are "
                         f"{list(EXPORTABLE_ENVS)}")
    return name


def check_manifest(manifest: dict, env, env_name: str, path: str) -> None:
    """Refuse an export that does not act on ``env`` (``env_name``): another environment, the
    RMP²-in-environment kind, or another observation layout; the message names ``path``."""
    meta = manifest.get("metadata", {})
    exported_env = envs.BRAX_NAMES.get(meta.get("env"), meta.get("env"))
    if exported_env != env_name:
        raise ValueError(f"{path} was exported for env {meta.get('env')!r}, not the requested "
                         f"--env {env_name!r}")
    if meta.get("policy") in UNSUPPORTED_KINDS:
        raise ValueError(f"{path}: policy kind {meta['policy']!r} acts through envs.RMPInEnv; "
                         "sim-to-sim runs joint-acceleration policies only")
    layout = {k: [s.start, s.stop] for k, s in env.observation_layout().items()}
    if meta.get("observation_layout") != layout or manifest["obs_size"] != env.observation_size:
        raise ValueError(f"{path}: its observation layout differs from {env_name}'s default one "
                         f"(obs_size {manifest['obs_size']} vs {env.observation_size})")


def single_obs_policy(exported: jax_export.Exported):
    """``act(obs (obs_size,)) -> (dof,)`` calling ``exported``; under ``vmap`` it calls the
    exported function once on the whole batch (``jax.export`` has no batching rule)."""

    @jax.custom_batching.custom_vmap
    def act(obs):
        return exported.call(obs[None])[0]

    @act.def_vmap
    def _batched(axis_size, in_batched, obs):
        del axis_size
        if not in_batched[0]:
            return act(obs), False
        return exported.call(obs), True

    return act


def mjx_episodes(env, exported: jax_export.Exported, num_scenes: int, seed: int,
                 horizon: int) -> dict[str, np.ndarray]:
    """Per-episode statistics of ``exported`` in MJX (:func:`envs.evaluate.make_rollout`)."""
    act = single_obs_policy(exported)
    rollout = make_rollout(env, num_scenes, horizon, policy=lambda state: act(state.obs))
    out = jax.block_until_ready(rollout(jax.random.PRNGKey(seed)))
    return {k: np.asarray(v, np.float64) for k, v in out.items()}


def _side(per_episode: dict[str, np.ndarray], seconds: float) -> dict:
    return {"mean_return": float(per_episode["return"].mean()),
            "success_pct": 100.0 * float(per_episode["success"].mean()),
            "safe_pct": 100.0 * float(per_episode["safe"].mean()),
            "mean_final_goal_distance": float(per_episode["final_goal_distance"].mean()),
            "seconds": seconds}


def compare(mujoco: dict[str, np.ndarray], mjx: dict[str, np.ndarray]) -> dict:
    """Per-scene differences MuJoCo − MJX: flips of success and safety (scenes whose flag
    differs), ``|Δ final goal distance|`` (max, median) and ``|Δ return|`` (max)."""
    dist = np.abs(mujoco["final_goal_distance"] - mjx["final_goal_distance"])
    return {"success_pp": 100.0 * float(mujoco["success"].mean() - mjx["success"].mean()),
            "safe_pp": 100.0 * float(mujoco["safe"].mean() - mjx["safe"].mean()),
            "success_flips": int((mujoco["success"] != mjx["success"]).sum()),
            "safety_flips": int((mujoco["safe"] != mjx["safe"]).sum()),
            "max_abs_final_distance_diff": float(dist.max()),
            "median_abs_final_distance_diff": float(np.median(dist)),
            "max_abs_return_diff": float(np.abs(mujoco["return"] - mjx["return"]).max())}


def model_record(env) -> dict:
    """The model variant both simulators run: integrator, timestep, substeps per control step,
    whether MuJoCo's constraint pipeline is on, and each side's float width."""
    m = env.mj_model
    integrator = mujoco.mjtIntegrator(int(m.opt.integrator)).name.removeprefix("mjINT_")
    return {"integrator": integrator.lower(), "timestep": float(m.opt.timestep),
            "substeps": env.substeps, "constraint_stages": env.constraint_stages,
            "mujoco_float": "float64", "mjx_float": "float32"}


def _batch_policy(exported: jax_export.Exported):
    call = jax.jit(exported.call)
    return lambda obs: np.asarray(call(obs))


def evaluate_export(env, env_name: str, path: str | Path, label: str, scenes: Scenes,
                    seed: int, horizon: int, stream: IO[str] | None = None) -> dict:
    """One policy's record: MuJoCo and MJX statistics on the same scenes (``scenes``, those of
    :func:`~agents.run.sim2sim_mujoco.sample_scenes` with ``seed``) and their differences
    (:func:`compare`), with the export's provenance and the model variant simulated."""
    exported, manifest = load_export(path)
    check_manifest(manifest, env, env_name, str(path))
    num_scenes = len(scenes.q0)
    bar = ProgressBar(horizon, stream)

    def progress(t: int) -> None:
        if t % 50 == 0 or t == horizon:
            bar.update(t, f"MuJoCo {label}")

    t0 = time.perf_counter()
    mj = run_episodes(env, _batch_policy(exported), scenes, horizon, on_step=progress)
    bar.close()
    t1 = time.perf_counter()
    print(f"MJX {label}: {num_scenes} scenes × {horizon} steps (compile included)…",
          file=stream or sys.stderr)
    mx = mjx_episodes(env, exported, num_scenes, seed, horizon)
    t2 = time.perf_counter()
    meta = manifest.get("metadata", {})
    return {"env": env_name, "policy": label, "kind": meta.get("policy"),
            "source": {k: meta.get(k) for k in ("source", "checkpoint", "iteration", "seed")},
            "artifact": Path(path).name, "sha256": manifest["sha256"], "scenes": num_scenes,
            "scene_seed": seed, "horizon": horizon, "model": model_record(env),
            "mujoco": _side(mj, t1 - t0), "mjx": _side(mx, t2 - t1), "diff": compare(mj, mx)}


def sim2sim(env_name: str, policies: Sequence[str | Path] = (), hand_designed: bool = False,
            num_scenes: int = 256, seed: int = 0, horizon: int | None = None,
            stream: IO[str] | None = None) -> list[dict]:
    """Records (:func:`evaluate_export`) of the hand-designed policy (exported to a temporary
    folder first) and of every exported policy in ``policies`` on ``env_name``'s default
    environment. Raises ``ValueError``/``FileNotFoundError`` naming the bad argument or file."""
    env_name = env_name_of(env_name)
    check_int(num_scenes, "num_scenes")
    check_int(seed, "seed", minimum=0)
    if horizon is not None:
        check_int(horizon, "horizon")
    if not policies and not hand_designed:
        raise ValueError("give at least one exported policy (--policy) or --hand-designed")
    for p in policies:
        if not Path(p).is_file():
            raise FileNotFoundError(f"--policy {str(p)!r}: no such file")
    env = envs.make(env_name)
    for p in policies:  # every export is checked before the first one runs
        check_manifest(load_export(p)[1], env, env_name, str(p))
    horizon = env.horizon if horizon is None else horizon
    records, scenes = [], sample_scenes(env, num_scenes, seed)
    with tempfile.TemporaryDirectory() as tmp:
        todo = [(Path(p), Path(p).stem) for p in policies]
        if hand_designed:
            path = Path(tmp) / "hand_designed.jaxexport"
            export_run(path, env_name=env_name, kind="hand_designed")
            todo.insert(0, (path, "hand-designed"))
        for path, label in todo:
            records.append(evaluate_export(env, env_name, path, label, scenes, seed, horizon,
                                           stream))
    return records


def view(env_name: str, policy: str | Path | None = None, seed: int = 0,
         horizon: int | None = None) -> None:
    """Show scene 0 of ``seed`` under the exported ``policy`` (default: the hand-designed one)
    in MuJoCo's passive viewer (:func:`agents.run.sim2sim_mujoco.view_scene`)."""
    env_name = env_name_of(env_name)
    require_display()
    env = envs.make(env_name)
    with tempfile.TemporaryDirectory() as tmp:
        if policy is None:
            policy = Path(tmp) / "hand_designed.jaxexport"
            export_run(policy, env_name=env_name, kind="hand_designed", platforms=("cpu",))
        exported, manifest = load_export(policy)
        check_manifest(manifest, env, env_name, str(policy))
    view_scene(env, _batch_policy(exported), sample_scenes(env, 1, seed),
               env.horizon if horizon is None else horizon)


def table_row(r: dict) -> list:
    """The :data:`COLUMNS` cells of one record."""
    mj, mx, d = r["mujoco"], r["mjx"], r["diff"]
    return [r["env"], r["policy"], r["scenes"], round(mj["mean_return"], 2),
            round(mx["mean_return"], 2), round(mj["success_pct"], 2), round(mx["success_pct"], 2),
            round(mj["safe_pct"], 2), round(mx["safe_pct"], 2), d["success_flips"],
            d["safety_flips"], float(f"{d['max_abs_final_distance_diff']:.3g}"),
            float(f"{d['median_abs_final_distance_diff']:.3g}"), round(mj["seconds"], 1),
            round(mx["seconds"], 1)]


def write_results(out_dir: str | Path, records: list[dict], command: str) -> Path:
    """Write ``out_dir/summary.json`` and ``table.csv`` (:func:`mjxrmp.results.summary.
    write_study`): the records of ``records`` plus those already there for other
    (environment, policy) pairs; each environment's run keeps the command that produced it."""
    out_dir = Path(out_dir)
    old_runs, old = {}, []
    if (out_dir / "summary.json").exists():
        summary = load_summary(out_dir / "summary.json")
        old_runs, old = summary["runs"], summary.get("raw", [])
    new_keys = {(r["env"], r["policy"]) for r in records}
    kept = [r for r in old if (r["env"], r["policy"]) not in new_keys]
    run = run_record(command)
    runs = {**old_runs, **{r["env"]: run for r in records}}
    allr = sorted(kept + records, key=lambda r: (r["env"], r["policy"]))
    runs = {k: v for k, v in runs.items() if any(r["env"] == k for r in allr)}
    headline = [(r["env"], [f"{r['env']} {r['policy']}: success / safe % (MJX vs MuJoCo)",
                            f"{r['mjx']['success_pct']:.1f} / {r['mjx']['safe_pct']:.1f}",
                            f"{r['mujoco']['success_pct']:.1f} / {r['mujoco']['safe_pct']:.1f}"])
                for r in allr]
    return write_study(out_dir, HEAD, runs, headline,
                       (STUDY, COLUMNS, [table_row(r) for r in allr]), allr)


__all__ = ["COLUMNS", "STUDY", "UNSUPPORTED_KINDS", "check_manifest", "compare", "env_name_of",
           "evaluate_export", "mjx_episodes", "model_record", "sim2sim", "single_obs_policy",
           "table_row", "view", "write_results"]
