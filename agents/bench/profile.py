"""The control-step profile of the reaching environments (docs/reports/performance.md):
phase timings (:mod:`agents.bench.phases`), GPU kernels per control step from
``jax.profiler`` traces, and the joint-limit checks of dropping the constraint stages,
written as the ``performance`` study (``results/performance/summary.json``).

:func:`agents.bench.kernels.kernel_stats` runs a compiled phase under ``jax.profiler.trace``
and counts the kernels on the GPU's compute streams and their busy time; at a few hundred
environments a control step is bounded by kernel launches rather than arithmetic, so the kernel
count is the quantity to cut.
"""

from __future__ import annotations

import collections
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax

from agents.bench.kernels import kernel_stats
from agents.bench.phases import PPO_POLICY, PPO_SEEDS, limit_excursions, phase_programs, time_phase
from agents.run.loading import deterministic_policy, env_policy, load_run
from mjxrmp.results.summary import earlier_raw, run_record, slug, write_study

#: Phases whose kernels are counted (the rest are timed only).
TRACED = ("physics_as_is", "physics_contact_free", "env_step_raw", "env_step",
          "env_step_reset_always", "env_step_pooled", "ppo_rollout")


def limit_checks(env_name: str, episodes: int, horizon: int, key: jax.Array,
                 trained_run: str | None = None) -> dict[str, dict[str, Any]]:
    """The joint-limit check (:func:`agents.bench.phases.limit_excursions`) of the
    hand-designed policy and, with ``trained_run`` (a training run directory of this
    environment), of that run's first seed's deterministic policy at its newest checkpoint."""
    out: dict[str, dict[str, Any]] = {
        "hand_designed": limit_excursions(env_name, episodes, horizon, key)}
    if trained_run is not None:
        loaded = load_run(trained_run)
        if loaded.spec.env != env_name:
            raise ValueError(f"trained run {trained_run} trained on {loaded.spec.env!r}, "
                             f"not {env_name!r}")
        policy = env_policy(*deterministic_policy(loaded, 0))
        out["trained"] = {**limit_excursions(env_name, episodes, horizon, key, policy),
                          "run": f"{loaded.spec.policy}, {loaded.step} iterations, seed "
                                 f"{loaded.seeds[0]}"}
    return out


def profile_env(env_name: str, batch: int, steps: int, repeats: int, episodes: int,
                horizon: int, key: jax.Array, trained_run: str | None = None,
                phases: Sequence[str] | None = None) -> dict[str, Any]:
    """Phase timings, kernel counts and the joint-limit checks (:func:`limit_checks`) for one
    environment; ``phases``: only these phases (default None: every phase; a subset, which
    must hold the floor ``physics_contact_free``, is for quick checks)."""
    k_phase, k_limit = jax.random.split(key)
    programs = phase_programs(env_name, batch, steps, k_phase)
    if phases is not None:
        if not set(phases) <= set(programs) or "physics_contact_free" not in phases:
            raise ValueError(f"phases must be phases of {sorted(programs)} including "
                             f"physics_contact_free, got {list(phases)}")
        programs = {name: fn for name, fn in programs.items() if name in phases}
    timed = {name: time_phase(fn, steps, repeats) for name, fn in programs.items()}
    kernels = {name: kernel_stats(programs[name], steps) for name in TRACED if name in programs}
    limits = (limit_checks(env_name, episodes, horizon, k_limit, trained_run) if episodes
              else None)
    return {"batch": batch, "steps": steps, "repeats": repeats, "phases": timed,
            "kernels": kernels, "limits": limits}


def _ms(phases: dict, name: str) -> str:
    return f"{phases[name]['per_step_s'] * 1e3:.3f}" if name in phases else "—"


def _rows(env_name: str, r: dict[str, Any]) -> list[list[Any]]:
    """One table row per phase: environment, phase, ms per control step, ratio to the
    contact-free physics floor, kernels per step (— without a GPU)."""
    floor = r["phases"]["physics_contact_free"]["per_step_s"]
    rows = []
    for name, t in r["phases"].items():
        k = r["kernels"].get(name)
        rows.append([env_name, name, f"{t['per_step_s'] * 1e3:.3f}",
                     f"{t['per_step_s'] / floor:.2f}",
                     "—" if k is None else f"{k['kernels_per_step']:.0f}"])
    return rows


def _run_name(env_name: str, record: dict[str, Any]) -> str:
    """The study's name of one environment's measurement: ``profile_<env>_<device>``."""
    return "profile_" + slug(f"{env_name}_{record['device']}")


def write_profile(results: dict[str, dict[str, Any]], out_dir: Path) -> Path:
    """``out_dir/summary.json`` and ``table.csv`` of the ``performance`` study from the results
    of :func:`profile_env` by environment, each carrying its own run record (``record``:
    :func:`run_record`), so environments measured by different commands share one study."""
    rows = [row for env_name, r in results.items() for row in _rows(env_name, r)]
    headline = []
    for env_name, r in results.items():
        p, run = r["phases"], _run_name(env_name, r["record"])
        headline.append((run, [
            f"{env_name}, {r['batch']} environments: contact-free physics floor / physics as "
            "generated / environment step / training step (auto-reset: on a CPU computed where "
            "an episode ended, on a GPU at every step) / on a CPU with a reset at every step / "
            f"with reset pools / reset / PPO rollout ({PPO_POLICY}, {PPO_SEEDS} seeds; policy "
            "forward and sampling included), ms per control step",
            "—",
            " / ".join(_ms(p, n) for n in ("physics_contact_free", "physics_as_is",
                                           "env_step_raw", "env_step", "env_step_reset_always",
                                           "env_step_pooled", "reset", "ppo_rollout"))]))
        for who, lim in (r["limits"] or {}).items():
            policy = ("hand-designed policy" if who == "hand_designed"
                      else f"trained policy ({lim['run']})")
            headline.append((run, [
                f"{env_name}: {policy}, {lim['episodes']} episodes × {lim['steps']} steps, "
                "largest joint-limit excess with / without the constraint stages (rad); largest "
                "joint drift between the two, and between two runs with them (rad)",
                "—", f"{lim['max_excess_as_is']:.2g} / {lim['max_excess_contact_free']:.2g}; "
                     f"{lim['max_abs_dq']:.3g}, {lim['repeat_max_abs_dq']:.3g}"]))
    columns = ["environment", "phase", "ms per control step", "× floor", "kernels per step"]
    head = {"study": "performance", "title": "Control-step profile",
            "report": "docs/reports/performance.md"}
    runs = {_run_name(env_name, r["record"]): r["record"] for env_name, r in results.items()}
    return write_study(out_dir, head, runs, headline, ("phases", columns, rows), results)


def kept_profiles(out_dir: Path, env_names: Sequence[str]) -> dict[str, dict[str, Any]]:
    """The results of an existing ``performance`` study in ``out_dir`` for environments not in
    ``env_names`` (so a run replaces only its own environments' rows, and the others keep their
    own run records); empty without a study."""
    return {env_name: r for env_name, r in earlier_raw(out_dir, {}).items()
            if env_name not in env_names and "record" in r}


def run_profile(env_names: list[str], batch: int, steps: int, repeats: int, episodes: int,
                horizon: int, seed: int, out_dir: Path, command: str,
                trained_runs: dict[str, str] | None = None) -> Path:
    """Profile every environment of ``env_names`` (:func:`profile_env`; ``trained_runs`` maps an
    environment to a training run whose policy is limit-checked too), printing a line per
    environment, and write the study (:func:`write_profile`) after each environment, keeping
    the other environments of an earlier study in ``out_dir`` (:func:`kept_profiles`)."""
    trained_runs = trained_runs or {}
    unknown = sorted(set(trained_runs) - set(env_names))
    if unknown:
        raise ValueError(f"trained_runs names environments {unknown} that are not profiled "
                         f"({env_names})")
    record = run_record(command)
    key = jax.random.PRNGKey(seed)
    results = collections.OrderedDict(kept_profiles(out_dir, env_names))
    for i, env_name in enumerate(env_names):
        results[env_name] = {**profile_env(env_name, batch, steps, repeats, episodes, horizon,
                                           jax.random.fold_in(key, i),
                                           trained_runs.get(env_name)), "record": record}
        print(env_name, {k: _ms(results[env_name]["phases"], k)
                         for k in results[env_name]["phases"]}, flush=True)
        path = write_profile(dict(results), out_dir)  # a cut run keeps these
    return path


__all__ = ["TRACED", "kept_profiles", "limit_checks", "profile_env", "run_profile",
           "write_profile"]
