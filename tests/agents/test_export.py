"""Policy export (:mod:`agents.run.export`) and the standalone loader (``scripts/load_policy.py``).

Exports ``rmp_residual`` and ``nn`` policies of ``three_link/env3`` with perturbed random
parameters, then loads them in a fresh Python process that cannot import the project (a
``sys.meta_path`` blocker refuses ``mjxrmp``/``agents``/``envs``; the editable install would
otherwise make them importable) and checks the actions against the in-process compiled
``apply`` with the parameters as arguments (as in training) at batch sizes 1 and 7 (one
symbolic-batch export serves both)
and a single unbatched observation.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from agents.ppo import make_policy
from agents.ppo.policies import ObservationSpec, hand_designed_mean
from agents.run.export import (
    RMP_INPUTS,
    check_names,
    export_from_params,
    export_policy,
    init_params,
    load_export,
    manifest_path,
)
from mjxrmp.policies import default_config

REPO = Path(__file__).resolve().parents[2]
LOADER = REPO / "scripts" / "load_policy.py"
ENV = "three_link/env3"
KINDS = ("rmp_residual", "nn")
BATCHES = (1, 7)
#: In practice the exported actions equal the compiled apply's bit for bit (same batch size);
#: without export_policy's optimisation barrier constant folding moves rmp_residual by ~1e-5.
#: float32 rounding: the exported program is compiled in another process, where XLA may fuse
#: the RMP² resolve differently (accelerations of order 10, so a few ulp are a few 1e-6).
TOL = dict(rtol=1e-5, atol=1e-5)


def _subprocess_env() -> dict:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["JAX_PLATFORMS"] = "cpu"
    return env


def _observations(env, n: int, seed: int = 0) -> np.ndarray:
    """``n`` plausible observations built from the layout (cheaper than compiling ``reset``):
    joint angles in ±1 rad, obstacles of radius 0.05–0.1 m, the last one padded (radius −1) in
    every other row."""
    rng = np.random.default_rng(seed)
    layout = env.observation_layout()
    dof = layout["qd"].stop - layout["qd"].start
    dim = layout["goal_minus_x"].stop - layout["goal_minus_x"].start
    obs = np.zeros((n, env.observation_size), np.float32)
    q = rng.uniform(-1.0, 1.0, (n, dof))
    obs[:, layout["sin_q"]], obs[:, layout["cos_q"]] = np.sin(q), np.cos(q)
    obs[:, layout["qd"]] = rng.uniform(-0.5, 0.5, (n, dof))
    obs[:, layout["goal_minus_x"]] = rng.uniform(-1.0, 1.0, (n, dim))
    vec = layout["obstacle_vectors"]
    obs[:, vec] = rng.uniform(-0.5, 0.5, (n, vec.stop - vec.start))
    block = obs[:, layout["obstacles"]].reshape(n, -1, dim + 1)
    block[..., :dim] = rng.uniform(-0.9, 0.9, block[..., :dim].shape)
    block[..., dim] = rng.uniform(0.05, 0.1, block[..., dim].shape)
    block[::2, -1] = 0.0
    block[::2, -1, dim] = -1.0
    obs[:, layout["obstacles"]] = block.reshape(n, -1)
    return obs


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """Export both kinds with perturbed random parameters; save observations and the actions
    of the in-process compiled ``apply`` (one compile per batch size)."""
    out = tmp_path_factory.mktemp("export")
    env = envs.make(ENV)
    obs_all = _observations(env, max(BATCHES))
    cases = {}
    for i, kind in enumerate(KINDS):
        module = make_policy(kind, env)
        init = jax.jit(module.init)(jax.random.PRNGKey(i), jnp.zeros((env.observation_size,)))
        leaves, treedef = jax.tree.flatten(init)
        keys = jax.random.split(jax.random.PRNGKey(10 + i), len(leaves))
        params = jax.tree.unflatten(treedef, [
            x + 0.3 * jax.random.normal(k, x.shape, x.dtype)
            for x, k in zip(leaves, keys, strict=True)])
        path = out / kind / "policy.jaxexport"
        manifest = export_policy(lambda p, o, m=module: m.apply(p, o)[0], params,
                                 env.observation_size, path,
                                 metadata={"env": ENV, "policy": kind, "iteration": 3})
        apply = jax.jit(lambda p, o, m=module: m.apply(p, o)[0])
        for b in BATCHES:
            obs = obs_all[:b]
            np.save(out / f"obs_{b}.npy", obs)
            expected = np.asarray(apply(params, obs))
            np.save(out / f"expected_{kind}_{b}.npy", expected)
            # the perturbation matters (for rmp_residual: the residual network is not ~0)
            assert np.abs(expected - np.asarray(apply(init, obs))).max() > 1e-2
        cases[kind] = (path, manifest)
    return out, cases


def test_manifest(exported):
    _, cases = exported
    for kind, (path, manifest) in cases.items():
        on_disk = json.loads(manifest_path(path).read_text())
        assert on_disk == manifest
        assert manifest["sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()
        assert (manifest["obs_size"], manifest["action_size"]) == (26, 3)
        assert manifest["dtype"] == "float32" and manifest["format_version"] == 1
        assert manifest["platforms"] == ["cpu", "cuda"], manifest["platform_errors"]
        assert manifest["metadata"] == {"env": ENV, "policy": kind, "iteration": 3}
        assert manifest["jax_version"] == jax.__version__
        assert not list(path.parent.glob("*.tmp"))


def test_fresh_process_matches_apply(exported, tmp_path):
    """Load both exports in a process that cannot import the project; several batch sizes."""
    out, cases = exported
    loader = tmp_path / "load_policy.py"  # a copy, as a user would carry it elsewhere
    shutil.copy(LOADER, loader)
    script = textwrap.dedent(f"""
        import importlib.abc, importlib.util, json, sys
        import numpy as np

        BLOCKED = ("mjxrmp", "agents", "envs")

        class Block(importlib.abc.MetaPathFinder):
            def find_spec(self, name, path=None, target=None):
                if name.split(".")[0] in BLOCKED:
                    raise ImportError(f"project package {{name}} imported by the loader")
                return None

        sys.meta_path.insert(0, Block())
        spec = importlib.util.spec_from_file_location("load_policy", {str(loader)!r})
        lp = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(lp)
        for kind in {KINDS!r}:
            policy = lp.load_policy({str(out)!r} + f"/{{kind}}/policy.jaxexport")
            for b in {BATCHES!r}:
                obs = np.load({str(out)!r} + f"/obs_{{b}}.npy")
                np.save(f"actions_{{kind}}_{{b}}.npy", policy(obs))
            np.save(f"single_{{kind}}.npy", policy(obs[0]))
        loaded = sorted({{m.split(".")[0] for m in sys.modules}} & set(BLOCKED))
        print(json.dumps({{"loaded": loaded}}))
    """)
    proc = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, env=_subprocess_env(),
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert json.loads(proc.stdout.strip().splitlines()[-1]) == {"loaded": []}
    for kind in cases:
        for b in BATCHES:
            actions = np.load(tmp_path / f"actions_{kind}_{b}.npy")
            expected = np.load(out / f"expected_{kind}_{b}.npy")
            assert actions.shape == (b, 3) and actions.dtype == np.float32
            np.testing.assert_allclose(actions, expected, **TOL, err_msg=f"{kind} b={b}")
        single = np.load(tmp_path / f"single_{kind}.npy")
        np.testing.assert_allclose(single, np.load(out / f"expected_{kind}_1.npy")[0], **TOL)


def test_loader_cli(exported, tmp_path):
    out, cases = exported
    path, _ = cases["rmp_residual"]
    proc = subprocess.run(
        [sys.executable, str(LOADER), str(path), "--obs", str(out / "obs_7.npy"),
         "--out", "actions.npy", "--check-isolated"],
        cwd=tmp_path, env=_subprocess_env(), capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert "isolated no project package imported" in proc.stdout
    np.testing.assert_allclose(np.load(tmp_path / "actions.npy"),
                               np.load(out / "expected_rmp_residual_7.npy"), **TOL)


REFUSALS = textwrap.dedent("""
    import json, sys
    import numpy as np
    from load_policy import PolicyLoadError, load_policy

    out = {}
    for name in ("bad", "swapped", "lonely"):
        try:
            load_policy(name + ".jaxexport")
            out[name] = "loaded"
        except PolicyLoadError as e:
            out[name] = str(e)
    policy = load_policy("good.jaxexport")
    try:
        policy(np.zeros((2, policy.obs_size + 1), np.float32))
        out["shape"] = "ran"
    except ValueError as e:
        out["shape"] = str(e)
    print(json.dumps(out))
""")


def test_corrupted_or_mismatched_blob_refused(exported, tmp_path):
    """The loader, copied next to the files as a user would (a subprocess), refuses a corrupted
    blob, a blob next to another export's manifest, a blob without manifest and observations of
    the wrong shape."""
    _, cases = exported
    src, _ = cases["nn"]
    shutil.copy(LOADER, tmp_path / "load_policy.py")
    shutil.copy(src, tmp_path / "good.jaxexport")
    shutil.copy(manifest_path(src), tmp_path / "good.json")
    blob = bytearray(src.read_bytes())
    blob[len(blob) // 2] ^= 0xFF
    (tmp_path / "bad.jaxexport").write_bytes(bytes(blob))
    shutil.copy(manifest_path(src), tmp_path / "bad.json")
    shutil.copy(cases["rmp_residual"][0], tmp_path / "swapped.jaxexport")
    shutil.copy(manifest_path(src), tmp_path / "swapped.json")
    shutil.copy(src, tmp_path / "lonely.jaxexport")
    proc = subprocess.run([sys.executable, "-c", REFUSALS], cwd=tmp_path,
                          env=_subprocess_env(), capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-4000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert "corrupted" in out["bad"]
    assert "sha256" in out["swapped"]
    assert "manifest" in out["lonely"]
    assert "obs must have shape" in out["shape"]


def test_export_policy_validates_arguments(tmp_path):
    fn = lambda p, o: o[:, :2] * p  # noqa: E731
    path = tmp_path / "p.jaxexport"
    for bad in (0, -3, 2.0, True):
        with pytest.raises(ValueError, match="obs_size"):
            export_policy(fn, 1.0, bad, path)
    with pytest.raises(ValueError, match="path"):
        export_policy(fn, 1.0, 4, tmp_path / "p.bin")
    with pytest.raises(ValueError, match="metadata"):
        export_policy(fn, 1.0, 4, path, metadata={"x": object()})
    with pytest.raises(ValueError, match="platforms"):
        export_policy(fn, 1.0, 4, path, platforms=("gpu",))
    with pytest.raises(ValueError, match="matmul_precision"):
        export_policy(fn, 1.0, 4, path, matmul_precision="fastest")
    with pytest.raises(TypeError, match="apply_fn must return one array"):
        export_policy(lambda p, o: (o, o), 1.0, 4, path)
    assert not path.exists()
    manifest = export_policy(fn, 2.0, 4, path, platforms=("cpu",), matmul_precision="highest")
    assert (manifest["action_size"], manifest["platforms"]) == (2, ["cpu"])
    assert manifest["matmul_precision"] == "highest"


def test_export_from_params_and_cli(tmp_path):
    """:func:`export_from_params` metadata, clear name errors, and ``scripts/export.py`` end to
    end (a subprocess)."""
    params = init_params(ENV, "nn", seed=0)
    manifest = export_from_params(ENV, "nn", params, tmp_path / "a.jaxexport",
                                  {"iteration": 7}, platforms=("cpu",))
    meta = manifest["metadata"]
    assert (meta["env"], meta["policy"], meta["robot"], meta["iteration"]) == (
        ENV, "nn", "three_link", 7)
    assert meta["observation_layout"]["obstacles"] == [17, 26]
    with pytest.raises(ValueError, match=r"valid names are \['franka'"):
        export_from_params("three_link/env9", "nn", params, tmp_path / "c.jaxexport")
    with pytest.raises(ValueError, match=r"point2d.*has no policy classes"):
        check_names("point2d", "nn")
    with pytest.raises(ValueError, match="valid kinds"):
        check_names(ENV, "mlp")
    script = str(REPO / "scripts" / "export.py")
    proc = subprocess.run([sys.executable, script, "--env", ENV, "--policy", "nn", "--out",
                           str(tmp_path / "b.jaxexport"), "--platforms", "cpu"],
                          env=_subprocess_env(), capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert "obs (26,) -> action (3,)" in proc.stdout
    assert json.loads((tmp_path / "b.json").read_text())["metadata"]["seed"] == 0
    proc = subprocess.run([sys.executable, script, "--out", str(tmp_path / "d.jaxexport")],
                          env=_subprocess_env(), capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2 and "--checkpoint RUN_DIR" in proc.stderr


def test_hand_designed_export_and_load_export(tmp_path):
    """``scripts/export.py --hand-designed`` exports the hand-designed RMP² policy (a function of
    the observation alone, documented in the manifest); :func:`load_export` reads it back and
    refuses a corrupted blob and a missing manifest, naming the file."""
    out = tmp_path / "hd.jaxexport"
    proc = subprocess.run([sys.executable, str(REPO / "scripts" / "export.py"), "--hand-designed",
                           "--env", ENV, "--out", str(out), "--platforms", "cpu"],
                          env=_subprocess_env(), capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-4000:]
    exported, manifest = load_export(out)
    meta = manifest["metadata"]
    assert (meta["policy"], meta["rmp_inputs"], manifest["action_size"]) == (
        "hand_designed", RMP_INPUTS, 3)
    env = envs.make(ENV)
    obs = _observations(env, 5)
    spec, config = ObservationSpec.from_env(env), default_config("three_link")
    expected = jax.jit(lambda o: hand_designed_mean(spec, config, o))(jnp.asarray(obs))
    np.testing.assert_allclose(exported.call(obs), expected, **TOL)
    bad = tmp_path / "bad.jaxexport"
    bad.write_bytes(out.read_bytes()[:-1] + b"x")
    shutil.copy(manifest_path(out), manifest_path(bad))
    with pytest.raises(ValueError, match=r"bad\.jaxexport.*sha256"):
        load_export(bad)
    manifest_path(bad).unlink()
    with pytest.raises(FileNotFoundError, match=r"bad\.json"):
        load_export(bad)
