"""brax's own PPO trainer on our environments, on current JAX (docs/design.md §5.1, §5.3).

brax 0.14's trainers (``brax.training.agents.ppo.train`` among them) call
``jax.device_put_replicated``, which JAX 0.10 removed (brax issue 671). This module leaves brax
unedited:

* :func:`device_put_replicated` — a stand-in built from public JAX API with what the removed
  function returned: the value along a new leading axis, one single-device copy per device,
  assembled with a ``NamedSharding`` over those devices;
* :func:`replicated_device_put` — a context manager that installs the stand-in as
  ``jax.device_put_replicated`` for the duration of the ``with`` block only and removes it
  afterwards (a JAX that still has the function is left alone);
* :func:`train_with_brax_ppo` — brax's PPO inside that block, on an environment built with
  :func:`envs.make`.

The environments run under brax's own wrappers unchanged (:mod:`envs.wrappers`): brax's
auto-reset restarts each batch slot's first scene (goal, obstacles, initial state), so the
scenes seen in training are new only after brax's host-side resets (``num_resets_per_eval``).
Our own PPO (:mod:`agents.ppo`) re-samples a scene at every reset and is the project's trainer.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from brax.training.agents.ppo import train as brax_ppo
from jax.sharding import Mesh, NamedSharding, PartitionSpec

import envs

__all__ = ["device_put_replicated", "replicated_device_put", "train_with_brax_ppo"]

_NAME = "device_put_replicated"
_AXIS = "i"


def device_put_replicated(x: Any, devices: Sequence[jax.Device]) -> Any:
    """Every array leaf of ``x`` broadcast along a new leading axis of size ``len(devices)``,
    slice ``i`` on ``devices[i]`` (the removed ``jax.device_put_replicated``)."""
    devices = list(devices)
    if not devices:
        raise ValueError("devices must be a non-empty sequence of JAX devices, got none")
    # The axis is named like brax's pmap axis ("i"): arrays placed under another name carry a
    # different sharding, and brax's training epoch would compile a second time for them.
    sharding = NamedSharding(Mesh(np.array(devices), (_AXIS,)), PartitionSpec(_AXIS))

    def put(leaf):
        leaf = jnp.asarray(leaf)
        shards = [jax.device_put(leaf[None], d) for d in devices]
        return jax.make_array_from_single_device_arrays((len(devices), *leaf.shape), sharding,
                                                        shards)

    return jax.tree.map(put, x)


@contextlib.contextmanager
def replicated_device_put() -> Iterator[None]:
    """Within the block, ``jax.device_put_replicated`` is :func:`device_put_replicated` (unless
    the installed JAX still has its own); the attribute is removed again on exit."""
    if hasattr(jax, _NAME):
        yield
        return
    setattr(jax, _NAME, device_put_replicated)
    try:
        yield
    finally:
        delattr(jax, _NAME)


def train_with_brax_ppo(env_name: str, *, env_kwargs: dict[str, Any] | None = None,
                        **ppo_kwargs: Any) -> tuple[Callable[..., Any], Any, dict[str, Any]]:
    """Train ``envs.make(env_name, **env_kwargs)`` with brax's PPO
    (``brax.training.agents.ppo.train``, keyword arguments ``ppo_kwargs``) on current JAX.

    ``episode_length`` defaults to the environment's ``horizon``. Returns brax's
    ``(make_policy, params, metrics)``.
    """
    env = envs.make(env_name, **(env_kwargs or {}))
    ppo_kwargs.setdefault("episode_length", int(env.unwrapped.horizon))
    with replicated_device_put():
        return brax_ppo.train(environment=env, **ppo_kwargs)
