"""In-graph dataset operations: uniform minibatches (:func:`sample`, :func:`sample_with`) and
reward relabelling (:func:`relabel_rewards`, thesis §8.3); docs/design.md §2.4."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from offline.data.table import Dataset, is_traced

RELABELLINGS = ("zero", "random", "negated")


def sample(dataset: Dataset, key: jax.Array, batch_size: int) -> Dataset:
    """A minibatch of ``batch_size`` transitions drawn uniformly with replacement.

    Pure and jittable (``batch_size`` static: ``jax.jit(sample, static_argnames="batch_size")``
    or a closure); the result is a :class:`Dataset` of ``batch_size`` rows with the same
    metadata. Indices come from ``jax.random.randint(key, (batch_size,), 0, N)``.
    """
    return sample_with(dataset, None, key, batch_size)[0]


def sample_with(dataset: Dataset, rows: Any, key: jax.Array, batch_size: int
                ) -> tuple[Dataset, Any]:
    """:func:`sample` together with the same rows of ``rows``, a pytree of per-transition arrays
    (leading size ``N``, e.g. values precomputed for every transition; ``None`` leaves stay
    ``None``). The minibatch is the one :func:`sample` draws with ``key``."""
    if not isinstance(batch_size, int | np.integer) or batch_size <= 0:
        raise ValueError(f"batch_size must be a positive (static) integer, got {batch_size!r}")
    n = dataset.rewards.shape[0]
    if n == 0:
        raise ValueError("cannot sample from an empty dataset (N = 0)")
    bad = [x.shape for x in jax.tree.leaves(rows) if x.shape[:1] != (n,)]
    if bad:
        raise ValueError(f"rows must have one entry per transition ({n}), got shapes {bad}")
    idx = jax.random.randint(key, (int(batch_size),), 0, n)
    take = lambda x: jnp.take(x, idx, axis=0)  # noqa: E731
    return jax.tree.map(take, dataset), jax.tree.map(take, rows)


def relabel_rewards(dataset: Dataset, fn: str | Callable[[Dataset], Any] | Any, *,
                    key: jax.Array | None = None) -> Dataset:
    """The dataset with new rewards (thesis §8.3 wrong-reward experiments, PLfO labelling).

    ``fn`` is one of

    * ``"zero"`` — all rewards 0; ``"negated"`` — ``−r``; ``"random"`` — i.i.d. ``U[0, 1]``
      (needs ``key``);
    * a callable ``fn(dataset) -> (N,)`` array (e.g. a learned reward model applied to
      ``observations`` / ``next_observations``);
    * an ``(N,)`` array of rewards.

    The new rewards keep the dataset's reward dtype. The relabelling is recorded in
    ``metadata["reward_relabel"]`` (a list, oldest first). Jittable when ``fn`` is (the
    finiteness check runs only on concrete arrays).
    """
    rewards = dataset.rewards
    n, dtype = rewards.shape[0], rewards.dtype
    if isinstance(fn, str):
        if fn not in RELABELLINGS:
            raise ValueError(f"unknown relabelling fn={fn!r}; valid names are "
                             f"{list(RELABELLINGS)} or a callable / array")
        if fn == "zero":
            new = jnp.zeros_like(rewards)
        elif fn == "negated":
            new = -rewards
        else:
            if key is None:
                raise ValueError("relabel_rewards(fn='random') needs a PRNG key (key=...)")
            new = jax.random.uniform(key, (n,), dtype=dtype)
        label = fn
    elif callable(fn):
        new = fn(dataset)
        label = getattr(fn, "__name__", type(fn).__name__)
    else:
        new = fn
        label = "array"
    if not hasattr(new, "shape"):
        new = np.asarray(new)
    if tuple(new.shape) != (n,):
        raise ValueError(f"relabelled rewards must have shape ({n},), got {tuple(new.shape)}")
    new = new.astype(dtype)
    if not is_traced(new) and not np.isfinite(np.asarray(new)).all():
        raise ValueError(f"relabelled rewards ({label}) contain non-finite values")
    history = list(dataset.metadata.get("reward_relabel", []))
    return dataset.replace(rewards=new,
                           metadata=dataset.metadata.updated(reward_relabel=[*history, label]))



__all__ = ["RELABELLINGS", "relabel_rewards", "sample", "sample_with"]
