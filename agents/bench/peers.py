"""PPO peers side by side on ``three_link/env3`` (docs/reports/peers.md): our trainer
(:mod:`agents.run.program`, policy ``nn``), brax 0.14.2's own PPO trainer
(:func:`agents.brax_compat.train_with_brax_ppo`) and rejax's PPO (:mod:`agents.bench.peer_rejax`,
optional ``peers`` extra), all at the settings of one :class:`agents.ppo.PPOConfig` (the
``thesis`` preset by default): environments, unroll length, minibatches, epochs, learning rate,
γ, GAE λ, clip ε, value and entropy coefficients, gradient clipping, observation
normalisation, the policy MLP of our ``nn`` policy and the value MLP, one seed.

Every trainer runs ``iterations`` iterations in chunks of ``chunk`` (brax: one training epoch per
chunk, its evaluations off) and is timed the same way (:mod:`agents.bench.peer_common`): steady
environment steps/s, wall time with compile and set-up, compile and set-up alone. Every final
policy's deterministic action is scored by :func:`envs.evaluate.make_rollout` on the same
``episodes`` scenes (mean episode return and success %), so returns are compared at equal
environment steps.

Layouts (:data:`LAYOUTS`): ``thesis`` — the peers and ours with 128 environments, one seed;
``gpu`` — the peers with 8,192 environments, ours as 64 vmapped seeds × 128 and as one seed ×
8,192. :func:`write_peers` keeps the study's rows of other devices and layouts.
"""

from __future__ import annotations

import functools
import importlib.util
import json
import math
import time
from pathlib import Path
from typing import Any

import jax
from brax.training.agents.ppo import networks as brax_networks

from agents.bench.peer_common import (
    PeerRun,
    PolicyNet,
    evaluate_act,
    first_seed,
    timed_chunks,
    timing,
)
from agents.bench.peer_table import settings_table, write_peers
from agents.brax_compat import train_with_brax_ppo
from agents.ppo import PPOConfig, make_env_and_policy
from agents.ppo.networks import activation_fn
from agents.run.program import build, seed_keys
from agents.run.spec import RunSpec, parse_overrides, preset

ENV = "three_link/env3"
TRAINERS = ("ours", "brax", "rejax")
#: Layout → (peer environments, our ``(seeds, environments)`` variants).
LAYOUTS: dict[str, tuple[int, tuple[tuple[int, int], ...]]] = {
    "thesis": (128, ((1, 128),)),
    "gpu": (8192, ((64, 128), (1, 8192))),
}


def our_policy_net(env_name: str) -> PolicyNet:
    """The MLP of our ``nn`` policy for ``env_name`` (:func:`agents.ppo.make_policy`)."""
    module = make_env_and_policy(env_name, "nn")[1]
    return PolicyNet(tuple(module.hidden_sizes), module.activation, float(module.log_std_init))


def train_ours(env_name: str, config: PPOConfig, seeds: int, iterations: int, chunk: int,
               seed: int) -> PeerRun:
    """Our trainer (:func:`agents.run.program.build`, policy ``nn``) with ``seeds`` vmapped
    seeds; the act of the first seed's policy mean."""
    t0 = time.perf_counter()
    spec = RunSpec(env=env_name, policy="nn", seeds=tuple(range(seed, seed + seeds)), ppo=config)
    program = build(spec)
    state = program.init(seed_keys(spec.seeds))
    exe = program.executable(state, chunk)
    state, times = timed_chunks(lambda s: exe(s)[0], state, iterations // chunk)
    wall = time.perf_counter() - t0
    trainer, ts = program.trainer, first_seed(state)

    def act(obs):
        return trainer.policy.apply(ts.params["policy"], obs, trainer.policy_norm(ts))[0]

    return PeerRun(act, times, wall, iterations * config.batch_size * seeds)


def _brax_network_factory(net: PolicyNet, config: PPOConfig) -> Any:
    """brax's PPO networks with our policy MLP (Gaussian, not tanh-squashed, log-std from
    ``net``) and value MLP."""

    def factory(obs_size, action_size, preprocess_observations_fn):
        make = functools.partial(brax_networks.make_ppo_networks, obs_size, action_size,
                                 preprocess_observations_fn=preprocess_observations_fn,
                                 distribution_type="normal", noise_std_type="log",
                                 init_noise_std=math.exp(net.log_std_init))
        policy = make(policy_hidden_layer_sizes=net.hidden_sizes,
                      activation=activation_fn(net.activation))
        value = make(value_hidden_layer_sizes=config.value_hidden_sizes,
                     activation=activation_fn(config.value_activation))
        return policy.replace(value_network=value.value_network)

    return factory


def brax_kwargs(config: PPOConfig, net: PolicyNet, iterations: int, chunk: int,
                seed: int) -> dict[str, Any]:
    """brax PPO keyword arguments for ``config``: one unroll of ``rollout_length`` per
    environment per iteration, split into ``num_minibatches`` minibatches of whole unrolls;
    ``iterations // chunk`` training epochs of ``chunk`` iterations, no evaluations; one
    device."""
    if config.num_envs % config.num_minibatches:
        raise ValueError(f"PPOConfig.num_minibatches={config.num_minibatches} must divide "
                         f"num_envs={config.num_envs} for brax (minibatches of whole unrolls)")
    return dict(
        num_timesteps=iterations * config.batch_size, num_evals=iterations // chunk + 1,
        run_evals=False, max_devices_per_host=1, num_envs=config.num_envs,
        unroll_length=config.rollout_length, num_minibatches=config.num_minibatches,
        batch_size=config.num_envs // config.num_minibatches,
        num_updates_per_batch=config.update_epochs, learning_rate=config.learning_rate,
        discounting=config.gamma, gae_lambda=config.gae_lambda,
        clipping_epsilon=config.clip_eps, vf_loss_coefficient=config.vf_coef,
        entropy_cost=config.ent_coef, max_grad_norm=config.max_grad_norm,
        normalize_advantage=config.normalize_advantages,
        normalize_observations=config.normalize_observations, reward_scaling=1.0, seed=seed,
        network_factory=_brax_network_factory(net, config))


def train_brax(env_name: str, config: PPOConfig, iterations: int, chunk: int, seed: int,
               net: PolicyNet) -> PeerRun:
    """brax's PPO trainer (:func:`brax_kwargs`); chunk times from brax's epoch wall times."""
    walls: list[float] = []
    t0 = time.perf_counter()
    make_policy, params, _ = train_with_brax_ppo(
        env_name, progress_fn=lambda step, m: walls.append(float(m["training/walltime"])),
        **brax_kwargs(config, net, iterations, chunk, seed))
    wall = time.perf_counter() - t0
    policy = make_policy(params, deterministic=True)
    key = jax.random.PRNGKey(0)
    times = [b - a for a, b in zip([0.0, *walls[:-1]], walls, strict=True)]
    return PeerRun(lambda obs: policy(obs[None], key)[0][0], times, wall,
                   iterations * config.batch_size)


def train_rejax(env_name: str, config: PPOConfig, iterations: int, chunk: int, seed: int,
                net: PolicyNet) -> PeerRun:
    """rejax's PPO (:func:`agents.bench.peer_rejax.train_rejax`)."""
    from agents.bench import peer_rejax  # lazy: rejax and gymnax are the optional peers extra

    return peer_rejax.train_rejax(env_name, config, iterations, chunk, seed, net.hidden_sizes,
                                  net.activation, net.log_std_init)


def check_trainers(trainers: list[str]) -> None:
    """Error naming the trainer when one is unknown or rejax's ``peers`` extra is missing."""
    for name in trainers:
        if name not in TRAINERS:
            raise ValueError(f"unknown trainer {name!r}; valid trainers are {TRAINERS}")
    if "rejax" in trainers and not all(importlib.util.find_spec(m) for m in ("rejax", "gymnax")):
        raise ValueError("trainer 'rejax' needs the peers extra (pip install -e '.[peers]'); "
                         "install it or leave rejax out of the trainers")


def measure(trainer: str, layout: str, config: PPOConfig, seeds: int, iterations: int,
            chunk: int, episodes: int, horizon: int | None, seed: int,
            env_name: str = ENV) -> dict[str, Any]:
    """One row: ``trainer`` at ``config`` (``seeds`` vmapped seeds for ours) for
    ``iterations`` iterations, timed (:func:`agents.bench.peer_common.timing`), its final
    policy scored on ``episodes`` episodes of ``horizon`` steps (``None``: the environment's)."""
    if iterations % chunk:
        raise ValueError(f"iterations={iterations} must be a multiple of chunk={chunk}")
    if seeds != 1 and trainer != "ours":
        raise ValueError(f"seeds={seeds}: only our trainer vmaps seeds; {trainer} runs one")
    net = our_policy_net(env_name)
    if trainer == "ours":
        run = train_ours(env_name, config, seeds, iterations, chunk, seed)
    else:
        train = {"brax": train_brax, "rejax": train_rejax}[trainer]
        run = train(env_name, config, iterations, chunk, seed, net)
    score = evaluate_act(env_name, run.act, episodes, horizon, seed)
    return {"trainer": trainer, "layout": layout, "env": env_name, "seeds": seeds,
            "num_envs": config.num_envs, "rollout_length": config.rollout_length,
            "iterations": iterations, "chunk": chunk, "env_steps": run.env_steps,
            "policy_env_steps": run.env_steps // seeds,
            **timing(run), "chunks_s": run.chunk_s, "eval_episodes": score["episodes"],
            "eval_return": score["mean_return"], "eval_success_pct": score["success_pct"],
            "compile_cache": bool(jax.config.jax_compilation_cache_dir)}


def plan(layouts: list[str], trainers: list[str]) -> list[tuple[str, str, int, int]]:
    """``(layout, trainer, seeds, environments)`` of every row, in order."""
    out = []
    for layout in layouts:
        if layout not in LAYOUTS:
            raise ValueError(f"unknown layout {layout!r}; valid layouts are {sorted(LAYOUTS)}")
        peer_envs, ours = LAYOUTS[layout]
        for trainer in trainers:
            variants = ours if trainer == "ours" else ((1, peer_envs),)
            out += [(layout, trainer, s, n) for s, n in variants]
    return out


def run_peers(layouts: list[str], trainers: list[str], iterations: int, chunk: int,
              episodes: int, horizon: int | None, seed: int, overrides: dict[str, Any],
              out_dir: Path, command: str, preset_name: str = "thesis") -> Path:
    """Measure every row of :func:`plan` (``preset_name`` with ``overrides``; a failure is
    recorded in its row), print it, and write the study after each row (:func:`write_peers`)."""
    check_trainers(trainers)
    rows: list[dict[str, Any]] = []
    path = out_dir / "summary.json"
    for layout, trainer, seeds, num_envs in plan(layouts, trainers):
        config = preset(preset_name, **{**overrides, "num_envs": num_envs})
        try:
            row = measure(trainer, layout, config, seeds, iterations, chunk, episodes, horizon,
                          seed)
        except Exception as err:  # recorded in the row (e.g. out of memory); the others go on
            row = {"trainer": trainer, "layout": layout, "seeds": seeds, "num_envs": num_envs,
                   "error": f"{type(err).__name__}: {err}"[:500]}
        rows.append(row)
        print(json.dumps({k: v for k, v in row.items() if k != "chunks_s"}), flush=True)
        path = write_peers(rows, out_dir, command, settings_table(config, our_policy_net(ENV)))
    return path

def run_from_settings(settings: dict[str, Any], command: str, out_dir: Path) -> Path:
    """:func:`run_peers` from ``scripts/bench.py``'s ``peer*`` settings: layouts ``peers``
    (none given: ``thesis``), ``peer_trainers``, ``peer_iterations`` in chunks of
    ``peer_chunk``, ``peer_episodes`` evaluation episodes, ``peer_set`` preset overrides
    (``FIELD=VALUE``); ``quick`` shrinks everything to a smoke test."""
    quick = settings["quick"]
    overrides = parse_overrides(settings["peer_set"])
    if quick:
        overrides = {"rollout_length": 16, "num_minibatches": 2, "update_epochs": 1, **overrides}
    iterations = settings["peer_iterations"] or (2 if quick else 8)
    chunk = settings["peer_chunk"] or (1 if quick else 2)
    episodes = settings["peer_episodes"] or (4 if quick else 64)
    return run_peers(settings["peers"] or ["thesis"], settings["peer_trainers"], iterations,
                     chunk, episodes, 50 if quick else None, settings["seed"], overrides,
                     out_dir, command)


__all__ = ["ENV", "LAYOUTS", "TRAINERS", "brax_kwargs", "check_trainers", "measure",
           "our_policy_net", "plan", "run_from_settings", "run_peers", "train_brax", "train_ours",
           "train_rejax"]
