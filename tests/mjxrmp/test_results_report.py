"""mjxrmp.results: the summary.json schema, atomic writes and the generated benchmark tables."""

from __future__ import annotations

import json

import pytest

from mjxrmp._xla import CPU_FLAG, GPU_FLAG
from mjxrmp.results.report import fill_report, headline_table, render_all, render_table, stale_files
from mjxrmp.results.summary import (
    SummaryError,
    cpu_name,
    load_summary,
    run_record,
    validate_summary,
    write_summary,
)


def _summary(study: str = "demo") -> dict:
    return {
        "study": study,
        "title": "Demo study",
        "report": f"docs/reports/{study}.md",
        "runs": {"gpu": {"command": "python scripts/x.py --n 2", "device": "H100",
                         "versions": {"jax": "0.11.2"}, "date": "2026-11-22"}},
        "headline": {"columns": ["quantity", "thesis", "ours"],
                     "rows": [{"run": "gpu", "cells": ["reward", 0.5, 0.61234]}]},
        "tables": {"detail": {"columns": ["a", "b"], "rows": [[1, "x|y"]]}},
        "deviations": ["fewer seeds than the thesis"],
    }


def _repo(tmp_path, summary: dict, report_text: str):
    (tmp_path / "results" / summary["study"]).mkdir(parents=True)
    write_summary(tmp_path / "results" / summary["study"] / "summary.json", summary)
    (tmp_path / "docs" / "reports").mkdir(parents=True)
    (tmp_path / "docs" / "reports" / f"{summary['study']}.md").write_text(report_text)
    return tmp_path


def test_render_table_by_hand():
    text = render_table(["a", "b"], [[1, "x|y"], [0.123456, "z"]])
    assert text == "| a | b |\n|---|---|\n| 1 | x\\|y |\n| 0.1235 | z |\n"


def test_headline_rows_carry_their_runs_device_date_and_command():
    line = headline_table(_summary()).splitlines()[2]
    assert line == "| reward | 0.5 | 0.6123 | H100 | 2026-11-22 | `python scripts/x.py --n 2` |"


@pytest.mark.parametrize("broken, field", [
    (lambda s: s.pop("runs"), "missing field 'runs'"),
    (lambda s: s["runs"]["gpu"].pop("device"), "runs.gpu"),
    (lambda s: s["runs"]["gpu"].update(date="22/11/2026"), "expected YYYY-MM-DD"),
    (lambda s: s["headline"]["rows"][0].update(run="cpu"), "is not one of the runs"),
    (lambda s: s["headline"]["rows"][0]["cells"].pop(), "expected 3 (one per column)"),
    (lambda s: s["tables"]["detail"]["rows"].append([1]), "tables.detail.rows[1]"),
])
def test_schema_errors_name_the_field(broken, field):
    summary = _summary()
    broken(summary)
    with pytest.raises(SummaryError, match=field.replace("(", r"\(").replace(")", r"\)")
                       .replace("[", r"\[").replace("]", r"\]")):
        validate_summary(summary)


def test_write_summary_is_atomic_and_round_trips(tmp_path):
    path = write_summary(tmp_path / "s" / "summary.json", _summary())
    assert load_summary(path) == _summary()
    assert [p.name for p in path.parent.iterdir()] == ["summary.json"]
    with pytest.raises(SummaryError):
        write_summary(tmp_path / "bad.json", {"study": "x"})
    assert not (tmp_path / "bad.json").exists()


def test_load_summary_names_a_file_that_is_not_json(tmp_path):
    path = tmp_path / "summary.json"
    path.write_text("{not json")
    with pytest.raises(SummaryError, match="not valid JSON"):
        load_summary(path)


def test_run_record_has_versions_an_iso_date_and_the_xla_flags():
    record = run_record("python scripts/x.py", device="CPU")
    assert set(record) == {"command", "device", "versions", "date", "xla_flags"}
    assert "jax" in record["versions"]
    validate_summary({**_summary(), "runs": {"gpu": record}})


def test_cpu_runs_name_the_processor():
    """A CPU run's device names the cores and a model (never an empty ``CPU ()``)."""
    name = cpu_name()
    assert name.startswith("CPU (") and "-core " in name and not name.endswith("-core )")


def test_run_record_keeps_the_users_xla_flags(monkeypatch):
    """XLA flags change what a benchmark measures: the recorded command carries the user's,
    not the CPU and GPU flags every script sets itself."""
    monkeypatch.setenv("XLA_FLAGS", f"{CPU_FLAG} {GPU_FLAG}")
    record = run_record("python scripts/x.py", device="CPU")
    assert record["command"] == "python scripts/x.py"
    assert record["xla_flags"] == f"{CPU_FLAG} {GPU_FLAG}"  # what was in force, all of it
    monkeypatch.setenv("XLA_FLAGS", f"--xla_gpu_enable_command_buffer=FUSION {CPU_FLAG} {GPU_FLAG}")
    assert run_record("python scripts/x.py", device="CPU")["command"] == (
        'XLA_FLAGS="--xla_gpu_enable_command_buffer=FUSION" python scripts/x.py')


def test_report_blocks_are_rendered_and_checked(tmp_path):
    text = "# Demo\n\n<!-- table: demo/detail -->\nstale\n<!-- end table -->\n\nprose\n"
    root = _repo(tmp_path, _summary(), text)
    rendered = render_all(root)
    report = rendered[root / "docs/reports/demo.md"]
    assert report == ("# Demo\n\n<!-- table: demo/detail -->\n| a | b |\n|---|---|\n"
                      "| 1 | x\\|y |\n<!-- end table -->\n\nprose\n")
    assert "## Demo study" in rendered[root / "BENCHMARKS.md"]
    assert set(stale_files(rendered)) == {root / "BENCHMARKS.md", root / "docs/reports/demo.md"}
    for path, body in rendered.items():
        path.write_text(body)
    assert stale_files(render_all(root)) == []


def test_unknown_table_and_wrong_folder_are_refused(tmp_path):
    with pytest.raises(SummaryError, match="has no table 'missing'"):
        fill_report("<!-- table: demo/missing -->\n<!-- end table -->", {"demo": _summary()})
    root = _repo(tmp_path, _summary(), "")
    data = json.loads((root / "results/demo/summary.json").read_text())
    data["study"] = "other"
    (root / "results/demo/summary.json").write_text(json.dumps(data))
    with pytest.raises(SummaryError, match="differs from its folder"):
        render_all(root)
