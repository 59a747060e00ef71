"""Offline datasets of named recipes, collected inside one compiled graph (thesis chapters 7–8,
docs/design.md §2.4).

:func:`collect` rolls out a behaviour policy (:mod:`offline.data.behaviours`, also importable
from here) for ``num_episodes`` episodes with :func:`offline.data.rollouts.rollout` (no
auto-reset; episodes cut at collisions unless ``cut_at_collision=False``; the recorded action is
the one the environment applied) and turns the arrays into a
:class:`~offline.data.dataset.Dataset`; :func:`collect_recipe` concatenates the sources of a
D4RL-style recipe.

**Determinism.** Episode ``i`` of a source uses the key ``fold_in(source_key, i)``, split into a
reset key (scene) and an action key (``fold_in(action_key, t)`` at step ``t`` for the noise).
A source's key is ``fold_in(PRNGKey(seed), crc32(role:name))``. The data therefore depend only
on the seed, the source and the episode index — not on the batch size, the chunking, or which
other sources a recipe has — and a larger ``scale`` extends a dataset (its first episodes are
those of the smaller one).

**Recipes** (:func:`collect_recipe`, in the spirit of D4RL; ``n = scale`` episodes per source):

=================  ============================================  ==============================
recipe             sources with a PPO run (``ppo_run``)          without a PPO run (FALLBACK)
=================  ============================================  ==============================
``random``         ``random`` ×n                                 same
``medium``         ``ppo-medium`` ×n                             ``noisy-0.5`` ×n as "medium"
``medium-replay``  the run's checkpoints up to the medium one    ``random``, ``noisy-1.0``,
                   (``ppo-replay-<step>``, stochastic), n split  ``noisy-0.5`` (n split evenly,
                   evenly over them, earliest first              in that order)
``medium-expert``  medium ×n + ``expert`` ×n                     ``noisy-0.5`` ×n +
                                                                 ``expert`` ×n
``expert``         ``expert`` ×n                                 same
``mixed``          ``random``, ``noisy-1.0``, ``noisy-0.5``,     ``random``, ``noisy-1.0``,
                   ``noisy-0.1``, ``ppo-low``, ``ppo-medium``    ``noisy-0.5``, ``noisy-0.1``
                   ×n each + medium-replay (n split)             ×n each (no PPO sources)
=================  ============================================  ==============================

Splitting n over k parts gives the first ``n mod k`` parts one episode more. Sources appear in
the dataset in the order listed; a source's episodes are identical in every recipe that has it
(same seed, role and behaviour), e.g. ``expert`` in ``expert`` and ``medium-expert``.

* ``ppo-medium`` is the run's checkpoint ``ppo_step`` (default: its newest), ``ppo-low`` its
  earliest checkpoint; both act stochastically unless ``ppo_stochastic=False``; medium-replay
  always samples (it stands for the data PPO collected while training). "Medium" quality is
  whatever checkpoint is passed: choose one whose return is well below the expert's. A run keeps
  only its 3 newest checkpoints unless it was trained with ``scripts/train.py
  --keep-checkpoints 0`` (``RunSpec.keep_checkpoints=None``), so train it that way for a
  medium-replay dataset that covers the whole run.
* ``mixed`` is the union of every non-expert source: random, the noisy experts (the thesis'
  Meta-World mixed data, §7.4.2) and the PPO snapshots (the D4RL mixed data, §7.4.1).
* **Fallback — read this.** Without a PPO run, ``medium`` / ``medium-expert`` /
  ``medium-replay`` contain *no PPO data*: "medium" is the expert with Gaussian noise σ = 0.5 and
  "medium-replay" the sequence random → σ 1.0 → σ 0.5; ``mixed`` simply lacks the PPO sources.
  The dataset's ``metadata["fallback"]`` says so in words (``None`` when no fallback was used),
  :func:`collect_recipe` emits a ``UserWarning`` and ``scripts/collect.py`` prints a warning.
* **The noisy experts are not much worse than the expert.** Measured on the same 128 scenes
  (seed 0, 600 steps, CPU): mean return expert / σ 0.1 / σ 0.5 / σ 1.0 / random = 243.6 /
  243.0 / 236.0 / 207.0 / −6.8 on 3-link env3 (safe 100 / 100 / 100 / 97.7 / 79.7 %), 278.4 /
  277.7 / 272.6 / 254.3 / −3.6 on env1. The σ = 0.5 "medium" stand-in thus reaches ~97 % of
  the expert's return — far above D4RL's "medium" (about a third of expert); the quality gap
  in fallback data is between random and everything else.

Every dataset's metadata records the environment (name, constructor arguments, horizon, action
limit, reward range, observation layout), the seed, the recipe and for each source its role,
behaviour, episode count, the episode-id range it occupies and its summary statistics (mean
return, terminals, timeouts, safe % and success %).
"""


from __future__ import annotations

import dataclasses
import os
import warnings
from collections.abc import Callable, Mapping
from typing import Any

import jax
import numpy as np

import envs as envs_pkg
from agents.run.loading import checkpoint_steps
from offline.data import dataset as odata
from offline.data.behaviours import (
    NOISE_LEVELS,
    Behaviour,
    expert,
    noisy_expert,
    ppo_policy,
    uniform_random,
)
from offline.data.rollouts import environment_metadata, rollout, source_key, to_dataset

#: Recipe names accepted by :func:`collect_recipe` (see the module docstring).
RECIPES = ("random", "medium", "medium-replay", "medium-expert", "expert", "mixed")
#: σ of the noisy expert that stands in for "medium" without a PPO run.
FALLBACK_MEDIUM_SIGMA = 0.5


def _cut_metadata(cut_at_collision: bool) -> dict[str, Any]:
    """``{"cut_at_collision": False}`` for uncut data, nothing for the default."""
    return {} if cut_at_collision else {"cut_at_collision": False}


def _source_summary(ds: odata.Dataset, ep: Mapping[str, np.ndarray]) -> dict[str, Any]:
    _, s = odata.episode_statistics(ds)
    return {
        "episodes": s["num_episodes"],
        "transitions": s["num_transitions"],
        "return_mean": s["return_mean"],
        "return_std": s["return_std"],
        "length_mean": s["length_mean"],
        "terminals": s["num_terminals"],
        "timeouts": s["num_timeouts"],
        "safe_pct": 100.0 * float(np.mean(ep["safe"])),
        "success_pct": 100.0 * float(np.mean(ep["success"])),
        "nonfinite_episodes": int(np.sum(ep["nonfinite"] > 0)),
    }


def collect(env_name: str, behaviour: Behaviour, num_episodes: int, *, seed: int = 0,
            key: jax.Array | None = None, env_kwargs: Mapping[str, Any] | None = None,
            horizon: int | None = None, batch_size: int | None = None,
            metadata: Mapping[str, Any] | None = None,
            progress: Callable[[str], None] | None = None,
            cut_at_collision: bool = True) -> odata.Dataset:
    """A :class:`offline.data.dataset.Dataset` of ``num_episodes`` episodes of ``behaviour`` on
    ``env_name`` (see the module docstring). ``key`` (default ``PRNGKey(seed)``) drives scenes
    and noise; ``metadata`` entries are added to the recorded ones. ``cut_at_collision=False``
    gives full-horizon episodes without collision terminals (no length bias, thesis §8.3.3;
    module docstring) and records ``metadata["cut_at_collision"] = False``."""
    if key is None:
        key = jax.random.PRNGKey(seed)
    traj = rollout(env_name, behaviour, num_episodes, key, env_kwargs=env_kwargs,
                   horizon=horizon, batch_size=batch_size, progress=progress,
                   cut_at_collision=cut_at_collision)
    meta = {**environment_metadata(env_name, env_kwargs, horizon), "seed": int(seed),
            "behaviour": behaviour.describe(), "num_episodes": int(num_episodes),
            **_cut_metadata(cut_at_collision)}
    ds = to_dataset(traj, meta)
    summary = _source_summary(ds, traj["episode"])
    return ds.replace(metadata=ds.metadata.updated(summary=summary, **dict(metadata or {})))


# --------------------------------------------------------------------------------------------
# Recipes


@dataclasses.dataclass(frozen=True)
class Source:
    """One part of a recipe: ``episodes`` episodes of ``behaviour`` in the role ``role``
    (``"random"``, ``"medium"``, ``"medium-replay"``, ``"expert"``, ``"noisy"``, ``"low"``);
    ``fallback`` marks a stand-in for missing PPO data."""

    role: str
    behaviour: Behaviour
    episodes: int
    fallback: bool = False


def _split(n: int, k: int) -> list[int]:
    return [n // k + (1 if i < n % k else 0) for i in range(k)]


def recipe_sources(recipe: str, scale: int, *, ppo_run: str | os.PathLike | None = None,
                   ppo_step: int | None = None, ppo_seed_index: int = 0,
                   ppo_stochastic: bool = True) -> tuple[list[Source], str | None]:
    """``(sources, fallback)`` of ``recipe`` with ``scale`` episodes per source (the table of
    the module docstring); ``fallback`` is a sentence saying what stands in for missing PPO
    data, or None. Sources with zero episodes are left out."""
    if recipe not in RECIPES:
        raise ValueError(f"unknown recipe={recipe!r}; valid recipes are {list(RECIPES)}")
    if not isinstance(scale, int | np.integer) or scale < 1:
        raise ValueError(f"scale must be a positive integer, got {scale!r}")
    n = int(scale)
    fallback = None
    if ppo_run is not None:
        steps = checkpoint_steps(ppo_run)
        if not steps:
            raise FileNotFoundError(f"PPO run {os.fspath(ppo_run)!r} has no checkpoint")
        medium_step = steps[-1] if ppo_step is None else int(ppo_step)
        if medium_step not in steps:
            raise ValueError(f"ppo_step={ppo_step!r} is not a checkpoint of {ppo_run!r}; "
                             f"available steps are {steps}")
        run = os.fspath(ppo_run)
        medium = [Source("medium", ppo_policy(run, medium_step, seed_index=ppo_seed_index,
                                              stochastic=ppo_stochastic,
                                              name=f"ppo-medium-step{medium_step}"), n)]
        low = [Source("low", ppo_policy(run, steps[0], seed_index=ppo_seed_index,
                                        stochastic=ppo_stochastic,
                                        name=f"ppo-low-step{steps[0]}"), n)]
        replay_steps = [s for s in steps if s <= medium_step]
        replay = [Source("medium-replay",
                         ppo_policy(run, s, seed_index=ppo_seed_index, stochastic=True,
                                    name=f"ppo-replay-step{s}"), m)
                  for s, m in zip(replay_steps, _split(n, len(replay_steps)), strict=True)]
    else:
        medium = [Source("medium", noisy_expert(FALLBACK_MEDIUM_SIGMA), n, fallback=True)]
        low = []
        replay = [Source("medium-replay", b, m, fallback=True)
                  for b, m in zip((uniform_random(), noisy_expert(1.0),
                                   noisy_expert(FALLBACK_MEDIUM_SIGMA)), _split(n, 3),
                                  strict=True)]
    exp = [Source("expert", expert(), n)]
    rand = [Source("random", uniform_random(), n)]
    noisy = [Source("noisy", noisy_expert(s), n) for s in sorted(NOISE_LEVELS, reverse=True)]
    table = {
        "random": rand,
        "medium": medium,
        "medium-replay": replay,
        "medium-expert": medium + exp,
        "expert": exp,
        "mixed": rand + noisy + (low + medium + replay if ppo_run is not None else []),
    }
    sources = [s for s in table[recipe] if s.episodes > 0]
    if ppo_run is None and recipe in ("medium", "medium-replay", "medium-expert"):
        what = {"medium": f"'medium' is the expert with Gaussian action noise sigma="
                          f"{FALLBACK_MEDIUM_SIGMA}",
                "medium-expert": f"its 'medium' half is the expert with Gaussian action noise "
                                 f"sigma={FALLBACK_MEDIUM_SIGMA}",
                "medium-replay": "'medium-replay' is random -> noisy expert sigma=1.0 -> "
                                 f"sigma={FALLBACK_MEDIUM_SIGMA}"}[recipe]
        fallback = f"FALLBACK: no PPO run given, this dataset contains no PPO data; {what}"
    elif ppo_run is None and recipe == "mixed":
        fallback = ("FALLBACK: no PPO run given, 'mixed' has no PPO sources (random and the "
                    "noisy experts only)")
    return sources, fallback


def collect_recipe(env_name: str, recipe: str, scale: int, *, seed: int = 0,
                   ppo_run: str | os.PathLike | None = None, ppo_step: int | None = None,
                   ppo_seed_index: int = 0, ppo_stochastic: bool = True,
                   env_kwargs: Mapping[str, Any] | None = None, horizon: int | None = None,
                   batch_size: int | None = None,
                   progress: Callable[[str], None] | None = None,
                   cut_at_collision: bool = True) -> odata.Dataset:
    """The dataset of ``recipe`` (module docstring table) with ``scale`` episodes per source.

    Sources are concatenated in table order (episode ids ``0 … K−1``);
    ``metadata["sources"]`` lists each with its role, behaviour, episode count,
    ``episode_ids`` range ``[start, stop)`` and summary; ``metadata["fallback"]`` is None or the
    sentence saying what stands in for missing PPO data (also emitted as a ``UserWarning``).
    ``batch_size`` defaults to ``scale``; every source runs in chunks of exactly that many
    episodes (smaller sources are padded), so all scripted sources share one compiled program
    and all PPO checkpoints of the run another. ``cut_at_collision=False``: every source is
    collected without collision cuts (:func:`collect`).
    """
    sources, fallback = recipe_sources(recipe, scale, ppo_run=ppo_run, ppo_step=ppo_step,
                                       ppo_seed_index=ppo_seed_index,
                                       ppo_stochastic=ppo_stochastic)
    if fallback is not None:
        warnings.warn(fallback, UserWarning, stacklevel=2)
    batch = int(scale if batch_size is None else batch_size)
    parts, described, start = [], [], 0
    for src in sources:
        if progress is not None:
            progress(f"[{recipe}] source {src.behaviour.name} ({src.role}): "
                     f"{src.episodes} episodes")
        ds = collect(env_name, src.behaviour, src.episodes,
                     key=source_key(seed, src.role, src.behaviour.name), seed=seed,
                     env_kwargs=env_kwargs, horizon=horizon, batch_size=batch,
                     progress=progress, cut_at_collision=cut_at_collision)
        parts.append(ds)
        described.append({"role": src.role, "behaviour": src.behaviour.describe(),
                          "episodes": src.episodes, "fallback": src.fallback,
                          "episode_ids": [start, start + src.episodes],
                          "summary": ds.metadata["summary"]})
        start += src.episodes
    meta = {**environment_metadata(env_name, env_kwargs, horizon), "seed": int(seed),
            "recipe": recipe, "scale": int(scale), "num_episodes": start,
            "ppo_run": None if ppo_run is None else os.fspath(ppo_run),
            "fallback": fallback, "sources": described, **_cut_metadata(cut_at_collision)}
    ds = odata.concatenate(*parts, metadata=meta)
    _, summary = odata.episode_statistics(ds)
    return ds.replace(metadata=ds.metadata.updated(summary=summary))


def resolve_request(env: str, recipe: str, episodes: int) -> str:
    """The environment name of a collection request (brax names resolved), after checking that
    it is a data-collection environment (every one but ``point2d``, which has no RMP² expert),
    that ``recipe`` is one of :data:`RECIPES` and ``episodes >= 1`` (``ValueError`` otherwise)."""
    valid_envs = sorted(n for n in envs_pkg.ENVIRONMENTS if n != "point2d")
    env_name = envs_pkg.BRAX_NAMES.get(env, env)
    if env_name not in valid_envs:
        raise ValueError(f"unknown --env {env!r}; valid names are {valid_envs}")
    if recipe not in RECIPES:
        raise ValueError(f"unknown --recipe {recipe!r}; valid recipes are {list(RECIPES)}")
    if episodes < 1:
        raise ValueError(f"--episodes must be >= 1, got {episodes}")
    return env_name


def overall_summary(dataset: odata.Dataset) -> dict[str, Any]:
    """The statistics of a recipe dataset as a whole, in the form of its sources' summaries:
    episodes, transitions, return mean and std, terminals, timeouts, and safe % and success %
    (the sources' values weighted by their episodes)."""
    _, summ = odata.episode_statistics(dataset)
    eps = summ["num_episodes"]
    sources = dataset.metadata["sources"]
    safe = [s["summary"]["safe_pct"] * s["episodes"] for s in sources]
    success = [s["summary"]["success_pct"] * s["episodes"] for s in sources]
    return {
        "episodes": eps, "transitions": summ["num_transitions"],
        "return_mean": summ["return_mean"], "return_std": summ["return_std"],
        "terminals": summ["num_terminals"], "timeouts": summ["num_timeouts"],
        "safe_pct": sum(safe) / eps, "success_pct": sum(success) / eps,
    }


def source_of_episodes(dataset: odata.Dataset) -> np.ndarray:
    """Per-transition index into ``metadata["sources"]`` of a recipe dataset (host-side)."""
    ids = np.asarray(dataset.episode_ids)
    out = np.full(ids.shape, -1, np.int64)
    for i, s in enumerate(dataset.metadata["sources"]):
        lo, hi = s["episode_ids"]
        out[(ids >= lo) & (ids < hi)] = i
    return out



__all__ = [
    "FALLBACK_MEDIUM_SIGMA",
    "RECIPES",
    "Behaviour",
    "Source",
    "collect",
    "collect_recipe",
    "expert",
    "noisy_expert",
    "overall_summary",
    "ppo_policy",
    "recipe_sources",
    "resolve_request",
    "source_of_episodes",
    "uniform_random",
]
