"""A one-step offline bandit with a known best action, shared by the actor-critic learner
tests (ATAC/PSPI, IQL, CQL): two-dimensional random states, actions uniform in
``[−LIMIT, LIMIT]``, reward ``1 − 4(a/LIMIT − A_STAR)²`` and every transition terminal, so a
learner that maximises the reward moves its policy from the behaviour's mean action 0 to
``A_STAR · LIMIT``."""

import numpy as np

from offline.data import dataset as odata

LIMIT = 2.0
A_STAR = 0.5  # best normalised action of the bandit
N = 512


def make_bandit() -> odata.Dataset:
    """The bandit's ``N`` transitions (module docstring), seed 0."""
    rng = np.random.default_rng(0)
    obs = rng.uniform(-1, 1, (N, 2)).astype(np.float32)
    act = rng.uniform(-LIMIT, LIMIT, (N, 1)).astype(np.float32)
    rew = (1.0 - 4.0 * (act[:, 0] / LIMIT - A_STAR) ** 2).astype(np.float32)
    nxt = rng.uniform(-1, 1, (N, 2)).astype(np.float32)
    return odata.create(obs, act, rew, nxt, np.ones(N, bool), np.zeros(N, bool), np.arange(N),
                        {"action_limit": LIMIT})


def mean_reward(normalised_actions: np.ndarray) -> float:
    """The bandit's mean reward of actions divided by ``LIMIT`` (the behaviour's is −4/3, the
    best 1)."""
    return float(np.mean(1.0 - 4.0 * (np.asarray(normalised_actions) - A_STAR) ** 2))
