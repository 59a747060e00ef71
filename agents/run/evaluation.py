"""Evaluate training checkpoints: many checkpoints × setups × training seeds × episodes at once.

Every checkpoint (of a run directory written by ``scripts/train.py``, restored with
:func:`agents.run.loading.load_run`) acts, for each of its training seeds, with its
deterministic policy — the Gaussian mean, clipped by the environment — for ``num_episodes``
episodes of ``horizon`` control steps (default: the environment's 600) on each setup (default:
the run's own environment), with :func:`envs.evaluate.make_rollout` (episodes frozen once done,
so the per-episode statistics are exact).

**One compiled call.** Checkpoints of the same environment and policy kind form a group; a
group runs as one ``jax.jit``: for each setup (a branch of a Python loop inside the traced
function, so setups with different observation sizes live side by side) a ``vmap`` over the
stacked (checkpoint, training seed) parameters around the ``vmap`` over episodes. Checkpoints of
different environments or policy kinds cannot share parameter stacks: they are evaluated as
separate groups, one compiled call each. Every member of a group sees the same episodes (scenes
from ``eval_seed``): common random numbers across checkpoints, seeds and runs.

**Other setups.** A policy reads the observation layout it was trained on, so a 3-link policy
runs on another 3-link setup when the observations agree (every setup has three obstacle
slots, size 26; ``env1`` built with ``num_obstacles=1`` has size 16): mismatches are refused
naming both sizes. The report and its table are in :mod:`agents.run.eval_report`.

**Checked inputs.** ``"latest"`` and ``"all"`` mean intact checkpoints (a corrupt one is skipped
with a one-line warning naming it; :mod:`agents.run.checkpoint`); an explicitly requested
corrupt checkpoint, or one whose parameters hold NaN/inf, is refused with an error naming it, so
a diverged policy is never reported (a NaN action reads as zero acceleration and looks safe).
"""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Callable, Sequence

import jax
import numpy as np
from brax.envs.base import Env

from agents.run import checkpoint
from agents.run.loading import (
    LoadedRun,
    PolicyParams,
    checkpoint_steps,
    env_policy,
    make_env,
    mean_action_fn,
    policy_params,
    read_spec,
)
from agents.run.rows import stacked
from envs.evaluate import make_rollout

#: Setups a reaching policy can be evaluated on (every reaching environment).
SETUPS = ("three_link/env1", "three_link/env2", "three_link/env3", "franka")
#: Per-episode statistics of :func:`envs.evaluate.make_rollout` kept by the sweep.
STATS = ("return", "success", "safe", "final_goal_distance", "length", "nonfinite")


def _intact_steps(ckpt_dir: str, newest_only: bool) -> list[int]:
    """Every intact checkpoint step, or only the newest; corrupt ones are warned about."""
    steps = ([checkpoint.latest_intact_step(ckpt_dir)] if newest_only
             else checkpoint.intact_steps(ckpt_dir))
    steps = [s for s in steps if s is not None]
    if not steps:
        raise checkpoint.CorruptCheckpointError(ckpt_dir, "none of its checkpoints is intact")
    return steps


def resolve_steps(run_dir: str, tokens: Sequence[str | int] = ("latest",)) -> list[int]:
    """The checkpoint steps of ``run_dir`` that ``tokens`` name (ascending, distinct):
    ``"all"`` (every intact one), ``"latest"`` (the newest intact one) or iteration numbers;
    corrupt checkpoints skipped for ``"all"``/``"latest"`` are named in a warning. Raises
    ``FileNotFoundError`` for a missing directory or ``run.json``, a run without checkpoints or
    a step it does not have (listing the available ones), and
    :class:`agents.run.checkpoint.CorruptCheckpointError` when no checkpoint is intact."""
    read_spec(run_dir)  # clear errors for a missing directory or run.json first
    available = checkpoint_steps(run_dir)
    ckpt_dir = os.path.join(run_dir, "checkpoints")
    if not available:
        raise FileNotFoundError(f"no checkpoint in {ckpt_dir!r}")
    out: set[int] = set()
    for tok in tokens:
        if tok in ("all", "latest"):
            out.update(_intact_steps(ckpt_dir, newest_only=tok == "latest"))
        else:
            try:
                step = int(tok)
            except ValueError:
                raise ValueError(f"--steps takes 'all', 'latest' or iteration numbers, got "
                                 f"{tok!r}") from None
            if step not in available:
                raise FileNotFoundError(f"{run_dir!r} has no checkpoint of iteration {step}; "
                                        f"available: {available}")
            out.add(step)
    return sorted(out)


def group_key(loaded: LoadedRun) -> tuple:
    """Checkpoints with equal keys can be stacked into one parameter batch: same environment,
    policy kind and policy parameter structure (shapes, dtypes, observation statistics)."""
    one = jax.eval_shape(lambda: policy_params(loaded, 0))
    leaves, treedef = jax.tree.flatten(one)
    return (loaded.spec.env, loaded.spec.policy, treedef,
            tuple((x.shape, str(x.dtype)) for x in leaves))


def group_checkpoints(checkpoints: Sequence[LoadedRun]) -> list[list[LoadedRun]]:
    """``checkpoints`` split into stackable groups (:func:`group_key`), in first-seen order."""
    groups: dict[tuple, list[LoadedRun]] = {}
    for c in checkpoints:
        groups.setdefault(group_key(c), []).append(c)
    return list(groups.values())


def _layout(env: Env) -> dict[str, tuple[int, int]]:
    base = env.unwrapped
    return {k: (s.start, s.stop) for k, s in base.observation_layout().items()}


def setup_env(loaded: LoadedRun, setup: str) -> Env:
    """The single environment ``setup`` as ``loaded``'s policy kind acts on it. Raises
    ``ValueError`` when the policy cannot read its observations (naming both observation
    sizes) or its action size differs."""
    if setup not in SETUPS:
        raise ValueError(f"unknown setup={setup!r}; valid setups are {list(SETUPS)}")
    train_env = make_env(loaded.spec.env, loaded.spec.policy)
    env = train_env if setup == loaded.spec.env else make_env(setup, loaded.spec.policy)
    what = f"the {loaded.spec.policy} policy trained on {loaded.spec.env}"
    a, b = int(train_env.observation_size), int(env.observation_size)
    if a != b:
        raise ValueError(f"cannot evaluate {what} (observation size {a}) on {setup} "
                         f"(observation size {b}): observation sizes differ")
    if _layout(train_env) != _layout(env):
        raise ValueError(f"cannot evaluate {what} on {setup}: both observations have size {a} "
                         f"but different layouts ({_layout(train_env)} vs {_layout(env)})")
    if int(train_env.action_size) != int(env.action_size):
        raise ValueError(f"cannot evaluate {what} (action size {train_env.action_size}) on "
                         f"{setup} (action size {env.action_size})")
    return env


@dataclasses.dataclass
class Sweep:
    """Per-episode results of one group: ``episodes[setup][stat]`` is ``(members,
    num_episodes)``; member ``i`` is training seed ``members[i][1]`` (an index into
    ``checkpoints[members[i][0]].seeds``) of checkpoint ``members[i][0]``."""

    checkpoints: list[LoadedRun]
    setups: tuple[str, ...]
    members: list[tuple[int, int]]
    episodes: dict[str, dict[str, np.ndarray]]
    horizons: dict[str, int]
    compile_seconds: float
    run_seconds: float


def stack_params(checkpoints: Sequence[LoadedRun]
                 ) -> tuple[PolicyParams, list[tuple[int, int]]]:
    """``(stack, members)``: every checkpoint's per-seed :class:`agents.run.loading.PolicyParams`
    concatenated along the leading axis, and ``(checkpoint index, seed index)`` per row. Raises
    :class:`agents.run.checkpoint.NonFiniteCheckpointError` naming the checkpoint and the leaf
    if any parameter is NaN/inf."""
    for c in checkpoints:
        leaf = checkpoint.first_nonfinite(policy_params(c))
        if leaf is not None:
            raise checkpoint.NonFiniteCheckpointError(
                f"cannot evaluate checkpoint {c.step} of {c.run_dir}: its policy parameters hold "
                f"non-finite values in {leaf} (the run diverged)")
    stack = stacked([policy_params(c) for c in checkpoints])
    members = [(i, s) for i, c in enumerate(checkpoints) for s in range(len(c.seeds))]
    return stack, members


def make_sweep(checkpoints: Sequence[LoadedRun], setups: Sequence[str], num_episodes: int,
               horizon: int | None = None) -> tuple[Callable, dict[str, int]]:
    """``(sweep, horizons)``: ``sweep(stack, key) -> {setup: {stat: (members, num_episodes)}}``
    for a parameter ``stack`` of :func:`stack_params` (not jitted; :func:`run_sweep` jits it).
    Every member plays the same ``num_episodes`` episodes, keys ``split(key, num_episodes)``."""
    first = checkpoints[0]
    apply_fn = mean_action_fn(first)
    env_of = {s: setup_env(first, s) for s in setups}
    horizons = {s: int(env.horizon if horizon is None else horizon) for s, env in env_of.items()}

    def sweep(stack, key):
        out = {}
        for s, env in env_of.items():
            def one(p, env=env, s=s):
                per_episode = make_rollout(env, num_episodes, horizons[s],
                                           policy=env_policy(apply_fn, p))(key)
                return {k: per_episode[k] for k in STATS}

            out[s] = jax.vmap(one)(stack)
        return out

    return sweep, horizons


def run_sweep(checkpoints: Sequence[LoadedRun], setups: Sequence[str] | None = None,
              num_episodes: int = 256, eval_seed: int = 0, horizon: int | None = None) -> Sweep:
    """Evaluate every (checkpoint, training seed) of one group on every setup (default: the
    group's training environment) in one compiled call; see :class:`Sweep`. Raises
    ``ValueError`` for checkpoints of different groups (:func:`group_checkpoints`) and setups
    the policy cannot act on (:func:`setup_env`)."""
    checkpoints = list(checkpoints)
    if not checkpoints:
        raise ValueError("no checkpoints to evaluate")
    if len(group_checkpoints(checkpoints)) != 1:
        kinds = sorted({(c.spec.env, c.spec.policy) for c in checkpoints})
        raise ValueError(f"checkpoints of different environments/policy kinds {kinds} cannot "
                         "share one compiled call; split them with group_checkpoints")
    if not (isinstance(num_episodes, int) and num_episodes >= 1):
        raise ValueError(f"num_episodes must be a positive integer, got {num_episodes!r}")
    if horizon is not None and not (isinstance(horizon, int) and horizon >= 1):
        raise ValueError(f"horizon must be None or a positive integer, got {horizon!r}")
    setups = tuple(dict.fromkeys(setups or (checkpoints[0].spec.env,)))
    sweep, horizons = make_sweep(checkpoints, setups, num_episodes, horizon)
    stack, members = stack_params(checkpoints)
    key = jax.random.PRNGKey(eval_seed)
    t0 = time.perf_counter()
    compiled = jax.jit(sweep).lower(stack, key).compile()
    t1 = time.perf_counter()
    out = jax.tree.map(np.asarray, jax.block_until_ready(compiled(stack, key)))
    t2 = time.perf_counter()
    return Sweep(checkpoints, setups, members, out, horizons, t1 - t0, t2 - t1)


__all__ = [
    "SETUPS",
    "STATS",
    "Sweep",
    "group_checkpoints",
    "group_key",
    "make_sweep",
    "resolve_steps",
    "run_sweep",
    "setup_env",
    "stack_params",
]
