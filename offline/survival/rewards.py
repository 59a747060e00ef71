"""Chapter-8 data: wrong rewards, terminal handling, length bias and the positive-data-bias
estimate (thesis §8.3 "Why offline RL can learn right behaviours from wrong rewards", §8.4.1;
docs/design.md §4.5).

* **Wrong rewards** (§8.4.1): the true reward (``"original"``), the zero reward, i.i.d.
  ``U[0, 1]`` rewards and the negated reward — :data:`REWARD_VARIANTS`, applied with
  :func:`offline.data.dataset.relabel_rewards`.
* **Terminal handling** (docs/design.md §4.5, "report both settings"): ``"keep"`` the collision
  terminals (absorbing, ``d = 1`` in the Bellman target) or ``"remove"`` them
  (:func:`offline.data.scenarios.terminals_as_timeouts`: the learner bootstraps through them) —
  :data:`TERMINAL_MODES`.
* :func:`variant` builds one (reward, terminals) combination of a dataset and records it in the
  metadata (``metadata["survival_variant"]``); :func:`variants` yields all eight of one dataset,
  :func:`variant_grid` those of every recipe dataset of :func:`offline.data.collect.collect_recipe`.
* **Length bias** (§8.3.3, Fig 8.5): :func:`length_bias_statistics` gives the per-episode
  (length, return) scatter, their correlation, the fraction of cut episodes and the mean length
  of successful vs failed episodes. Datasets *without* length bias come from
  ``offline.data.collect.collect_recipe(..., cut_at_collision=False)`` (every episode runs the full
  horizon, like D4RL's halfcheetah in §8.4.1).
* **Designed length bias by a goal deadline** (the issue's "timeout-before-goal" cut):
  :func:`cut_before_goal` ends every episode that has not brought the end effector within the
  success radius of the goal by its ``deadline``-th transition there, with a **terminal** (a
  failed episode, absorbing as a collision), and keeps the episodes that arrive in time whole.
  Failures are then short and successes long: the length bias of §8.3.3 by construction, on
  top of (or instead of) the collision cut.
* **The goal as the absorbing state** (§8.3.1 and §8.4.1's "goal-oriented problems have data
  bias": successful trajectories end in a termination signal, i.e. unbounded length, failed
  ones have a bounded length; footnote 4: terminals are removed where they mark failures):
  :func:`absorbing_goal` ends every episode whose last next observation is within the success
  radius with a **terminal** and every other episode with a **timeout**. Under pessimism a
  successful episode's value chain is then anchored by its terminal, while a failed one runs
  into a state with no data after it, which a pessimistic critic may value as low as it likes.
  With ``at_arrival=True`` a successful episode ends at its first step into the goal region,
  as the thesis's Meta-World data do, rather than at the horizon.
* **The goal-oriented reward form** (thesis §7.4.2: "a non-positive reward function that
  promotes the agent to reach the goal, which is a terminal state, as fast as possible"; §8.4.1:
  under the random and the negated reward "reward for each step is non-negative"):
  :func:`goal_oriented` shifts the environment's reward by its maximum, ``r − r_max ≤ 0``. The
  reaching reward itself is positive near the goal (docs/design.md §4.3), so its plain negation
  costs the agent for approaching the goal; after the shift the negated reward is
  ``r_max − r ≥ 0``, the wrong reward the thesis's goal-oriented experiments use. Zero and
  random rewards do not depend on the form (:data:`FORM_DEPENDENT` names those that do).
* **Positive data bias** (eq 8.3): :func:`positive_data_bias`.
"""

from __future__ import annotations

import zlib
from collections.abc import Iterator, Mapping
from typing import Any

import jax
import numpy as np

from offline.data import dataset as odata
from offline.data.scenarios import terminals_as_timeouts

#: Data rewards of thesis §8.4.1: the true one and the three wrong ones.
REWARD_VARIANTS = ("original", "zero", "random", "negated")
#: What happens to collision terminals: kept (absorbing) or turned into timeouts.
TERMINAL_MODES = ("keep", "remove")
#: The wrong rewards eq 8.3 takes the worst score over.
WRONG_REWARDS = ("zero", "random", "negated")
#: Forms of the true reward: the environment's own, or shifted to be non-positive (goal-oriented).
REWARD_FORMS = ("env", "goal")
#: Data rewards computed from the true reward, so they change with its form.
FORM_DEPENDENT = ("original", "negated")


def variant_name(reward: str, terminals: str) -> str:
    """The name of a (reward, terminals) combination, e.g. ``"zero-keep"``."""
    _check_variant(reward, terminals)
    return f"{reward}-{terminals}"


def _check_variant(reward: str, terminals: str) -> None:
    if reward not in REWARD_VARIANTS:
        raise ValueError(f"reward must be one of {list(REWARD_VARIANTS)}, got {reward!r}")
    if terminals not in TERMINAL_MODES:
        raise ValueError(f"terminals must be one of {list(TERMINAL_MODES)}, got {terminals!r}")


def variant(dataset: odata.Dataset, reward: str, terminals: str,
            key: jax.Array | None = None) -> odata.Dataset:
    """``dataset`` with the data reward ``reward`` and terminal handling ``terminals``.

    ``reward``: ``"original"`` keeps the rewards; ``"zero"`` (all 0), ``"random"`` (i.i.d.
    ``U[0, 1]`` from ``key``, required) and ``"negated"`` (``−r``) are the wrong rewards of
    thesis §8.4.1 (:func:`offline.data.dataset.relabel_rewards`, which also appends to
    ``metadata["reward_relabel"]``). ``terminals``: ``"keep"`` or ``"remove"`` (every terminal
    becomes a timeout, :func:`offline.data.scenarios.terminals_as_timeouts`). The result's
    ``metadata["survival_variant"]`` is ``{"name", "reward", "terminals"}``.
    """
    _check_variant(reward, terminals)
    odata.validate(dataset)
    out = dataset if reward == "original" else odata.relabel_rewards(dataset, reward, key=key)
    if terminals == "remove":
        out = terminals_as_timeouts(out)
    return out.replace(metadata=out.metadata.updated(survival_variant={
        "name": variant_name(reward, terminals), "reward": reward, "terminals": terminals}))


def variants(dataset: odata.Dataset, key: jax.Array) -> Iterator[tuple[str, odata.Dataset]]:
    """Every ``(name, variant(dataset, reward, terminals, key))``, rewards outer, in the order
    of :data:`REWARD_VARIANTS` × :data:`TERMINAL_MODES`. Both terminal modes of ``"random"``
    use ``key``, so they carry the same random rewards and differ only in their flags."""
    for reward in REWARD_VARIANTS:
        for terminals in TERMINAL_MODES:
            yield variant_name(reward, terminals), variant(dataset, reward, terminals, key)


def variant_grid(datasets: Mapping[str, odata.Dataset], key: jax.Array
                 ) -> Iterator[tuple[str, str, odata.Dataset]]:
    """``(recipe, variant name, dataset)`` for every dataset of ``datasets`` (e.g. recipe name
    → :func:`offline.data.collect.collect_recipe` dataset) and every variant (:func:`variants`).
    Recipe ``r`` draws its random rewards from ``fold_in(key, crc32(r))``, so a recipe's
    variants do not depend on which other recipes are in the grid."""
    for recipe, ds in datasets.items():
        sub = jax.random.fold_in(key, zlib.crc32(recipe.encode()) & 0x7FFFFFFF)
        for name, out in variants(ds, sub):
            yield recipe, name, out


def _mean_or_nan(x: np.ndarray) -> float:
    return float(x.mean()) if x.size else float("nan")


def length_bias_statistics(dataset: odata.Dataset, *, success: Any = None,
                           success_quantile: float = 0.75) -> dict[str, Any]:
    """The length bias of ``dataset`` (thesis §8.3.3 and Fig 8.5), as a JSON-ready dict.

    * ``episode_ids``, ``lengths``, ``returns`` — the Fig 8.5 scatter (one point per episode:
      length, undiscounted true return), in order of appearance;
    * ``length_return_correlation`` — Pearson correlation of length and return; NaN when it is
      undefined (fewer than two episodes, or all lengths or all returns equal — e.g. a dataset
      collected with ``cut_at_collision=False``, where every episode has the horizon's length);
    * ``cut_fraction`` — fraction of episodes ending in a terminal (cut at a collision);
    * ``mean_length_success`` / ``mean_length_failure`` (NaN for an empty group) and
      ``num_success``. Success per episode is ``success`` when given (a boolean array with one
      entry per episode, e.g. ``offline.data.rollouts.rollout(...)["episode"]["success"]``;
      ``success_source = "given"``). The collector's metadata holds only aggregate success
      rates, not per-episode flags, so otherwise the episodes whose return is at least the
      ``success_quantile`` quantile of the returns (NumPy's linear interpolation; ties all
      count) are called successful (``success_source = "top_return_quantile"``, threshold in
      ``success_threshold``).

    Returns must be the true ones: a dataset whose rewards were relabelled
    (``metadata["reward_relabel"]``) raises ``ValueError``.
    """
    odata.validate(dataset)
    if dataset.metadata.get("reward_relabel"):
        raise ValueError(f"dataset rewards were relabelled ({dataset.metadata['reward_relabel']})"
                         f"; length_bias_statistics needs the true rewards")
    if not 0.0 <= float(success_quantile) <= 1.0:
        raise ValueError(f"success_quantile must lie in [0, 1], got {success_quantile!r}")
    per, _ = odata.episode_statistics(dataset)
    k = per.episode_ids.size
    lengths, returns = per.lengths.astype(np.float64), per.returns
    threshold = None
    if success is not None:
        won = np.asarray(success)
        if won.shape != (k,) or won.dtype != np.bool_:
            raise ValueError(f"success must be a boolean array of shape (num_episodes,) = "
                             f"({k},), got dtype {won.dtype} and shape {won.shape}")
        source = "given"
    else:
        threshold = float(np.quantile(returns, success_quantile)) if k else float("nan")
        won = returns >= threshold
        source = "top_return_quantile"
    defined = k >= 2 and np.ptp(lengths) > 0 and np.ptp(returns) > 0
    corr = float(np.corrcoef(lengths, returns)[0, 1]) if defined else float("nan")
    return {
        "num_episodes": int(k),
        "episode_ids": per.episode_ids.tolist(),
        "lengths": per.lengths.tolist(),
        "returns": returns.tolist(),
        "length_return_correlation": corr,
        "cut_fraction": _mean_or_nan(per.terminated.astype(np.float64)),
        "success_source": source,
        "success_threshold": threshold,
        "num_success": int(won.sum()),
        "mean_length_success": _mean_or_nan(lengths[won]),
        "mean_length_failure": _mean_or_nan(lengths[~won]),
    }


def goal_distances(dataset: odata.Dataset, which: str = "next_observations") -> np.ndarray:
    """``‖g − x‖`` per transition from the ``goal_minus_x`` block of the observation layout
    recorded in the dataset's metadata (:func:`offline.data.rollouts.environment_metadata`), for
    ``which`` = ``"observations"`` or ``"next_observations"``; float64 ``(N,)``."""
    layout = dataset.metadata.get("observation_layout")
    if not layout or "goal_minus_x" not in layout:
        raise ValueError("dataset metadata has no observation_layout with a 'goal_minus_x' "
                         "block (collect it with offline.data.collect)")
    if which not in ("observations", "next_observations"):
        raise ValueError(f"which must be 'observations' or 'next_observations', got {which!r}")
    start, stop = layout["goal_minus_x"]
    block = np.asarray(getattr(dataset, which), np.float64)[:, start:stop]
    return np.linalg.norm(block, axis=-1)


def arrived_by(dataset: odata.Dataset, deadline: int, radius: float = 0.05) -> np.ndarray:
    """Per episode (in order): whether the end effector is within ``radius`` of the goal
    (``next_observations``, :func:`goal_distances`) at any of its first ``deadline``
    transitions; bool ``(num_episodes,)``. Host-side; the arguments are not checked."""
    ids = np.asarray(dataset.episode_ids)
    starts, lengths = odata.episode_bounds(ids)
    if not starts.size:
        return np.zeros(0, bool)
    position = np.arange(ids.size) - np.repeat(starts, lengths)
    early = (goal_distances(dataset) < radius) & (position < deadline)
    return np.logical_or.reduceat(early, starts)


def cut_before_goal(dataset: odata.Dataset, deadline: int, radius: float = 0.05
                    ) -> odata.Dataset:
    """``dataset`` with a designed length bias (module docstring): an episode whose end
    effector is not within ``radius`` of the goal (``next_observations``, :func:`goal_distances`)
    at any of its first ``deadline`` transitions keeps only those, the last one a terminal (its
    timeout cleared); episodes that arrive in time, or end before the deadline, are unchanged.
    Host-side; records ``metadata["goal_deadline"] = {"deadline", "radius", "cut_episodes"}``.
    The default radius is the reaching environments' success radius (0.05 m)."""
    odata.validate(dataset)
    if not (isinstance(deadline, int | np.integer) and not isinstance(deadline, bool)
            and deadline >= 1):
        raise ValueError(f"deadline must be an integer >= 1, got {deadline!r}")
    if not (isinstance(radius, int | float) and radius > 0):
        raise ValueError(f"radius must be a positive number, got {radius!r}")
    ids = np.asarray(dataset.episode_ids)
    starts, lengths = odata.episode_bounds(ids)
    position = np.arange(ids.size) - np.repeat(starts, lengths)
    cut = ~arrived_by(dataset, deadline, radius) & (lengths > deadline)
    cut_rows = np.repeat(cut, lengths)
    keep = ~cut_rows | (position < deadline)
    out = odata.take_rows(dataset, keep)
    last = (cut_rows & (position == deadline - 1))[keep]
    terminals = np.where(last, 1, np.asarray(out.terminals)).astype(np.asarray(out.terminals).dtype)
    timeouts = np.where(last, 0, np.asarray(out.timeouts)).astype(np.asarray(out.timeouts).dtype)
    meta = out.metadata.updated(goal_deadline={"deadline": int(deadline), "radius": float(radius),
                                               "cut_episodes": int(cut.sum())})
    return odata.validate(out.replace(terminals=terminals, timeouts=timeouts, metadata=meta))


def absorbing_goal(dataset: odata.Dataset, radius: float = 0.05, *,
                   at_arrival: bool = False) -> odata.Dataset:
    """``dataset`` with the goal as its only absorbing state (module docstring; thesis §8.3.1,
    §8.4.1): the last transition of an episode whose last next observation is within ``radius``
    of the goal (:func:`goal_distances`) becomes a terminal, the last transition of every other
    episode a timeout, and no other transition ends an episode (collision terminals become
    timeouts). Host-side.

    With ``at_arrival`` an episode ends at its **first** transition into the goal region (the
    rest of it is dropped), as in the thesis's Meta-World data (§8.4.1: a successful trajectory
    ends with the termination signal when it reaches the goal), so the terminal sits where the
    agent arrives rather than after it has lingered there; otherwise transitions are unchanged.
    Records ``metadata["absorbing_goal"] = {"radius", "episodes_at_goal", "at_arrival"}``."""
    odata.validate(dataset)
    if not (isinstance(radius, int | float) and not isinstance(radius, bool) and radius > 0):
        raise ValueError(f"radius must be a positive number, got {radius!r}")
    if at_arrival:
        ids = np.asarray(dataset.episode_ids)
        starts, lengths = odata.episode_bounds(ids)
        inside = goal_distances(dataset) < radius
        before = np.cumsum(inside) - np.repeat(np.cumsum(inside)[starts] - inside[starts],
                                                lengths)  # arrivals so far, this one included
        dataset = odata.take_rows(dataset, (before == 0) | (inside & (before == 1)))
    ids = np.asarray(dataset.episode_ids)
    starts, lengths = odata.episode_bounds(ids)
    last = np.zeros(ids.size, bool)
    last[starts + lengths - 1] = True
    at_goal = last & (goal_distances(dataset) < radius)
    dtype = np.asarray(dataset.terminals).dtype
    meta = dataset.metadata.updated(absorbing_goal={"radius": float(radius),
                                                    "episodes_at_goal": int(at_goal.sum()),
                                                    "at_arrival": bool(at_arrival)})
    return odata.validate(dataset.replace(terminals=at_goal.astype(dtype),
                                          timeouts=(last & ~at_goal).astype(dtype),
                                          metadata=meta))


def goal_oriented(dataset: odata.Dataset, reward_max: float | None = None) -> odata.Dataset:
    """``dataset`` with the goal-oriented form of its true reward, ``r − reward_max`` (module
    docstring; thesis §7.4.2, §8.4.1): every reward becomes non-positive, so the goal's
    terminal, after which nothing is paid, is the best place to be, and the negated reward
    (:func:`variant`) becomes ``reward_max − r ≥ 0``. ``reward_max`` defaults to the upper end
    of the environment's reward range recorded by the collector (``metadata["reward_range"]``).
    Refuses relabelled rewards (the shift is of the true reward) and rewards above
    ``reward_max``. Records ``metadata["reward_form"] = {"form": "goal", "reward_max"}``."""
    odata.validate(dataset)
    if dataset.metadata.get("reward_relabel"):
        raise ValueError(f"dataset rewards were relabelled ({dataset.metadata['reward_relabel']})"
                         f"; goal_oriented shifts the true rewards")
    if dataset.metadata.get("reward_form"):
        raise ValueError("dataset rewards are already in the goal-oriented form")
    if reward_max is None:
        reward_range = dataset.metadata.get("reward_range")
        if reward_range is None:
            raise ValueError("reward_max not given and the dataset metadata has no "
                             "reward_range (collect it with offline.data.collect)")
        reward_max = reward_range[1]
    if isinstance(reward_max, bool) or not np.isfinite(reward_max):
        raise ValueError(f"reward_max must be a finite number, got {reward_max!r}")
    rewards = np.asarray(dataset.rewards)
    top = float(rewards.max()) if rewards.size else -np.inf
    if top > reward_max:
        raise ValueError(f"dataset has a reward of {top:g} above reward_max = {reward_max:g}")
    shifted = (rewards.astype(np.float64) - float(reward_max)).astype(rewards.dtype)
    meta = dataset.metadata.updated(reward_form={"form": "goal",
                                                 "reward_max": float(reward_max)})
    return odata.validate(dataset.replace(rewards=shifted, metadata=meta))


def positive_data_bias(scores: Mapping[str, float], *, optimal: float = 100.0) -> float:
    """The empirical positive-data-bias estimate of thesis eq 8.3 (Fig 8.6, docs/design.md §4.5):

    ``Ĵ* / max(Ĵ* − min(J_zero, J_random, J_negated), 0)``

    with ``scores`` the true-reward scores of the policies learned with the wrong rewards
    (keys ``"zero"``, ``"random"``, ``"negated"``; other keys such as ``"original"`` are
    ignored) and ``optimal = Ĵ*`` (100 for normalised scores: expert 100, random 0). It is
    ``inf`` when a wrong-reward score reaches (or exceeds) ``Ĵ*``; larger means a stronger
    positive bias, 1 when the worst wrong-reward score is 0.
    """
    if not isinstance(scores, Mapping):
        raise ValueError(f"scores must be a mapping from reward name to score, got "
                         f"{type(scores).__name__}")
    missing = [r for r in WRONG_REWARDS if r not in scores]
    if missing:
        raise ValueError(f"scores lacks the wrong-reward score(s) {missing}; eq 8.3 needs "
                         f"{list(WRONG_REWARDS)}")
    values = {r: float(scores[r]) for r in WRONG_REWARDS}
    bad = {r: v for r, v in values.items() if not np.isfinite(v)}
    if bad:
        raise ValueError(f"scores must be finite, got {bad}")
    if not (np.isfinite(optimal) and optimal > 0):
        raise ValueError(f"optimal (the estimated optimal score J*) must be finite and > 0, "
                         f"got {optimal!r}")
    gap = max(float(optimal) - min(values.values()), 0.0)
    return float("inf") if gap == 0.0 else float(optimal) / gap


__all__ = [
    "FORM_DEPENDENT",
    "REWARD_FORMS",
    "REWARD_VARIANTS",
    "TERMINAL_MODES",
    "WRONG_REWARDS",
    "absorbing_goal",
    "arrived_by",
    "cut_before_goal",
    "goal_distances",
    "goal_oriented",
    "length_bias_statistics",
    "positive_data_bias",
    "variant",
    "variant_grid",
    "variant_name",
    "variants",
]
