"""Issue 27, case 3: a refused ``--resume`` overwrote ``run.json`` (leaving the run
unexportable), two processes on one ``--out`` corrupted each other, and the refusal dumped two
22-field dicts. Now ``run.json`` is written only after the checks, the refusal names the
differing field, and a run holds a lock on its directory that a second process is refused by
(and that ``kill -9`` releases)."""

from __future__ import annotations

import dataclasses
import os
import re
import subprocess
import sys
import textwrap

import pytest

from agents.ppo import PPOConfig
from agents.run.checkpoint import IncompatibleCheckpointError
from agents.run.directory import LOCK_FILE, RunDirectoryInUseError
from agents.run.loading import checkpoint_steps
from agents.run.logs import improvement_summary
from agents.run.spec import RunSpec
from agents.run.training import run_training

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

SPEC = RunSpec(env="three_link/env3", policy="nn", seeds=(0,), log_every=1, checkpoint_every=1,
               ppo=PPOConfig(num_envs=4, rollout_length=8, num_minibatches=1, update_epochs=1,
                             total_iterations=2, episode_length=6, policy_hidden_sizes=(8,),
                             value_hidden_sizes=(8,)))

# A second process that holds the run directory's lock until it is killed.
HOLDER = textwrap.dedent("""
    import sys, time
    from agents.run.directory import lock_run_directory
    with lock_run_directory(sys.argv[1]):
        print("LOCKED", flush=True)
        time.sleep(300)
""")


def _with(spec: RunSpec, **ppo) -> RunSpec:
    return dataclasses.replace(spec, ppo=dataclasses.replace(spec.ppo, **ppo))


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A finished tiny run (2 iterations): ``(result, run directory)``."""
    out = str(tmp_path_factory.mktemp("run"))
    return run_training(SPEC, out, progress=False), out


def _read(path: str) -> bytes:
    with open(path, "rb") as f:
        return f.read()


def test_finite_run_is_unchanged(trained):
    """A valid run behaves as before: its summary still gives a verdict; the lock file is
    left behind, unlocked, with the process id."""
    result, out = trained
    assert re.search(r": (not )?improved\n", improvement_summary(result.history) + "\n")
    assert _read(os.path.join(out, LOCK_FILE)).decode().strip() == str(os.getpid())


def test_refused_resume_leaves_run_json_intact(trained):
    """issue case 3: `--resume` with another learning_rate is refused naming `learning_rate`
    (not two dumped dicts) and leaves run.json byte-identical."""
    _, out = trained
    before = _read(os.path.join(out, "run.json"))
    other = _with(SPEC, learning_rate=1e-3, total_iterations=4)
    with pytest.raises(IncompatibleCheckpointError, match="learning_rate") as info:
        run_training(other, out, resume=True, progress=False)
    assert "num_envs" not in str(info.value)
    assert _read(os.path.join(out, "run.json")) == before
    assert checkpoint_steps(out) == [1, 2]


def test_concurrent_writer_is_refused_until_the_holder_dies(trained):
    """issue case 3, concurrent writers: while another process holds the run directory, a
    second run (in-process and through scripts/train.py, exit status 2) is refused naming the
    holder's pid, writing nothing; after `kill -9` of the holder the run resumes."""
    _, out = trained
    before = _read(os.path.join(out, "run.json"))
    env = {**os.environ, "JAX_PLATFORMS": "cpu",
           "PYTHONPATH": ROOT + os.pathsep + os.environ.get("PYTHONPATH", "")}
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, out], stdout=subprocess.PIPE,
                              text=True, env=env)
    try:
        lines = iter(holder.stdout.readline, "")  # (MuJoCo may print notes first)
        assert any(line.strip() == "LOCKED" for line in lines), "the holder did not start"
        longer = _with(SPEC, total_iterations=3)
        with pytest.raises(RunDirectoryInUseError,
                           match=rf"^{re.escape(out)} is in use by process {holder.pid} "):
            run_training(longer, out, resume=True, progress=False)
        proc = subprocess.run(
            [sys.executable, os.path.join(ROOT, "scripts", "train.py"), "--env",
             "three_link/env3", "--policy", "nn", "--out", out, "--resume", "--no-progress"],
            capture_output=True, text=True, timeout=600, cwd=ROOT, env=env)
        assert proc.returncode == 2, proc.stderr[-3000:]
        assert f"is in use by process {holder.pid}" in proc.stderr.strip().splitlines()[-1]
        assert _read(os.path.join(out, "run.json")) == before
    finally:
        holder.kill()  # SIGKILL: the operating system releases the lock
        holder.wait()
    resumed = run_training(longer, out, resume=True, progress=False)
    assert resumed.history["loss"].shape == (1, 3) and checkpoint_steps(out)[-1] == 3
