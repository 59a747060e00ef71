"""Diagnostics behind the offline reports' claims about what limits policy improvement (thesis
§7.3.2–§7.4; docs/design.md §2.4, results in ``results/offline`` and ``results/ch7``).

* :func:`action_gap` — how much one control step's action changes the expert's discounted
  return (its Q-value): the signal a critic must resolve for ATAC's relative pessimism
  ``Q(s, π) − Q(s, μ)`` (thesis §7.3.2) to prefer one action over another.
* :func:`learning_curve` — ATAC with the true reward against its BC warm start (and BC of all
  or of the best episodes) on a ``mixed`` dataset, scored after every chunk (thesis §7.3.3:
  warm start, then the slow actor rate).
* :func:`bc_by_source` / :func:`bc_by_scale` — BC on each source of a ``mixed`` dataset next to
  that source's own score, and BC of expert data of growing size (thesis §7.4 normalisation).

``scripts/offline_diagnostics.py`` is the command line of all of them.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from envs.evaluate import hand_designed_policy
from offline.data import collect
from offline.data import dataset as odata
from offline.data.rollouts import make_env
from offline.experiment.evaluate import Evaluator, make_evaluator
from offline.experiment.run import build, init_runs, seed_beta_runs, seed_keys, train_chunked
from offline.experiment.settings import control_rate_kwargs, substeps_tag
from offline.learners import atac, bc
from offline.learners.base import Trainer, actor_params
from offline.learners.registry import Budget

#: The one-step actions of :func:`branch_returns`, in its output order.
ACTION_BRANCHES = ("expert", "negated", "zero", "plus_one", "minus_one")
#: The learning-curve programs of :func:`learning_curve`.
CURVE_PROGRAMS = ("atac", "bc", "topbc")
#: Seed of the evaluation key every diagnostic scores its policies with.
EVAL_SEED = 10_000


def branch_returns(env: Any, policy: Callable[[Any], jax.Array], key: jax.Array, t0: int, *,
                   gamma: float = 0.99, horizon: int = 400) -> jax.Array:
    """Discounted returns ``Q^μ(s_{t0}, a) = Σ_{t=0}^{horizon} γ^t r_t`` of the five one-step
    actions :data:`ACTION_BRANCHES` (the expert's own, its negation, zero, +1 and −1 on every
    joint) from the state reached by ``t0`` steps of the expert ``μ`` (``policy``, clipped to
    [−1, 1]) after ``env.reset(key)``; after that step the expert acts for ``horizon`` steps.
    The state is frozen and earns nothing once ``done``. Shape ``(5,)``; jittable."""
    def expert(state: Any) -> jax.Array:
        return jnp.clip(policy(state), -1.0, 1.0)

    state = env.reset(key)
    state = jax.lax.fori_loop(0, t0, lambda i, s: env.step(s, expert(s)), state)
    a_expert = expert(state)

    def discounted_return(a0: jax.Array) -> jax.Array:
        s1 = env.step(state, a0)

        def body(carry, t):
            st, acc = carry
            nxt = env.step(st, expert(st))
            nxt = jax.tree.map(lambda x, y: jnp.where(st.done > 0, y, x), nxt, st)
            return (nxt, acc + jnp.where(st.done > 0, 0.0, nxt.reward) * gamma ** (t + 1)), None

        (_, acc), _ = jax.lax.scan(body, (s1, s1.reward), jnp.arange(horizon))
        return acc

    ones = jnp.ones_like(a_expert)
    return jax.vmap(discounted_return)(jnp.stack([a_expert, -a_expert, 0 * ones, ones, -ones]))


def gap_summary(q: np.ndarray) -> dict[str, float]:
    """Scene means of the action gaps of ``q`` (``(scenes, 5)`` from :func:`branch_returns`):
    ``q_expert`` (the expert's Q), ``expert_vs_negated``, ``expert_vs_zero``,
    ``plus_vs_minus`` (absolute differences) and ``range`` (max − min over the five actions)."""
    q = np.asarray(q, np.float64)
    return {"q_expert": float(q[:, 0].mean()),
            "expert_vs_negated": float(np.abs(q[:, 0] - q[:, 1]).mean()),
            "expert_vs_zero": float(np.abs(q[:, 0] - q[:, 2]).mean()),
            "plus_vs_minus": float(np.abs(q[:, 3] - q[:, 4]).mean()),
            "range": float((q.max(1) - q.min(1)).mean())}


def action_gap(env_name: str, t0: int, *, substeps: int | None = None, scenes: int = 64,
               seed: int = 3, gamma: float = 0.99, horizon: int = 400) -> dict[str, Any]:
    """:func:`branch_returns` of the hand-designed expert on ``scenes`` scenes of ``env_name``
    (keys split from ``PRNGKey(seed)``) at ``substeps`` physics substeps per control step
    (:func:`offline.experiment.settings.control_rate_kwargs`; ``None``: the environment's own):
    the settings, the per-scene ``q`` (``scenes × 5``) and :func:`gap_summary`."""
    env = make_env(env_name, control_rate_kwargs(env_name, substeps))
    expert = hand_designed_policy(env)
    keys = jax.random.split(jax.random.PRNGKey(seed), scenes)
    q = np.asarray(jax.jit(jax.vmap(lambda k: branch_returns(
        env, expert, k, t0, gamma=gamma, horizon=horizon)))(keys))
    return {"env": env_name, "substeps": substeps or int(env.substeps), "t0": t0,
            "scenes": scenes, "seed": seed, "gamma": gamma, "horizon": horizon,
            "branches": list(ACTION_BRANCHES), "q": q.tolist(), **gap_summary(q)}


def make_scorer(evaluator: Evaluator, trainer: Trainer
                ) -> Callable[[Any], dict[str, list[float]]]:
    """``score(state)``: every run of a (vmapped) training state of ``trainer`` scored by
    ``evaluator`` with key ``PRNGKey(EVAL_SEED)``, per run ``normalized_score``, ``safe_pct``
    and ``success_pct`` (thesis §7.4); compiled once, reused after every chunk."""
    key = jax.random.PRNGKey(EVAL_SEED)
    program = jax.jit(jax.vmap(lambda p: evaluator.evaluate(trainer.act, p, key)))

    def score(state: Any) -> dict[str, list[float]]:
        res = program(actor_params(state))
        return {k: np.asarray(res[k], np.float64).tolist()
                for k in ("normalized_score", "safe_pct", "success_pct")}

    return score


def source_scores(dataset: odata.Dataset, evaluator: Evaluator) -> dict[str, float]:
    """The normalised score of each source of a recipe dataset: its episodes' mean return in
    the data, normalised with ``evaluator``'s reference returns (thesis §7.4)."""
    return {str(s["behaviour"].get("name")): float(evaluator.normalized_score(
        s["summary"]["return_mean"])) for s in dataset.metadata["sources"]}


def top_episodes(dataset: odata.Dataset, top: float) -> odata.Dataset:
    """The episodes of ``dataset`` whose return is at or above the ``1 − top`` quantile."""
    per, _ = odata.episode_statistics(dataset)
    return odata.filter_episodes(dataset, per.returns >= np.quantile(per.returns, 1 - top))


def curve_trainer(program: str, dataset: odata.Dataset, *, steps: int, hidden: Sequence[int],
                  actor: str, warm: int, actor_lr: float, top: float) -> Trainer:
    """The trainer of one :func:`learning_curve` program: ``atac`` (true reward, ``warm`` BC
    warm-start steps, then actor rate ``actor_lr``), ``bc`` (all of ``dataset``) or ``topbc``
    (BC of :func:`top_episodes`)."""
    hidden = tuple(hidden)
    if program == "atac":
        return atac.make_train(dataset, atac.ATACConfig(
            hidden_sizes=hidden, num_steps=steps, warmstart_steps=warm, actor_lr=actor_lr,
            actor=actor))
    if program not in CURVE_PROGRAMS:
        raise ValueError(f"unknown program={program!r}; valid programs are {CURVE_PROGRAMS}")
    data = top_episodes(dataset, top) if program == "topbc" else dataset
    return bc.make_train(data, bc.BCConfig(num_steps=steps, hidden_sizes=hidden, actor=actor))


def learning_curve(program: str, dataset: odata.Dataset, evaluator: Evaluator, *,
                   steps: int, chunk: int, seeds: int = 5, betas: Sequence[float] = (16.0,),
                   warm: int = 10_000, actor_lr: float = 5e-7, top: float = 0.5,
                   actor: str = "nn_residual", hidden: Sequence[int] = (256, 256, 256),
                   log: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Does ATAC with the TRUE reward improve on its BC warm start? One program
    (:func:`curve_trainer`) on ``dataset``, ``seeds`` seeds vmapped (for ``atac`` every seed at
    every β of ``betas``, seed-major), scored by :func:`make_scorer` after every ``chunk`` steps.
    Returns the runs' seeds and betas, :func:`source_scores` and the curve: per chunk the
    step, per-run ``score``, ``safe``, ``success`` and the chunk's training-metric means."""
    t0 = time.perf_counter()
    trainer = curve_trainer(program, dataset, steps=steps, hidden=hidden, actor=actor,
                            warm=warm, actor_lr=actor_lr, top=top)
    run_seeds, run_betas = seed_beta_runs(range(seeds), list(betas) if program == "atac"
                                          else None)
    keys = seed_keys(run_seeds)
    score = make_scorer(evaluator, trainer)
    curve: list[dict[str, Any]] = []

    def on_chunk(state: Any, means: dict, done: int) -> None:
        r = score(state)
        curve.append({"step": done, "score": r["normalized_score"], "safe": r["safe_pct"],
                      "success": r["success_pct"],
                      "metrics": {k: np.asarray(v).tolist() for k, v in means.items()}})
        if log is not None:
            log(f"[{program} lr={actor_lr}] step {done}: score "
                f"{np.mean(r['normalized_score']):.1f} ({time.perf_counter() - t0:.0f} s)")

    train_chunked(trainer, keys, chunk, on_chunk, state=init_runs(trainer, keys, run_betas))
    return {"program": program, "seeds": run_seeds, "betas": run_betas,
            "sources": source_scores(dataset, evaluator), "curve": curve,
            "seconds": time.perf_counter() - t0, "device": jax.devices()[0].device_kind}


def cached_recipe(path: Path, env_name: str, recipe: str, scale: int,
                  env_kwargs: dict[str, int] | None) -> odata.Dataset:
    """The ``recipe`` dataset of ``scale`` episodes per source (seed 0) on ``env_name``, read
    from ``path`` or collected (the no-PPO fallback's warning silenced) and saved there."""
    if not path.exists():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            ds = collect.collect_recipe(env_name, recipe, scale, seed=0, env_kwargs=env_kwargs)
        path.parent.mkdir(parents=True, exist_ok=True)
        odata.save(ds, path)
    return odata.load(path)


def bc_scores(dataset: odata.Dataset, evaluator: Evaluator, budget: Budget,
              seeds: Sequence[int]) -> dict[str, list[float]]:
    """BC (the chapter-7 table's learner, :func:`offline.experiment.run.build`) on ``dataset``
    at ``budget``, the ``seeds`` vmapped, then :func:`make_scorer`."""
    trainer = build("BC", dataset, None, budget)
    state, _ = train_chunked(trainer, seed_keys(seeds), budget.steps)
    return make_scorer(evaluator, trainer)(state)


def _scored(name: str, rows: int, scores: dict[str, list[float]], t0: float,
            **extra: Any) -> dict[str, Any]:
    """One result row: BC's per-seed scores, their mean and standard error."""
    s = np.asarray(scores["normalized_score"], np.float64)
    sem = float(s.std(ddof=1) / np.sqrt(s.size)) if s.size > 1 else float("nan")
    return {"name": name, "transitions": rows, **extra, "bc": scores,
            "bc_mean": float(s.mean()), "bc_sem": sem,
            "safe_mean": float(np.mean(scores["safe_pct"])),
            "seconds": time.perf_counter() - t0}


def bc_by_source(mixed: odata.Dataset, evaluator: Evaluator, budget: Budget,
                 seeds: Sequence[int], log: Callable[[str], None] | None = None
                 ) -> list[dict[str, Any]]:
    """BC (:func:`bc_scores`) on each source of a ``mixed`` recipe dataset alone and on all of
    it, each next to the normalised score of the behaviour that collected it (its episodes'
    mean return in the data; thesis §7.4): one row per part."""
    src = collect.source_of_episodes(mixed)
    per, _ = odata.episode_statistics(mixed)
    parts = [(s["behaviour"]["name"], src == i, s["summary"]["return_mean"])
             for i, s in enumerate(mixed.metadata["sources"])]
    parts.append(("all of mixed", np.ones_like(src, bool), float(np.mean(per.returns))))
    rows = []
    for name, mask, behaviour_return in parts:
        t0 = time.perf_counter()
        scores = bc_scores(odata.take_rows(mixed, mask), evaluator, budget, seeds)
        rows.append(_scored(name, int(mask.sum()), scores, t0, behaviour=float(
            evaluator.normalized_score(behaviour_return))))
        if log is not None:
            r = rows[-1]
            log(f"  {name:13s}: {r['transitions']:6d} transitions; behaviour "
                f"{r['behaviour']:6.1f}; BC {r['bc_mean']:6.1f} ± {r['bc_sem']:4.1f}, safe "
                f"{r['safe_mean']:5.1f} % ({r['seconds']:.0f} s)")
    return rows


def bc_by_scale(env_name: str, episodes: Sequence[int], evaluator: Evaluator, budget: Budget,
                seeds: Sequence[int], env_kwargs: dict[str, int] | None = None,
                log: Callable[[str], None] | None = None) -> list[dict[str, Any]]:
    """BC (:func:`bc_scores`) of ``n`` expert episodes on ``env_name`` with ``env_kwargs`` (the
    ``expert`` recipe, seed 0) for every ``n`` of ``episodes``: one row per size, with the
    collection time."""
    rows = []
    for n in episodes:
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ds = collect.collect_recipe(env_name, "expert", n, seed=0,
                                        env_kwargs=env_kwargs)
        tc = time.perf_counter() - t0
        rows.append(_scored(f"{n} episodes", int(ds.size), bc_scores(ds, evaluator, budget,
                                                                     seeds), t0,
                            episodes=n, collect_seconds=tc))
        if log is not None:
            r = rows[-1]
            log(f"{n} episodes {ds.size} score {np.round(r['bc']['normalized_score'], 1)} "
                f"safe {np.round(r['bc']['safe_pct'])} succ {np.round(r['bc']['success_pct'])} "
                f"collect {tc:.0f}s total {r['seconds']:.0f}s")
    return rows


def mixed_file(data_dir: Path, env_name: str, substeps: int | None) -> Path:
    """The seed-0 ``mixed`` dataset of ``env_name`` (any scale) that ``scripts/reproduce_ch7.py
    --stage collect`` wrote to ``data_dir`` at ``substeps`` (its
    :func:`offline.experiment.ch7.data_path` name); ``FileNotFoundError`` when there is none."""
    tag = "".join(f"_{part}" for part in substeps_tag(substeps))
    found = sorted(Path(data_dir).glob(f"{env_name.replace('/', '-')}_mixed_x*_s0{tag}.npz"))
    if not found:
        raise FileNotFoundError(f"no {env_name} mixed dataset with substeps {substeps} in "
                                f"{data_dir}")
    return found[0]


def _print(line: str) -> None:
    print(line, flush=True)


def _action_gap_command(args: Any) -> dict[str, Any]:
    """``action-gap``: :func:`action_gap` with the parsed flags, one summary line printed."""
    r = action_gap(args.env, args.t0, substeps=args.substeps, scenes=args.scenes,
                   seed=args.seed, gamma=args.gamma, horizon=args.horizon)
    _print(f"{r['env']} substeps {r['substeps']} T0 {r['t0']} Q(expert) mean "
           f"{r['q_expert']:.3f} |Q(ex)-Q(-ex)| mean {r['expert_vs_negated']:.4f} "
           f"|Q(ex)-Q(0)| {r['expert_vs_zero']:.4f} |Q(+1)-Q(-1)| {r['plus_vs_minus']:.4f} "
           f"max over actions - min: {r['range']:.4f}")
    return r


def _atac_vs_bc_command(args: Any) -> dict[str, Any]:
    """``atac-vs-bc``: the cached ``mixed`` data, the evaluator and :func:`learning_curve`."""
    env_kwargs = control_rate_kwargs(args.env, args.substeps)
    ds = cached_recipe(Path(args.data), args.env, "mixed", args.scale, env_kwargs)
    ev = make_evaluator(args.env, args.eval_episodes, env_kwargs=env_kwargs)
    _print(f"sources (normalised): {source_scores(ds, ev)}")
    return learning_curve(args.program, ds, ev, steps=args.steps, chunk=args.chunk,
                          seeds=args.seeds, betas=args.betas, warm=args.warm,
                          actor_lr=args.actor_lr, top=args.top, actor=args.actor,
                          hidden=args.hidden, log=_print)


def _bc_command(args: Any) -> dict[str, Any]:
    """``bc-sources`` / ``bc-scale``: :func:`bc_by_source` or :func:`bc_by_scale`."""
    env_kwargs = control_rate_kwargs(args.env, args.substeps)
    ev = make_evaluator(args.env, args.eval_episodes, env_kwargs=env_kwargs)
    budget = Budget(steps=args.steps, actor=args.actor)
    seeds = list(range(args.seeds))
    _print(f"{args.env}, substeps {args.substeps}, BC {args.steps} steps x {args.seeds} seeds, "
           f"{args.eval_episodes} evaluation episodes per seed; reference returns expert "
           f"{ev.reference['expert_return']:.2f}, random {ev.reference['random_return']:.2f}")
    if args.command == "bc-sources":
        mixed = odata.load(mixed_file(Path(args.data), args.env, args.substeps))
        rows = bc_by_source(mixed, ev, budget, seeds, log=_print)
    else:
        rows = bc_by_scale(args.env, args.episodes, ev, budget, seeds, env_kwargs, log=_print)
    return {"rows": rows, "reference": dict(ev.reference),
            "device": jax.devices()[0].device_kind}


#: What each ``scripts/offline_diagnostics.py`` subcommand runs.
COMMANDS: dict[str, Callable[[Any], dict[str, Any]]] = {
    "action-gap": _action_gap_command, "atac-vs-bc": _atac_vs_bc_command,
    "bc-sources": _bc_command, "bc-scale": _bc_command}


def run_command(args: Any) -> dict[str, Any]:
    """Run the ``scripts/offline_diagnostics.py`` subcommand ``args.command`` with its parsed
    flags (:data:`COMMANDS`) and return its result, the flags under ``"args"``."""
    return {**COMMANDS[args.command](args), "args": dict(vars(args))}


__all__ = [
    "ACTION_BRANCHES",
    "COMMANDS",
    "CURVE_PROGRAMS",
    "EVAL_SEED",
    "action_gap",
    "bc_by_scale",
    "bc_by_source",
    "bc_scores",
    "branch_returns",
    "cached_recipe",
    "curve_trainer",
    "gap_summary",
    "learning_curve",
    "make_scorer",
    "mixed_file",
    "run_command",
    "source_scores",
    "top_episodes",
]
