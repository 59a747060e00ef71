"""Training runs (agents/run/, scripts/train.py): chunked and resumed runs equal uninterrupted
ones, incompatible checkpoints are refused, an interrupted run keeps its progress, data-parallel
sharding on 4 forced host devices equals one device, observation statistics match a float64
reference."""

from __future__ import annotations

import dataclasses
import io
import json
import os
import shutil
import subprocess
import sys
import textwrap
import threading

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from script_main import load_script

import envs
from agents.ppo import PPOConfig, make_train, make_trainer
from agents.ppo.normalization import init_stats, normalize, update_stats
from agents.run import checkpoint, training
from agents.run.loading import checkpoint_steps
from agents.run.logs import read_csv
from agents.run.program import Program, build
from agents.run.spec import RunSpec, parse_overrides, preset
from agents.run.training import run_training

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

TINY_PPO = PPOConfig(num_envs=4, rollout_length=8, num_minibatches=2, update_epochs=2,
                     total_iterations=4, policy_hidden_sizes=(8,), value_hidden_sizes=(8,),
                     episode_length=6, normalize_observations=True)
# 3-link env1 with the nn policy: the cheapest reaching task to compile; 2 seeds vmapped.
SPEC = RunSpec(env="three_link/env1", policy="nn", seeds=(0, 1),
               ppo=dataclasses.replace(TINY_PPO, episode_length=10), log_every=2,
               checkpoint_every=2)


def _assert_tree_close(a, b, rtol=1e-5, atol=1e-6):
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=rtol, atol=atol)


def test_running_stats_match_float64_reference():
    rng = np.random.default_rng(0)
    chunks = [rng.normal(3.0, 2.0, size=(n, 5)).astype(np.float32) for n in (7, 1, 30, 12)]
    stats = init_stats(5)
    np.testing.assert_array_equal(normalize(stats, jnp.asarray(chunks[0])), chunks[0])
    for c in chunks:
        stats = update_stats(stats, jnp.asarray(c))
    ref = np.concatenate(chunks).astype(np.float64)
    assert float(stats.count) == ref.shape[0]
    np.testing.assert_allclose(stats.mean, ref.mean(0), rtol=1e-5)
    np.testing.assert_allclose(stats.var, ref.var(0), rtol=1e-4)
    z = normalize(stats, jnp.asarray(ref[:3], jnp.float32))
    np.testing.assert_allclose(z, (ref[:3] - ref.mean(0)) / ref.std(0), rtol=1e-3, atol=1e-4)
    with pytest.raises(ValueError, match="obs_size"):
        init_stats(0)


def test_chunked_run_equals_one_call():
    """run(run(s, 2), 2) == run(s, 4): iteration keys come from fold_in(key, iteration)."""
    trainer = make_trainer(envs.make("point2d"), config=TINY_PPO)
    state = jax.jit(trainer.init)(jax.random.PRNGKey(0))
    run = jax.jit(trainer.run, static_argnums=1)
    full, m_full = run(state, 4)
    half, m1 = run(state, 2)
    rest, m2 = run(half, 2)
    assert int(rest.iteration) == 4
    _assert_tree_close(full.params, rest.params)
    for k in m_full:
        np.testing.assert_allclose(m_full[k], np.concatenate([m1[k], m2[k]]), rtol=1e-5,
                                   atol=1e-6, equal_nan=True, err_msg=k)
    # make_train(...)(key) is the same program end to end.
    params, _ = jax.jit(make_train(envs.make("point2d"), config=TINY_PPO))(
        jax.random.PRNGKey(0))
    _assert_tree_close(params, full.params)
    with pytest.raises(TypeError, match="config="):
        make_trainer(envs.make("point2d"), TINY_PPO)


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    out = str(tmp_path_factory.mktemp("full"))
    return run_training(SPEC, out, progress=False), out


def test_run_writes_logs_curves_and_checkpoints(uninterrupted):
    result, out = uninterrupted
    for name in ("run.json", "metrics.csv", "learning_curves.png"):
        assert os.path.getsize(os.path.join(out, name)) > 0, name
    assert any(f.startswith("events.out.tfevents") for f in os.listdir(os.path.join(out, "tb")))
    assert checkpoint.latest_step(os.path.join(out, "checkpoints")) == 4
    history, seeds = read_csv(os.path.join(out, "metrics.csv"))
    assert seeds == (0, 1)
    np.testing.assert_allclose(history["mean_reward"], result.history["mean_reward"], rtol=1e-6)
    assert result.history["mean_reward"].shape == (2, 4)
    with open(os.path.join(out, "run.json")) as f:
        assert json.load(f)["policy"] == "nn"


def test_resumed_run_equals_uninterrupted(uninterrupted, tmp_path):
    result, _ = uninterrupted
    out = str(tmp_path / "run")
    short = dataclasses.replace(SPEC, ppo=dataclasses.replace(SPEC.ppo, total_iterations=2))
    run_training(short, out, progress=False)
    with pytest.raises(FileExistsError, match="resume"):
        run_training(SPEC, out, progress=False)
    resumed = run_training(SPEC, out, resume=True, progress=False)
    for k, v in result.history.items():
        np.testing.assert_allclose(resumed.history[k], v, rtol=1e-5, atol=1e-6,
                                   equal_nan=True, err_msg=k)
    _assert_tree_close(resumed.state.params, result.state.params)
    history, _ = read_csv(os.path.join(out, "metrics.csv"))
    assert history["mean_reward"].shape == (2, 4)


def test_a_resume_compiles_its_first_chunk_while_it_restores(uninterrupted, tmp_path,
                                                            monkeypatch):
    """--resume compiles the chunk after the newest checkpoint ahead (4 of 5 iterations done:
    a chunk of 1), without holding init's trace; a second run in the process compiles nothing
    again; a checkpoint of another configuration is refused with nothing compiled ahead."""
    calls, compiles = [], []
    compile_ahead, compile_run = Program.compile_ahead, Program._compile_run

    def noting_ahead(self, keys, n, hold_init=True):
        calls.append((n, hold_init))
        return compile_ahead(self, keys, n, hold_init)

    def noting_compile(self, state, n, *rest):
        compiles.append(n)
        return compile_run(self, state, n, *rest)

    monkeypatch.setattr(Program, "compile_ahead", noting_ahead)
    monkeypatch.setattr(Program, "_compile_run", noting_compile)
    _, out = uninterrupted
    five = dataclasses.replace(SPEC, ppo=dataclasses.replace(SPEC.ppo, total_iterations=5))
    program = build(five)
    for i in range(2):
        shutil.copytree(os.path.join(out, "checkpoints"), tmp_path / f"r{i}" / "checkpoints")
        resumed = run_training(five, str(tmp_path / f"r{i}"), resume=True, progress=False)
        assert resumed.history["mean_reward"].shape == (2, 5)
        assert calls[-1] == (1, False) and not program.ahead and not program.lowering
    assert compiles == [1]
    other = dataclasses.replace(five, ppo=dataclasses.replace(five.ppo, learning_rate=1e-2))
    with pytest.raises(checkpoint.IncompatibleCheckpointError, match="learning_rate"):
        run_training(other, str(tmp_path / "r0"), resume=True, progress=False)
    assert len(calls) == 2


def test_a_resume_reads_its_checkpoint_while_the_environment_builds(uninterrupted, tmp_path,
                                                                     monkeypatch):
    """--resume reads the newest checkpoint's meta (the first use of orbax) in the background
    while the environment builds: the build below waits until that read has begun, and fails
    when the read comes only after it."""
    read = threading.Event()
    load_meta, real_build = checkpoint.load_meta, training.build

    def noting_meta(*args, **kwargs):
        read.set()
        return load_meta(*args, **kwargs)

    def waiting_build(*args, **kwargs):
        assert read.wait(timeout=30), "the checkpoint was not read while the environment built"
        return real_build(*args, **kwargs)

    monkeypatch.setattr(checkpoint, "load_meta", noting_meta)
    monkeypatch.setattr(training, "build", waiting_build)
    _, out = uninterrupted
    five = dataclasses.replace(SPEC, ppo=dataclasses.replace(SPEC.ppo, total_iterations=5))
    shutil.copytree(os.path.join(out, "checkpoints"), tmp_path / "r" / "checkpoints")
    resumed = run_training(five, str(tmp_path / "r"), resume=True, progress=False)
    assert resumed.history["mean_reward"].shape == (2, 5)


def test_interrupted_run_keeps_completed_iterations(uninterrupted, tmp_path):
    """Ctrl-C after the second chunk: the checkpoint written on the way out holds all 4 done
    iterations; --resume finishes and equals the uninterrupted run."""
    result, _ = uninterrupted
    out = str(tmp_path / "run")
    spec = dataclasses.replace(SPEC, checkpoint_every=4,
                               ppo=dataclasses.replace(SPEC.ppo, total_iterations=6))

    class Interrupt(io.StringIO):
        lines = 0

        def write(self, text):
            self.lines += text.count("\n")
            if self.lines >= 2:
                raise KeyboardInterrupt
            return super().write(text)

    with pytest.raises(KeyboardInterrupt):
        run_training(spec, out, progress=True, stream=Interrupt())
    assert checkpoint.latest_step(os.path.join(out, "checkpoints")) == 4
    resumed = run_training(spec, out, resume=True, progress=False)
    np.testing.assert_allclose(resumed.history["mean_reward"][:, :4],
                               result.history["mean_reward"], rtol=1e-5, atol=1e-6)
    assert resumed.history["mean_reward"].shape == (2, 6)


def test_host_logs_a_chunk_while_the_next_one_is_being_dispatched(uninterrupted, tmp_path,
                                                                     monkeypatch):
    """The device runs chunk k+1 while the host logs and checkpoints chunk k, even where
    dispatching a chunk blocks until the device has run it (as on a GPU): here the dispatch of
    chunk k+1 waits until chunk k is being logged, which would never happen if the two were done
    one after the other on one thread. The run still equals the one of the ``uninterrupted``
    fixture."""
    logging, waited = {}, []
    launch, append = training._launch, training._RunLog.append

    def blocking_launch(program, spec, state, start):
        if 0 < start < spec.ppo.total_iterations:  # chunk k+1 waits for chunk k's logging
            waited.append(logging.setdefault(start - 2, threading.Event()).wait(timeout=60))
        return launch(program, spec, state, start)

    def recording_append(self, metrics, start, done, seconds):
        logging.setdefault(start, threading.Event()).set()
        return append(self, metrics, start, done, seconds)

    monkeypatch.setattr(training, "_launch", blocking_launch)
    monkeypatch.setattr(training._RunLog, "append", recording_append)
    result = run_training(SPEC, str(tmp_path / "run"), progress=False)
    assert waited == [True]  # SPEC: 4 iterations in chunks of 2
    _assert_tree_close(result.state.params, uninterrupted[0].state.params, rtol=0, atol=0)


def test_keep_checkpoints_none_keeps_every_snapshot(tmp_path):
    """``keep_checkpoints=None`` keeps every checkpoint (the snapshots a medium-replay dataset
    is collected from); the default keeps the 3 newest; bad values are refused."""
    long = dataclasses.replace(SPEC.ppo, total_iterations=8)
    run_training(dataclasses.replace(SPEC, ppo=long, keep_checkpoints=None),
                 str(tmp_path / "all"), progress=False)
    assert checkpoint_steps(tmp_path / "all") == [2, 4, 6, 8]
    run_training(dataclasses.replace(SPEC, ppo=long), str(tmp_path / "newest"), progress=False)
    assert checkpoint_steps(tmp_path / "newest") == [4, 6, 8]
    for bad in (0, -1, 2.5):
        with pytest.raises(ValueError, match="keep_checkpoints"):
            dataclasses.replace(SPEC, keep_checkpoints=bad)


def test_incompatible_checkpoint_is_refused(uninterrupted, tmp_path):
    _, out = uninterrupted
    other = dataclasses.replace(SPEC, policy="nn_residual")
    with pytest.raises(checkpoint.IncompatibleCheckpointError, match="policy"):
        run_training(other, out, resume=True, progress=False)
    other = dataclasses.replace(SPEC, env="three_link/env2")
    with pytest.raises(checkpoint.IncompatibleCheckpointError, match="env"):
        run_training(other, out, resume=True, progress=False)
    with pytest.raises(FileNotFoundError, match="no checkpoint"):
        run_training(SPEC, str(tmp_path / "empty"), resume=True, progress=False)


def test_bad_names_are_refused_naming_the_valid_ones(capsys):
    """``--set``, ``--preset`` and ``--policy`` errors name the valid choices; the CLI refuses an
    unknown environment before building anything (a subprocess: scripts are not imported)."""
    with pytest.raises(ValueError, match="learning_rate"):
        parse_overrides(["learning_rat=1"])
    with pytest.raises(ValueError, match="NAME=VALUE"):
        parse_overrides(["learning_rate"])
    assert parse_overrides(["learning_rate=1e-4", "policy_hidden_sizes=64,64",
                            "max_grad_norm=none", "normalize_observations=true",
                            "num_envs=8"]) == {
        "learning_rate": 1e-4, "policy_hidden_sizes": (64, 64), "max_grad_norm": None,
        "normalize_observations": True, "num_envs": 8}
    with pytest.raises(ValueError, match="thesis"):
        preset("huge")
    with pytest.raises(ValueError, match="rmp_residual"):
        RunSpec(policy="mlp")
    with pytest.raises(SystemExit) as refused:  # scripts/train.py's main, in this process
        load_script("train.py").main(["--env", "three_link/env9"])
    err = capsys.readouterr().err
    assert refused.value.code == 2 and "three_link/env3" in err, err[-2000:]


SHARDED = textwrap.dedent("""
    import dataclasses
    import jax, numpy as np
    import envs
    from agents.ppo import PPOConfig, make_mesh, make_trainer
    assert jax.device_count() == 4, jax.devices()
    cfg = PPOConfig(num_envs=8, rollout_length=8, num_minibatches=2, update_epochs=2,
                    total_iterations=3, policy_hidden_sizes=(8,), value_hidden_sizes=(8,),
                    episode_length=6, normalize_observations=True)
    keys = jax.numpy.stack([jax.random.PRNGKey(1), jax.random.PRNGKey(2)])
    out = {}
    # the sharded run shuffles within one block per device (the default); the single-device
    # run is told to use the same 4 blocks, so both compute the same numbers
    runs = (("single", None, dataclasses.replace(cfg, shuffle_blocks=4)),
            ("sharded", make_mesh(4), cfg))
    for name, mesh, c in runs:
        tr = make_trainer(envs.make("point2d"), config=c, mesh=mesh)
        state = jax.jit(jax.vmap(tr.init))(keys)
        state, metrics = jax.jit(jax.vmap(tr.run, in_axes=(0, None)), static_argnums=1)(
            state, 3)
        if mesh is not None:
            obs = state.env_state.obs
            assert len(obs.sharding.device_set) == 4, obs.sharding
        out[name] = (state.params, metrics)
    for a, b in zip(jax.tree.leaves(out["single"]), jax.tree.leaves(out["sharded"]),
                    strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-4, atol=1e-6)
    print("SHARDED_OK")
""")


def test_sharded_training_on_4_host_devices_equals_single_device():
    env = dict(os.environ)
    env["XLA_FLAGS"] = (env.get("XLA_FLAGS", "") +
                        " --xla_force_host_platform_device_count=4").strip()
    env["JAX_PLATFORMS"] = "cpu"
    env["PYTHONPATH"] = ROOT + os.pathsep + env.get("PYTHONPATH", "")
    proc = subprocess.run([sys.executable, "-c", SHARDED], env=env, cwd=ROOT,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0 and "SHARDED_OK" in proc.stdout, proc.stderr[-3000:]
