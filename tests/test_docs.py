"""The documentation: the API reference builds without a pdoc warning, and docs/design.md
stays in step with the code (its numbered sections exist, its equation-to-code references resolve).

The documented API-reference command (README, docs/design.md §6) is

    MUJOCO_GL=disable pdoc -o build/api mjxrmp envs agents offline

This test builds the same reference into a temporary folder with :func:`pdoc.pdoc` and fails on
any warning pdoc emits, with one exception: pdoc cannot resolve postponed annotations
(``from __future__ import annotations``) of a ``typing.NamedTuple``'s generated constructor, whose
globals are not the defining module's. That is a limitation of pdoc itself, not of a docstring, so
those warnings are accepted only when the named object really is a NamedTuple constructor.
"""

import importlib
import os
import pkgutil
import re
import warnings
from pathlib import Path

import pdoc
import pytest
from pdoc import extract

ROOT = Path(__file__).resolve().parents[1]
DESIGN = ROOT / "docs" / "design.md"
PACKAGES = ("mjxrmp", "envs", "agents", "offline")
#: The numbered sections that code and docs cite as ``docs/design.md §N``.
SECTIONS = ("1", "2", "2.1", "2.2", "2.3", "2.4", "2.5", "3", "4", "4.1", "4.2", "4.3", "4.4",
            "4.5", "4.6", "5", "5.1", "5.2", "5.3", "5.4", "5.5", "5.6", "5.7", "5.8", "5.9",
            "5.10", "5.11", "6")
#: ``module:attribute`` references in docs/design.md, e.g. ``mjxrmp.core.rmp2:pullback``.
REFERENCE = re.compile(r"`((?:mjxrmp|envs|agents|offline)(?:\.\w+)*):(\w+(?:\.\w+)*)`")
#: A citation ``docs/design.md §4.5`` (also the later items of ``§4.2, §4.6``).
CITATION = re.compile(r"docs/design\.md ((?:§[\d.]*\d(?:, )?)+)")
#: pdoc's warning for an annotation it cannot resolve in a constructor signature.
NAMEDTUPLE_INIT = re.compile(
    r"^Error parsing type annotation ForwardRef\(.*\) for ([\w.]+)\.__init__\."
)


def _resolve(dotted: str) -> object | None:
    """The object called ``dotted`` (module path, then attributes), or None."""
    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        for name in parts[i:]:
            obj = getattr(obj, name, None)
        return obj
    return None


def _is_namedtuple_constructor_warning(message: str) -> bool:
    """Whether ``message`` is pdoc's unresolved-annotation warning for a NamedTuple constructor."""
    match = NAMEDTUPLE_INIT.match(message)
    if match is None:
        return False
    cls = _resolve(match.group(1))
    return isinstance(cls, type) and issubclass(cls, tuple) and hasattr(cls, "_fields")


def _all_modules() -> list[str]:
    """Every public module and package under :data:`PACKAGES`, parents before children."""
    names = set(PACKAGES)
    for package in PACKAGES:
        path = importlib.import_module(package).__path__
        names.update(info.name for info in pkgutil.walk_packages(path, f"{package}.")
                     if not any(part.startswith("_") for part in info.name.split(".")))
    return sorted(names)


def _pdoc_specs(modules: list[str]) -> list[str]:
    """The fewest module specs that make pdoc document every one of ``modules`` exactly once.

    pdoc recurses into a package but skips the submodules its ``__all__`` does not list, and
    warns about a module that two specs add; so a module gets its own spec only when no
    earlier spec reached it.
    """
    specs: list[str] = []
    covered: set[str] = set()
    for name in modules:
        if name not in covered:
            specs.append(name)
            covered.update(extract.walk_specs([name]))
    return specs


def test_api_reference_builds_without_warnings(tmp_path: Path, capfd, monkeypatch) -> None:
    monkeypatch.setenv("MUJOCO_GL", "disable")  # no OpenGL probe when pdoc imports MuJoCo
    modules = _all_modules()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        pdoc.pdoc(*_pdoc_specs(modules), output_directory=tmp_path)
    pdoc_warnings = [
        str(w.message) for w in caught if "pdoc" in w.filename.replace(os.sep, "/").split("/")
    ]
    problems = [m for m in pdoc_warnings if not _is_namedtuple_constructor_warning(m)]
    assert not problems, "pdoc warned:\n" + "\n".join(problems)
    stderr = capfd.readouterr().err
    assert "Warn" not in stderr, stderr
    assert (tmp_path / "index.html").exists()
    missing = [m for m in modules if not (tmp_path / (m.replace(".", "/") + ".html")).exists()]
    assert not missing, f"modules without a reference page: {missing}"


def test_documented_command_covers_every_module() -> None:
    """``pdoc mjxrmp envs agents offline`` reaches every module (pdoc follows ``__all__``)."""
    hidden = sorted(set(_all_modules()) - set(extract.walk_specs(list(PACKAGES))))
    assert not hidden, f"hidden from the API reference: {hidden}"


def _design_sections() -> set[str]:
    return set(re.findall(r"^#+ §([\d.]+) ", DESIGN.read_text(encoding="utf-8"), flags=re.M))


def test_design_has_the_cited_sections() -> None:
    assert _design_sections() == set(SECTIONS)


def test_design_references_resolve() -> None:
    refs = REFERENCE.findall(DESIGN.read_text(encoding="utf-8"))
    assert len(refs) > 50
    missing = [f"{mod}:{attr}" for mod, attr in refs
               if _resolve(f"{mod}.{attr}") is None]
    assert not missing, f"docs/design.md names objects that do not exist: {missing}"


def test_citations_name_existing_sections() -> None:
    sections = _design_sections()
    files = [p for folder in (*PACKAGES, "scripts", "tests") for p in (ROOT / folder).rglob("*.py")]
    files += [ROOT / "README.md", ROOT / "pyproject.toml", *(ROOT / "docs").rglob("*.md")]
    bad = [
        f"{path.relative_to(ROOT)}: §{cited}"
        for path in sorted(files)
        for match in CITATION.finditer(path.read_text(encoding="utf-8"))
        for cited in re.findall(r"§([\d.]*\d)", match.group(1))
        if cited not in sections
    ]
    assert not bad, "citations of missing docs/design.md sections: " + ", ".join(bad)


def test_readme_opens_with_the_two_commands() -> None:
    lines = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 200
    first = lines[lines.index("```bash") + 1 : lines.index("```bash") + 4]
    assert first[0].endswith('pip install -e ".[plots]" && python scripts/train.py')
    assert first[1].endswith('pip install -e ".[test]" && python -m pytest -q')
    assert first[2] == "```"


@pytest.mark.slow
def test_readme_examples_run() -> None:
    """Every ``python`` block of the README runs with the current import paths (minutes on CPU)."""
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```python\n(.*?)```", readme, flags=re.S)
    assert len(blocks) >= 5
    for i, block in enumerate(blocks):
        exec(compile(block, f"README.md python block {i}", "exec"), {})
