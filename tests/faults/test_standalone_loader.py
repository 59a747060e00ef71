"""Issue 27, case 7 (the standalone loader): ``load_policy.py --out DIR/`` wrote ``DIR.npy`` and
reported the wrong path; a text observation file gave numpy's pickle message. The loader is
copied next to a real export (as a user carries it) and its CLI ``main`` is run in-process."""

from __future__ import annotations

import importlib.util
import shutil
from pathlib import Path
from types import ModuleType

import jax.numpy as jnp
import numpy as np
import pytest

from agents.run.export import export_policy

LOADER = Path(__file__).resolve().parents[2] / "scripts" / "load_policy.py"
OBS_SIZE = 3


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> tuple[Path, ModuleType]:
    """A folder with a tiny real export (``actions = 2·obs[:, :2]``, CPU only), an observation
    file and a copy of the loader, imported as a module."""
    root = tmp_path_factory.mktemp("loader")
    export_policy(lambda p, o: o[:, :2] * p, jnp.full((2,), 2.0), OBS_SIZE,
                  root / "policy.jaxexport", platforms=("cpu",))
    np.save(root / "obs.npy", np.arange(2 * OBS_SIZE, dtype=np.float32).reshape(2, OBS_SIZE))
    shutil.copy(LOADER, root / "load_policy.py")
    spec = importlib.util.spec_from_file_location("standalone_load_policy",
                                                  root / "load_policy.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return root, module


def _run(site, capsys, *args: str) -> tuple[int, str, str]:
    root, loader = site
    code = loader.main([str(root / "policy.jaxexport"), *args])
    out, err = capsys.readouterr()
    return code, out, err


EXPECTED = np.array([[0.0, 2.0], [6.0, 8.0]], np.float32)


@pytest.mark.parametrize("make_dir", [False, True])
def test_out_directory_receives_actions_npy(site, capsys, tmp_path, make_dir):
    """issue case 7: `load_policy.py --out DIR/` wrote `DIR.npy` and reported the wrong path;
    a directory (ending in a separator, or existing without one) now receives
    ``DIR/actions.npy`` and that path is reported."""
    root, loader = site
    target = tmp_path / "results"
    if make_dir:
        target.mkdir()
    arg = str(target) if make_dir else str(target) + "/"
    code, out, err = _run(site, capsys, "--obs", str(root / "obs.npy"), "--out", arg)
    assert code == 0, err
    written = target / loader.ACTIONS_NAME
    np.testing.assert_array_equal(np.load(written), EXPECTED)
    assert f"wrote    {written}\n" in out
    assert not (tmp_path / "results.npy").exists()


def test_out_file_path_reported_as_written(site, capsys, tmp_path):
    """issue case 7: ``--out name`` without ``.npy`` is written by numpy as ``name.npy``; the
    report now names that file."""
    root, _ = site
    code, out, err = _run(site, capsys, "--obs", str(root / "obs.npy"),
                          "--out", str(tmp_path / "acts"))
    assert code == 0, err
    np.testing.assert_array_equal(np.load(tmp_path / "acts.npy"), EXPECTED)
    assert f"wrote    {tmp_path / 'acts.npy'}\n" in out


@pytest.mark.parametrize("content, reason", [
    ("0 1 2\n3 4 5\n", "not in that format"),
    (None, "no such file"),
])
def test_text_or_missing_observations_named(site, capsys, tmp_path, content, reason):
    """issue case 7: a text observation file gave numpy's pickle message; it (and a missing
    file) now gives one line naming the file and the expected format, exit code 2."""
    obs = tmp_path / "obs.txt"
    if content is not None:
        obs.write_text(content)
    code, out, err = _run(site, capsys, "--obs", str(obs))
    assert code == 2
    assert err == (f"error: --obs {obs}: expected a NumPy .npy array file (numpy.save) of "
                   f"observations (b, obs_size) or (obs_size,); {reason}\n")
    assert "pickle" not in err and out == ""


def test_wrong_observation_shape_is_one_line(site, capsys, tmp_path):
    """Observations of the wrong width give the loader's one-line shape message, not a
    traceback."""
    np.save(tmp_path / "wide.npy", np.zeros((2, OBS_SIZE + 1), np.float32))
    code, _, err = _run(site, capsys, "--obs", str(tmp_path / "wide.npy"))
    assert code == 2
    assert err == f"error: obs must have shape (b, {OBS_SIZE}) with b >= 1 or ({OBS_SIZE},), " \
                  f"got (2, {OBS_SIZE + 1})\n"
