"""The compiled program of a training run: the PPO trainer of a :class:`agents.run.spec.RunSpec`
with ``init`` and ``run`` vmapped over seeds and jitted, compiled ahead of time per chunk length
(cached, so runs that differ only in length, seeds or logging share compiled code), and a
timing split of one iteration."""

from __future__ import annotations

import dataclasses
import functools
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh

from agents.ppo import PPOConfig, Trainer, TrainState, make_env_and_policy, make_trainer
from agents.run.program_cache import exported, exported_shapes, in_background
from agents.run.spec import RunSpec
from envs.wrappers import CONDITIONAL_RESET_BACKENDS
from mjxrmp._xla import run_once_compiler_options

#: The ``axis_name`` of the vmap over seeds (lets the rollout's auto-reset and reset pools take
#: one branch for all seeds: :func:`agents.ppo.make_trainer`).
SEED_AXIS = "seeds"


@dataclasses.dataclass
class Program:
    """A trainer with ``init(keys)`` and ``run(state, n)`` vmapped over seeds and jitted, plus
    the ahead-of-time compiled chunk executables (one per chunk length)."""

    trainer: Trainer
    init: Callable
    run: Callable
    executables: dict[tuple[int, Any], Any] = dataclasses.field(default_factory=dict)
    #: ``init`` per (row count, with scenes) (from its exported program where there is one).
    inits: dict[tuple[int, bool], Any] = dataclasses.field(default_factory=dict)
    #: Chunk programs being compiled in a background thread (:meth:`compile_ahead`), by length.
    ahead: dict[int, Future] = dataclasses.field(default_factory=dict)
    #: Set once such a chunk is lowered (or its thread failed): :meth:`initial_state` waits.
    lowering: list[threading.Event] = dataclasses.field(default_factory=list)
    compile_seconds: float = 0.0
    #: What shapes the program (JSON data), for :mod:`agents.run.program_cache`; None keeps
    #: nothing between processes (sharded programs).
    description: dict[str, Any] | None = None

    def executable(self, state: TrainState, n: int) -> Any:
        """The compiled ``run(·, n)`` (compiled on first use, from the exported program of an
        earlier process where there is one: :func:`agents.run.program_cache.exported`, or by
        :meth:`compile_ahead`; the time spent here is added to ``compile_seconds``)."""
        key, job = _chunk_key(state, n), self.ahead.pop(n, None)
        if job is not None or key not in self.executables:
            t0 = time.perf_counter()
            if job is not None:  # stored under the key of init's shapes, normally this one
                job.result()
            if key not in self.executables:
                self.executables[key] = self._compile_run(state, n)
            self.compile_seconds += time.perf_counter() - t0
        return self.executables[key]

    def _compile_run(self, state: Any, n: int, lowered: Callable[[], None] = lambda: None
                     ) -> Any:
        run = self._from_artifact(lambda s: self.run(s, n), (state,), {"chunk": n},
                                  lowered=lowered)
        if run is None:
            program = self.run.lower(state, n)
            lowered()
            run = program.compile()
        return run

    def compile_ahead(self, keys: jax.Array, n: int, hold_init: bool = True) -> Future:
        """Start compiling ``run(·, n)`` for the state ``init(keys)`` returns in a background
        thread (from :meth:`state_shapes`), so that it overlaps the compile and run of ``init``
        itself, or a resume's restore (XLA compiles without the GIL: 3-link thesis chunk, H200,
        32.8 s → 25.8 s for both; docs/design.md §5.6). With ``hold_init``, tracing ``init``
        waits until the chunk is lowered, so that the two traces do not share the GIL (the
        chunk's is the longer path). :meth:`executable` waits for it; an error in the thread is
        raised there. Not for sharded programs (the shapes carry no sharding)."""
        lowered = threading.Event()

        def compile_chunk() -> None:
            try:
                shapes = self.state_shapes(keys)
                key = _chunk_key(shapes, n)
                if key not in self.executables:  # a run before this one in the process
                    self.executables[key] = self._compile_run(shapes, n, lowered.set)
            finally:
                lowered.set()

        if hold_init:
            self.lowering.append(lowered)
        self.ahead[n] = in_background(compile_chunk, f"compile chunk {n}")
        return self.ahead[n]

    def _from_artifact(self, fn: Callable, args: tuple, what: dict[str, Any],
                       compiler_options: dict[str, Any] | None = None,
                       lowered: Callable[[], None] | None = None) -> Callable | None:
        """``fn`` compiled from its exported program (:func:`agents.run.program_cache.exported`),
        or None for a sharded or multi-process program."""
        if self.description is None or jax.process_count() > 1:
            return None
        return exported(fn, args, {**self.description, **what}, compiler_options, lowered)

    def initial_state(self, keys: jax.Array, scenes: dict[str, jax.Array] | None = None
                      ) -> TrainState:
        """``init(keys)``, or ``init(keys, scenes)`` (each row's environments sample from its
        own scene parameters, leaves with a leading row axis: a packed sweep over setups),
        compiled once per row count, from the exported init program of an earlier process
        where there is one (the time is added to ``compile_seconds``). It runs once, so it
        compiles with :func:`mjxrmp._xla.run_once_compiler_options` (on the CPU a lower
        optimisation level: docs/design.md §5.6)."""
        args = (keys,) if scenes is None else (keys, scenes)
        n, lowering, self.lowering = (keys.shape[0], scenes is not None), self.lowering, []
        if n not in self.inits:
            t0 = time.perf_counter()
            for chunk_lowered in lowering:  # compile_ahead's trace first
                chunk_lowered.wait()
            options = run_once_compiler_options(jax.default_backend())
            what = {"program": "init"} if scenes is None else {"program": "init_scenes"}
            init = self._from_artifact(self.init, args, what, options)
            self.inits[n] = init or self.init.lower(*args).compile(
                compiler_options=options or None)
            self.compile_seconds += time.perf_counter() - t0
        return self.inits[n](*args)

    def state_shapes(self, keys: jax.Array) -> Any:
        """``jax.eval_shape(init, keys)`` (the state's structure, shapes and dtypes as
        ``jax.ShapeDtypeStruct`` leaves), read from the exported init program of an earlier
        process where there is one instead of tracing ``init`` (a resume's restore target)."""
        shapes = None
        if self.description is not None and jax.process_count() == 1:
            shapes = exported_shapes((keys,), {**self.description, "program": "init"},
                                     run_once_compiler_options(jax.default_backend()))
        return jax.eval_shape(self.init, keys) if shapes is None else shapes


def _chunk_key(state: Any, n: int) -> tuple:
    """What a chunk executable is kept under: its length and the state's tree structure, shapes
    and dtypes (a sweep's state also carries hparams; seeds or sweep rows change the shapes)."""
    return (n, jax.tree.structure(state),
            tuple((x.shape, str(x.dtype)) for x in jax.tree.leaves(state)))


@functools.lru_cache(maxsize=8)
def _program(env: str, policy: str, ppo: PPOConfig, mesh: Mesh | None,
             reset_pools: bool) -> Program:
    env_obj, module = make_env_and_policy(env, policy)
    trainer = make_trainer(env_obj, module, ppo, mesh, seed_axis=SEED_AXIS,
                           reset_pools=reset_pools)
    init = jax.jit(jax.vmap(trainer.init, axis_name=SEED_AXIS))
    run = jax.jit(jax.vmap(trainer.run, in_axes=(0, None), axis_name=SEED_AXIS),
                  static_argnums=1)
    description = None if mesh is not None else {
        "program": "ppo_chunk", "env": env, "policy": policy,
        "ppo": dataclasses.asdict(ppo), "reset_pools": reset_pools}
    return Program(trainer, init, run, description=description)


def build(spec: RunSpec, mesh: Mesh | None = None, reset_pools: bool = False) -> Program:
    """The :class:`Program` of ``spec`` (cached: runs that differ only in length, seeds or
    logging share compiled code). ``reset_pools`` restarts episodes from reset pools
    (docs/design.md §5.7: the same transitions, a cheaper Franka step, but the rollout compiles
    about twice as long, so it is off by default)."""
    return _program(spec.env, spec.policy, dataclasses.replace(spec.ppo, total_iterations=1),
                    mesh, reset_pools)


def seed_keys(seeds: tuple[int, ...]) -> jax.Array:
    """Raw keys ``(num_seeds, 2)`` for the seeds."""
    return jnp.stack([jax.random.PRNGKey(s) for s in seeds])


def _median_seconds(fn: Callable[[], Any], repeats: int) -> float:
    """Median wall time of ``fn()`` (blocked) over ``repeats`` calls after one warm-up call."""
    jax.block_until_ready(fn())
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def profile_iteration(program: Program, state: TrainState, repeats: int = 3) -> dict[str, float]:
    """Median wall time (s) of one iteration's pieces for all seeds, compiled separately:
    ``rollout`` (environment + policy sampling, ``rollout_length`` steps), ``policy_forward``
    (the policy alone — RMP² included — on the rollout's ``rollout_length × num_envs``
    observations), ``update`` (GAE + every epoch and minibatch, RMP² backprop included) and
    ``rollout_reset_pools`` (the same rollout restarting episodes from reset pools:
    :func:`agents.ppo.make_trainer`) and, where the auto-reset is conditional (the CPU),
    ``rollout_reset_always`` (the reset computed at every step and selected). Does not change
    ``state``."""
    trainer = program.trainer
    n = trainer.config.rollout_length
    keys = jnp.broadcast_to(jax.random.PRNGKey(0), (state.iteration.shape[0], 2))
    rollout = jax.jit(jax.vmap(trainer.rollout, axis_name=SEED_AXIS))
    update = jax.jit(jax.vmap(trainer.update, axis_name=SEED_AXIS))
    _, tr = rollout(state, keys)

    def forward(ts, obs):
        def body(c, o):
            return c, trainer.policy.apply(ts.params["policy"], o, trainer.policy_norm(ts))[0]

        return jax.lax.scan(body, 0, obs)[1]

    forward = jax.jit(jax.vmap(forward))
    # where the auto-reset is not conditional, the always-reset rollout is ``rollout`` itself
    kinds = [("rollout_reset_pools", SEED_AXIS, True)] + (
        [("rollout_reset_always", None, False)]
        if jax.default_backend() in CONDITIONAL_RESET_BACKENDS else [])
    variants = {name: jax.jit(jax.vmap(make_trainer(
        trainer.env, trainer.policy, trainer.config, seed_axis=axis, reset_pools=pools).rollout,
        axis_name=SEED_AXIS)) for name, axis, pools in kinds}
    pieces = {"rollout": lambda: rollout(state, keys),
              **{name: functools.partial(fn, state, keys) for name, fn in variants.items()},
              "policy_forward": lambda: forward(state, tr.obs[:, :n]),
              "update": lambda: update(state, tr, keys)}
    return {name: _median_seconds(fn, repeats) for name, fn in pieces.items()}


__all__ = ["SEED_AXIS", "Program", "build", "profile_iteration", "seed_keys"]
