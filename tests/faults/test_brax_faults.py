"""Issue case 8, brax's own code on our environments: the pieces that failed, each checked
without compiling a rollout (the end-to-end runs are in ``tests/envs/test_brax_interop.py``)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from agents.brax_compat import device_put_replicated, replicated_device_put
from envs.base import accumulate_episode, episode_info


@pytest.mark.parametrize("name", ["three_link/env3", "point2d"])
def test_step_keeps_the_metric_keys_wrappers_add(name):
    """issue case 8: brax's ``EvalWrapper`` failed because ``step`` built a new metrics dict and
    dropped the ``reward`` key the wrapper adds at reset."""
    env = envs.make(name)
    state = jax.eval_shape(env.reset, jax.random.PRNGKey(0))
    state = state.replace(metrics={**state.metrics, "reward": state.reward})
    out = jax.eval_shape(env.step, state, jnp.zeros((env.action_size,), jnp.float32))
    assert set(out.metrics) == set(state.metrics)


def _brax_info(episode_length: float, steps: float, counted: float) -> dict:
    """Accumulators that counted ``episode_length`` steps, and brax's ``EpisodeWrapper``
    counters ``steps`` and ``episode_metrics["length"] = counted``."""
    info = episode_info()
    info.update(episode_return=jnp.float32(2.5), episode_length=jnp.float32(episode_length),
                episode_collided=jnp.float32(1.0), steps=jnp.float32(steps),
                episode_metrics={"length": jnp.float32(counted)})
    return info


def _step(info: dict) -> dict:
    return accumulate_episode(info, jnp.float32(0.5), jnp.float32(0.0), jnp.float32(0.0))


def test_accumulators_restart_after_a_brax_auto_reset():
    """issue case 8: under brax's ``AutoResetWrapper`` the info counters ran on into the next
    episode; they restart at its first step (action_repeat 1 and 2)."""
    out = _step(_brax_info(episode_length=7, steps=0, counted=7))  # brax zeroed steps
    assert (float(out["episode_return"]), float(out["episode_length"])) == (0.5, 1.0)
    assert float(out["episode_collided"]) == 0.0
    # action_repeat = 2: two inner steps per brax step, counters move after both.
    info = _brax_info(episode_length=8, steps=0, counted=8)
    info = _step(_step(info))
    assert (float(info["episode_return"]), float(info["episode_length"])) == (1.0, 2.0)


@pytest.mark.parametrize("episode_length, steps, counted", [
    (3, 3, 3),  # an episode going on
    (0, 0, 7),  # our auto-reset already replaced the accumulators by zeros
    (0, 0, 0),  # the first step after a reset
    (1, 0, 0),  # second inner step of the first step (action_repeat 2)
])
def test_accumulators_run_on_within_an_episode(episode_length, steps, counted):
    """issue case 8: the restart rule fires only at the first step after brax's auto-reset."""
    info = _brax_info(episode_length, steps, counted)
    out = _step(info)
    assert float(out["episode_length"]) == episode_length + 1
    assert float(out["episode_return"]) == 3.0
    without_brax = {k: v for k, v in info.items() if k not in ("steps", "episode_metrics")}
    assert float(_step(without_brax)["episode_length"]) == episode_length + 1


def test_brax_trainers_get_device_put_replicated_only_inside_the_helper():
    """issue case 8: brax's PPO calls ``jax.device_put_replicated``, removed from current JAX;
    the helper's stand-in exists only within its block, also when the block raises."""
    devices = jax.local_devices()[:1]
    x = {"w": jnp.arange(6.0).reshape(2, 3), "n": jnp.int32(4)}
    assert not hasattr(jax, "device_put_replicated")
    with replicated_device_put():
        y = jax.device_put_replicated(x, devices)
    assert not hasattr(jax, "device_put_replicated")
    assert y["w"].shape == (1, 2, 3) and y["n"].shape == (1,) and y["n"].dtype == jnp.int32
    np.testing.assert_array_equal(y["w"][0], x["w"])
    assert [s.device for s in y["w"].addressable_shards] == devices
    with pytest.raises(RuntimeError, match="inside"), replicated_device_put():
        raise RuntimeError("inside")
    assert not hasattr(jax, "device_put_replicated")
    with pytest.raises(ValueError, match="devices"):
        device_put_replicated(x, [])
