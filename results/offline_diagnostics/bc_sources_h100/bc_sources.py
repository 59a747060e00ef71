"""BC on each source of the chapter-7 `mixed` data, against that source's own score (session 14).

Why BC of `mixed` scores about 91 at 10 Hz: `mixed` (offline.collect, no PPO run) is random plus
the expert with Gaussian action noise σ 1.0, 0.5 and 0.1. This trains BC (the table's learner,
offline.experiment.build, NN-RESIDUAL actor, 5 seeds vmapped) on each source alone and on the
whole of `mixed`, evaluates it as reproduce_ch7.py does, and prints it next to the normalised
score of the behaviour that collected the source (its episodes' mean return in the data,
normalised with the evaluator's reference returns). Usage:
python bc_sources.py DATA_DIR ENV [STEPS] (data from `reproduce_ch7.py --stage collect
--substeps 24 --scale 400 ...`).
"""
import glob
import math
import sys
import time

import jax
import numpy as np
from offline.learner import actor_params
from offline.sweep import control_rate_kwargs

from offline import collect, evaluate, experiment
from offline import data as odata

DATA, ENV = sys.argv[1], sys.argv[2]
STEPS = int(sys.argv[3]) if len(sys.argv) > 3 else 50_000
SEEDS, EVAL_EPISODES = 5, 64


def main() -> None:
    kwargs = control_rate_kwargs(ENV, 24)
    mixed = odata.load(glob.glob(f"{DATA}/{ENV.replace('/', '-')}_mixed_x*_s0_substeps_24.npz")[0])
    ev = evaluate.make_evaluator(ENV, EVAL_EPISODES, env_kwargs=kwargs)
    budget = experiment.Budget(steps=STEPS, actor="nn_residual")
    src = collect.source_of_episodes(mixed)
    parts = [(s["behaviour"]["name"], src == i, s["summary"]["return_mean"])
             for i, s in enumerate(mixed.metadata["sources"])]
    per, _ = odata.episode_statistics(mixed)
    parts.append(("all of mixed", np.ones_like(src, bool), float(np.mean(per.returns))))
    print(f"{ENV} at 10 Hz, BC {STEPS} steps x {SEEDS} seeds, {EVAL_EPISODES} evaluation "
          f"episodes per seed; reference returns expert {ev.reference['expert_return']:.2f}, "
          f"random {ev.reference['random_return']:.2f}", flush=True)
    for name, rows, behaviour_return in parts:
        t0 = time.perf_counter()
        trainer = experiment.build("BC", odata.take_rows(mixed, rows), None, budget)
        state, _ = experiment.train_chunked(trainer, experiment.seed_keys(range(SEEDS)), STEPS)
        res = jax.vmap(lambda p, _t=trainer: ev.evaluate(_t.act, p, jax.random.PRNGKey(10_000)))(
            actor_params(state))
        score = np.asarray(res["normalized_score"], np.float64)
        print(f"  {name:13s}: {int(rows.sum()):6d} transitions; behaviour "
              f"{float(ev.normalized_score(behaviour_return)):6.1f}; BC {score.mean():6.1f} ± "
              f"{score.std(ddof=1) / math.sqrt(SEEDS):4.1f}, safe "
              f"{float(np.mean(res['safe_pct'])):5.1f} % ({time.perf_counter() - t0:.0f} s)",
              flush=True)


if __name__ == "__main__":
    main()
