"""XLA:GPU's concurrent command-buffer scheduling, which every script sets (docs/design.md §5.11),
changes only the order in which independent kernels run: the same environment rollout, run in a
process with it and in one with XLA's default scheduling (``LHS``), gives the same
trajectories for both robots. Needs a GPU (the flag means nothing to the CPU backend); skipped
elsewhere."""

from __future__ import annotations

import os
import pathlib
import shutil
import subprocess
import sys

import numpy as np
import pytest

from mjxrmp import _xla

ROOT = pathlib.Path(__file__).resolve().parents[2]
#: Joint positions may differ by this much (rad) after the rollout: float rounding, not a
#: different motion (the constraint-pipeline check of docs/design.md §5.8 allows the same).
TOLERANCE = 1e-4

_ROLLOUT = """
import sys, jax, numpy as np
import envs
from env_rollouts import random_action_qpos
out = {name.replace("/", "_"): random_action_qpos(envs.make(name), 100, 512)
       for name in ("three_link/env3", "franka")}
assert jax.default_backend() == "gpu", jax.default_backend()
np.savez(sys.argv[1], **out)
"""


def _rollout(path: pathlib.Path, mode_flag: str) -> dict[str, np.ndarray]:
    env = {k: v for k, v in os.environ.items() if k not in ("JAX_PLATFORMS", "XLA_FLAGS")}
    env.update(XLA_FLAGS=mode_flag, JAX_PLATFORMS="cuda", MJXRMP_COMPILE_CACHE="off",
               PYTHONPATH=os.pathsep.join([str(ROOT), str(ROOT / "tests"),
                                           env.get("PYTHONPATH", "")]))
    env.pop("JAX_COMPILATION_CACHE_DIR", None)  # each mode compiles its own programs
    subprocess.run([sys.executable, "-c", _ROLLOUT, str(path)], env=env, cwd=ROOT,
                   check=True, timeout=900)
    with np.load(path) as data:
        return dict(data)


@pytest.mark.skipif(shutil.which("nvidia-smi") is None, reason="needs an NVIDIA GPU")
def test_concurrent_kernels_give_the_same_trajectories(tmp_path):
    concurrent = _rollout(tmp_path / "concurrent.npz", _xla.GPU_FLAG)
    serial = _rollout(tmp_path / "serial.npz",
                      "--xla_gpu_command_buffer_scheduling_mode=LHS")
    assert set(concurrent) == {"three_link_env3", "franka"}
    for name, qpos in concurrent.items():
        assert np.all(np.isfinite(qpos)) and qpos.shape[:2] == (100, 512)
        gap = float(np.max(np.abs(qpos - serial[name])))
        assert gap <= TOLERANCE, f"{name}: max |Δqpos| {gap:.2e} rad"
