"""PPO (thesis §6.2.3) for the reaching tasks, one concept per module.

* :mod:`agents.ppo.config` — :class:`PPOConfig` and its ``thesis()`` preset;
* :mod:`agents.ppo.losses` — GAE and the clipped-surrogate/value/entropy loss;
* :mod:`agents.ppo.networks` — Gaussian policy and value MLPs;
* :mod:`agents.ppo.normalization` — running observation statistics;
* :mod:`agents.ppo.policies` — the policy classes of thesis §6.2.2 (NN, residuals, RMP²);
* :mod:`agents.ppo.state` — the train state and transitions;
* :mod:`agents.ppo.rollout` — acting in the batched environments;
* :mod:`agents.ppo.update` — the SGD epochs of one iteration;
* :mod:`agents.ppo.hparams` — scalar hyper-parameters as per-run data (packed sweeps);
* :mod:`agents.ppo.sharding` — data parallelism over a device mesh;
* :mod:`agents.ppo.train` — ``make_train(env, policy, config) -> train(key)`` and
  ``make_trainer`` for chunked or sharded runs.
"""

from agents.ppo import (
    config,
    hparams,
    losses,
    networks,
    normalization,
    policies,
    rollout,
    sharding,
    state,
    train,
    update,
)
from agents.ppo.config import PPOConfig
from agents.ppo.losses import gae, gaussian_entropy, gaussian_log_prob, ppo_loss
from agents.ppo.networks import GaussianPolicy, PPONetworks, ValueMLP
from agents.ppo.policies import KINDS, make_env_and_policy, make_policy
from agents.ppo.sharding import make_mesh
from agents.ppo.state import TrainState, Transition
from agents.ppo.train import Trainer, make_train, make_trainer

__all__ = [
    "KINDS",
    "GaussianPolicy",
    "PPOConfig",
    "PPONetworks",
    "TrainState",
    "Trainer",
    "Transition",
    "ValueMLP",
    # the modules, so that the API reference lists them
    "config",
    "gae",
    "gaussian_entropy",
    "gaussian_log_prob",
    "hparams",
    "losses",
    "make_env_and_policy",
    "make_mesh",
    "make_policy",
    "make_train",
    "make_trainer",
    "networks",
    "normalization",
    "policies",
    "ppo_loss",
    "rollout",
    "sharding",
    "state",
    "train",
    "update",
]
