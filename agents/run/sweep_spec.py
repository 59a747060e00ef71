"""What a packed sweep is (docs/design.md §2.3): :class:`SweepSpec` — a base run, environment
setups that share a model, policy kinds that share a network and a grid of scalar PPO
hyper-parameters — and the per-row data one program needs to train all its runs
(:func:`row_values`, :func:`row_scenes`). :mod:`agents.run.sweep` trains it."""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp

import envs
from agents.ppo.hparams import SWEEPABLE
from agents.ppo.policies import BASE_WEIGHT, packed_kind
from agents.run.spec import RunSpec
from mjxrmp.config import check_float


@dataclasses.dataclass(frozen=True)
class SweepSpec:
    """A grid ``((name, (value, ...)), ...)`` of :data:`SWEEPABLE` hyper-parameters, a list
    of environment setups ``envs`` (names for :func:`envs.make` that differ only in their scene
    parameters, e.g. ``three_link/env2`` and ``three_link/env3``; empty: the base's
    environment) and a list of policy kinds ``policies`` that share a network (``nn`` and
    ``nn_residual``; empty: the base's kind) over the ``base`` run (its seeds, length and
    logging cadence are every point's)."""

    base: RunSpec
    grid: tuple[tuple[str, tuple[float, ...]], ...] = ()
    envs: tuple[str, ...] = ()
    policies: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if not isinstance(self.base, RunSpec):
            raise TypeError(f"SweepSpec.base must be a RunSpec, got {type(self.base).__name__}")
        grid = tuple((name, tuple(values)) for name, values in dict(self.grid).items())
        setups = tuple(self.envs)
        if len(set(setups)) != len(setups) or len(setups) == 1 or not all(
                isinstance(e, str) for e in setups):
            raise ValueError(f"SweepSpec.envs must list two or more distinct environment names "
                             f"(or none), got {self.envs!r}")
        object.__setattr__(self, "envs", setups)
        kinds = tuple(self.policies)
        if len(set(kinds)) != len(kinds) or len(kinds) == 1:
            raise ValueError(f"SweepSpec.policies must list two or more distinct policy kinds "
                             f"(or none), got {self.policies!r}")
        if kinds:
            packed_kind(kinds)  # refuses kinds that differ in network structure
        object.__setattr__(self, "policies", kinds)
        if (not grid and not setups and not kinds) or len(grid) != len(self.grid):
            raise ValueError(f"SweepSpec.grid must name each hyper-parameter once, and a sweep "
                             f"needs a grid or two or more envs or policies; got "
                             f"grid={self.grid!r}")
        for name, values in grid:
            if name not in SWEEPABLE:
                raise ValueError(f"SweepSpec.grid: {name!r} cannot be swept; sweepable names "
                                 f"are {list(SWEEPABLE)}")
            if not values or len(set(values)) != len(values):
                raise ValueError(f"SweepSpec.grid[{name!r}] must list distinct values, got "
                                 f"{values!r}")
            for v in values:
                check_float(v, f"SweepSpec.grid[{name!r}] value", allow_zero=True)
        object.__setattr__(self, "grid", grid)
        self.points()  # every point's PPOConfig validates its values

    def points(self) -> list[tuple[str, RunSpec]]:
        """``(name, spec)`` per point: every env of :attr:`envs` (outermost), every kind of
        :attr:`policies`, then the grid in row-major order of :attr:`grid`."""
        names = [name for name, _ in self.grid]
        out = []
        for env, kind, values in itertools.product(
                self.envs or (self.base.env,), self.policies or (self.base.policy,),
                itertools.product(*(v for _, v in self.grid))):
            point = dict(zip(names, values, strict=True))
            spec = dataclasses.replace(self.base, env=env, policy=kind,
                                       ppo=dataclasses.replace(self.base.ppo, **point))
            label = ([f"env={env.replace('/', '-')}"] if self.envs else []) + (
                [f"policy={kind}"] if self.policies else [])
            out.append((",".join(label + [f"{k}={v:g}" for k, v in point.items()]), spec))
        return out

    def program_spec(self) -> RunSpec:
        """The run whose program trains every point: the first point, with the kind that
        trains all of :attr:`policies` (:func:`agents.ppo.policies.packed_kind`)."""
        first = self.points()[0][1]
        return dataclasses.replace(first, policy=packed_kind(self.policies or (first.policy,)))

    def to_json(self) -> dict[str, Any]:
        """The sweep as JSON data (``sweep.json``)."""
        return {"base": self.base.to_json(), "grid": {k: list(v) for k, v in self.grid},
                "envs": list(self.envs), "policies": list(self.policies),
                "points": [name for name, _ in self.points()]}


def parse_grid(items: list[str]) -> tuple[tuple[str, tuple[float, ...]], ...]:
    """``["learning_rate=1e-4,3e-4", "ent_coef=0,0.01"]`` → the grid of a :class:`SweepSpec`;
    an error names the item and what was expected."""
    grid = []
    for item in items:
        name, sep, values = item.partition("=")
        try:
            parsed = tuple(float(v) for v in values.split(","))
        except ValueError:
            parsed = ()
        if not sep or not parsed:
            raise ValueError(f"--grid {item!r}: expected NAME=VALUE,VALUE,... with NAME one of "
                             f"{list(SWEEPABLE)} and numeric values")
        grid.append((name.strip(), parsed))
    return tuple(grid)


def row_values(sweep: SweepSpec) -> tuple[dict[str, jax.Array], list[str]]:
    """``TrainState.hparams`` of every row (point-major, then seed; None without a grid or
    policies) and the rows' names."""
    points, seeds = sweep.points(), sweep.base.seeds
    hp = {k: jnp.asarray([getattr(spec.ppo, k) for _, spec in points for _ in seeds],
                         jnp.float32) for k, _ in sweep.grid}
    if sweep.policies:
        hp["base_weight"] = jnp.asarray([BASE_WEIGHT[spec.policy] for _, spec in points
                                         for _ in seeds], jnp.float32)
    return hp or None, [f"{name} seed {s}" for name, _ in points for s in seeds]


def model_groups(names: Sequence[str]) -> list[dict[str, Any]]:
    """The environments called ``names`` grouped by the model they share
    (:meth:`envs.reaching.ReachEnv.shares_model`: three_link env2 and env3 differ only in the
    goal region), in order of first appearance, each group ``{name: environment}``: what one
    packed program can train."""
    groups: list[dict[str, Any]] = []
    for name in names:
        env = envs.make(name).unwrapped
        for group in groups:
            first = next(iter(group.values()))
            if hasattr(first, "shares_model") and first.shares_model(env):
                group[name] = env
                break
        else:
            groups.append({name: env})
    return groups


def row_scenes(sweep: SweepSpec) -> dict[str, jax.Array] | None:
    """Every row's scene parameters (point-major, then seed;
    :meth:`envs.reaching.ReachEnv.default_scene` of the point's environment), or None when the
    sweep has one environment. An error names an environment that does not share the first
    one's model (only the scene parameters may differ)."""
    if not sweep.envs:
        return None
    groups = model_groups(sweep.envs)
    if len(groups) > 1:
        (name, env), first = next(iter(groups[1].items())), groups[0][sweep.envs[0]]
        raise ValueError(
            f"SweepSpec.envs: {name!r} does not differ from {sweep.envs[0]!r} only in its "
            f"scene parameters (observation size {env.observation_size} vs "
            f"{first.observation_size}); environments that differ in their model (robot, "
            f"obstacle count, settings) must be separate sweeps")
    scenes = {name: env.default_scene() for name, env in groups[0].items()}
    per_row = [scenes[spec.env] for _, spec in sweep.points() for _ in sweep.base.seeds]
    return jax.tree.map(lambda *xs: jnp.stack(xs), *per_row)


__all__ = ["SweepSpec", "model_groups", "parse_grid", "row_scenes", "row_values"]
