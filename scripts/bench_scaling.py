"""Measure PPO at scale: packed sweeps on one GPU, or data parallelism over several GPUs.

Each call measures one part and rewrites ``results/scaling/summary.json`` and ``table.csv``
from every part present (:mod:`agents.bench.scaling`; findings in ``docs/reports/scaling.md``).
Meant for GPUs (the thesis preset); ``--preset cpu --iterations 1`` is a quick check here.

Examples::

    python scripts/bench_scaling.py sweeps --runs 4 16 64
    python scripts/bench_scaling.py setups --runs 8 16
    python scripts/bench_scaling.py data_parallel --devices 1 2 4
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from mjxrmp import _xla

_xla.configure_script()

import jax  # noqa: E402

import envs  # noqa: E402
from agents.bench.scaling import (  # noqa: E402
    PARTS,
    measure_data_parallel,
    measure_sweep,
    write_part,
    write_scaling_study,
)
from agents.ppo import KINDS  # noqa: E402
from agents.run.spec import PRESETS  # noqa: E402
from mjxrmp.results.summary import run_record  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent


def main(argv: list[str] | None = None) -> int:
    """Parse the arguments, measure the part, write it and the study; the exit status."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("part", choices=PARTS)
    p.add_argument("--env", default="three_link/env3")
    p.add_argument("--policy", default="rmp_residual")
    p.add_argument("--preset", default="thesis", help=f"one of {sorted(PRESETS)}")
    p.add_argument("--iterations", type=int, default=2, help="iterations per timed chunk")
    p.add_argument("--runs", type=int, nargs="+", default=[4, 16, 64],
                   help="sweeps: rows per program (multiples of --seeds)")
    p.add_argument("--setups", nargs="+", default=["three_link/env2", "three_link/env3"],
                   help="the setups part: environment setups that share a model, packed")
    p.add_argument("--seeds", type=int, default=4, help="vmapped seeds (per sweep point)")
    p.add_argument("--devices", type=int, nargs="+", default=[1, 2, 4],
                   help="data_parallel: GPU counts")
    p.add_argument("--per-device-envs", type=int, default=4096,
                   help="data_parallel: environments per GPU for weak scaling")
    p.add_argument("--strong-envs", type=int, default=4096,
                   help="data_parallel: total environments for strong scaling")
    p.add_argument("--out", type=Path, default=ROOT / "results" / "scaling")
    args = p.parse_args(argv)
    if args.env not in envs.ENVIRONMENTS or args.policy not in KINDS:
        p.error(f"--env must be one of {sorted(envs.ENVIRONMENTS)} and --policy one of "
                f"{list(KINDS)}")
    if args.preset not in PRESETS:
        p.error(f"unknown --preset {args.preset!r}; valid presets are {sorted(PRESETS)}")
    if args.iterations < 1 or args.seeds < 1 or any(r % args.seeds for r in args.runs):
        p.error("--iterations and --seeds must be positive and every --runs a multiple of "
                "--seeds")
    if args.part == "data_parallel" and max(args.devices) > len(jax.devices()):
        p.error(f"--devices {max(args.devices)} exceeds the {len(jax.devices())} devices "
                "JAX sees")
    command = " ".join(["python scripts/bench_scaling.py",
                        *(argv if argv is not None else sys.argv[1:])])
    if args.part == "setups":  # one setup's seeds, then each --runs with the setups packed
        rows = [measure_sweep(args.setups[-1], args.policy, args.seeds, args.iterations,
                              args.preset, args.seeds)] + [
            measure_sweep(args.env, args.policy, r, args.iterations, args.preset, args.seeds,
                          tuple(args.setups)) for r in args.runs]
        for r in rows:
            print(f"{r['runs']:4d} runs of {r['setups'] or r['env']}: "
                  f"{r['iteration_s']:.3f} s/iteration, compile {r['compile_s']:.0f} s")
    elif args.part == "sweeps":
        rows = [measure_sweep(args.env, args.policy, r, args.iterations, args.preset,
                              args.seeds) for r in args.runs]
        for r in rows:
            print(f"{r['runs']:4d} runs: {r['steps_per_s']:.3g} env steps/s, "
                  f"{r['iteration_s']:.2f} s/iteration, compile {r['compile_s']:.0f} s")
    else:
        rows = measure_data_parallel(args.env, args.policy, args.devices,
                                     args.per_device_envs, args.strong_envs, args.seeds,
                                     args.iterations, args.preset)
        for r in rows:
            print(f"{r['devices']} GPU(s), {r['mode']}, {r['num_envs']} envs: "
                  f"{r['steps_per_s']:.3g} env steps/s")
    dev = jax.devices()
    device = None if dev[0].platform == "cpu" else f"{len(dev)} × {dev[0].device_kind}"
    write_part(args.out, args.part, rows, run_record(command, device))
    print(f"wrote {write_scaling_study(args.out)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
