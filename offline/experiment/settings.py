"""Settings shared by the offline scripts (docs/design.md §2.5, §6): declarative tables of their
common command-line options (each script builds its parser from them:
``for option in LEARNER_OPTIONS: parser.add_argument(*option.flags, **option.spec)``), the learner
settings as result-row fields and cell keys, presets and the control rate.

A script's results are JSON lines keyed by a *cell key* (its settings as a JSON list). A setting
added after the first results were made enters the key only when it differs from
:data:`ORIGINAL_SETTINGS`, so earlier results keep their keys.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

from offline.data.rollouts import make_env
from offline.learners.registry import ACTOR_RATES, DEFAULT_WARMSTART
from offline.learners.residual_actor import ACTORS


class Option(NamedTuple):
    """One command-line option: ``parser.add_argument(*flags, **spec)``."""

    flags: tuple[str, ...]
    spec: dict[str, Any]


#: The learner settings of :func:`setting_fields` (the :class:`~offline.learners.registry.Budget`
#: fields ``normalize_observations``, ``actor``, ``warmstart``, ``actor_rate``).
LEARNER_OPTIONS = (
    Option(("--normalize-observations",), dict(
        action="store_true",
        help="standardise observations with the dynamics data's statistics "
             "(offline.learners.base.ObservationNormalizer; cells get their own key)")),
    Option(("--actor",), dict(
        choices=ACTORS, default="mlp",
        help="actor class of every learner: a tanh-Gaussian MLP, or the MLP added to the "
             "chapter-6 NN-RESIDUAL RMP² base (offline.learners.residual_actor; cells get their "
             "own key)")),
    Option(("--warmstart",), dict(
        type=float, default=DEFAULT_WARMSTART, metavar="FRACTION",
        help="fraction of the steps spent in ATAC's BC warm start (published: 100 k of 1 M; "
             "cells get their own key)")),
    Option(("--actor-rate",), dict(
        choices=ACTOR_RATES, default="published",
        help="ATAC-type actor rate of a shortened run: the published 5e-7 (default), or 5e-7 x "
             "1e6/steps, the rule of the first tables (offline.learners.registry.atac_config; "
             "cells get their own key)")),
)
#: ``--substeps N``: the control rate (:func:`control_rate_kwargs`).
SUBSTEPS_OPTION = Option(("--substeps",), dict(
    type=int, default=None, metavar="N",
    help="physics substeps per control step (default: the environment's 3, i.e. 80 Hz; 24 is "
         "10 Hz). The horizon keeps the episode length in seconds; step counts such as "
         "--goal-deadline are control steps at this rate. Data files and cell keys get their "
         "own names"))
#: ``--checkpoints DIR`` (:func:`offline.experiment.programs.train_program`).
CHECKPOINT_OPTION = Option(("--checkpoints",), dict(
    type=Path, default=None, metavar="DIR",
    help="save every program's state under DIR after each --chunk steps and continue an "
         "interrupted program from there (default: off)"))

#: The learner settings our first results were made with: result rows and checkpoints from
#: before a setting existed have these values, and cell keys name only the settings that differ.
ORIGINAL_SETTINGS = {"normalize_observations": False, "actor": "mlp",
                     "warmstart": DEFAULT_WARMSTART, "actor_rate": "scaled"}


def setting_fields(args: Any) -> dict[str, Any]:
    """The learner settings of ``args`` (parsed :data:`LEARNER_OPTIONS`) as result-row fields
    (also :class:`offline.learners.registry.Budget` keyword arguments), in
    :data:`ORIGINAL_SETTINGS` order."""
    return {"normalize_observations": bool(args.normalize_observations), "actor": args.actor,
            "warmstart": float(args.warmstart), "actor_rate": args.actor_rate}


def setting_changes(args: Any) -> dict[str, Any]:
    """The learner settings of ``args`` that differ from :data:`ORIGINAL_SETTINGS`."""
    return {k: v for k, v in setting_fields(args).items() if v != ORIGINAL_SETTINGS[k]}


def setting_key(args: Any) -> list:
    """Cell-key entries of :func:`setting_changes` (a flag for ``normalize_observations``, name
    and value for the others), so results made before a setting existed keep their keys
    whatever the current default."""
    key: list = []
    for k, v in setting_changes(args).items():
        key += [k] if k == "normalize_observations" else [k, v]
    return key


def apply_preset(args: Any, preset: Mapping[str, Any], positive: Sequence[str]) -> Any:
    """Fill the arguments of ``args`` left at ``None`` from ``preset`` and refuse
    (``ValueError``) any of ``positive`` that is below 1; returns ``args``."""
    for k, v in preset.items():
        if getattr(args, k) is None:
            setattr(args, k, v)
    for name in positive:
        if getattr(args, name) < 1:
            raise ValueError(f"--{name.replace('_', '-')} must be a positive integer")
    return args


def control_rate_kwargs(env_name: str, substeps: int | None) -> dict[str, int] | None:
    """The constructor arguments of environment ``env_name`` for ``substeps`` physics substeps
    per control step (``None``: its defaults), with the horizon that keeps the episode's length
    in seconds. Raises ``ValueError`` when the episode is not a whole number of control steps."""
    if substeps is None:
        return None
    env = make_env(env_name)
    total = env.horizon * env.substeps
    if isinstance(substeps, bool) or not isinstance(substeps, int) or substeps < 1 \
            or total % substeps:
        raise ValueError(f"--substeps must be a positive divisor of the episode's {total} "
                         f"physics steps on {env_name}, got {substeps!r}")
    return {"substeps": substeps, "horizon": total // substeps}


def substeps_tag(substeps: int | None) -> list:
    """Cell-key and file-name entries of a non-default control rate (``[]`` for the
    environment's own, so earlier results keep their keys)."""
    return [] if substeps is None else ["substeps", int(substeps)]


__all__ = [
    "CHECKPOINT_OPTION",
    "LEARNER_OPTIONS",
    "ORIGINAL_SETTINGS",
    "SUBSTEPS_OPTION",
    "Option",
    "apply_preset",
    "control_rate_kwargs",
    "setting_changes",
    "setting_fields",
    "setting_key",
    "substeps_tag",
]
