"""Offline BC (MLP actor) of N expert episodes on 3-link env3, scored by the evaluator
(session 12). Usage: python bc_scale.py STEPS N[,N...]"""
import sys
import time
import warnings

import jax
import numpy as np
from offline.learner import actor_params

from offline import collect, evaluate, experiment


def main() -> None:
    steps = int(sys.argv[1])
    ev = evaluate.make_evaluator("three_link/env3", 64)
    for n in [int(x) for x in sys.argv[2].split(",")]:
        t0 = time.time()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ds = collect.collect_recipe("three_link/env3", "expert", n, seed=0)
        tc = time.time() - t0
        tr = experiment.build("BC", ds, None, experiment.Budget(steps=steps, actor="mlp"))
        st, _ = experiment.train_chunked(tr, experiment.seed_keys([0, 1]), steps)
        program = jax.jit(jax.vmap(
            lambda p, act=tr.act: ev.evaluate(act, p, jax.random.PRNGKey(10_000))))
        r = program(actor_params(st))
        print(n, "episodes", ds.size, "score", np.asarray(r["normalized_score"]).round(1),
              "safe", np.asarray(r["safe_pct"]).round(0),
              "succ", np.asarray(r["success_pct"]).round(0),
              f"collect {tc:.0f}s total {time.time() - t0:.0f}s", flush=True)


if __name__ == "__main__":
    main()
