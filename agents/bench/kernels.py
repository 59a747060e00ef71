"""GPU kernels of a compiled program, read from a ``jax.profiler`` trace: how many kernels a
step launches, how long they keep the GPU busy, and (by kernel name) how much of that is matrix
products and reductions (docs/reports/performance.md).

:func:`kernel_stats` runs a compiled function once under ``jax.profiler.trace`` (with a Perfetto
trace) and reads the complete events on the GPU's stream threads. When the kernels' summed time
is close to the wall time of the steps they belong to, the GPU is busy and fewer launches do not
help; when it is far below, the steps wait on launches.
"""

from __future__ import annotations

import glob
import gzip
import json
import re
import tempfile
from typing import Any

import jax

#: Kernel kinds by name (XLA's GPU fusions are named after their root, e.g. ``gemm_fusion_dot``,
#: ``input_reduce_fusion``; library calls keep their library's names); the rest is ``other``.
KINDS = (("matrix products", re.compile(r"gemm|cublas|cutlass|matmul", re.IGNORECASE)),
         ("reductions", re.compile(r"reduce", re.IGNORECASE)))


def gpu_kernel_events(trace_path: str) -> list[dict[str, Any]]:
    """The complete (``"X"``) events on the stream threads of the GPU processes of a Perfetto
    ``trace.json.gz``: one per kernel or copy the GPU ran."""
    with gzip.open(trace_path) as f:
        events = json.load(f)
    events = events["traceEvents"] if isinstance(events, dict) else events
    procs, threads = {}, {}
    for e in events:
        if e.get("ph") == "M" and e.get("name") == "process_name":
            procs[e["pid"]] = e["args"]["name"]
        elif e.get("ph") == "M" and e.get("name") == "thread_name":
            threads[(e["pid"], e["tid"])] = e["args"]["name"]
    gpu = {p for p, name in procs.items() if "/device:GPU" in name}
    return [e for e in events if e.get("ph") == "X" and e.get("pid") in gpu
            and "Stream" in threads.get((e["pid"], e["tid"]), "")]


def kernel_kind(name: str) -> str:
    """The :data:`KINDS` entry a kernel name matches first, else ``"other"``."""
    return next((kind for kind, pattern in KINDS if pattern.search(name)), "other")


def summarise(kernels: list[dict[str, Any]], steps: int) -> dict[str, Any]:
    """Per step of ``steps``: kernels, their summed (busy) µs, the µs from the first kernel's
    start to the last one's end (span), and kernels and busy µs by :func:`kernel_kind`."""
    by_kind: dict[str, list[float]] = {kind: [0, 0.0] for kind, _ in KINDS} | {"other": [0, 0.0]}
    for e in kernels:
        entry = by_kind[kernel_kind(e.get("name", ""))]
        entry[0] += 1
        entry[1] += e.get("dur", 0.0)
    span = (max(e["ts"] + e.get("dur", 0.0) for e in kernels) - min(e["ts"] for e in kernels)
            if kernels else 0.0)
    return {"kernels_per_step": len(kernels) / steps,
            "busy_us_per_step": float(sum(e.get("dur", 0.0) for e in kernels)) / steps,
            "span_us_per_step": float(span) / steps,
            "by_kind": {kind: {"kernels_per_step": n / steps, "busy_us_per_step": us / steps}
                        for kind, (n, us) in by_kind.items()}}


def kernel_stats(fn: Any, steps: int) -> dict[str, Any] | None:
    """:func:`summarise` of the GPU kernels of one call of ``fn()`` (``steps`` steps, already
    compiled and run once), from a ``jax.profiler`` trace; None on a machine without a GPU."""
    if jax.devices()[0].platform != "gpu":
        return None
    with tempfile.TemporaryDirectory() as d:
        with jax.profiler.trace(d, create_perfetto_trace=True):
            jax.block_until_ready(fn())
        traces = glob.glob(f"{d}/**/*.trace.json.gz", recursive=True)
        if not traces:
            raise RuntimeError(f"jax.profiler wrote no Perfetto trace under {d}")
        return summarise(gpu_kernel_events(traces[0]), steps)


__all__ = ["KINDS", "gpu_kernel_events", "kernel_kind", "kernel_stats", "summarise"]
