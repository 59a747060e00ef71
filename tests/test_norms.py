"""The house rules of the layout, checked on the source tree (docs/design.md §6).

Package modules ≤ 400 lines, scripts ≤ 200, functions ≤ 80 (a jitted trainer closure nested in a
``make_*train*`` factory ≤ 200); packages import only the layers below them and no import cycles;
no project import inside a function unless the line carries ``# lazy: <why>``; tests and
scripts never import ``scripts``; environments are built only through ``envs.make``; configs
validate through ``mjxrmp/config.py`` alone; the project cites only its own docs; ``results/``
holds data only; the README and the benchmark page stay short.
"""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("mjxrmp", "envs", "agents", "offline")
PROJECT = (*PACKAGES, "scripts")
ENV_CLASSES = ("ThreeLinkReach", "FrankaReach", "PointRobot2D", "ReachEnv")


def _files(*roots: str) -> list[Path]:
    return sorted(p for r in roots for p in (ROOT / r).rglob("*.py"))


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _functions(tree: ast.AST):
    """Yield ``(node, enclosing function names)`` for every function definition."""
    stack = [(tree, ())]
    while stack:
        node, outer = stack.pop()
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef):
                yield child, outer
                stack.append((child, (*outer, child.name)))
            else:
                stack.append((child, outer))


def _imports(tree: ast.AST):
    """Yield ``(node, imported project module names, runs at import time)``."""
    in_function = {id(n) for fn, _ in _functions(tree) for n in ast.walk(fn) if n is not fn}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
        else:
            continue
        names = [n for n in names if n.split(".")[0] in PROJECT]
        if names:
            yield node, names, id(node) not in in_function


def test_package_modules_are_at_most_400_lines():
    long = {str(p.relative_to(ROOT)): n for p in _files(*PACKAGES)
            if (n := len(p.read_text().splitlines())) > 400}
    assert not long, f"package modules over 400 lines: {long}"


def test_scripts_are_at_most_200_lines():
    long = {p.name: n for p in _files("scripts") if (n := len(p.read_text().splitlines())) > 200}
    assert not long, f"scripts over 200 lines: {long}"


def test_functions_are_at_most_80_lines():
    long = []
    for path in _files(*PROJECT):
        for fn, outer in _functions(ast.parse(path.read_text())):
            n = fn.end_lineno - fn.lineno + 1
            closure = bool(outer) and re.fullmatch(r"make_\w*train\w*", outer[-1])
            if n > (200 if closure else 80):
                long.append(f"{path.relative_to(ROOT)}:{fn.name} ({n} lines)")
    assert not long, "functions over the limit:\n" + "\n".join(long)


def _graph() -> dict[str, set[str]]:
    modules = {_module_name(p): p for p in _files(*PROJECT)}
    graph = {}
    for name, path in modules.items():
        deps = set()
        for _, names, top in _imports(ast.parse(path.read_text())):
            if top:
                deps.update(n for n in names if n in modules and n != name)
        graph[name] = deps
    return graph


def test_no_import_cycles():
    graph, cycles = _graph(), []
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []

    def visit(v: str) -> None:  # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while (w := stack.pop()) != v:
                component.append(w)
            if component:
                cycles.append(sorted([*component, v]))

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10_000))
    for v in graph:
        if v not in index:
            visit(v)
    assert not cycles, f"import cycles: {cycles}"


def test_packages_import_only_the_layers_below_them():
    """mjxrmp ← envs ← agents ← offline ← scripts (docs/design.md §1), lazy imports included."""
    layer = {name: i for i, name in enumerate(PROJECT)}
    bad = []
    for path in _files(*PACKAGES):
        own = layer[path.relative_to(ROOT).parts[0]]
        for node, names, _ in _imports(ast.parse(path.read_text())):
            above = sorted({n.split(".")[0] for n in names if layer[n.split(".")[0]] > own})
            if above:
                bad.append(f"{path.relative_to(ROOT)}:{node.lineno} imports {above}")
    assert not bad, "imports against the layering:\n" + "\n".join(bad)


def test_function_level_project_imports_carry_the_lazy_marker():
    bad = []
    for path in _files(*PROJECT, "tests"):
        lines = path.read_text().splitlines()
        for node, _, top in _imports(ast.parse("\n".join(lines))):
            line = lines[node.lineno - 1]
            if not top and "# lazy:" not in line:
                bad.append(f"{path.relative_to(ROOT)}:{node.lineno}: {line.strip()}")
    assert not bad, "project imports inside functions without '# lazy: <why>':\n" + "\n".join(bad)


@pytest.mark.parametrize("where", ["tests", "scripts"])
def test_nothing_imports_a_script(where):
    bad = [f"{p.relative_to(ROOT)}:{node.lineno}" for p in _files(where)
           for node, names, _ in _imports(ast.parse(p.read_text()))
           if any(n == "scripts" or n.startswith("scripts.") for n in names)]
    assert not bad, f"imports of scripts: {bad}"


def test_environments_are_built_only_through_envs_make():
    pattern = re.compile(r"\b(" + "|".join(ENV_CLASSES) + r")\(")
    bad = [f"{p.relative_to(ROOT)}:{i}" for p in _files("mjxrmp", "agents", "offline", "scripts")
           for i, line in enumerate(p.read_text().splitlines(), 1)
           if pattern.search(line) and not line.lstrip().startswith(("#", "class "))]
    assert not bad, f"environments constructed outside envs.make: {bad}"


def test_config_validators_live_only_in_mjxrmp_config():
    pattern = re.compile(r"def _?(check|require|validate)_(int|float|positive\w*|fraction|bool|"
                         r"finite\w*|sizes|parts|unit_interval|choice)\b|"
                         r"def _positive_(int|float)\b")
    bad = [f"{p.relative_to(ROOT)}:{i}" for p in _files(*PROJECT) if p != ROOT / "mjxrmp/config.py"
           for i, line in enumerate(p.read_text().splitlines(), 1) if pattern.search(line)]
    assert not bad, f"private copies of the config validators: {bad}"


def test_the_project_cites_only_its_own_docs():
    # Spelled in pieces so that this file does not match itself.
    pattern = re.compile("DESIGN" + " §|ANCHOR" + "_FACTS")
    files = [p for p in ROOT.rglob("*") if p.suffix in (".py", ".md") and p.is_file()
             and not any(part in (".git", "build") or part.startswith(".venv")
                         for part in p.relative_to(ROOT).parts)]
    bad = [str(p.relative_to(ROOT)) for p in files if pattern.search(p.read_text())]
    assert not bad, f"citations of documents outside the project: {bad}"


def test_results_hold_only_data():
    bad = [str(p.relative_to(ROOT)) for p in (ROOT / "results").rglob("*")
           if p.suffix in (".sh", ".py", ".log")]
    assert not bad, f"logs or programs in results/: {bad}"


def test_reports_match_the_summaries():
    out = subprocess.run([sys.executable, str(ROOT / "scripts/report.py"), "--check"],
                         capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 0, out.stdout + out.stderr


def test_benchmarks_and_readme_stay_short():
    bench = (ROOT / "BENCHMARKS.md").read_text()
    assert len(bench.splitlines()) <= 300
    assert "session" not in bench.lower()
    readme = (ROOT / "README.md").read_text().splitlines()
    assert len(readme) <= 200
    commands = [line for line in readme[:8] if line.startswith("python3 -m venv")]
    assert len(commands) == 2 and "pytest" in commands[1], readme[:8]
