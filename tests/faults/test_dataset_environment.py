"""Issue 27, case 7 (datasets): the offline environment check compared only sizes (a 3-link env3
dataset was accepted for env2) and its message named the wrong environment. The datasets carry
the metadata :mod:`offline.data.collect` records (:func:`offline.data.rollouts.
environment_metadata`); the environments are the real ones."""

from __future__ import annotations

import numpy as np
import pytest

import envs
from offline.data import dataset as od
from offline.data.rollouts import environment_metadata


def _dataset(env_name: str, metadata: dict | None = None) -> od.Dataset:
    """Four transitions of one episode with the sizes of ``env_name`` and ``metadata``."""
    env = envs.make(env_name)
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(4, env.observation_size)).astype(np.float32)
    actions = rng.uniform(-0.5, 0.5, size=(4, env.action_size)).astype(np.float32)
    return od.create(obs, actions, np.zeros(4, np.float32), obs, [0, 0, 0, 0], [0, 0, 0, 1],
                     [0, 0, 0, 0], metadata)


@pytest.fixture(scope="module")
def env3_data() -> od.Dataset:
    return _dataset("three_link/env3", environment_metadata("three_link/env3"))


def test_env3_dataset_refused_for_env2(env3_data):
    """issue case 7: a 3-link env3 dataset was accepted for env2 (same sizes); the recorded
    environment id is compared and the message names both."""
    assert env3_data.metadata["env"] == "three_link/env3"
    with pytest.raises(ValueError, match=r"^mixed was collected on three_link/env3, the "
                                         r"learner's environment is three_link/env2$"):
        od.check_environment(env3_data, envs.make("three_link/env2"), name="mixed")


def test_matching_environment_accepted(env3_data):
    """The environment id matches through brax names and wrappers."""
    assert od.check_environment(env3_data, envs.make("three_link/env3")) is env3_data
    brax_named = env3_data.replace(metadata=env3_data.metadata.updated(env="three_link_env3"))
    od.check_environment(brax_named, envs.make("three_link_env3"))
    assert od.environment_id(envs.make("three_link/env3", rmp_in_env=True)) == "three_link/env3"
    assert od.environment_id(object()) is None


def test_size_message_names_the_learners_environment():
    """issue case 7: the size message named the dataset's environment as the learner's; it now
    names the learner's. A dataset without a recorded id is checked on sizes only, with a
    one-line warning."""
    anonymous = _dataset("three_link/env3")
    warned = pytest.warns(UserWarning, match=r"^dataset records no environment id "
                                           r"\(metadata\['env'\]\); only its sizes are checked "
                                           r"against franka$")
    refused = pytest.raises(ValueError, match=r"^dataset has observation size 26, but the "
                                              r"environment 'franka' expects 45$")
    with warned, refused:
        od.check_environment(anonymous, envs.make("franka"))
    with pytest.warns(UserWarning, match="records no environment id"):
        od.check_environment(anonymous, envs.make("three_link/env2"))
