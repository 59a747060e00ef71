"""The scripts' persistent compilation cache (mjxrmp._xla, docs/design.md §5.6): where it lives,
how it is switched off, that a user's own ``JAX_COMPILATION_CACHE_DIR`` wins, that importing the
library leaves it off, and that a real script run fills it."""

from __future__ import annotations

import json
import math
import os
import pathlib
import subprocess
import sys

import jax
import pytest

from mjxrmp import _xla

ROOT = pathlib.Path(__file__).resolve().parents[2]


def _script_env(**extra: str) -> dict[str, str]:
    """The test process's environment without the session's cache settings, plus ``extra``."""
    drop = (_xla.JAX_CACHE_DIR_ENV, _xla.JAX_MIN_TIME_ENV, _xla.CACHE_ENV, "XDG_CACHE_HOME")
    return {**{k: v for k, v in os.environ.items() if k not in drop}, **extra}


def test_default_directory_is_under_the_home_cache(monkeypatch, tmp_path):
    monkeypatch.setenv("HOME", str(tmp_path))
    expected = str(tmp_path / ".cache" / "mjxrmp" / "jax")
    assert _xla.compile_cache_dir({}) == expected
    assert _xla.compile_cache_dir({"XDG_CACHE_HOME": "relative/dir"}) == expected  # not absolute


def test_xdg_cache_home_is_respected():
    assert _xla.compile_cache_dir({"XDG_CACHE_HOME": "/x/cache"}) == "/x/cache/mjxrmp/jax"


def test_override_names_the_directory(monkeypatch, tmp_path):
    monkeypatch.setenv("HOME", str(tmp_path))
    env = {"XDG_CACHE_HOME": "/x/cache"}
    assert _xla.compile_cache_dir({**env, _xla.CACHE_ENV: "/data/jax"}) == "/data/jax"
    assert _xla.compile_cache_dir({_xla.CACHE_ENV: "~/jc"}) == str(tmp_path / "jc")


@pytest.mark.parametrize("value", ["off", "0", "false", "OFF", " False "])
def test_opt_out_values(value):
    assert _xla.compile_cache_dir({_xla.CACHE_ENV: value}) is None


def test_a_user_set_jax_directory_wins(monkeypatch, tmp_path):
    """Neither the directory, nor JAX's config, nor our override is touched."""
    mine, ours = tmp_path / "mine", tmp_path / "ours"
    assert _xla.compile_cache_dir({_xla.JAX_CACHE_DIR_ENV: str(mine),
                                   _xla.CACHE_ENV: str(ours)}) is None
    monkeypatch.setenv(_xla.JAX_CACHE_DIR_ENV, str(mine))
    monkeypatch.setenv(_xla.CACHE_ENV, str(ours))
    before = jax.config.jax_compilation_cache_dir
    assert _xla.configure_compile_cache() is None
    assert os.environ[_xla.JAX_CACHE_DIR_ENV] == str(mine)
    assert jax.config.jax_compilation_cache_dir == before
    assert not ours.exists()


def test_switched_off_or_unwritable_leaves_everything_as_it_was(monkeypatch, tmp_path, capsys):
    monkeypatch.delenv(_xla.JAX_CACHE_DIR_ENV, raising=False)
    before = jax.config.jax_compilation_cache_dir
    monkeypatch.setenv(_xla.CACHE_ENV, "off")
    assert _xla.configure_compile_cache() is None
    (tmp_path / "file").write_text("")
    blocked = tmp_path / "file" / "jax"
    monkeypatch.setenv(_xla.CACHE_ENV, str(blocked))
    assert _xla.configure_compile_cache() is None
    assert f"compile cache off: cannot create {blocked}" in capsys.readouterr().err
    assert _xla.JAX_CACHE_DIR_ENV not in os.environ
    assert jax.config.jax_compilation_cache_dir == before


def test_importing_the_library_leaves_the_cache_off():
    code = "import mjxrmp, jax; print(jax.config.jax_compilation_cache_dir)"
    out = subprocess.run([sys.executable, "-c", code], env=_script_env(), cwd=ROOT,
                         capture_output=True, text=True, timeout=300, check=True)
    assert out.stdout.strip() == "None"


def test_a_script_run_fills_the_default_cache(tmp_path):
    """``scripts/reproduce_ch3.py`` at a few steps, with only ``XDG_CACHE_HOME`` set: its
    compiled simulations land in ``$XDG_CACHE_HOME/mjxrmp/jax``."""
    cache = tmp_path / "xdg" / "mjxrmp" / "jax"
    subprocess.run([sys.executable, "scripts/reproduce_ch3.py", "--out", str(tmp_path / "out"),
                    "--steps", "3", "--robots", "2", "--seeds", "1"],
                   env=_script_env(XDG_CACHE_HOME=str(tmp_path / "xdg")), cwd=ROOT,
                   capture_output=True, text=True, timeout=600, check=True)
    assert any(p.name.startswith("jit_simulate") for p in cache.iterdir())


def test_cpu_workarounds_are_added_where_the_installed_jaxlib_needs_them(monkeypatch):
    """jaxlib 0.10 gets both CPU workarounds (a user's own value of an option is kept), 0.11
    neither (it aborts on options it does not know), 0.9 only the fusion-emitter one."""
    monkeypatch.setattr(_xla, "_jaxlib_version", lambda: (0, 10))
    assert _xla.cpu_xla_flags("") == f"{_xla.CPU_FLAG} {_xla.YNN_FLAG}"
    own = "--xla_cpu_experimental_ynn_fusion_type=dot"
    assert _xla.cpu_xla_flags(own) == f"{own} {_xla.CPU_FLAG}"
    monkeypatch.setattr(_xla, "_jaxlib_version", lambda: (0, 11))
    assert _xla.cpu_xla_flags("--xla_dump_to=x") == "--xla_dump_to=x"
    monkeypatch.setattr(_xla, "_jaxlib_version", lambda: (0, 9))
    assert _xla.cpu_xla_flags("") == _xla.CPU_FLAG


def test_run_once_programs_compile_at_a_low_cpu_level(monkeypatch):
    """A program that runs once (a PPO run's init) compiles at RUN_ONCE_CPU_LEVEL on the CPU,
    at a lower level where XLA_FLAGS asks for one (the suite's O0), with no options elsewhere."""
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_use_fusion_emitters=false")
    level = {"xla_backend_optimization_level": _xla.RUN_ONCE_CPU_LEVEL}
    assert _xla.run_once_compiler_options("cpu") == level
    assert _xla.run_once_compiler_options("gpu") == {}
    monkeypatch.setenv("XLA_FLAGS", "--xla_backend_optimization_level=0")
    assert _xla.run_once_compiler_options("cpu") == {"xla_backend_optimization_level": 0}
    monkeypatch.setenv("XLA_FLAGS", "--xla_backend_optimization_level=3")
    assert _xla.run_once_compiler_options("cpu") == level


def test_a_low_level_compile_computes_what_the_default_does():
    """The same reset-like program (a reset scene of the 3-link environment) compiled with the
    run-once options and with XLA's defaults agrees to float32 rounding."""
    import envs  # lazy: only this test builds an environment

    env = envs.make("three_link/env3")
    keys = jax.random.split(jax.random.PRNGKey(3), 8)
    lowered = jax.jit(jax.vmap(lambda k: env.reset(k).obs)).lower(keys)
    low = lowered.compile(compiler_options=_xla.run_once_compiler_options("cpu"))(keys)
    default = lowered.compile(compiler_options={"xla_backend_optimization_level": 3})(keys)
    assert float(jax.numpy.max(jax.numpy.abs(low - default))) <= 1e-6


_LOCATIONS = """
import json, re
import jax, jax.numpy as jnp
from mjxrmp import _xla
_xla.configure_script()
def inner(x):
    with jax.named_scope("inner_part"):
        return jnp.sin(x) * 2
def outer(x): return inner(x) + 1
x = jnp.linspace(0.0, 1.0, 5)
lowered = jax.jit(outer).lower(x)
names = re.findall(r'op_name="([^"]*)"', lowered.compile().as_text())
callsites = lowered.as_text(debug_info=True).count("callsite(")
print(jax.config.jax_traceback_in_locations_limit, callsites,
      any("inner_part" in n for n in names), json.dumps(jax.jit(outer)(x).tolist()))
"""


@pytest.mark.parametrize("user_value", [None, "100"])
def test_scripts_compile_with_one_source_frame_unless_the_user_sets_the_limit(user_value):
    """After ``configure_script`` (JAX already imported) a compiled program's operations carry
    one source frame, not a chain of call sites (JAX's default limit is 100 frames); a user's
    ``JAX_TRACEBACK_IN_LOCATIONS_LIMIT`` is kept. Operation names keep their named scopes and the
    computed values are the same."""
    # no compile cache: its key ignores debug information, so a hit could bring back an
    # executable compiled under another limit
    env = {k: v for k, v in _script_env(**{_xla.CACHE_ENV: "off"}).items()
           if k != _xla.TRACEBACK_LIMIT_ENV}
    if user_value is not None:
        env[_xla.TRACEBACK_LIMIT_ENV] = user_value
    out = subprocess.run([sys.executable, "-c", _LOCATIONS], env=env, cwd=ROOT,
                         capture_output=True, text=True, timeout=300, check=True)
    limit, callsites, scoped, values = out.stdout.strip().split(" ", 3)
    assert int(limit) == (_xla.TRACEBACK_FRAMES if user_value is None else int(user_value))
    assert (int(callsites) > 0) == (user_value is not None)
    assert scoped == "True"
    expected = [2 * math.sin(i / 4) + 1 for i in range(5)]
    assert all(abs(a - b) <= 1e-6 for a, b in zip(json.loads(values), expected, strict=True))


def test_a_limit_that_is_not_an_integer_is_refused(monkeypatch):
    monkeypatch.setenv(_xla.TRACEBACK_LIMIT_ENV, "few")
    with pytest.raises(ValueError, match="JAX_TRACEBACK_IN_LOCATIONS_LIMIT must be an integer"):
        _xla.configure_locations()


def test_scripts_let_gpu_kernels_run_concurrently_unless_the_user_chooses_a_mode():
    """``gpu_xla_flags`` adds XLA:GPU's concurrent command-buffer scheduling to the user's flags
    once; a user who chose a scheduling mode keeps it."""
    assert _xla.gpu_xla_flags("") == _xla.GPU_FLAG
    assert _xla.gpu_xla_flags("--xla_dump_to=/tmp/d") == f"--xla_dump_to=/tmp/d {_xla.GPU_FLAG}"
    once = _xla.gpu_xla_flags("--xla_dump_to=/tmp/d")
    assert _xla.gpu_xla_flags(once) == once
    for mode in ("LHS", "SERIALIZE"):
        mine = f"--xla_gpu_command_buffer_scheduling_mode={mode}"
        assert _xla.gpu_xla_flags(mine) == mine


def test_the_installed_jaxlib_accepts_the_scripts_flags():
    """XLA aborts on a flag it does not know: a script's flags must be ones the installed
    jaxlib parses (a computation runs after ``configure_script``)."""
    code = ("from mjxrmp import _xla; _xla.configure_script(); import os, jax.numpy as jnp; "
            "print(float(jnp.arange(4.0).sum()), os.environ['XLA_FLAGS'])")
    env = {k: v for k, v in _script_env(**{_xla.CACHE_ENV: "off"}).items() if k != "XLA_FLAGS"}
    out = subprocess.run([sys.executable, "-c", code], env=env, cwd=ROOT,
                         capture_output=True, text=True, timeout=300, check=True)
    total, flags = out.stdout.strip().split(" ", 1)
    assert float(total) == 6.0 and _xla.GPU_FLAG in flags.split()


def test_a_child_given_a_cache_uses_it_and_not_its_parents(tmp_path):
    """A script exports JAX's cache variable (configure_compile_cache), which compile_cache_dir
    lets win: the environment for a child with its own cache drops it, so a benchmark's cold
    run in a fresh directory does not find an earlier run's programs in the parent's cache."""
    parent = {_xla.JAX_CACHE_DIR_ENV: str(tmp_path / "parent"), "KEEP": "1"}
    assert _xla.compile_cache_dir(parent) is None  # JAX would use the parent's directory
    child = _xla.child_cache_environ(str(tmp_path / "fresh"), parent)
    assert _xla.compile_cache_dir(child) == str(tmp_path / "fresh")
    assert child["KEEP"] == "1" and _xla.JAX_CACHE_DIR_ENV not in child
    assert parent[_xla.JAX_CACHE_DIR_ENV] == str(tmp_path / "parent")  # the caller's is kept
