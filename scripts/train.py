"""Train a policy with PPO on a reaching task — the project's main job.

With no arguments: ``rmp_residual`` on ``three_link/env3``, CPU-sized (``--preset cpu``:
64 environments × 128 steps × 400 iterations, about 1.5 minutes on 2 CPU cores), written to
``runs/three_link-env3_rmp_residual``. ``--preset thesis`` runs the thesis scale (128 × 512 steps,
500 iterations, 30 epochs; meant for a GPU). See :mod:`agents.run.training` for what the run
directory holds; ``--resume`` continues a run from its newest checkpoint.

Exit status: 0 done; 2 refused (bad arguments, a run directory that holds another run or is in
use by another process, an incompatible checkpoint); 3 the training diverged (a non-finite loss,
metric or parameter; the message names the iteration, seed and quantity, the last finite
checkpoint is kept); 130 interrupted (a checkpoint of what is done is written).

Examples::

    python scripts/train.py
    python scripts/train.py --env three_link/env1 --policy nn --seeds 0 1 2 3 --preset thesis
    python scripts/train.py --out runs/my_run --resume
    python scripts/train.py --set learning_rate=1e-4 --set total_iterations=50
    python scripts/train.py --seeds 0 1 --grid learning_rate=1e-4,3e-4 --grid ent_coef=0,0.01
    python scripts/train.py --env three_link/env2 three_link/env3 --seeds 0 1 2 3
    python scripts/train.py --policy nn nn_residual --seeds 0 1 2 3

``--grid NAME=V1,V2,...`` (repeatable), several ``--env`` setups that share a model (env2 and
env3 differ only in the goal region) or several ``--policy`` kinds that share a network (nn and
nn_residual: the hand-designed base added or not) train a packed sweep instead: every setup ×
kind × point of the grid × every seed in one compiled program (:mod:`agents.run.sweep`), into
``--out`` (default ``runs/sweep_<envs>_<policies>``) with one ordinary run directory per point,
``sweep.csv`` and ``sweep_curves.png``.

While it imports, the command starts the device (:func:`agents.run.program_cache.start_device`)
and, repeated (``--out``, ``--resume``, ``--no-progress``, ``--checkpoint-every`` and
``--keep-checkpoints`` aside), compiles the programs the last one used
(:func:`agents.run.program_cache.prefetch`; with the compile cache, ``MJXRMP_COMPILE_CACHE``).

Multi-process (multi-host) training (docs/multihost.md): run the same command in every process
with ``--coordinator HOST:PORT --num-processes N --process-id I`` (or ``--distributed`` to take
them from ``MJXRMP_COORDINATOR``/``MJXRMP_NUM_PROCESSES``/``MJXRMP_PROCESS_ID`` or the cluster's
environment, e.g. SLURM); the environment batch is sharded over every device of every process.
"""

from __future__ import annotations

import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from mjxrmp import _xla

_xla.configure_script()

from agents.run.program_cache import command_label, prefetch, remember, start_device  # noqa: E402

#: Options (with a value / without) that do not change what a command compiles.
_UNCOMPILED = ({"--out", "--checkpoint-every", "--keep-checkpoints"}, {"--resume", "--no-progress"})
#: Options of a multi-process run (JAX must not start before ``jax.distributed`` connects).
_MULTIPROCESS = ("--distributed", "--coordinator", "--num-processes", "--process-id")


def _start_prefetch(argv: list[str]) -> None:
    """Start the device and compile the programs the same command used last time in background
    threads while the imports below run (:func:`agents.run.program_cache.start_device`,
    :func:`~agents.run.program_cache.prefetch`); not in a multi-process run (any abbreviation of
    its options counts)."""
    names = {a.split("=", 1)[0] for a in argv if a.startswith("--") and len(a) > 2}
    if not any(f.startswith(n) for n in names for f in _MULTIPROCESS):
        start_device()
        prefetch(command_label(argv, *_UNCOMPILED))


if __name__ == "__main__":
    _start_prefetch(sys.argv[1:])

import envs  # noqa: E402
from agents.ppo import KINDS, make_mesh  # noqa: E402
from agents.ppo.hparams import SWEEPABLE  # noqa: E402
from agents.run.directory import RunDirectoryInUseError  # noqa: E402
from agents.run.distributed import initialize, mesh_devices  # noqa: E402
from agents.run.spec import PRESETS, RunSpec, parse_overrides, preset  # noqa: E402
from agents.run.sweep import run_sweep  # noqa: E402
from agents.run.sweep_spec import SweepSpec, parse_grid  # noqa: E402
from agents.run.training import result_summary, run_training  # noqa: E402
from mjxrmp.divergence import EXIT_DIVERGED, DivergenceError  # noqa: E402


def _parser() -> argparse.ArgumentParser:
    """The command line's arguments."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--env", nargs="+", default=["three_link/env3"],
                   help=f"environment; one of {sorted(envs.ENVIRONMENTS)}; several setups that "
                        "share a model (three_link/env2 three_link/env3) train as a sweep")
    p.add_argument("--policy", nargs="+", default=["rmp_residual"],
                   help=f"policy kind; one of {KINDS}; several that share a network (nn "
                        "nn_residual) train as a sweep")
    p.add_argument("--preset", default="cpu", help=f"PPO settings; one of {sorted(PRESETS)}")
    p.add_argument("--seeds", type=int, nargs="+", default=[0],
                   help="seeds, trained together in one vmapped program")
    p.add_argument("--iterations", type=int, default=None, help="override total_iterations")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="override any PPOConfig field (repeatable)")
    p.add_argument("--out", default=None, help="run directory (default runs/<env>_<policy>)")
    p.add_argument("--resume", action="store_true", help="continue the run in --out")
    p.add_argument("--log-every", type=int, default=5,
                   help="iterations per compiled chunk / log line")
    p.add_argument("--checkpoint-every", type=int, default=25, help="iterations per checkpoint")
    p.add_argument("--keep-checkpoints", type=int, default=3, metavar="N",
                   help="keep the N newest checkpoints; 0 keeps every one (the snapshots an "
                        "offline medium-replay dataset is collected from)")
    p.add_argument("--devices", type=int, default=None,
                   help="shard the environment batch over this many devices")
    p.add_argument("--distributed", action="store_true",
                   help="multi-process run: connect the processes with jax.distributed (the "
                        "flags below, MJXRMP_* variables or the cluster's, e.g. SLURM)")
    p.add_argument("--coordinator", default=None, metavar="HOST:PORT",
                   help="multi-process run: address of process 0's coordinator service")
    p.add_argument("--num-processes", type=int, default=None,
                   help="multi-process run: number of processes")
    p.add_argument("--process-id", type=int, default=None,
                   help="multi-process run: this process's id (0 writes the run directory)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--grid", action="append", default=[], metavar="NAME=V1,V2,...",
                   help=f"sweep a hyper-parameter (repeatable; one of {list(SWEEPABLE)}): all "
                        "points × seeds train in one program")
    return p


def main(argv: list[str] | None = None) -> int:
    """Parse the arguments into a :class:`agents.run.spec.RunSpec`, train it
    (:func:`agents.run.training.run_training`) and print the summary; the exit status."""
    p = _parser()
    args = p.parse_args(argv)

    for env in args.env:
        if env not in envs.ENVIRONMENTS:
            p.error(f"unknown --env {env!r}; valid names are {sorted(envs.ENVIRONMENTS)}")
    for kind in args.policy:
        if kind not in KINDS:
            p.error(f"unknown --policy {kind!r}; valid kinds are {list(KINDS)}")
    if args.preset not in PRESETS:
        p.error(f"unknown --preset {args.preset!r}; valid presets are {sorted(PRESETS)}")
    try:
        if args.distributed or (args.coordinator, args.num_processes, args.process_id) != (
                None, None, None):
            initialize(args.coordinator, args.num_processes, args.process_id)
        devices = mesh_devices(args.devices)
        overrides = parse_overrides(args.set)
        if args.iterations is not None:
            overrides["total_iterations"] = args.iterations
        spec = RunSpec(env=args.env[0], policy=args.policy[0], seeds=tuple(args.seeds),
                       ppo=preset(args.preset, **overrides), log_every=args.log_every,
                       checkpoint_every=args.checkpoint_every,
                       keep_checkpoints=args.keep_checkpoints or None)
        setups = tuple(args.env) if len(args.env) > 1 else ()
        kinds = tuple(args.policy) if len(args.policy) > 1 else ()
        sweep = (SweepSpec(spec, parse_grid(args.grid), setups, kinds)
                 if args.grid or setups or kinds else None)
    except (TypeError, ValueError) as e:
        p.error(str(e))
    if sweep is not None and (devices or 1) > 1:
        p.error("a sweep (--grid, several --env or --policy) runs on one device and one process; "
                "leave out --devices")
    stem = f"{'+'.join(e.replace('/', '-') for e in args.env)}_{'+'.join(args.policy)}"
    out = args.out or os.path.join("runs", f"sweep_{stem}" if sweep else stem)
    print(f"training {', '.join(args.policy)} on {', '.join(args.env)}, seeds "
          f"{list(spec.seeds)}, preset {args.preset}: {spec.ppo.total_iterations} iterations × "
          f"{spec.ppo.batch_size} steps → {out}", file=sys.stderr)
    if sweep is not None:
        print(f"sweep of {len(sweep.points())} points × {len(spec.seeds)} seeds in one program",
              file=sys.stderr)
    try:
        result = (run_sweep(sweep, out, resume=args.resume, progress=not args.no_progress)
                  if sweep is not None else
                  run_training(spec, out, resume=args.resume, progress=not args.no_progress,
                               mesh=make_mesh(devices)))
    except (FileExistsError, FileNotFoundError, ValueError, RunDirectoryInUseError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except DivergenceError as e:
        print(f"error: {e}", file=sys.stderr)
        return EXIT_DIVERGED
    except KeyboardInterrupt:
        return 130
    remember(command_label(sys.argv[1:] if argv is None else argv, *_UNCOMPILED))
    if result.history:
        print(result_summary(result), file=sys.stderr)
    print(f"wrote {out}/" + ("sweep.csv, sweep_curves.png and one run directory per point"
                             if sweep is not None else
                             "metrics.csv, learning_curves.png, tb/, checkpoints/"),
          file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
