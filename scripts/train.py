"""Train a policy with PPO on a reaching task — the project's main job.

With no arguments: ``rmp_residual`` on ``three_link/env3``, CPU-sized (``--preset cpu``:
64 environments × 128 steps × 400 iterations, about 5 minutes on 2 CPU cores), written to
``runs/three_link-env3_rmp_residual``. ``--preset thesis`` runs the thesis scale (128 × 512 steps,
500 iterations, 30 epochs; meant for a GPU). See :mod:`agents.run.training` for what the run
directory holds; ``--resume`` continues a run from its newest checkpoint.

Examples::

    python scripts/train.py
    python scripts/train.py --env three_link/env1 --policy nn --seeds 0 1 2 3 --preset thesis
    python scripts/train.py --out runs/my_run --resume
    python scripts/train.py --set learning_rate=1e-4 --set total_iterations=50
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from mjxrmp import _xla

_xla.configure_cpu_flags()

import envs  # noqa: E402
from agents.ppo.policies import KINDS  # noqa: E402
from agents.ppo.train import PPOConfig  # noqa: E402
from agents.run.training import (  # noqa: E402
    PRESETS,
    RunSpec,
    improvement_summary,
    make_mesh,
    preset,
    run_training,
)


def _parse_overrides(items: list[str]) -> dict:
    """``["learning_rate=1e-4", "policy_hidden_sizes=64,64"]`` → typed PPOConfig overrides."""
    fields = {f.name: f for f in dataclasses.fields(PPOConfig)}
    defaults = PPOConfig()
    out = {}
    for item in items:
        if "=" not in item:
            raise ValueError(f"--set expects NAME=VALUE, got {item!r}")
        name, value = item.split("=", 1)
        if name not in fields:
            raise ValueError(f"--set: unknown PPOConfig field {name!r}; valid fields are "
                             f"{sorted(fields)}")
        current = getattr(defaults, name)
        if isinstance(current, bool):
            out[name] = value.lower() in ("1", "true", "yes")
        elif isinstance(current, tuple):
            out[name] = tuple(int(v) for v in value.split(",") if v)
        elif value.lower() == "none":
            out[name] = None
        elif isinstance(current, int) and name != "max_grad_norm":
            out[name] = int(value)
        else:
            out[name] = float(value)
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--env", default="three_link/env3",
                   help=f"environment; one of {sorted(envs.ENVIRONMENTS)}")
    p.add_argument("--policy", default="rmp_residual", help=f"policy kind; one of {KINDS}")
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
                   help="call jax.distributed.initialize() first (multi-host runs)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    args = p.parse_args(argv)

    if args.env not in envs.ENVIRONMENTS:
        p.error(f"unknown --env {args.env!r}; valid names are {sorted(envs.ENVIRONMENTS)}")
    if args.policy not in KINDS:
        p.error(f"unknown --policy {args.policy!r}; valid kinds are {list(KINDS)}")
    if args.preset not in PRESETS:
        p.error(f"unknown --preset {args.preset!r}; valid presets are {sorted(PRESETS)}")
    if args.distributed:
        import jax

        jax.distributed.initialize()
    try:
        overrides = _parse_overrides(args.set)
        if args.iterations is not None:
            overrides["total_iterations"] = args.iterations
        spec = RunSpec(env=args.env, policy=args.policy, seeds=tuple(args.seeds),
                       ppo=preset(args.preset, **overrides), log_every=args.log_every,
                       checkpoint_every=args.checkpoint_every,
                       keep_checkpoints=args.keep_checkpoints or None)
    except (TypeError, ValueError) as e:
        p.error(str(e))
    out = args.out or os.path.join("runs", f"{args.env.replace('/', '-')}_{args.policy}")
    print(f"training {spec.policy} on {spec.env}, seeds {list(spec.seeds)}, preset "
          f"{args.preset}: {spec.ppo.total_iterations} iterations × {spec.ppo.batch_size} "
          f"steps → {out}", file=sys.stderr)
    try:
        result = run_training(spec, out, resume=args.resume, progress=not args.no_progress,
                              mesh=make_mesh(args.devices))
    except (FileExistsError, FileNotFoundError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    if result.history:
        print(improvement_summary(result.history), file=sys.stderr)
        rate = result.env_steps / max(result.train_seconds, 1e-9)
        print(f"compile {result.compile_seconds:.1f} s, training {result.train_seconds:.1f} s, "
              f"{rate:.3g} env steps/s", file=sys.stderr)
    print(f"wrote {out}/metrics.csv, learning_curves.png, tb/, checkpoints/", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
