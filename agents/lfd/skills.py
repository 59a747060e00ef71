"""Saved, reloadable and exportable LfD skills: LASA flow fields and Franka strategy policies.

A skill is a folder (written atomically: a temporary folder renamed into place)::

    <path>/skill.json   what the skill is: FORMAT, FORMAT_VERSION, kind ("lasa" | "franka"),
                        strategy, the configuration as JSON data, the goal(s), the state
                        dimension, the training data's name/fold, library versions
    <path>/arrays/0/    the learned arrays and the goal(s) as one orbax step
                        (agents.run.checkpoint: integrity record, non-finite values refused)

:func:`load_skill` rebuilds the configuration from ``skill.json`` (a missing or bad entry is a
:class:`SkillFormatError` naming the file and the field), builds the arrays' target structure
from it and restores them. :meth:`Skill.velocity` maps a batch ``x (b, dim)`` to ``(b, dim)``:

* ``"lasa"``: the flow field's velocity toward its goal, ``ẋ = −s(x) J_φ⁻¹ ∇Φ̄(ψ(x))``
  (thesis §4.2; :meth:`agents.lfd.flow_field.FlowField.velocity`), as the LASA evaluation rolls
  it out (normalised workspace, goal at the origin);
* ``"franka"``: ``q̇ = π_θ(q)`` of eq 5.1 in the *execution form* the Franka evaluation
  integrates (:func:`agents.lfd.execution.policy_velocity`: learned and default leaves, the
  velocity-form joint-limit and posture leaves of the stored
  :class:`~agents.lfd.config.ExecutionParams`, no obstacle), before the integrator's clip to
  ``±q̇_max``. Every strategy, ``"two_step"`` included, takes this one path.

:func:`export_skill` writes :meth:`Skill.velocity` as a standalone ``jax.export`` artifact with
its manifest (:func:`agents.run.export.export_policy`; load it with ``scripts/load_policy.py``).
"""

from __future__ import annotations

import dataclasses
import datetime
import functools
import json
import os
import platform
import secrets
import shutil
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from agents.lfd.config import DOF, ExecutionParams, LfdConfig, StrategyConfig
from agents.lfd.execution import Execution, execution_config, policy_velocity
from agents.lfd.flow_field import FlowField
from agents.lfd.franka_scenario import FrankaEvalConfig
from agents.lfd.policy import StrategyResult, init_params
from agents.run import checkpoint
from mjxrmp.atomic import atomic_write
from mjxrmp.geometry import make_obstacles
from mjxrmp.learned.nominal import NominalPotential
from mjxrmp.results.summary import package_versions

__all__ = ["FORMAT", "FORMAT_VERSION", "KINDS", "SKILL_FILE", "Skill", "SkillFormatError",
           "export_skill", "franka_skill", "lasa_skill", "load_skill", "save_franka_skills",
           "save_lasa_skills", "save_skill"]

#: Value of ``skill.json``'s ``format`` field.
FORMAT = "mjxrmp-lfd-skill"
#: Layout version of ``skill.json`` and the arrays; bump when a field changes meaning.
FORMAT_VERSION = 1
KINDS = ("lasa", "franka")
SKILL_FILE, ARRAYS_DIR = "skill.json", "arrays"
#: Radius of the inactive obstacle of the Franka execution form (masked out: any value works).
_INACTIVE_RADIUS = 0.05
_CONFIGS = {"lasa": LfdConfig, "franka": StrategyConfig}


class SkillFormatError(ValueError):
    """A ``skill.json`` that is unreadable, incomplete, inconsistent or of another version."""


@dataclasses.dataclass(frozen=True, eq=False)
class Skill:
    """A learned skill: ``kind``, its ``config`` (:class:`LfdConfig` or :class:`StrategyConfig`),
    ``arrays`` (the learned pytree and the goal(s)), the ``description`` of ``skill.json`` and,
    for Franka skills, the ``execution`` leaves and Euler sub-step ``step`` (s)."""

    kind: str
    config: LfdConfig | StrategyConfig
    arrays: dict
    description: dict
    execution: ExecutionParams | None = None
    step: float | None = None

    @property
    def dim(self) -> int:
        """The state dimension: 2 (LASA) or 7 (Franka joints)."""
        return int(self.description["dim"])

    @property
    def apply(self) -> Callable[[dict, jax.Array], jax.Array]:
        """``apply(arrays, x (b, dim)) -> (b, dim)``: the velocity as a pure function of the
        arrays (what :meth:`velocity` runs compiled and :func:`export_skill` exports)."""
        return _apply_fn(self.kind, self.config, self.execution, self.step)

    def velocity(self, x: jax.Array) -> jax.Array:
        """The skill's velocity (module docstring) at ``x (b, dim)``; jittable."""
        x = jnp.asarray(x, jnp.float32)
        if x.ndim != 2 or x.shape[1] != self.dim:
            raise ValueError(f"x must have shape (b, {self.dim}), got {x.shape}")
        return _compiled(self.kind, self.config, self.execution, self.step)(self.arrays, x)


def _lasa_velocity(config: LfdConfig, arrays: dict, x: jax.Array) -> jax.Array:
    return FlowField(dim=x.shape[-1], config=config).velocity(arrays["variables"], x,
                                                              arrays["goal"])


def _franka_velocity(config: StrategyConfig, params: ExecutionParams, step: float,
                     arrays: dict, x: jax.Array) -> jax.Array:
    result = StrategyResult(arrays["params"], arrays["constants"], None, None)
    obstacles = make_obstacles(jnp.zeros((1, 3), x.dtype), jnp.full((1,), _INACTIVE_RADIUS),
                               jnp.zeros((1,)))
    hand = execution_config()

    def one(q):
        ex = Execution(obstacles, jnp.zeros_like(q), step, arrays["q_posture"],
                       params.posture_weight, params, hand)
        return policy_velocity(config, result, q, arrays["goals"], arrays["q_goal"], ex)

    return jax.vmap(one)(x)


def _apply_fn(kind: str, config: Any, execution: ExecutionParams | None,
              step: float | None) -> Callable[[dict, jax.Array], jax.Array]:
    if kind == "lasa":
        return functools.partial(_lasa_velocity, config)
    return functools.partial(_franka_velocity, config, execution, step)


@functools.lru_cache(maxsize=16)
def _compiled(kind: str, config: Any, execution: ExecutionParams | None,
              step: float | None) -> Callable[[dict, jax.Array], jax.Array]:
    """One compiled velocity per skill configuration (arrays are arguments, not constants)."""
    return jax.jit(_apply_fn(kind, config, execution, step))


def _versions() -> dict[str, str]:
    return {"python": platform.python_version(),
            **package_versions(("jax", "jaxlib", "flax", "orbax-checkpoint", "mjxrmp"))}


def _floats(a: Any) -> Any:
    """A float32 array as nested lists of Python floats (exact: float32 → float64 → JSON)."""
    return np.asarray(a, np.float32).astype(np.float64).tolist()


def _description(kind: str, config: Any, dim: int, data: dict, goals: dict, **extra) -> dict:
    return {"format": FORMAT, "format_version": FORMAT_VERSION, "kind": kind,
            "strategy": "flow_field" if kind == "lasa" else config.strategy,
            "config": dataclasses.asdict(config), "dim": dim, "data": dict(data),
            "goals": {k: _floats(v) for k, v in goals.items()}, **extra,
            "versions": _versions(),
            "created": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")}


def lasa_skill(config: LfdConfig, variables: dict, goal: Any, data: dict) -> Skill:
    """A LASA skill from a trained field's ``variables`` (one shape, no leading axis), its
    ``goal (2,)`` (the origin in the normalised frame) and ``data`` (e.g. ``{"name":
    "LASA/Angle", "fold": None, "seed": 0}``)."""
    goal = jnp.asarray(goal, jnp.float32)
    arrays = {"variables": variables, "goal": goal}
    return Skill("lasa", config, arrays,
                 _description("lasa", config, int(goal.shape[0]), data, {"goal": goal}))


def franka_skill(config: StrategyConfig, result: StrategyResult, goals: Any, q_goal: Any,
                 q_posture: Any, execution: ExecutionParams, step: float, data: dict) -> Skill:
    """A Franka skill from one trained model ``result`` (no fold axis) of ``config``, the
    control-point ``goals (3, 3)``, ``q_goal (7,)``, the posture ``q_posture (7,)`` of the
    execution form, its ``execution`` leaves and Euler sub-step ``step`` (s), and ``data``
    (e.g. ``{"name": "franka_demos/drawer_closing", "fold": 0}``)."""
    g = {"goals": jnp.asarray(goals, jnp.float32), "q_goal": jnp.asarray(q_goal, jnp.float32),
         "q_posture": jnp.asarray(q_posture, jnp.float32)}
    arrays = {"params": result.params, "constants": result.constants, **g}
    extra = {"execution": dataclasses.asdict(execution), "execution_step": float(step)}
    if config.strategy == "two_step":
        extra["nominal_centers"] = int(result.constants.centers.shape[-2])
    return Skill("franka", config, arrays,
                 _description("franka", config, DOF, data, g, **extra), execution, float(step))


def save_skill(path: str | os.PathLike, skill: Skill) -> Path:
    """Write ``skill`` to the folder ``path`` (module docstring) atomically: everything goes to a
    temporary sibling folder that is renamed to ``path`` last. An existing ``path`` raises
    ``FileExistsError``. Returns ``path``."""
    path = Path(path)
    if path.exists():
        raise FileExistsError(f"skill folder {str(path)!r} already exists")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.parent / f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp"
    try:
        checkpoint.save(tmp / ARRAYS_DIR, 0, skill.arrays,
                        {"kind": skill.kind, "format": FORMAT}, max_to_keep=None)
        atomic_write(tmp / SKILL_FILE, (json.dumps(skill.description, indent=1,
                                                   allow_nan=False) + "\n").encode())
        os.rename(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return path


def save_lasa_skills(out: str | os.PathLike, names: Sequence[str], config: LfdConfig,
                     variables: dict, seed: int) -> list[Path]:
    """Save every shape of a LASA run (``variables`` stacked over ``names``, as
    :class:`agents.lfd.lasa_eval.LasaRun`'s ``result.variables``) to ``out/<shape>/``; the goal
    is the origin of the normalised frame. Returns the folders."""
    paths = []
    for i, name in enumerate(names):
        var = jax.tree.map(lambda a, i=i: a[i], variables)
        skill = lasa_skill(config, var, np.zeros(2, np.float32),
                           {"name": f"LASA/{name}", "fold": None, "seed": seed})
        paths.append(save_skill(Path(out) / name, skill))
    return paths


def save_franka_skills(out: str | os.PathLike, config: FrankaEvalConfig, task: str,
                       strategy: str, folds: Sequence[int], result: StrategyResult, goals: Any,
                       q_goal: Any, q_posture: Any) -> list[Path]:
    """Save the kept model of every leave-one-out fold of one task and strategy of a Franka
    comparison (:func:`agents.lfd.franka_folds.evaluate_strategy`: ``result`` stacked over
    ``folds``, the held-out demonstrations' ``goals (F, 3, 3)`` and ``q_goal (F, 7)``, the
    posture ``q_posture (F, 7)``) to ``out/<task>/<strategy>/fold_<f>/``, with the execution
    leaves and sub-step of ``config``. Returns the folders."""
    cfg = config.strategy_config(strategy)
    execution = ExecutionParams(posture_weight=config.posture_weight, substeps=config.substeps)
    paths = []
    for i, f in enumerate(folds):
        data = {"name": f"franka_demos/{task}", "fold": int(f), "dt": config.dt,
                "seed": config.seed}
        skill = franka_skill(cfg, jax.tree.map(lambda a, i=i: a[i], result), goals[i],
                             q_goal[i], q_posture[i], execution,
                             config.exec_dt / config.substeps, data)
        paths.append(save_skill(Path(out) / task / strategy / f"fold_{f}", skill))
    return paths


# -- loading ---------------------------------------------------------------------------------


def _field(desc: dict, name: str, kind: type | tuple, where: Path) -> Any:
    if name not in desc:
        raise SkillFormatError(f"{where}: field {name!r} is missing")
    value = desc[name]
    if not isinstance(value, kind) or (isinstance(value, bool) and kind is not bool):
        raise SkillFormatError(f"{where}: field {name!r} must be of type "
                               f"{getattr(kind, '__name__', kind)}, got {value!r}")
    return value


def _config(cls: type, data: dict, where: Path) -> Any:
    """``cls(**data)`` with JSON lists turned back into tuples, validated by ``cls``."""
    names = {f.name: f for f in dataclasses.fields(cls)}
    missing = sorted(set(names) - set(data))
    unknown = sorted(set(data) - set(names))
    if missing or unknown:
        what = f"config.{(missing or unknown)[0]} is {'missing' if missing else 'unknown'}"
        raise SkillFormatError(f"{where}: {what}")
    values = {k: tuple(v) if isinstance(v, list) else v for k, v in data.items()}
    try:
        return cls(**values)
    except (TypeError, ValueError) as e:
        raise SkillFormatError(f"{where}: config: {e}") from None


def _goal(desc: dict, name: str, shape: tuple, where: Path) -> np.ndarray:
    goals = _field(desc, "goals", dict, where)
    try:
        a = np.asarray(goals[name], np.float32)
    except (KeyError, TypeError, ValueError):
        a = None
    if a is None or a.shape != shape or not np.all(np.isfinite(a)):
        raise SkillFormatError(f"{where}: field 'goals.{name}' must be finite numbers of "
                               f"shape {shape}")
    return a


def _template(kind: str, config: Any, desc: dict, where: Path) -> dict:
    """The arrays' structure, shapes and dtypes, from the configuration."""
    sds = lambda *s: jax.ShapeDtypeStruct(s, jnp.float32)  # noqa: E731
    key = jax.random.PRNGKey(0)
    if kind == "lasa":
        dim = desc["dim"]
        return {"variables": jax.eval_shape(FlowField(dim, config).init, key), "goal": sds(dim)}
    K, m = config.num_leaves, config.leaf_dim
    out = {"goals": sds(3, 3), "q_goal": sds(DOF), "q_posture": sds(DOF)}
    if config.strategy != "two_step":
        params, constants = jax.eval_shape(lambda k: init_params(config, k), key)
        return {"params": params, "constants": constants, **out}
    T = _field(desc, "nominal_centers", int, where)
    metric = jax.eval_shape(jax.vmap(lambda k: config.metric.init(
        k, jnp.zeros((m,), jnp.float32))["params"]), jax.random.split(key, K))
    potential = jax.eval_shape(jax.vmap(NominalPotential), sds(K, T, m), sds(K, T), sds(K),
                               sds(K), sds(K))
    return {"params": {"metric": metric, "scale": sds(K)}, "constants": potential, **out}


def _read(path: Path) -> dict:
    where = path / SKILL_FILE
    try:
        desc = json.loads(where.read_text())
    except FileNotFoundError:
        raise FileNotFoundError(f"{where} not found: not a saved skill folder") from None
    except (OSError, ValueError) as e:
        raise SkillFormatError(f"{where}: unreadable JSON ({e})") from None
    if not isinstance(desc, dict):
        raise SkillFormatError(f"{where}: must hold a JSON object")
    if _field(desc, "format", str, where) != FORMAT:
        raise SkillFormatError(f"{where}: field 'format' is {desc['format']!r}, expected "
                               f"{FORMAT!r}")
    version = _field(desc, "format_version", int, where)
    if version != FORMAT_VERSION:
        raise SkillFormatError(f"{where}: format_version={version} but this code reads "
                               f"format_version={FORMAT_VERSION}")
    return desc


def load_skill(path: str | os.PathLike) -> Skill:
    """The skill saved in the folder ``path`` by :func:`save_skill` (module docstring)."""
    path = Path(path)
    where, desc = path / SKILL_FILE, _read(path)
    kind = _field(desc, "kind", str, where)
    if kind not in KINDS:
        raise SkillFormatError(f"{where}: field 'kind' is {kind!r}, expected one of {KINDS}")
    for name, typ in (("strategy", str), ("data", dict), ("versions", dict)):
        _field(desc, name, typ, where)
    config = _config(_CONFIGS[kind], _field(desc, "config", dict, where), where)
    dim = _field(desc, "dim", int, where)
    want_dim = DOF if kind == "franka" else 2
    if dim != want_dim:
        raise SkillFormatError(f"{where}: field 'dim' is {dim}, expected {want_dim} for {kind}")
    execution = step = None
    if kind == "lasa":
        goals = {"goal": _goal(desc, "goal", (dim,), where)}
    else:
        if desc["strategy"] != config.strategy:
            raise SkillFormatError(f"{where}: field 'strategy' is {desc['strategy']!r} but "
                                   f"config.strategy is {config.strategy!r}")
        goals = {n: _goal(desc, n, s, where) for n, s in
                 (("goals", (3, 3)), ("q_goal", (DOF,)), ("q_posture", (DOF,)))}
        execution = _config(ExecutionParams, _field(desc, "execution", dict, where), where)
        step = float(_field(desc, "execution_step", (int, float), where))
    arrays, _ = checkpoint.restore(path / ARRAYS_DIR, _template(kind, config, desc, where),
                                   step=0)
    for name, value in goals.items():
        if not np.array_equal(np.asarray(arrays[name]), value):
            raise SkillFormatError(f"{where}: field 'goals.{name}' differs from the saved "
                                   "arrays")
    return Skill(kind, config, arrays, desc, execution, step)


def export_skill(skill: Skill | str | os.PathLike, out: str | os.PathLike,
                 platforms: Sequence[str] = ("cpu", "cuda"),
                 matmul_precision: str | None = "highest", force: bool = False) -> dict:
    """Export :meth:`Skill.velocity` (a :class:`Skill` or a saved skill folder) to the
    standalone artifact ``out`` (``.jaxexport``) and its manifest with
    :func:`agents.run.export.export_policy` (observation = state ``x``, action = velocity);
    full float32 matrix products by default, as the LfD scripts train. The manifest's
    ``metadata`` holds the skill's kind, strategy, data, goals and ``source: "lfd-skill"``. An
    existing ``out`` or manifest raises ``FileExistsError`` unless ``force``. Returns the
    manifest."""
    from agents.run.export import export_policy, manifest_path  # lazy: loads the MJX environments

    existing = [p for p in (Path(out), manifest_path(out)) if p.exists()]
    if existing and not force:
        raise FileExistsError(f"{str(existing[0])!r} already exists; pass force=True (--force) "
                              "to overwrite it")
    if not isinstance(skill, Skill):
        skill = load_skill(skill)
    d = skill.description
    meta = {"source": "lfd-skill", "kind": skill.kind, "strategy": d["strategy"],
            "data": d["data"], "goals": d["goals"],
            "action": "velocity dx/dt of the state (LASA: normalised plane; Franka: joints)"}
    return export_policy(skill.apply, skill.arrays, skill.dim, out, metadata=meta,
                         platforms=platforms, matmul_precision=matmul_precision)
