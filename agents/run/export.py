"""Deterministic policy export with :mod:`jax.export`.

:func:`export_policy` serialises the deterministic policy ``obs (b, obs_size) float32 → action
mean (b, action_size) float32`` with a symbolic batch dimension ``b ≥ 1`` and the parameters
baked in as constants (behind an optimisation barrier, so that the exported function computes
bit for bit what ``jax.jit(apply_fn)(params, obs)`` computes at the same batch size on the same
backend). It writes two files:

* ``<name>.jaxexport`` — the bytes of :meth:`jax.export.Exported.serialize` (StableHLO plus
  the calling convention; needs the ``flatbuffers`` package on both ends);
* ``<name>.json`` — a manifest (:data:`FORMAT`, :data:`FORMAT_VERSION`, shapes, dtype, the
  platforms actually lowered for, JAX versions, the blob's SHA-256, creation time and the
  caller's ``metadata``).

:func:`export_from_params` exports a reaching policy of the project (its metadata: environment,
policy kind, robot, observation layout); :func:`export_run` is what ``scripts/export.py`` calls
(a checkpoint's policy, or a freshly initialised one).

Parameters with a NaN or inf leaf are refused (``ValueError`` naming the leaf): a diverged
policy is never exported. :func:`export_run` refuses to overwrite an existing blob or manifest
unless ``force=True`` (``scripts/export.py --force``).

Load either with ``scripts/load_policy.py`` (standalone: ``jax``, ``numpy`` and the standard
library only), with :func:`load_export` inside the project, or with ``jax.export.deserialize``
directly. The hand-designed RMP² policy exports the same way (policy kind ``hand_designed``:
``scripts/export.py --hand-designed --env ENV``); it, like every kind with an RMP² part, reads
its RMP² inputs from the observation alone (manifest ``metadata.rmp_inputs``).

The module is lowered for several platforms at once (default ``("cpu", "cuda")``; lowering for
CUDA needs no GPU). Where lowering for a requested platform fails, the platforms that do lower
are exported and the manifest records the failures under ``platform_errors``.

Seen on 2026-11-22: blobs exported with jax 0.10.2 on a CPU-only machine loaded with jax 0.11.2
and ran on an H100 and on its CPU. CPU results matched bit for bit for ``nn`` (within ~1e-6
relative for ``rmp_residual``, a different XLA); GPU results differed from CPU ones by ~5e-4
relative for ``nn`` at the default matmul precision and ~5e-7 with
``matmul_precision="highest"`` (docs/design.md §5.4).
"""

from __future__ import annotations

import contextlib
import datetime
import hashlib
import importlib.metadata
import json
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
from jax import export as jax_export

import envs
from agents.ppo import KINDS, make_env_and_policy
from agents.run.checkpoint import first_nonfinite
from agents.run.loading import deterministic_policy, load_run
from mjxrmp.atomic import atomic_write

#: Value of the manifest's ``format`` field.
FORMAT = "mjxrmp-policy-export"
#: Manifest layout version; bump when a field changes meaning.
FORMAT_VERSION = 1
#: Suffix of the serialized blob; the manifest is ``path.with_suffix(".json")``.
SUFFIX = ".jaxexport"
#: Platforms ``jax.export`` can lower for.
KNOWN_PLATFORMS = ("cpu", "cuda", "rocm", "tpu")
#: Values of ``matmul_precision`` (those of ``jax.default_matmul_precision``).
MATMUL_PRECISIONS = ("default", "high", "highest", "bfloat16", "tensorfloat32", "float32")
#: Policy kinds whose RMP² part reads its inputs decoded from the observation.
RMP_KINDS = ("hand_designed", "nn_residual", "rmp_residual")
#: How those kinds decode the RMP² inputs (manifest ``metadata.rmp_inputs``): the observation
#: alone determines them (:func:`agents.ppo.policies.decode_observation`).
RMP_INPUTS = ("q = atan2(sin_q, cos_q); qd = qd; goal = goal_minus_x + FK(q); obstacles = "
              "(centre, radius) rows of 'obstacles', active where radius > 0")
#: Environments the policy classes support: the reaching environments (not ``point2d``).
EXPORTABLE_ENVS = tuple(sorted(
    name for name, factory in envs.ENVIRONMENTS.items()
    if isinstance(getattr(factory, "func", factory), type)
    and issubclass(getattr(factory, "func", factory), envs.ReachEnv)
))


def _jaxlib_version() -> str:
    try:
        return importlib.metadata.version("jaxlib")
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


def manifest_path(path: str | os.PathLike) -> Path:
    """The manifest that belongs to the blob ``path`` (``.jaxexport`` → ``.json``)."""
    return Path(path).with_suffix(".json")


def _check_args(obs_size, path, metadata, platforms,
                matmul_precision) -> tuple[Path, tuple[str, ...]]:
    if isinstance(obs_size, bool) or not isinstance(obs_size, int) or obs_size <= 0:
        raise ValueError(f"obs_size must be a positive int, got {obs_size!r}")
    if not isinstance(path, str | os.PathLike):
        raise TypeError(f"path must be a str or os.PathLike, got {type(path).__name__}")
    path = Path(path)
    if path.suffix != SUFFIX:
        raise ValueError(f"path must end in {SUFFIX!r}, got {str(path)!r}")
    if metadata is not None:
        if not isinstance(metadata, dict):
            raise TypeError(f"metadata must be a dict or None, got {type(metadata).__name__}")
        try:
            json.dumps(metadata, allow_nan=False)
        except (TypeError, ValueError) as e:
            raise ValueError(f"metadata must be JSON-serialisable: {e}") from e
    if isinstance(platforms, str):
        platforms = (platforms,)
    platforms = tuple(platforms)
    if not platforms:
        raise ValueError("platforms must name at least one platform")
    unknown = [p for p in platforms if p not in KNOWN_PLATFORMS]
    if unknown:
        raise ValueError(f"unknown platforms={unknown}; valid platforms are {KNOWN_PLATFORMS}")
    if len(set(platforms)) != len(platforms):
        raise ValueError(f"platforms must not repeat, got {platforms}")
    if matmul_precision is not None and matmul_precision not in MATMUL_PRECISIONS:
        raise ValueError(f"matmul_precision must be None or one of {MATMUL_PRECISIONS}, got "
                         f"{matmul_precision!r}")
    return path, platforms


def _lower(fn: Callable, spec: jax.ShapeDtypeStruct, platforms: Sequence[str]):
    """``(exported, platform_errors)``: all ``platforms`` at once, else those that lower alone."""
    try:
        return jax_export.export(fn, platforms=tuple(platforms))(spec), {}
    except Exception as e:  # fall back platform by platform (reported in the manifest)
        if len(platforms) == 1:
            raise
        first_error = e
    ok, errors = [], {}
    for p in platforms:
        try:
            jax_export.export(fn, platforms=(p,))(spec)
            ok.append(p)
        except Exception as e:
            errors[p] = f"{type(e).__name__}: {e}"[:2000]
    if not ok:  # not a platform problem: report the original error
        first_error.add_note(f"lowering failed for every requested platform {tuple(platforms)}")
        raise first_error
    return jax_export.export(fn, platforms=tuple(ok))(spec), errors


def _barrier_policy(apply_fn: Callable[[Any, jax.Array], jax.Array], params: Any
                    ) -> Callable[[jax.Array], jax.Array]:
    """``obs ↦ apply_fn(params, obs)`` as float32, the parameters behind an optimisation barrier.

    The barrier keeps XLA from constant-folding through the baked parameters: the exported
    function then computes exactly what the compiled ``apply_fn`` computes with the parameters
    passed as arguments (as in training). Without it, folding reorders float32 arithmetic (up to
    ~4e-5 relative for rmp_residual, whose RMP² solve amplifies it).
    """
    params = jax.tree.map(jnp.asarray, params)

    def policy(obs):
        mean = apply_fn(jax.lax.optimization_barrier(params), obs)
        if not hasattr(mean, "shape") or not hasattr(mean, "dtype"):
            raise TypeError(
                "apply_fn must return one array (the action mean), got "
                f"{type(mean).__name__}; use e.g. lambda p, o: module.apply(p, o)[0]"
            )
        return jnp.asarray(mean, jnp.float32)

    return policy


def _action_size(exported: jax_export.Exported, obs_size: int) -> int:
    """The static action size of an export ``(b, obs_size) -> (b, action_size)``."""
    (out,) = exported.out_avals
    if len(out.shape) != 2 or not jax_export.is_symbolic_dim(out.shape[0]) \
            or jax_export.is_symbolic_dim(out.shape[1]):
        raise ValueError(
            f"apply_fn must map obs (b, {obs_size}) to a mean (b, action_size); got shape "
            f"{out.shape}"
        )
    return int(out.shape[1])


def _manifest(exported: jax_export.Exported, blob: bytes, path: Path, obs_size: int,
              platforms: Sequence[str], platform_errors: dict[str, str],
              matmul_precision: str | None, metadata: dict | None) -> dict:
    """The manifest of the blob ``blob`` written to ``path`` (see the module docstring)."""
    action_size = _action_size(exported, obs_size)
    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "file": path.name,
        "sha256": hashlib.sha256(blob).hexdigest(),
        "size_bytes": len(blob),
        "obs_size": obs_size,
        "action_size": action_size,
        "dtype": "float32",
        "input_shape": ["b", obs_size],
        "output_shape": ["b", action_size],
        "batch": "symbolic dimension b >= 1",
        "platforms": list(exported.platforms),
        "requested_platforms": list(platforms),
        "platform_errors": platform_errors,
        "matmul_precision": matmul_precision or "default",
        "jax_version": jax.__version__,
        "jaxlib_version": _jaxlib_version(),
        "calling_convention_version": exported.calling_convention_version,
        "created": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "metadata": dict(metadata or {}),
    }


def export_policy(
    apply_fn: Callable[[Any, jax.Array], jax.Array],
    params: Any,
    obs_size: int,
    path: str | os.PathLike,
    metadata: dict | None = None,
    platforms: Sequence[str] = ("cpu", "cuda"),
    matmul_precision: str | None = None,
) -> dict:
    """Export ``obs ↦ apply_fn(params, obs)`` and write the blob and its manifest; return it.

    ``apply_fn(params, obs) -> mean`` maps a batch ``obs (b, obs_size)`` to ``(b, action_size)``
    (e.g. ``lambda p, o: module.apply(p, o)[0]``), traced once with a symbolic ``b``; ``params``
    (a pytree of arrays) is baked in as constants. ``path`` ends in ``.jaxexport``; the manifest
    goes to ``path.with_suffix(".json")``; parent directories are created and both files are
    written atomically (temporary file + ``os.replace``), the blob first. ``metadata`` (a
    JSON-serialisable dict: env name, policy kind, iteration, ...) is stored under the
    manifest's ``metadata`` key. Platforms of ``platforms`` that fail to lower are dropped (at
    least one must succeed) and listed in the manifest's ``platform_errors``.
    ``matmul_precision=None`` keeps the backend's default float32 matmul precision, as in
    training (on recent NVIDIA GPUs a TF32-class precision: ``nn`` actions on an H100 then
    differ from CPU ones by ~5e-4 relative); ``"highest"`` bakes full float32 precision into
    every matrix product (``jax.default_matmul_precision`` while tracing). Parameters with a
    NaN/inf leaf raise ``ValueError`` naming it.
    """
    path, platforms = _check_args(obs_size, path, metadata, platforms, matmul_precision)
    if not callable(apply_fn):
        raise TypeError(f"apply_fn must be callable, got {type(apply_fn).__name__}")
    leaf = first_nonfinite(params)
    if leaf is not None:
        raise ValueError(f"params hold non-finite values in {leaf}: refusing to export "
                         f"{str(path)!r} (a diverged policy?)")
    (b,) = jax_export.symbolic_shape("b")
    spec = jax.ShapeDtypeStruct((b, obs_size), jnp.float32)
    precision = (contextlib.nullcontext() if matmul_precision is None
                 else jax.default_matmul_precision(matmul_precision))
    with precision:
        exported, platform_errors = _lower(jax.jit(_barrier_policy(apply_fn, params)), spec,
                                           platforms)
    blob = bytes(exported.serialize())
    manifest = _manifest(exported, blob, path, obs_size, platforms, platform_errors,
                         matmul_precision, metadata)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, blob)
    atomic_write(manifest_path(path),
                  (json.dumps(manifest, indent=2, allow_nan=False) + "\n").encode())
    return manifest


def check_names(env_name: str, kind: str) -> None:
    """Raise ``ValueError`` listing the valid names if ``env_name`` or ``kind`` is unknown."""
    name = envs.BRAX_NAMES.get(env_name, env_name)
    if name not in EXPORTABLE_ENVS:
        what = "has no policy classes" if name in envs.ENVIRONMENTS else "is unknown"
        raise ValueError(
            f"env_name={env_name!r} {what}; valid names are {list(EXPORTABLE_ENVS)}"
        )
    if kind not in KINDS:
        raise ValueError(f"unknown policy kind={kind!r}; valid kinds are {list(KINDS)}")


def init_params(env_name: str, kind: str, seed: int = 0) -> Any:
    """Freshly initialised parameters of the ``kind`` policy for ``env_name``."""
    check_names(env_name, kind)
    env, module = make_env_and_policy(env_name, kind)
    return jax.jit(module.init)(jax.random.PRNGKey(seed), jnp.zeros((env.observation_size,)))


def export_from_params(env_name: str, kind: str, params: Any, out: str | os.PathLike,
                       metadata: dict | None = None,
                       platforms: Sequence[str] = ("cpu", "cuda"),
                       matmul_precision: str | None = None,
                       apply_fn: Callable | None = None) -> dict:
    """Export the deterministic mean of the ``kind`` policy for ``env_name`` with ``params``.

    ``apply_fn(params, obs) -> mean`` defaults to the module's mean on the raw observation;
    pass :func:`agents.run.loading.deterministic_policy`'s pair for a checkpoint (observation
    statistics included). The manifest's ``metadata`` holds ``env``, ``policy``, ``robot``,
    ``observation_layout`` (``{name: [start, stop]}``), ``action`` (what the action means)
    and, for kinds with an RMP² part (:data:`RMP_KINDS`), ``rmp_inputs``, updated with
    ``metadata`` (e.g. ``iteration``, ``seed``, ``checkpoint``). ``platforms`` and
    ``matmul_precision`` go to :func:`export_policy`. Returns the manifest.
    """
    check_names(env_name, kind)
    env, module = make_env_and_policy(env_name, kind)
    base = getattr(env, "unwrapped", env)
    meta = {
        "env": env_name,
        "policy": kind,
        "robot": str(base.robot_name),
        "observation_layout": {k: [s.start, s.stop]
                               for k, s in base.observation_layout().items()},
        "action": ("raw residual RMP (A_r row-major, a_r), squashed by envs.RMPInEnv"
                   if kind == "rmp_residual_env"
                   else "joint-acceleration mean (unclipped; the environment clips)"),
    }
    if kind in RMP_KINDS:
        meta["rmp_inputs"] = RMP_INPUTS
    meta.update(metadata or {})
    if apply_fn is None:
        def apply_fn(p, o):
            return module.apply(p, o)[0]
    return export_policy(apply_fn, params, int(env.observation_size), out, metadata=meta,
                         platforms=platforms, matmul_precision=matmul_precision)


def export_run(out: str | os.PathLike, checkpoint: str | os.PathLike | None = None,
               step: int | None = None, train_seed_index: int = 0, env_name: str | None = None,
               kind: str | None = None, seed: int = 0,
               platforms: Sequence[str] = ("cpu", "cuda"),
               matmul_precision: str | None = None, force: bool = False) -> dict:
    """What ``scripts/export.py`` exports: with ``checkpoint`` (a run directory) the policy of
    checkpoint ``step`` (default: the newest intact one; NaN/inf parameters are refused) and
    training seed ``train_seed_index``, its observation statistics baked in; otherwise a freshly
    initialised ``kind`` policy for ``env_name`` (``params = module.init(PRNGKey(seed),
    zeros(obs_size))``). An existing ``out`` or manifest raises ``FileExistsError`` naming it
    unless ``force``. Returns the manifest (:func:`export_from_params`)."""
    existing = [p for p in (Path(out), manifest_path(out)) if p.exists()]
    if existing and not force:
        raise FileExistsError(f"{str(existing[0])!r} already exists; pass force=True (--force) "
                              "to overwrite it")
    if checkpoint is not None:
        run = load_run(checkpoint, step)
        apply_fn, params = deterministic_policy(run, train_seed_index)
        env_name, kind = run.spec.env, run.spec.policy
        meta = {"source": "checkpoint", "checkpoint": os.path.abspath(checkpoint),
                "iteration": run.iteration, "seed": run.seeds[train_seed_index]}
    else:
        if env_name is None or kind is None:
            raise ValueError("export_run needs a checkpoint, or env_name and kind")
        apply_fn, params = None, init_params(env_name, kind, seed)
        meta = {"source": "init", "seed": seed, "iteration": 0}
    return export_from_params(env_name, kind, params, out, meta, platforms=platforms,
                              matmul_precision=matmul_precision, apply_fn=apply_fn)


def load_export(path: str | os.PathLike) -> tuple[jax_export.Exported, dict]:
    """``(exported, manifest)`` of the blob ``path`` written by :func:`export_policy`, checked as
    ``scripts/load_policy.py`` checks it (that script is standalone by design):
    ``FileNotFoundError`` for a missing blob or manifest, ``ValueError`` naming the file for a
    foreign manifest, a SHA-256 mismatch or input/output shapes unlike the manifest's."""
    path = Path(path)
    if path.suffix != SUFFIX:
        raise ValueError(f"policy path must end in {SUFFIX!r}, got {str(path)!r}")
    for p in (path, manifest_path(path)):
        if not p.is_file():
            raise FileNotFoundError(f"exported policy file {str(p)!r} not found")
    try:
        manifest = json.loads(manifest_path(path).read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"manifest {str(manifest_path(path))!r} is not valid JSON: {e}") from None
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise ValueError(f"manifest {str(manifest_path(path))!r} is not a {FORMAT!r} manifest")
    blob = path.read_bytes()
    if hashlib.sha256(blob).hexdigest() != manifest.get("sha256"):
        raise ValueError(f"{str(path)!r} does not match its manifest's sha256 (corrupted?)")
    exported = jax_export.deserialize(bytearray(blob))
    shapes = ([tuple(a.shape[1:]) for a in exported.in_avals],
              [tuple(a.shape[1:]) for a in exported.out_avals])
    if shapes != ([(manifest.get("obs_size"),)], [(manifest.get("action_size"),)]):
        raise ValueError(f"{str(path)!r}: exported shapes {shapes} differ from the manifest's "
                         f"obs_size/action_size")
    return exported, manifest


__all__ = ["EXPORTABLE_ENVS", "FORMAT", "FORMAT_VERSION", "KNOWN_PLATFORMS", "MATMUL_PRECISIONS",
           "RMP_INPUTS", "RMP_KINDS", "SUFFIX", "check_names", "export_from_params",
           "export_policy", "export_run", "init_params", "load_export", "manifest_path"]
