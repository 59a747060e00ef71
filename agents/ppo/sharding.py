"""Data parallelism for PPO (docs/design.md §2.3): a 1-D device mesh over the environment batch.

The environment batch, the rollout and every minibatch are sharded over the mesh's first axis;
parameters are replicated, so XLA all-reduces the gradients. The same program runs on one CPU,
several GPUs or several hosts (after ``jax.distributed.initialize``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from agents.ppo.config import PPOConfig


def make_mesh(num_devices: int | None) -> Mesh | None:
    """A 1-D ``("batch",)`` mesh over the first ``num_devices`` devices (None for 1 or None)."""
    if num_devices is None or num_devices == 1:
        return None
    devices = jax.devices()
    if not (isinstance(num_devices, int) and 1 <= num_devices <= len(devices)):
        raise ValueError(f"num_devices must be between 1 and {len(devices)} (the devices JAX "
                         f"sees), got {num_devices!r}")
    return Mesh(np.array(devices[:num_devices]), ("batch",))


def check_mesh(config: PPOConfig, mesh: Mesh | None) -> None:
    """Raise unless ``mesh`` is None or a mesh whose size divides ``num_envs``, the minibatch
    size and ``shuffle_blocks`` (when set) of ``config``."""
    if mesh is None:
        return
    if not isinstance(mesh, Mesh):
        raise TypeError(f"mesh must be a jax.sharding.Mesh or None, got {type(mesh)}")
    for name, n in (("num_envs", config.num_envs), ("minibatch_size", config.minibatch_size)):
        if n % mesh.size:
            raise ValueError(f"PPOConfig {name}={n} must be divisible by the mesh size "
                             f"{mesh.size} to shard the environment batch")
    if config.shuffle_blocks is not None and config.shuffle_blocks % mesh.size:
        raise ValueError(f"PPOConfig shuffle_blocks={config.shuffle_blocks} must be a "
                         f"multiple of the mesh size {mesh.size}")


def batch_axis_sharding(mesh: Mesh | None, num_envs: int) -> Callable[..., Any]:
    """``constrain(tree, axis)``: shard every leaf whose dimension ``axis`` is the environment
    batch (size ``num_envs``) over the mesh's first axis, replicate the others (identity when
    ``mesh`` is None)."""
    if mesh is None:
        return lambda tree, axis=0: tree
    name = mesh.axis_names[0]

    def constrain(tree, axis=0):
        def one(x):
            if x.ndim > axis and x.shape[axis] == num_envs:
                spec = PartitionSpec(*([None] * axis), name)
            else:
                spec = PartitionSpec()
            return jax.lax.with_sharding_constraint(x, NamedSharding(mesh, spec))

        return jax.tree.map(one, tree)

    return constrain


__all__ = ["batch_axis_sharding", "check_mesh", "make_mesh"]
