"""End-to-end training time, measured the way a user meets it: ``scripts/train.py`` run as a
fresh process and timed from launch to exit (imports, compile, training, checkpoints), and the
time a repeated short command takes to reach and finish its first iteration with JAX's
persistent compilation cache cold and then warm, and a resumed one (docs/design.md §5.6).
Written as the ``training_speed`` study (``results/training_speed/summary.json``)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from mjxrmp._xla import child_cache_environ
from mjxrmp.config import check_int
from mjxrmp.results.summary import earlier_raw, run_record, slug, write_study

ROOT = Path(__file__).resolve().parents[2]
#: The line :func:`agents.run.training.result_summary` prints about time.
_TIMES = re.compile(r"compile ([\d.]+) s, training ([\d.]+) s, ([\d.e+]+) env steps/s")


def timed_train(args: list[str], cache_dir: str, out_dir: str | None = None
                ) -> dict[str, Any]:
    """Run ``scripts/train.py ARGS --no-progress`` in a fresh process with the compile cache in
    ``cache_dir`` and no other (:func:`mjxrmp._xla.child_cache_environ`): ``wall_s`` from launch
    to exit, ``first_chunk_s`` from launch to the first write of ``out_dir/metrics.csv`` when
    ``out_dir`` (the run's ``--out``) is given and the run trains one chunk (the file is
    rewritten after every chunk), and, from its summary line, ``compile_s``, ``train_s`` and
    ``steps_per_s``. A failing command raises ``RuntimeError`` with its last output lines."""
    env = child_cache_environ(cache_dir)
    cmd = [sys.executable, str(ROOT / "scripts" / "train.py"), *args, "--no-progress"]
    launched = time.time()
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        tail = "\n".join((proc.stdout + proc.stderr).splitlines()[-8:])
        raise RuntimeError(f"train.py {' '.join(args)} exited {proc.returncode}:\n{tail}")
    m = _TIMES.search(proc.stderr)
    if m is None:
        raise RuntimeError(f"train.py {' '.join(args)} printed no timing line")
    out = {"wall_s": wall, "compile_s": float(m[1]), "train_s": float(m[2]),
           "steps_per_s": float(m[3])}
    if out_dir is not None:
        out["first_chunk_s"] = os.path.getmtime(os.path.join(out_dir, "metrics.csv")) - launched
    return out


def measure_training_speed(env: str, policy: str, seeds: list[int], iterations: int,
                           preset: str, work_dir: Path, first: bool = True, full: bool = True,
                           warm_runs: int = 1) -> dict[str, Any]:
    """With ``full``, ``full``: the whole run (``iterations``, chunks of 25, checkpoints every
    50) with a fresh compile cache (else None); with ``first``, ``first_cold`` /
    ``first_warm``: the same settings for one iteration (chunks of one, a new run directory
    each), first with a cache that holds no one-iteration program, then repeated with it
    ``warm_runs`` times (``first_warm`` the run of median ``first_chunk_s``, all of them in
    ``first_warm_runs``), and ``resumed``: the median of ``warm_runs`` resumes
    (:func:`_timed_resumes`; all of them in ``resumed_runs``) (else None). ``full=False``
    measures only the repeated command (its cold run fills the cache)."""
    if not (first or full):
        raise ValueError("measure_training_speed needs first=True or full=True (nothing to time)")
    check_int(warm_runs, "warm_runs")
    base = ["--env", env, "--policy", policy, "--preset", preset,
            "--seeds", *map(str, seeds)]
    work_dir.mkdir(parents=True, exist_ok=True)
    full_t = first_cold = None
    warm: list[dict[str, Any]] = []
    resumes: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(dir=work_dir) as tmp:
        cache = os.path.join(tmp, "cache")
        if full:
            full_t = timed_train([*base, "--iterations", str(iterations), "--log-every", "25",
                                  "--checkpoint-every", "50", "--out", f"{tmp}/full"], cache)
        one = [*base, "--iterations", "1", "--log-every", "1", "--checkpoint-every", "1"]
        if first:
            first_cold = timed_train([*one, "--out", f"{tmp}/first_cold"], cache,
                                     f"{tmp}/first_cold")
            warm = [timed_train([*one, "--out", f"{tmp}/warm{i}"], cache, f"{tmp}/warm{i}")
                    for i in range(warm_runs)]
            resumes = _timed_resumes(base, cache, tmp, warm_runs)
    return {"env": env, "policy": policy, "seeds": list(seeds), "iterations": iterations,
            "preset": preset, "full": full_t, "first_cold": first_cold,
            "first_warm": _median(warm), "resumed": _median(resumes),
            **({"first_warm_runs": warm, "resumed_runs": resumes} if len(warm) > 1 else {})}


def _median(runs: list[dict[str, Any]]) -> dict[str, Any] | None:
    """The run of median ``first_chunk_s`` (the lower one of an even count), None if none."""
    ordered = sorted(runs, key=lambda t: t["first_chunk_s"])
    return ordered[(len(ordered) - 1) // 2] if ordered else None


def _timed_resumes(base: list[str], cache: str, tmp: str, runs: int) -> list[dict[str, Any]]:
    """:func:`timed_train` of ``runs`` resumed commands with the warm cache: a run of two
    iterations (chunks and checkpoints of one) loses its last checkpoint and the same command
    continues it with ``--resume`` (``first_chunk_s``: launch to its one remaining iteration
    done), as often as asked (each resume rewrites the checkpoint the next one loses)."""
    two = [*base, "--iterations", "2", "--log-every", "1", "--checkpoint-every", "1",
           "--keep-checkpoints", "0", "--out", f"{tmp}/resumed"]
    timed_train(two, cache)
    out = []
    for _ in range(runs):
        shutil.rmtree(os.path.join(tmp, "resumed", "checkpoints", "2"))
        out.append(timed_train([*two, "--resume"], cache, f"{tmp}/resumed"))
    return out


def _row(r: dict[str, Any]) -> list[str]:
    f = r["full"]
    whole = ["—"] * 5 if f is None else [
        f"{f['wall_s']:.0f}", f"{f['compile_s']:.1f}", f"{f['train_s']:.0f}",
        f"{f['train_s'] / r['iterations']:.3f}", f"{f['steps_per_s']:.3g}"]
    return [r["env"], r["policy"], str(len(r["seeds"])), str(r["iterations"]), *whole,
            _wall(r["first_cold"]), _wall(r["first_warm"]), _first(r["first_warm"]),
            _first(r.get("resumed"))]


def _wall(t: dict[str, Any] | None) -> str:
    return "—" if t is None else f"{t['wall_s']:.1f}"


def _first(t: dict[str, Any] | None) -> str:
    """Launch to the end of the first iteration, where measured (older runs lack it)."""
    return f"{t['first_chunk_s']:.1f}" if t and "first_chunk_s" in t else "—"


COLUMNS = ["environment", "policy", "seeds", "iterations", "end to end (s)", "compile (s)",
           "training (s)", "s per iteration", "env steps/s",
           "one-iteration command, cold cache (s)", "the same, warm cache (s)",
           "launch to first iteration done, warm cache (s)",
           "resumed command, launch to first iteration done (s)"]


def write_training_speed(results: list[dict[str, Any]], out_dir: Path) -> Path:
    """``out_dir/summary.json`` and ``table.csv`` of the ``training_speed`` study; each result
    carries its own run record (``run``, ``record``: :func:`run_record`)."""
    headline = []
    for r in results:
        f, n = r["full"], len(r["seeds"])
        if f is not None:
            headline.append((r["run"], [
                f"{r['env']} {r['policy']}, {r['preset']} preset, {n} seed{'s' * (n != 1)} × "
                f"{r['iterations']} iterations: end to end from launch (compile, training)",
                "—", f"{f['wall_s']:.0f} s ({f['compile_s']:.0f} s, {f['train_s']:.0f} s)"]))
        if r["first_cold"] is not None:
            headline.append((r["run"], [
                f"{r['env']} {r['policy']}: a repeated one-iteration command, launch to exit "
                "with the compile cache cold / warm (launch to its first iteration done, warm)",
                "—", f"{_wall(r['first_cold'])} s / {_wall(r['first_warm'])} s "
                     f"({_first(r['first_warm'])} s)"]))
        if r.get("resumed") is not None:
            headline.append((r["run"], [
                f"{r['env']} {r['policy']}: a resumed command (same settings, warm cache), "
                "launch to its first iteration done", "—", f"{_first(r['resumed'])} s"]))
    head = {"study": "training_speed", "title": "Training end to end",
            "report": "docs/reports/training_speed.md"}
    return write_study(out_dir, head, {r["run"]: r["record"] for r in results}, headline,
                       ("runs", COLUMNS, [_row(r) for r in results]), results)


def _kept(out_dir: Path, device: str, items: list[tuple[str, str]]) -> list[dict[str, Any]]:
    """The results of an existing study in ``out_dir`` except those of the pairs in ``items``
    measured on ``device`` (so a run replaces only its own rows; other devices' rows stay, each
    with its own run record)."""
    return [r for r in earlier_raw(out_dir, []) if "record" in r
            and not (r["record"]["device"] == device and (r["env"], r["policy"]) in items)]


def run_training_speed(items: list[tuple[str, str]], seeds: list[int], iterations: int,
                       preset: str, work_dir: Path, out_dir: Path, command: str,
                       first: bool = True, full: bool = True, warm_runs: int = 1) -> Path:
    """Measure every ``(env, policy)`` of ``items`` (:func:`measure_training_speed`; ``first``,
    ``full`` and ``warm_runs`` choose the measurements), printing a line each and writing the
    study after each (a cut run keeps what it measured). Earlier rows are kept except those of
    the same pairs on the same device."""
    record = run_record(command)
    results = _kept(out_dir, record["device"], items)
    path = out_dir / "summary.json"
    for env, policy in items:
        r = measure_training_speed(env, policy, seeds, iterations, preset, work_dir, first,
                                   full, warm_runs)
        results.append({**r, "run": slug(f"{env}_{policy}_{record['device']}"), "record": record})
        print(" | ".join(_row(r)), flush=True)
        path = write_training_speed(results, out_dir)
    return path


__all__ = ["COLUMNS", "measure_training_speed", "run_training_speed", "timed_train",
           "write_training_speed"]
