"""Does the pessimistic critic separate goal-anchored episodes from failures (zero reward)?

Usage, from the repository root: ``python <this file> --cut CUT.npz [--full FULL.npz] ...``
with the medium-replay data of ``scripts/reproduce_ch8.py --stage collect`` (``CUT``: the
collision-cut file ``OUT/data/three_link-env3_medium-replay_cut_x<S>_s0.npz``, ``FULL``: the
``_full_`` one). The CPU run in ``output.jsonl`` next to this file:

    python scripts/reproduce_ch8.py --recipes medium-replay --goal-deadline 350 --scale 20 \
        --stage collect --out OUT
    python <this file> --cut OUT/data/three_link-env3_medium-replay_cut_x20_s0.npz \
        --steps 20000 --chunk 20000

For each ``--datasets`` entry (``goal``, ``deadline``: the cut data after
:func:`offline.survival.cut_before_goal` at 350 steps, with the goal or the failures absorbing;
``full``: the uncut data) and each ``--learners`` entry (PSPI: absolute pessimism, ATAC:
relative) it trains one program of ``--seeds`` seeds with the **zero** reward (NN-RESIDUAL
actor, ``--warmstart`` of the steps BC warm start, ``--actor-rate``). After every ``--chunk``
steps it prints one JSON line: the min-over-critics Q(s, a) of the data transitions averaged per
episode outcome (success: the episode reaches the goal within its first 350 transitions) and
position (all, first 50, last 10 transitions of each episode), and with ``--eval-episodes N``
the normalised score of the policies (thesis §7.4 normalisation, ``offline.evaluate``).
"""

import argparse
import json
import sys
import time

sys.path.insert(0, ".")

import mjxrmp  # noqa: F401  (sets the XLA:CPU flag before JAX initialises)

# isort: split
import jax
import jax.numpy as jnp
import numpy as np
from offline.networks import QEnsemble
from offline.sweep import run_actor_params

from offline import atac, collect, experiment, survival
from offline import data as odata

ENV = "three_link/env3"
DEADLINE = 350
PESSIMISM = {"PSPI": "absolute", "ATAC": "relative"}


def parse_args() -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cut", required=True, help="collision-cut medium-replay data (.npz)")
    p.add_argument("--full", default=None, help="uncut data (.npz), for --datasets full")
    p.add_argument("--datasets", nargs="+", default=["goal", "deadline"],
                   choices=["goal", "deadline", "full"])
    p.add_argument("--learners", nargs="+", default=["PSPI", "ATAC"], choices=list(PESSIMISM))
    p.add_argument("--steps", type=int, default=20000)
    p.add_argument("--chunk", type=int, default=20000)
    p.add_argument("--hidden", type=int, nargs="+", default=[128, 128])
    p.add_argument("--seeds", type=int, default=1)
    p.add_argument("--warmstart", type=float, default=0.5)
    p.add_argument("--actor-rate", default="scaled", choices=experiment.ACTOR_RATES)
    p.add_argument("--eval-episodes", type=int, default=0)
    args = p.parse_args()
    if "full" in args.datasets and args.full is None:
        p.error("--datasets full needs --full FULL.npz")
    return args


def main() -> None:
    args = parse_args()
    env = collect.make_env(ENV)
    radius = float(env.success_radius)
    cut = odata.check_environment(odata.load(args.cut), env, name="cut")
    deadline = survival.cut_before_goal(cut, DEADLINE, radius=radius)
    versions = {"goal": lambda: survival.absorbing_goal(deadline, radius=radius),
                "deadline": lambda: deadline,
                "full": lambda: odata.check_environment(odata.load(args.full), env, name="full")}
    evaluator = None
    if args.eval_episodes:
        from offline import evaluate

        evaluator = evaluate.make_evaluator(ENV, args.eval_episodes)
    budget = experiment.Budget(steps=args.steps, hidden=tuple(args.hidden), batch=256,
                               actor="nn_residual", warmstart=args.warmstart,
                               actor_rate=args.actor_rate)
    for name in args.datasets:
        ds = versions[name]()
        for learner in args.learners:
            train(args, name, ds, learner, budget, evaluator, radius)


def train(args: argparse.Namespace, name: str, ds: odata.Dataset, learner: str,
          budget: experiment.Budget, evaluator, radius: float) -> None:
    """One zero-reward program of ``learner`` on ``ds``; a JSON line after every chunk."""
    episodes_arrived = survival.arrived_by(ds, DEADLINE, radius)
    _, lengths = odata.episode_bounds(np.asarray(ds.episode_ids))
    success = np.repeat(episodes_arrived, lengths)
    position = np.concatenate([np.arange(n) for n in lengths])
    from_end = np.concatenate([np.arange(n)[::-1] for n in lengths])
    groups = {"all": np.ones_like(success), "first50": position < 50, "last10": from_end < 10}
    zero = survival.variant(ds, "zero", "keep")
    plain = zero.replace(metadata=zero.metadata.updated(rewards_visible=True))
    obs = jnp.asarray(ds.observations, jnp.float32)
    act = jnp.asarray(ds.actions, jnp.float32)
    critic = QEnsemble(2, hidden_sizes=tuple(args.hidden))
    q_fn = jax.jit(jax.vmap(lambda c: critic.apply(c, obs, act).min(-1)))
    trainer = atac.make_train(plain, experiment.atac_config(budget,
                                                            pessimism=PESSIMISM[learner]))
    score_fn = None
    if evaluator is not None:
        score_fn = jax.jit(jax.vmap(lambda p: evaluator.evaluate(
            trainer.act, p, jax.random.PRNGKey(10_000))["normalized_score"]))
    t0 = time.time()

    def report(state, _metrics, done: int) -> None:
        q = np.asarray(q_fn(state.params["critic"]))  # (seeds, N)
        row = {"data": name, "learner": learner, "step": done, "steps": args.steps,
               "seeds": args.seeds, "wall_s": round(time.time() - t0, 1),
               "success_episodes": int(episodes_arrived.sum()), "episodes": int(lengths.size)}
        for g, mask in groups.items():
            row[f"q_success_{g}"] = float(q[:, success & mask].mean())
            row[f"q_fail_{g}"] = float(q[:, ~success & mask].mean())
        if score_fn is not None:
            row["score"] = np.asarray(score_fn(run_actor_params(state)), np.float64).tolist()
        print(json.dumps(row), flush=True)

    experiment.train_chunked(trainer, experiment.seed_keys(range(args.seeds)), args.chunk,
                             on_chunk=report)


if __name__ == "__main__":
    main()
