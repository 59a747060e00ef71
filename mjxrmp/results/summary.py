"""A study's ``summary.json``: the machine-written record behind every published table.

Schema (checked by :func:`validate_summary`; docs/design.md §6)::

    {
      "study": "ppo",                      # the folder name under results/
      "title": "PPO training",             # the BENCHMARKS.md section heading
      "report": "docs/reports/ppo.md",     # the reader's report for this study
      "runs": {"<run>": {"command": str, "device": str, "versions": {pkg: ver},
                         "date": "YYYY-MM-DD", "xla_flags": str}},   # xla_flags: optional
      "headline": {"columns": [str, ...], "rows": [{"run": "<run>", "cells": [...]}]},
      "tables": {"<name>": {"columns": [str, ...], "rows": [[...], ...]}},
      "deviations": [str, ...],            # differences from the thesis, one sentence each
      "figures": [str, ...]                # optional, files beside summary.json
    }
"""

from __future__ import annotations

import datetime
import json
import os
import platform
from collections.abc import Sequence
from importlib import metadata
from pathlib import Path
from typing import Any

from mjxrmp._xla import SCRIPT_FLAGS
from mjxrmp.atomic import atomic_write

REQUIRED = ("study", "title", "report", "runs", "headline", "deviations")
RUN_FIELDS = ("command", "device", "versions", "date")
PACKAGES = ("jax", "jaxlib", "mujoco", "mujoco-mjx", "brax", "flax", "optax", "numpy")


class SummaryError(ValueError):
    """A ``summary.json`` that does not follow the schema; the message names the file and field."""


def _need(cond: bool, where: str, what: str) -> None:
    if not cond:
        raise SummaryError(f"{where}: {what}")


def _check_table(table: Any, where: str, keyed_rows: bool) -> None:
    _need(isinstance(table, dict), where, "expected an object with 'columns' and 'rows'")
    cols = table.get("columns")
    _need(isinstance(cols, list) and len(cols) > 0, where, "'columns' must be a non-empty list")
    rows = table.get("rows")
    _need(isinstance(rows, list) and len(rows) > 0, where, "'rows' must be a non-empty list")
    for i, row in enumerate(rows):
        cells = row.get("cells") if keyed_rows and isinstance(row, dict) else row
        _need(isinstance(cells, list), f"{where}.rows[{i}]", "expected a list of cells")
        _need(len(cells) == len(cols), f"{where}.rows[{i}]",
              f"has {len(cells)} cells, expected {len(cols)} (one per column)")


def validate_summary(data: Any, where: str = "summary.json") -> dict:
    """Check ``data`` against the schema above and return it; raise :class:`SummaryError`."""
    _need(isinstance(data, dict), where, "expected a JSON object")
    for key in REQUIRED:
        _need(key in data, where, f"missing field {key!r}")
    runs = data["runs"]
    _need(isinstance(runs, dict) and runs, where, "'runs' must be a non-empty object")
    for name, run in runs.items():
        for field in RUN_FIELDS:
            _need(isinstance(run, dict) and field in run, f"{where}.runs.{name}",
                  f"missing field {field!r}")
        try:
            datetime.date.fromisoformat(run["date"])
        except (TypeError, ValueError):
            raise SummaryError(f"{where}.runs.{name}.date: expected YYYY-MM-DD, "
                               f"got {run['date']!r}") from None
    _check_table(data["headline"], f"{where}.headline", keyed_rows=True)
    for i, row in enumerate(data["headline"]["rows"]):
        _need(row.get("run") in runs, f"{where}.headline.rows[{i}].run",
              f"{row.get('run')!r} is not one of the runs {sorted(runs)}")
    for name, table in data.get("tables", {}).items():
        _check_table(table, f"{where}.tables.{name}", keyed_rows=False)
    _need(isinstance(data["deviations"], list), f"{where}.deviations", "expected a list")
    return data


def load_summary(path: str | os.PathLike) -> dict:
    """Read and validate one ``summary.json``."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise SummaryError(f"{path}: not valid JSON ({err})") from None
    return validate_summary(data, str(path))


def earlier_raw(out_dir: str | os.PathLike, default: Any) -> Any:
    """The ``raw`` measurements of the study already in ``out_dir`` (validated), or ``default``
    where there is none: what a run that replaces only its own rows starts from."""
    path = Path(out_dir) / "summary.json"
    return load_summary(path)["raw"] if path.exists() else default


def slug(text: str) -> str:
    """``text`` in lower case with every character but letters and digits replaced by ``_``:
    run names and file names built from environments and device kinds."""
    return "".join(c if c.isalnum() else "_" for c in text.lower())


def cpu_name() -> str:
    """``CPU (<cores>-core <model>)``: the model from ``/proc/cpuinfo`` where there is one
    (``platform.processor()`` is empty on many Linux machines), else from ``platform``."""
    model = platform.processor()
    try:
        with open("/proc/cpuinfo") as f:
            names = [line.split(":", 1)[1].strip() for line in f if line.startswith("model name")]
        model = names[0] if names else model
    except OSError:
        pass
    return f"CPU ({os.cpu_count()}-core {model or platform.machine()})"


def package_versions(packages: Sequence[str] = PACKAGES) -> dict[str, str]:
    """The installed version of each of ``packages`` (those not installed are left out)."""
    versions = {}
    for pkg in packages:
        try:
            versions[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            continue
    return versions


def run_record(command: str, device: str | None = None) -> dict:
    """The ``runs`` entry for a run made now: command, device, package versions, date and every
    XLA flag in force (``xla_flags``). XLA flags set by the user (not the flags every script
    sets itself, :data:`mjxrmp._xla.SCRIPT_FLAGS`: docs/design.md §5.2, §5.11) change what is
    measured, so the command records them too."""
    in_force = os.environ.get("XLA_FLAGS", "").split()
    flags = " ".join(f for f in in_force if f not in SCRIPT_FLAGS)
    if flags and not command.startswith("XLA_FLAGS="):
        command = f'XLA_FLAGS="{flags}" {command}'
    if device is None:
        import jax  # lazy: only a run that reports its own device needs JAX initialised

        dev = jax.devices()[0]
        device = dev.device_kind if dev.platform != "cpu" else cpu_name()
    return {"command": command, "device": device, "versions": package_versions(),
            "date": datetime.date.today().isoformat(), "xla_flags": " ".join(in_force)}


def write_summary(path: str | os.PathLike, data: dict) -> Path:
    """Validate ``data`` and write it to ``path`` as indented JSON (:func:`write_text`)."""
    validate_summary(data, str(path))
    return write_text(path, json.dumps(data, indent=1, ensure_ascii=False) + "\n")


def write_study(out_dir: str | os.PathLike, head: dict[str, str], runs: dict[str, dict],
                headline: list[tuple[str, list[str]]],
                table: tuple[str, list[str], list[list[Any]]], raw: Any) -> Path:
    """A study written as ``out_dir/summary.json`` and ``table.csv``: ``head`` holds ``study``,
    ``title`` and ``report``; ``runs`` the record of each run (:func:`run_record`) by name;
    ``headline`` its rows as ``(run, cells)`` with cells (quantity, thesis or peer figure,
    ours); ``table`` is ``(name, columns, rows)``, also written as the CSV; ``raw`` the
    measurements as measured."""
    name, columns, rows = table
    summary = {**head, "runs": runs,
               "headline": {"columns": ["quantity", "thesis or peer figure", "ours"],
                            "rows": [{"run": run, "cells": cells} for run, cells in headline]},
               "tables": {name: {"columns": columns, "rows": rows}},
               "deviations": [], "raw": raw}
    csv = "\n".join(",".join(str(c) for c in row) for row in [columns, *rows]) + "\n"
    write_text(Path(out_dir) / "table.csv", csv)
    return write_summary(Path(out_dir) / "summary.json", summary)


def write_text(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` to ``path`` atomically (:func:`mjxrmp.atomic.atomic_write`), creating its
    folder, and verify it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, text.encode())
    if path.read_text() != text:
        raise OSError(f"{path}: the written file differs from what was written")
    return path
