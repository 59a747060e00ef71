"""Standalone loader for policies exported by ``agents.run.export.export_policy``.

Imports only ``jax``, ``numpy`` and the standard library (``jax.export.deserialize`` also needs
``flatbuffers``), so this file can be copied next to an exported policy and used without the
project installed: that is why it holds its logic itself. ``agents.run.export`` writes the
manifest format it reads.

Python::

    from load_policy import load_policy
    policy = load_policy("policy.jaxexport")   # checks the manifest policy.json and its SHA-256
    actions = policy(obs)                      # obs (b, obs_size) or (obs_size,) → numpy float32

Command line::

    python load_policy.py policy.jaxexport --obs obs.npy --out actions.npy

``--obs`` is a NumPy ``.npy`` file (no pickles, no text); ``--out`` a file (``.npy`` appended
unless it ends so) or a directory (existing, or ending in a separator) that receives
:data:`ACTIONS_NAME`; the path written is printed. ``--check-isolated`` fails if a project
package (``mjxrmp``, ``agents``, ``envs``) got imported, and prints the top-level modules.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import time
from pathlib import Path

import jax
import numpy as np
from jax import export as jax_export

FORMAT = "mjxrmp-policy-export"
SUPPORTED_FORMAT_VERSIONS = (1,)
SUFFIX = ".jaxexport"
#: Packages of the exporting project that the loader must never need.
PROJECT_PACKAGES = ("mjxrmp", "agents", "envs")
#: File name of the actions when ``--out`` is a directory.
ACTIONS_NAME = "actions.npy"


class PolicyLoadError(ValueError):
    """The exported policy or its manifest is missing, corrupted or inconsistent."""


class LoadedPolicy:
    """Callable ``obs → action mean`` of an exported policy: ``obs (b, obs_size)`` (``b ≥ 1``)
    or ``(obs_size,)`` gives a ``numpy.float32`` array ``(b, action_size)`` or ``(action_size,)``.
    Attributes: ``manifest`` (dict), ``exported`` (:class:`jax.export.Exported`), ``obs_size``,
    ``action_size``, ``path``."""

    def __init__(self, path: Path, manifest: dict, exported: jax_export.Exported):
        self.path, self.manifest, self.exported = path, manifest, exported
        self.obs_size, self.action_size = int(manifest["obs_size"]), int(manifest["action_size"])
        self._call = jax.jit(exported.call)

    def __call__(self, obs) -> np.ndarray:
        obs = np.asarray(obs)
        if not (np.issubdtype(obs.dtype, np.floating) or np.issubdtype(obs.dtype, np.integer)):
            raise TypeError(f"obs must be a real array, got dtype {obs.dtype}")
        single = obs.ndim == 1
        if obs.ndim not in (1, 2) or obs.shape[-1] != self.obs_size or obs.size == 0:
            raise ValueError(f"obs must have shape (b, {self.obs_size}) with b >= 1 or "
                             f"({self.obs_size},), got {obs.shape}")
        batch = obs[None] if single else obs
        out = np.asarray(self._call(np.ascontiguousarray(batch, np.float32)))
        return out[0] if single else out

    def __repr__(self) -> str:
        return (f"LoadedPolicy({str(self.path)!r}, obs_size={self.obs_size}, "
                f"action_size={self.action_size}, platforms={self.exported.platforms})")


def _read_manifest(path: Path) -> dict:
    mpath = path.with_suffix(".json")
    try:
        manifest = json.loads(mpath.read_text())
    except FileNotFoundError:
        raise PolicyLoadError(f"manifest {mpath} not found (expected next to {path})") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise PolicyLoadError(f"manifest {mpath} is not valid JSON: {e}") from None
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise PolicyLoadError(f"manifest {mpath} is not a {FORMAT!r} manifest")
    if manifest.get("format_version") not in SUPPORTED_FORMAT_VERSIONS:
        raise PolicyLoadError(f"manifest {mpath} has format_version="
                              f"{manifest.get('format_version')!r}; this loader reads "
                              f"{SUPPORTED_FORMAT_VERSIONS}")
    for key in ("sha256", "obs_size", "action_size"):
        if key not in manifest:
            raise PolicyLoadError(f"manifest {mpath} lacks the field {key!r}")
    return manifest


def load_policy(path: str | os.PathLike) -> LoadedPolicy:
    """Load the exported policy ``path`` (``.jaxexport``) after checking its manifest: refuses
    (:class:`PolicyLoadError`) a missing or foreign manifest, a blob whose SHA-256 or size differs
    from the manifest's (corrupted or mismatched file), and an exported function whose
    input/output shapes disagree with the manifest's ``obs_size``/``action_size``."""
    path = Path(path)
    if path.suffix != SUFFIX:
        raise PolicyLoadError(f"path must end in {SUFFIX!r}, got {str(path)!r}")
    manifest = _read_manifest(path)
    try:
        blob = path.read_bytes()
    except FileNotFoundError:
        raise PolicyLoadError(f"exported policy {path} not found") from None
    digest = hashlib.sha256(blob).hexdigest()
    if digest != manifest["sha256"]:
        raise PolicyLoadError(f"{path} is corrupted or does not belong to its manifest: sha256 "
                              f"{digest} != manifest sha256 {manifest['sha256']} ({len(blob)} "
                              f"bytes, manifest {manifest.get('size_bytes')})")
    try:
        exported = jax_export.deserialize(bytearray(blob))
    except ImportError as e:
        raise ImportError(f"deserialising {path} needs the 'flatbuffers' package: {e}") from e
    obs_size, action_size = int(manifest["obs_size"]), int(manifest["action_size"])
    ins, outs = exported.in_avals, exported.out_avals
    if (len(ins) != 1 or len(ins[0].shape) != 2 or ins[0].shape[1] != obs_size
            or np.dtype(ins[0].dtype) != np.float32):
        raise PolicyLoadError(f"{path}: exported input {ins} does not match the manifest's "
                              f"obs (b, {obs_size}) float32")
    if len(outs) != 1 or len(outs[0].shape) != 2 or outs[0].shape[1] != action_size:
        raise PolicyLoadError(f"{path}: exported output {outs} does not match the manifest's "
                              f"action (b, {action_size})")
    return LoadedPolicy(path, manifest, exported)


def project_modules_loaded() -> list[str]:
    """Project packages (:data:`PROJECT_PACKAGES`) present in ``sys.modules``."""
    return sorted({m.split(".")[0] for m in sys.modules} & set(PROJECT_PACKAGES))


def output_path(out: str) -> Path:
    """The file ``--out out`` writes: ``out/``:data:`ACTIONS_NAME` for a directory (existing, or
    ``out`` ending in a separator), else ``out`` with ``.npy`` appended unless it ends so."""
    if out.endswith(("/", os.sep)) or Path(out).is_dir():
        return Path(out) / ACTIONS_NAME
    return Path(out if out.endswith(".npy") else out + ".npy")


def read_observations(path: Path) -> np.ndarray:
    """The array in the ``.npy`` file ``path``; ``ValueError`` naming it and the format if not."""
    try:
        obs = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as e:  # numpy takes a text file for a pickle
        obs = e
    if not isinstance(obs, np.ndarray):
        raise ValueError(f"--obs {path}: expected a NumPy .npy array file (numpy.save) of "
                         f"observations (b, obs_size) or (obs_size,); "
                         f"{'no such file' if isinstance(obs, OSError) else 'not in that format'}")
    return obs


def main(argv: list[str] | None = None) -> int:
    """CLI: load ``policy``, run it on ``--obs`` (``.npy``), save ``--out``, print a summary."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("policy", type=Path, help="exported policy (.jaxexport)")
    parser.add_argument("--obs", type=Path, required=True, help=".npy of observations")
    parser.add_argument("--out", help=f".npy file, or directory for {ACTIONS_NAME}")
    parser.add_argument("--check-isolated", action="store_true",
                        help="fail if a project package (mjxrmp, agents, envs) was imported")
    args = parser.parse_args(argv)
    try:
        policy = load_policy(args.policy)
        obs = read_observations(args.obs)
        t0 = time.perf_counter()
        actions, elapsed = policy(obs), time.perf_counter() - t0
        if (out := output_path(args.out) if args.out else None) is not None:
            out.parent.mkdir(parents=True, exist_ok=True)
            np.save(out, actions)
    except (ValueError, TypeError, OSError) as e:  # PolicyLoadError is a ValueError
        print(f"error: {e}", file=sys.stderr)
        return 2
    meta = policy.manifest.get("metadata", {})
    print(f"policy   {args.policy} ({', '.join(policy.exported.platforms)}; "
          f"{', '.join(f'{k}={meta[k]}' for k in ('env', 'policy') if k in meta) or 'no env'})"
          f"\nbackend  {jax.default_backend()}  jax {jax.__version__}")
    print(f"obs      {obs.shape} -> actions {actions.shape} {actions.dtype} in {elapsed:.3f} s "
          f"(compile included)\nactions  min {actions.min():.6g}  max {actions.max():.6g}  "
          f"mean |a| {np.abs(actions).mean():.6g}")
    if out is not None:
        print(f"wrote    {out}")
    if args.check_isolated:
        top = {m.split(".")[0] for m in sys.modules if not m.startswith("_")}
        print(f"modules  {' '.join(sorted(top - set(sys.stdlib_module_names)))} (non-stdlib)")
        if loaded := project_modules_loaded():
            print(f"error: project packages imported: {loaded}", file=sys.stderr)
            return 3
        print("isolated no project package imported")
    return 0


if __name__ == "__main__":
    sys.exit(main())
