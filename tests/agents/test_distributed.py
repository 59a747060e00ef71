"""Multi-process training (agents.run.distributed, docs/multihost.md): a two-process
``jax.distributed`` run on CPU (2 host devices each, one global 4-device mesh, resumed half way)
equals the single-process 4-device run and its checkpoint restores in one process; a refusal in
one process stops both; the coordinator/process flags and variables are checked."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import textwrap

import jax
import numpy as np
import pytest
from script_main import load_script

from agents.run.directory import lock_run_directory
from agents.run.distributed import (
    agree,
    barrier,
    is_multiprocess,
    is_writer,
    mesh_devices,
    resolve,
    to_host,
)
from agents.run.loading import load_run
from agents.run.logs import read_csv

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

#: One process of a run: ``python -c WORKER PROCESS_ID NUM_PROCESSES PORT OUT``. Two processes
#: train 2 iterations, then resume to 4 (restoring in 2 processes); one process trains 4.
WORKER = textwrap.dedent("""
    import sys
    pid, count, port, out = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3], sys.argv[4]
    from agents.run.distributed import initialize
    if count > 1:
        assert initialize(f"127.0.0.1:{port}", count, pid) == (pid, count)
    import jax
    from agents.ppo import make_mesh
    from agents.run.spec import RunSpec, preset
    from agents.run.training import run_training
    assert jax.device_count() == 4 and jax.local_device_count() == 4 // count, jax.devices()
    def spec(iterations):
        ppo = preset("cpu", num_envs=8, rollout_length=16, num_minibatches=2, update_epochs=2,
                     episode_length=8, normalize_observations=True,
                     total_iterations=iterations)
        return RunSpec(env="three_link/env3", policy="nn", seeds=(0,), ppo=ppo, log_every=2,
                       checkpoint_every=2)
    mesh = make_mesh(4)
    if count > 1:
        run_training(spec(2), out, progress=False, mesh=mesh)
    run_training(spec(4), out, resume=count > 1, progress=False, mesh=mesh)
    print("WORKER_OK", pid, flush=True)
""")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _spawn(pid: int, count: int, port: int, out: str) -> subprocess.Popen:
    env = dict(os.environ, JAX_PLATFORMS="cpu", PYTHONPATH=ROOT + os.pathsep + os.environ.get(
        "PYTHONPATH", ""), MJXRMP_COMPILE_CACHE="off")
    env["XLA_FLAGS"] = (env.get("XLA_FLAGS", "") +
                        f" --xla_force_host_platform_device_count={4 // count}").strip()
    return subprocess.Popen([sys.executable, "-c", WORKER, str(pid), str(count), str(port), out],
                            env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)


def _finish(procs: list[subprocess.Popen], timeout: float = 900) -> list[tuple[int, str]]:
    out = []
    for p in procs:
        try:
            text, _ = p.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            p.kill()
            text, _ = p.communicate()
        out.append((p.returncode, text))
    return out


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """``(two-process run directory, single-process run directory)``, trained concurrently."""
    two, one = (str(tmp_path_factory.mktemp(n)) for n in ("two", "one"))
    port = _free_port()
    procs = [_spawn(0, 2, port, two), _spawn(1, 2, port, two), _spawn(0, 1, 0, one)]
    for code, text in _finish(procs):
        assert code == 0 and "WORKER_OK" in text, text[-3000:]
    return two, one


def test_two_processes_equal_one_and_restore_in_one_process(runs):
    """Not bitwise: gloo all-reduces across the processes sum in another order than one
    process does, and Adam amplifies the float32 rounding of tiny gradients (measured: largest
    parameter difference 1.1e-5 after 4 iterations, already 8.7e-6 after 2, metrics 3e-7)."""
    two, one = runs
    a, b = load_run(two), load_run(one)  # the 2-process checkpoint, restored in this process
    assert a.step == b.step == 4 and jax.process_count() == 1
    for x, y in zip(jax.tree.leaves(a.state), jax.tree.leaves(b.state), strict=True):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-4, atol=2e-5)
    ha, seeds = read_csv(os.path.join(two, "metrics.csv"))
    hb, _ = read_csv(os.path.join(one, "metrics.csv"))
    assert seeds == (0,) and ha["loss"].shape == (1, 4)
    for k in hb:
        np.testing.assert_allclose(ha[k], hb[k], rtol=1e-4, atol=1e-6, equal_nan=True,
                                   err_msg=k)
    # process 0 alone wrote the run directory: one TensorBoard event file per run_training
    assert len(os.listdir(os.path.join(two, "tb"))) == 2


def test_a_refusal_in_one_process_stops_both(tmp_path):
    """Process 0 cannot lock a directory another process holds: both processes exit at once
    (process 1 names process 0) instead of waiting at the first collective."""
    out, port = str(tmp_path), _free_port()
    with lock_run_directory(out):
        results = _finish([_spawn(0, 2, port, out), _spawn(1, 2, port, out)], timeout=300)
    (c0, t0), (c1, t1) = results
    assert c0 != 0 and "RunDirectoryInUseError" in t0, t0[-2000:]
    assert c1 != 0 and "process(es) [0] refused" in t1, t1[-2000:]


def test_coordinator_flags_and_variables_are_checked():
    assert resolve("host:1234", 2, 1) == ("host:1234", 2, 1)
    env = {"MJXRMP_COORDINATOR": "10.0.0.1:999", "MJXRMP_NUM_PROCESSES": "4",
           "MJXRMP_PROCESS_ID": "3"}
    assert resolve(environ=env) == ("10.0.0.1:999", 4, 3)
    with pytest.raises(ValueError, match="process_id given without coordinator, num_processes"):
        resolve(process_id=1)
    with pytest.raises(ValueError, match=r"process_id must be in 0\.\.1"):
        resolve("host:1234", 2, 2)
    with pytest.raises(ValueError, match="coordinator must be HOST:PORT"):
        resolve("host", 2, 0)
    with pytest.raises(ValueError, match="MJXRMP_PROCESS_ID set but not MJXRMP_COORDINATOR"):
        resolve(environ={"MJXRMP_PROCESS_ID": "0"})
    with pytest.raises(ValueError, match="MJXRMP_NUM_PROCESSES must be a non-negative"):
        resolve(environ=dict(env, MJXRMP_NUM_PROCESSES="four"))
    with pytest.raises(SystemExit) as refused:  # scripts/train.py, before connecting anything
        load_script("train.py").main(["--num-processes", "2", "--process-id", "0"])
    assert refused.value.code == 2


def test_single_process_helpers_are_plain():
    assert not is_multiprocess() and is_writer()
    assert mesh_devices(None) is None and mesh_devices(3) == 3
    tree = {"a": jax.numpy.arange(3.0), "b": np.ones(2)}
    host = to_host(tree)
    assert all(isinstance(x, np.ndarray) for x in jax.tree.leaves(host))
    np.testing.assert_array_equal(host["a"], [0.0, 1.0, 2.0])
    barrier("nothing to wait for")
    agree(None, "nothing refused")
    with pytest.raises(KeyError, match="mine"):
        agree(KeyError("mine"), "refused")
