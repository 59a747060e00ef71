"""Structure of an offline learner's compiled gradient step: how many separate operations (on a GPU
roughly one kernel launch each) one gradient step executes, and which part of the step they
belong to (docs/design.md §4.5 sizes: batch 256, 3×256 MLPs).

With one seed a step is launch-bound on a GPU, so the number of operations per step, not the
FLOPs, sets its latency; with 8 vmapped seeds the GPU is busy instead, and the kernel trace that
:func:`step_structure` adds on a GPU (``gpu_kernels``) shows where its time goes
(docs/reports/performance.md). :func:`step_structure` compiles a trainer's ``run(state, chunk)``
vmapped over seeds exactly as :func:`offline.experiment.bench.measure` times it
(:func:`offline.experiment.bench.structure` builds the benchmark's trainers), reads the
optimised HLO (``jax.jit(...).lower(...).compile().as_text()``) with :func:`parse_hlo` and
counts with :func:`executed`:

* every instruction that is not free (:data:`FREE_OPS`: parameters, tuples, constants,
  bitcasts) counts once per execution; a fusion counts once (what it fuses is one kernel), a
  ``while`` loop counts its body and condition ``known_trip_count`` times (XLA records it), a
  conditional its most expensive branch;
* the total over the chunk divided by ``chunk`` gives the operations per gradient step, loop
  overhead and anything hoisted out of the loop included;
* each operation is attributed to the part of the step named by the outermost
  :data:`PARTS` scope in its ``op_name`` (the learners mark their parts with ``jax.named_scope``);
  ``other`` is what no scope covers (loop plumbing, copies, and everything of a learner without
  scopes).

The CPU and GPU compilers fuse differently (and XLA:CPU draws random bits in small rolled loops
that a GPU unrolls), so compare counts of the same backend only.
"""

from __future__ import annotations

import re
import time
from collections import Counter
from collections.abc import Sequence
from typing import Any, NamedTuple

import jax

from agents.bench.kernels import kernel_stats
from offline.learners.base import Trainer

#: Opcodes that launch nothing (buffer plumbing).
FREE_OPS = frozenset({"parameter", "get-tuple-element", "tuple", "constant", "bitcast",
                      "after-all", "opt-barrier", "partition-id", "replica-id"})
#: The ``jax.named_scope`` names the learners give the parts of a step (:func:`part_of`).
PARTS = ("rng", "minibatch", "warm_switch", "actor_forward", "critic_forward", "target_forward",
         "critic_loss", "pessimism", "critic_backward", "critic_optimizer", "projection",
         "target_update", "reward_update", "temperature", "actor_loss", "actor_backward",
         "actor_optimizer")

_HEADER = re.compile(r"^(ENTRY\s+)?%?([\w.\-]+)\s.*\{\s*$")
_INSTR = re.compile(r"^\s*(?:ROOT\s+)?%?([\w.\-]+)\s*=\s*(.*)$")
_OPCODE = re.compile(r"(?<![\w.\-%])([a-z][a-z0-9\-]*)\(")
_CALLS = re.compile(r"\b(calls|body|condition|to_apply|true_computation|false_computation)"
                    r"=%?([\w.\-]+)")
_BRANCHES = re.compile(r"branch_computations=\{([^}]*)\}")
_OP_NAME = re.compile(r'op_name="([^"]*)"')
_TRIPS = re.compile(r'"known_trip_count":\{"n":"(\d+)"\}')
#: ``op_name`` of the small loops in which XLA:CPU computes random bits (a GPU unrolls them).
RNG_LOOP = re.compile(r"threefry|_uniform|_normal|_randint|random_bits")


class Instruction(NamedTuple):
    """One HLO instruction: its ``opcode``, the computations it ``calls`` (role → names), its
    ``op_name`` metadata and the ``trips`` XLA knows for a ``while`` (None if unknown)."""

    opcode: str
    calls: dict[str, list[str]]
    op_name: str
    trips: int | None


class Module(NamedTuple):
    """A parsed HLO module: ``computations`` (name → instructions) and the ``entry`` name."""

    computations: dict[str, list[Instruction]]
    entry: str


def parse_hlo(text: str) -> Module:
    """Parse the text of an optimised HLO module (``Compiled.as_text()``)."""
    comps: dict[str, list[Instruction]] = {}
    entry, current = "", None
    for line in text.splitlines():
        if current is None or (line.startswith(("ENTRY", "%")) and line.rstrip().endswith("{")):
            head = _HEADER.match(line)
            if head:
                current = head.group(2)
                comps[current] = []
                entry = current if head.group(1) else entry
            continue
        if line.strip() == "}":
            current = None
            continue
        m = _INSTR.match(line)
        op = _OPCODE.search(m.group(2)) if m else None
        if op is None:
            continue
        calls: dict[str, list[str]] = {}
        for role, name in _CALLS.findall(line):
            calls.setdefault(role, []).append(name)
        branches = _BRANCHES.search(line)
        if branches:
            calls["branches"] = [b.strip().lstrip("%") for b in branches.group(1).split(",")]
        name = _OP_NAME.search(line)
        trips = _TRIPS.search(line)
        comps[current].append(Instruction(op.group(1), calls, name.group(1) if name else "",
                                          int(trips.group(1)) if trips else None))
    if not entry:
        raise ValueError("text is not an HLO module: it has no ENTRY computation")
    return Module(comps, entry)


def part_of(op_name: str, parts: Sequence[str] = PARTS) -> str:
    """The outermost of ``parts`` named as a scope in ``op_name`` (a backward pass done under
    one scope keeps that scope; scopes inside transforms read ``jvp(name)``), or ``"other"``."""
    found = [t for t in re.split(r"[/()]", op_name) if t in parts]
    return found[0] if found else "other"


def executed(module: Module, computation: str | None = None, unknown_trips: int = 1,
             rng_loops: bool = True) -> tuple[Counter, Counter]:
    """``(by_opcode, by_part)``: how many times each non-free opcode, and each part of
    :data:`PARTS`, executes when ``computation`` (default: the entry) runs once; ``while`` loops
    without a known trip count count ``unknown_trips`` iterations; without ``rng_loops`` a loop
    drawing random bits (:data:`RNG_LOOP`) counts as one operation."""
    by_op: Counter = Counter()
    by_part: Counter = Counter()
    for ins in module.computations[computation or module.entry]:
        if ins.opcode in FREE_OPS:
            continue
        by_op[ins.opcode] += 1
        by_part[part_of(ins.op_name)] += 1
        if ins.opcode == "while" and (rng_loops or not RNG_LOOP.search(ins.op_name)):
            trips = ins.trips if ins.trips is not None else unknown_trips
            for role in ("body", "condition"):
                op, part = executed(module, ins.calls[role][0], unknown_trips, rng_loops)
                by_op.update({k: trips * v for k, v in op.items()})
                by_part.update({k: trips * v for k, v in part.items()})
        elif ins.opcode == "conditional":
            names = ins.calls.get("branches") or (ins.calls.get("true_computation", [])
                                                  + ins.calls.get("false_computation", []))
            runs = [executed(module, n, unknown_trips, rng_loops) for n in names]
            op, part = max(runs, key=lambda r: sum(r[0].values()))
            by_op.update(op)
            by_part.update(part)
    return by_op, by_part


def hlo_summary(text: str, steps: int) -> dict:
    """Counts of the optimised HLO ``text`` of a program running ``steps`` gradient steps:
    operations (kernels on a GPU) per step in total, and counting each loop that draws random
    bits as one (XLA:CPU's are rolled loops, a GPU's are not), by opcode and by part
    (:func:`executed` over ``steps``), and the static size of the module (instructions
    including fused ones, fusions, loops)."""
    module = parse_hlo(text)
    by_op, by_part = executed(module)
    without_rng = sum(executed(module, rng_loops=False)[0].values())
    static = Counter(i.opcode for comp in module.computations.values() for i in comp)
    per_step = lambda c: {k: round(v / steps, 2) for k, v in c.most_common()}  # noqa: E731
    return {"ops_per_step": round(sum(by_op.values()) / steps, 2),
            "ops_per_step_rng_loops_as_one": round(without_rng / steps, 2),
            "fusions_per_step": round(by_op["fusion"] / steps, 2),
            "while_loops_per_step": round(by_op["while"] / steps, 2),
            "by_opcode": per_step(by_op), "by_part": per_step(by_part),
            "static": {"instructions": sum(static.values()), "fusions": static["fusion"],
                       "while_loops": static["while"], "computations": len(module.computations)}}


def step_structure(trainer: Trainer, seeds: int = 8, chunk: int = 64, seed: int = 0) -> dict:
    """:func:`hlo_summary` of ``trainer``'s compiled ``run(state, chunk)`` vmapped over
    ``seeds`` seeds (the program :func:`offline.experiment.bench.measure` times), with its
    backend, compile time and, on a GPU, the kernels one call runs (``gpu_kernels``)."""
    keys = jax.random.split(jax.random.key(seed), seeds)
    state = jax.jit(jax.vmap(trainer.init))(keys)
    run = jax.jit(jax.vmap(trainer.run, in_axes=(0, None)), static_argnums=1)
    t0 = time.perf_counter()
    compiled = run.lower(state, chunk).compile()
    row = {"seeds": seeds, "chunk": chunk, "backend": jax.default_backend(),
           "compile_s": round(time.perf_counter() - t0, 2)}
    return row | hlo_summary(compiled.as_text(), chunk) | {
        "gpu_kernels": _gpu_kernels(compiled, state, chunk)}


def _gpu_kernels(compiled: Any, state: Any, chunk: int) -> dict | None:
    """On a GPU, :func:`agents.bench.kernels.kernel_stats` of one call of the compiled ``run``
    after a warm-up call (kernels per gradient step, busy and span µs, matrix products and
    reductions apart); None elsewhere."""
    if jax.devices()[0].platform != "gpu":
        return None
    state, _ = jax.block_until_ready(compiled(state))
    return kernel_stats(lambda: compiled(state), chunk)


__all__ = ["FREE_OPS", "PARTS", "RNG_LOOP", "Instruction", "Module", "executed", "hlo_summary",
           "parse_hlo", "part_of", "step_structure"]
