"""Fault injection into policy export (issue 27, case 7, export half; agents/run/export.py,
scripts/export.py): an existing artifact is not overwritten without ``--force`` and non-finite
parameters are never exported (the NaN-checkpoint case is in test_checkpoint_integrity.py)."""

from __future__ import annotations

import hashlib
import os
import re
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

import mjxrmp  # noqa: F401  (XLA flags first)
from agents.run.export import export_from_params, export_policy, export_run, init_params

REPO = Path(__file__).resolve().parents[2]
ENV = "three_link/env1"


@pytest.fixture(scope="module")
def artifact(tmp_path_factory) -> Path:
    """A real export of a freshly initialised ``nn`` policy (seed 0) of 3-link env1."""
    path = tmp_path_factory.mktemp("export") / "policy.jaxexport"
    export_run(path, env_name=ENV, kind="nn", seed=0, platforms=("cpu",))
    return path


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_export_refuses_to_overwrite_without_force(artifact, tmp_path):
    """issue case 7: ``export.py`` overwrote an existing artifact without ``--force``. The
    package function refuses naming the path and the flag (blob or manifest alone), leaves both
    files untouched, and overwrites with ``force=True``."""
    before = (_digest(artifact), _digest(artifact.with_suffix(".json")))
    refusal = re.escape(f"{str(artifact)!r} already exists") + ".*--force"
    with pytest.raises(FileExistsError, match=refusal):
        export_run(artifact, env_name=ENV, kind="nn", seed=1, platforms=("cpu",))
    assert (_digest(artifact), _digest(artifact.with_suffix(".json"))) == before
    lonely = tmp_path / "lonely.jaxexport"
    lonely.with_suffix(".json").write_text("{}")
    with pytest.raises(FileExistsError, match=r"lonely\.json'? already exists"):
        export_run(lonely, env_name=ENV, kind="nn", platforms=("cpu",))
    assert not lonely.exists()
    manifest = export_run(artifact, env_name=ENV, kind="nn", seed=1, platforms=("cpu",),
                          force=True)
    assert manifest["metadata"]["seed"] == 1 and _digest(artifact) != before[0]


def test_export_cli_refuses_to_overwrite_without_force(artifact):
    """issue case 7 through ``scripts/export.py`` (a subprocess): exit status 2 and one error
    line naming the path and ``--force``; nothing rewritten."""
    before = _digest(artifact)
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    proc = subprocess.run([sys.executable, str(REPO / "scripts" / "export.py"), "--env", ENV,
                           "--policy", "nn", "--out", str(artifact), "--platforms", "cpu"],
                          capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == 2, proc.stderr[-3000:]
    error = proc.stderr.strip().splitlines()[-1]
    assert str(artifact) in error and "already exists" in error and "--force" in error
    assert _digest(artifact) == before


def test_export_refuses_non_finite_parameters(tmp_path):
    """issue case 7: non-finite parameters were exported. ``export_policy`` and
    ``export_from_params`` refuse them naming the first non-finite leaf; nothing is written."""
    path = tmp_path / "p.jaxexport"
    with pytest.raises(ValueError, match=r"non-finite values in \['scale'\]"):
        export_policy(lambda p, o: o * p["scale"], {"scale": np.float32(np.inf)}, 4, path,
                      platforms=("cpu",))
    params = init_params(ENV, "nn", seed=0)
    leaves, treedef = jax.tree.flatten(params)
    broken = jax.tree.unflatten(treedef, [leaves[0] * np.nan, *leaves[1:]])
    leaf = jax.tree_util.keystr(jax.tree_util.tree_flatten_with_path(params)[0][0][0])
    with pytest.raises(ValueError, match="non-finite values in " + re.escape(leaf)):
        export_from_params(ENV, "nn", broken, path, platforms=("cpu",))
    assert not path.exists() and not path.with_suffix(".json").exists()
