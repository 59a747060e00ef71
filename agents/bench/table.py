"""What the benchmark reports: the device it ran on, the row table, and per robot (and per
environment) the best throughput, the single-state latency and the RMP²/naive ratio."""

from __future__ import annotations

import math
import os
import platform
import re

import jax
import jax.numpy as jnp
import jaxlib


def device_info() -> dict:
    """Platform, device kind and count, versions, dtype, matmul precision, host CPUs, XLA flags
    and dispatch/affinity settings of this process."""
    dev = jax.devices()[0]
    return {
        "platform": dev.platform,
        "device_kind": dev.device_kind,
        "device_count": jax.device_count(),
        "jax": jax.__version__,
        "jaxlib": jaxlib.__version__,
        "dtype": str(jnp.zeros(()).dtype),
        "matmul_precision": jax.config.jax_default_matmul_precision or "default",
        "python": platform.python_version(),
        "host_cpus": os.cpu_count(),
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
        "cpu_async_dispatch": bool(jax.config.values["jax_cpu_enable_async_dispatch"]),
        "cpu_affinity": sorted(os.sched_getaffinity(0)),
    }


def device_slug(info: dict) -> str:
    """``cpu`` or the device kind in lower-case alphanumerics and ``_`` (file names)."""
    name = "cpu" if info["platform"] == "cpu" else info["device_kind"]
    return re.sub(r"[^a-z0-9]+", "_", name.lower()).strip("_")


def fmt_rate(x: float | None) -> str:
    """``2.31e7/s`` style (``-`` for a missing or non-positive rate)."""
    if x is None or not math.isfinite(x) or x <= 0:
        return "-"
    mantissa, exponent = f"{x:.2e}".split("e")
    return f"{mantissa}e{int(exponent)}/s"


def fmt_time(s: float | None) -> str:
    """Seconds as µs, ms or s with 3–4 significant digits."""
    if s is None or not math.isfinite(s):
        return "-"
    if s < 1e-3:
        return f"{s * 1e6:.1f} µs"
    if s < 1.0:
        return f"{s * 1e3:.2f} ms"
    return f"{s:.2f} s"


def format_table(rows: list[dict]) -> str:
    """The screen table: robot, implementation, mode, batch, evaluations/s, time per call,
    compile time, calls × repeats (errors shown in place)."""
    headers = ("robot", "impl", "mode", "batch", "evals/s", "time/call", "compile", "calls×reps")
    lines = []
    for r in rows:
        if r.get("error"):
            cells = (r["robot"], r["impl"], r["mode"], str(r["batch"]), "ERROR", "-", "-",
                     r["error"][:40])
        else:
            cells = (
                r["robot"], r["impl"], r["mode"], str(r["batch"]), fmt_rate(r["evals_per_s"]),
                fmt_time(r["time_per_call_s"]), fmt_time(r["compile_s"]),
                f"{r['calls_per_repeat']}×{r['repeats']}",
            )
        lines.append(cells)
    widths = [max(len(h), *(len(c[i]) for c in lines)) for i, h in enumerate(headers)]
    right = {3, 4, 5, 6, 7}

    def line(cells):
        return "  ".join(c.rjust(w) if i in right else c.ljust(w)
                         for i, (c, w) in enumerate(zip(cells, widths, strict=True)))

    out = [line(headers), line(tuple("-" * w for w in widths))]
    out += [line(c) for c in lines]
    return "\n".join(out)


def _env_summary(rows: list[dict], summary: dict) -> None:
    """Per environment and policy: the best control steps/s and its batch."""
    for r in rows:
        if r["mode"] == "env" and not r.get("error"):
            s = summary.setdefault(f"env {r['robot']}", {})
            name = f"{r['impl']}_best_steps_per_s"
            if r["evals_per_s"] > s.get(name, 0.0):
                s[name] = r["evals_per_s"]
                s[f"{r['impl']}_best_env_batch"] = r["batch"]


def _robot_summary(ok: list[dict]) -> dict:
    """Latency, best batch and RMP²/naive ratio at the largest batch both ran, for one robot's
    successful rows."""
    rmp2 = {r["batch"]: r for r in ok if r["impl"] == "rmp2" and r["mode"] == "batched"}
    nv = {r["batch"]: r for r in ok if r["impl"] == "naive" and r["mode"] == "batched"}
    s: dict = {}
    for impl in ("rmp2", "naive"):
        lat = [r for r in ok if r["impl"] == impl and r["mode"] == "single"]
        if lat:
            s[f"{impl}_latency_us"] = lat[0]["time_per_call_s"] * 1e6
    if rmp2:
        best = max(rmp2.values(), key=lambda r: r["evals_per_s"])
        s["rmp2_best_batch"] = best["batch"]
        s["rmp2_best_evals_per_s"] = best["evals_per_s"]
    common = sorted(set(rmp2) & set(nv))
    if common:
        b = common[-1]
        s["ratio_batch"] = b
        s["rmp2_over_naive"] = rmp2[b]["evals_per_s"] / nv[b]["evals_per_s"]
    return s


def summarise(rows: list[dict]) -> dict:
    """Per robot: latency, best batch, naive ratio at the largest batch both impls ran; per
    environment and policy: the best control steps/s."""
    summary: dict = {}
    _env_summary(rows, summary)
    for robot in dict.fromkeys(r["robot"] for r in rows if r["mode"] != "env"):
        summary[robot] = _robot_summary([r for r in rows if r["robot"] == robot
                                         and not r.get("error") and r["mode"] != "env"])
    return summary


def format_summary(summary: dict) -> str:
    """One line per robot or environment of :func:`summarise`'s numbers."""
    lines = []
    for robot, s in summary.items():
        parts = []
        for impl in ("random", "rmp2"):
            if f"{impl}_best_steps_per_s" in s:
                parts.append(f"{impl} actions: best {fmt_rate(s[f'{impl}_best_steps_per_s'])} "
                             f"control steps (batch {s[f'{impl}_best_env_batch']})")
        if "rmp2_best_batch" in s:
            parts.append(f"best RMP² batch {s['rmp2_best_batch']} "
                         f"({fmt_rate(s['rmp2_best_evals_per_s'])})")
        if "rmp2_latency_us" in s:
            parts.append(f"single-state latency {s['rmp2_latency_us']:.1f} µs")
        if "rmp2_over_naive" in s:
            parts.append(f"RMP²/naive at batch {s['ratio_batch']} = {s['rmp2_over_naive']:.1f}×")
        lines.append(f"{robot}: " + "; ".join(parts))
    return "\n".join(lines)


__all__ = ["device_info", "device_slug", "fmt_rate", "fmt_time", "format_summary",
           "format_table", "summarise"]
