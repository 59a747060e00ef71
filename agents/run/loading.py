"""Load a training run directory (:func:`agents.run.training.run_training`) and act with it.

:func:`load_run` rebuilds the :class:`~agents.run.spec.RunSpec` from ``run.json``, the
:class:`~agents.run.program.Program` with :func:`~agents.run.program.build` and restores a
checkpoint (default: the newest intact one) into the seed-stacked
:class:`~agents.ppo.state.TrainState`; the checkpoint's files must pass their integrity check
(:class:`agents.run.checkpoint.CorruptCheckpointError`), its meta must match the spec
(:class:`agents.run.checkpoint.IncompatibleCheckpointError`) and its state must be finite
(:class:`agents.run.checkpoint.NonFiniteCheckpointError`), so nothing downstream (evaluation,
export) ever acts with NaN parameters.

The deterministic policy of a checkpoint is its Gaussian mean (the environment clips it):
``apply_fn(policy_params, obs) -> mean`` with ``policy_params`` a :class:`PolicyParams` (the
policy's network parameters and, with observation normalisation, the observation statistics it
reads). :func:`policy_params` gives one seed's or the stack over all seeds (leading axis), so
evaluation can ``vmap`` over seeds and checkpoints and export can bake one seed in::

    run = load_run("runs/three_link-env3_rmp_residual")
    apply_fn, params = deterministic_policy(run, seed_index=0)
    mean = apply_fn(params, obs)                  # obs (obs_size,) or (batch, obs_size)
    policy = env_policy(apply_fn, params)         # policy(state) -> action, for make_rollout
"""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
from brax.envs.base import Env, State

from agents.ppo import PPOConfig, TrainState, make_env_and_policy
from agents.ppo.normalization import RunningStats
from agents.run import checkpoint
from agents.run.checkpoint import IncompatibleCheckpointError
from agents.run.program import Program, build, seed_keys
from agents.run.rows import row
from agents.run.spec import RunSpec


class PolicyParams(NamedTuple):
    """What the deterministic policy of one seed reads: the policy module's parameters and the
    observation statistics (None without observation normalisation). A leading axis on every
    leaf stacks several seeds (or checkpoints)."""

    params: Any
    norm: RunningStats | None


@dataclasses.dataclass
class LoadedRun:
    """A restored checkpoint of a run: ``state`` has a leading seed axis (``spec.seeds``)."""

    run_dir: str
    spec: RunSpec
    program: Program
    state: TrainState
    meta: dict[str, Any]
    step: int

    @property
    def iteration(self) -> int:
        """PPO iterations the checkpoint's policy was trained for."""
        return int(self.meta.get("iteration", self.step))

    @property
    def seeds(self) -> tuple[int, ...]:
        """The run's training seeds (the order of the state's leading axis)."""
        return self.spec.seeds

    @property
    def policy_module(self):
        """The flax policy module (``apply(params, obs, norm) -> (mean, log_std)``)."""
        return self.program.trainer.policy


def make_env(env_name: str, kind: str) -> Env:
    """The single (un-batched) environment ``env_name`` as policy ``kind`` acts on it (wrapped
    in :class:`envs.wrappers.RMPInEnv` for ``rmp_residual_env``), as in training."""
    return make_env_and_policy(env_name, kind)[0]


def spec_from_json(d: dict[str, Any]) -> RunSpec:
    """The :class:`RunSpec` of ``RunSpec.to_json()`` output (``run.json``): the nested PPO
    settings become a :class:`PPOConfig` and JSON lists become tuples again. Unknown keys raise
    ``ValueError`` naming them (a run written by a newer version of the code)."""
    if not isinstance(d, dict) or not isinstance(d.get("ppo"), dict):
        raise ValueError(f"run.json must be an object with a nested 'ppo' object, got {d!r:.200}")

    def fields_of(cls, values, what):
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(values) - names)
        if unknown:
            raise ValueError(f"{what} has unknown fields {unknown}; valid fields are "
                             f"{sorted(names)}")
        return {k: tuple(v) if isinstance(v, list) else v for k, v in values.items()}

    ppo = PPOConfig(**fields_of(PPOConfig, d["ppo"], "run.json 'ppo'"))
    top = fields_of(RunSpec, {k: v for k, v in d.items() if k != "ppo"}, "run.json")
    return RunSpec(ppo=ppo, **top)


def checkpoint_steps(run_dir: str | os.PathLike) -> list[int]:
    """The complete checkpoint steps (iterations) of a run directory, ascending ([] if none),
    verified or not (:func:`agents.run.checkpoint.all_steps`)."""
    return checkpoint.all_steps(os.path.join(os.fspath(run_dir), "checkpoints"))


def read_spec(run_dir: str | os.PathLike) -> RunSpec:
    """The :class:`RunSpec` in ``run_dir/run.json`` (clear errors for a missing directory or
    file)."""
    run_dir = os.fspath(run_dir)
    if not os.path.isdir(run_dir):
        raise FileNotFoundError(f"run directory {run_dir!r} does not exist")
    path = os.path.join(run_dir, "run.json")
    if not os.path.isfile(path):
        raise FileNotFoundError(f"{run_dir!r} has no run.json: not a training run directory "
                                "(scripts/train.py writes one)")
    with open(path) as f:
        try:
            d = json.load(f)
        except json.JSONDecodeError as e:
            raise ValueError(f"{path} is not valid JSON: {e}") from e
    try:
        return spec_from_json(d)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{path}: {e}") from e


def load_run(run_dir: str | os.PathLike, step: int | None = None) -> LoadedRun:
    """Restore checkpoint ``step`` (default: the newest intact one) of the run in ``run_dir``.

    The spec comes from ``run.json``, the program from :func:`agents.run.program.build` (cached,
    so loading several checkpoints of one run builds it once), the state with the template
    ``program.state_shapes(seed_keys(spec.seeds))`` (``jax.eval_shape`` of its init). Raises
    ``FileNotFoundError`` for a missing directory, ``run.json`` or checkpoint (naming the steps
    there are), :class:`agents.run.checkpoint.IncompatibleCheckpointError` when the checkpoint
    does not belong to the spec (environment, policy kind, seeds, PPO settings or array shapes
    differ), :class:`~agents.run.checkpoint.CorruptCheckpointError` for a corrupt requested step
    (or no intact one) and :class:`~agents.run.checkpoint.NonFiniteCheckpointError` for NaN/inf
    state.
    """
    run_dir = os.fspath(run_dir)
    spec = read_spec(run_dir)
    steps = checkpoint_steps(run_dir)
    ckpt_dir = os.path.join(run_dir, "checkpoints")
    if not steps:
        raise FileNotFoundError(f"no checkpoint in {ckpt_dir!r}")
    if step is not None and step not in steps:
        raise FileNotFoundError(f"no checkpoint of step={step!r} in {ckpt_dir!r}; available "
                                f"steps are {steps}")
    program = build(spec)
    template = program.state_shapes(seed_keys(spec.seeds))
    state, meta = checkpoint.restore(ckpt_dir, template, step=step, expected=spec.identity())
    return LoadedRun(run_dir, spec, program, state, meta, int(meta["step"]))


def policy_params(loaded: LoadedRun, seed_index: int | None = None) -> PolicyParams:
    """The :class:`PolicyParams` of seed ``loaded.seeds[seed_index]``, or (``None``) of every
    seed stacked along a leading axis."""
    n = len(loaded.seeds)
    state = loaded.state
    if seed_index is not None:
        if not (isinstance(seed_index, int) and -n <= seed_index < n):
            raise IndexError(f"seed_index={seed_index!r} out of range for {n} seed(s) "
                             f"{loaded.seeds}")
        state = row(state, seed_index % n)
    return PolicyParams(state.params["policy"], loaded.program.trainer.policy_norm(state))


def mean_action_fn(loaded_or_program: LoadedRun | Program) -> Callable[[PolicyParams, Any], Any]:
    """``apply_fn(policy_params, obs) -> mean``: the deterministic action (the Gaussian mean,
    unclipped) of the run's policy module, for one observation or a batch."""
    program = (loaded_or_program.program if isinstance(loaded_or_program, LoadedRun)
               else loaded_or_program)
    module = program.trainer.policy

    def apply_fn(p: PolicyParams, obs):
        return module.apply(p.params, obs, p.norm)[0]

    return apply_fn


def deterministic_policy(loaded: LoadedRun, seed_index: int = 0
                         ) -> tuple[Callable[[PolicyParams, Any], Any], PolicyParams]:
    """``(apply_fn, params)`` of seed ``loaded.seeds[seed_index]``: ``apply_fn(params, obs)`` is
    the mean action (jittable, any leading batch shape). The pair fits
    :func:`agents.run.export.export_policy` (``export_policy(apply_fn, params, obs_size, path)``)
    and :func:`env_policy`."""
    return mean_action_fn(loaded), policy_params(loaded, seed_index)


def env_policy(apply_fn: Callable[[PolicyParams, Any], Any], params: PolicyParams
               ) -> Callable[[State], jax.Array]:
    """``policy(state) -> action`` acting on ``state.obs`` with the mean action, as
    :func:`envs.evaluate.make_rollout` and the render script take it."""

    def policy(state):
        return apply_fn(params, state.obs)

    return policy


__all__ = [
    "IncompatibleCheckpointError",
    "LoadedRun",
    "PolicyParams",
    "checkpoint_steps",
    "deterministic_policy",
    "env_policy",
    "load_run",
    "make_env",
    "mean_action_fn",
    "policy_params",
    "read_spec",
    "spec_from_json",
]
