"""Diagnostic (session 12): does ATAC with the TRUE reward improve on its BC warm start on
3-link env3 `mixed`, whose sources score ~0 / 85 / 97 / 100 (random, sigma 1 / 0.5 / 0.1)?

Programs (one per process):
  bc      BC of all of `mixed`, curve every --chunk
  topbc   BC of the episodes whose return is in the top --top fraction
  atac    ATAC (true reward), actor lr --actor-lr, betas --betas vmapped, curve every --chunk

Writes one JSON line per program to --out.
"""
from __future__ import annotations

import argparse
import json
import time
import warnings
from pathlib import Path

import jax
import numpy as np
from offline.learner import actor_params

from offline import atac, bc, collect, evaluate
from offline import data as odata
from offline.experiment import init_runs, seed_beta_runs, seed_keys, train_chunked

ENV = "three_link/env3"


def dataset(path: Path, scale: int, env_kwargs: dict | None) -> odata.Dataset:
    if not path.exists():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            ds = collect.collect_recipe(ENV, "mixed", scale, seed=0, env_kwargs=env_kwargs)
        path.parent.mkdir(parents=True, exist_ok=True)
        odata.save(ds, path)
    return odata.load(path)


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--program", choices=["bc", "topbc", "atac"], required=True)
    p.add_argument("--scale", type=int, default=100)
    p.add_argument("--data", default="/tmp/mixed.npz")
    p.add_argument("--steps", type=int, default=100_000)
    p.add_argument("--warm", type=int, default=10_000)
    p.add_argument("--chunk", type=int, default=20_000)
    p.add_argument("--actor-lr", type=float, default=5e-7)
    p.add_argument("--betas", type=float, nargs="+", default=[16.0])
    p.add_argument("--seeds", type=int, default=5)
    p.add_argument("--top", type=float, default=0.5)
    p.add_argument("--actor", default="nn_residual")
    p.add_argument("--hidden", type=int, nargs="+", default=[256, 256, 256])
    p.add_argument("--eval-episodes", type=int, default=64)
    p.add_argument("--out", required=True)
    p.add_argument("--substeps", type=int, default=None,
                   help="physics substeps per control step (default 3: 80 Hz); the horizon "
                        "keeps the episode at 7.5 s")
    a = p.parse_args()

    t0 = time.perf_counter()
    env_kwargs = (None if a.substeps is None
                  else {"substeps": a.substeps, "horizon": 1800 // a.substeps})
    ds = dataset(Path(a.data), a.scale, env_kwargs)
    ev = evaluate.make_evaluator(ENV, a.eval_episodes, env_kwargs=env_kwargs)
    per, _ = odata.episode_statistics(ds)
    source_scores = {str(s["behaviour"].get("name")): float(ev.normalized_score(
        s["summary"]["return_mean"])) for s in ds.metadata["sources"]}
    print("sources (normalised):", source_scores, flush=True)

    hidden = tuple(a.hidden)
    if a.program in ("bc", "topbc"):
        data = ds
        if a.program == "topbc":
            cut = np.quantile(per.returns, 1 - a.top)
            data = odata.filter_episodes(ds, per.returns >= cut)
        trainer = bc.make_train(data, bc.BCConfig(num_steps=a.steps, hidden_sizes=hidden,
                                                  actor=a.actor))
        seeds, betas = list(range(a.seeds)), None
    else:
        cfg = atac.ATACConfig(hidden_sizes=hidden, num_steps=a.steps, warmstart_steps=a.warm,
                              actor_lr=a.actor_lr, actor=a.actor)
        trainer = atac.make_train(ds, cfg)
        seeds, betas = seed_beta_runs(range(a.seeds), a.betas)
    keys = seed_keys(seeds)
    program = jax.jit(jax.vmap(lambda prm: ev.evaluate(trainer.act, prm,
                                                       jax.random.PRNGKey(10_000))))
    curve: list[dict] = []

    def on_chunk(state, means, done):
        r = program(actor_params(state))
        scores = np.asarray(r["normalized_score"])
        row = {"step": done, "score": scores.tolist(),
               "safe": np.asarray(r["safe_pct"]).tolist(),
               "success": np.asarray(r["success_pct"]).tolist(),
               "metrics": {k: np.asarray(v).tolist() for k, v in means.items()}}
        curve.append(row)
        print(f"[{a.program} lr={a.actor_lr}] step {done}: score {scores.mean():.1f} "
              f"({time.perf_counter() - t0:.0f} s)", flush=True)

    state = init_runs(trainer, keys, betas)
    train_chunked(trainer, keys, a.chunk, on_chunk, state=state)
    out = {"program": a.program, "args": vars(a), "seeds": seeds, "betas": betas,
           "sources": source_scores, "curve": curve, "seconds": time.perf_counter() - t0,
           "device": jax.devices()[0].device_kind}
    with open(a.out, "a") as f:
        f.write(json.dumps(out) + "\n")


if __name__ == "__main__":
    main()
