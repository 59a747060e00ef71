"""What limits BC on near-expert Franka data at 10 Hz (session 14, CPU).

On the H100 (bc_sources_h100), BC on the `mixed` source "expert + noise σ 0.1" scored 88
although that behaviour scores 98. This trains BC on one source of a `mixed` file with a few
settings (actor class, steps, width) and scores each as reproduce_ch7.py does, to see which one
moves the ceiling. Usage: python bc_ceiling.py DATA_DIR ENV SOURCE [SEEDS] [EPISODES]
(SOURCE a behaviour name of the file's sources, e.g. noisy-0.1; data from
`reproduce_ch7.py --stage collect --substeps 24 --scale N ...`).
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

DATA, ENV, SOURCE = sys.argv[1], sys.argv[2], sys.argv[3]
SEEDS = int(sys.argv[4]) if len(sys.argv) > 4 else 3
EPISODES = int(sys.argv[5]) if len(sys.argv) > 5 else 32
#: (label, actor, steps, hidden)
SETTINGS = (("NN-RESIDUAL, 50 k steps, 3x256", "nn_residual", 50_000, (256, 256, 256)),
            ("NN-RESIDUAL, 5 k steps, 3x256", "nn_residual", 5_000, (256, 256, 256)),
            ("NN-RESIDUAL, 50 k steps, 3x512", "nn_residual", 50_000, (512, 512, 512)),
            ("plain MLP, 50 k steps, 3x256", "mlp", 50_000, (256, 256, 256)))


def main() -> None:
    mixed = odata.load(glob.glob(f"{DATA}/{ENV.replace('/', '-')}_mixed_x*_s0_substeps_24.npz")[0])
    names = [s["behaviour"]["name"] for s in mixed.metadata["sources"]]
    i = names.index(SOURCE)
    part = odata.take_rows(mixed, collect.source_of_episodes(mixed) == i)
    ev = evaluate.make_evaluator(ENV, EPISODES, env_kwargs=control_rate_kwargs(ENV, 24))
    behaviour = float(ev.normalized_score(mixed.metadata["sources"][i]["summary"]["return_mean"]))
    print(f"{ENV} at 10 Hz, BC on {SOURCE} ({part.size} transitions; behaviour {behaviour:.1f}), "
          f"{SEEDS} seeds, {EPISODES} evaluation episodes per seed", flush=True)
    for label, actor, steps, hidden in SETTINGS:
        t0 = time.perf_counter()
        budget = experiment.Budget(steps=steps, hidden=hidden, actor=actor)
        trainer = experiment.build("BC", part, None, budget)
        state, _ = experiment.train_chunked(trainer, experiment.seed_keys(range(SEEDS)), steps)
        res = jax.vmap(lambda p, _t=trainer: ev.evaluate(_t.act, p, jax.random.PRNGKey(10_000)))(
            actor_params(state))
        score = np.asarray(res["normalized_score"], np.float64)
        se = score.std(ddof=1) / math.sqrt(SEEDS)
        safe, success = (float(np.mean(res[k])) for k in ("safe_pct", "success_pct"))
        print(f"  {label:32s}: BC {score.mean():6.1f} ± {se:4.1f}, safe {safe:5.1f} %, success "
              f"{success:5.1f} % ({time.perf_counter() - t0:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
