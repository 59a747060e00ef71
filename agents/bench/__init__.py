"""Benchmarks behind ``scripts/bench.py`` (docs/design.md §2.5, §5.6): how fast the stack runs.

* :mod:`agents.bench.rmp2` — RMP² (and naive) policy evaluations: random inputs, batched
  throughput, single-state latency, float32 vs float64;
* :mod:`agents.bench.throughput` — environment control steps and PPO training steps per second;
* :mod:`agents.bench.table` — device description, the table and the per-robot summary;
* :mod:`agents.bench.run` — the whole benchmark, its JSON rewritten after every row;
* :mod:`agents.bench.scaling` — packed-sweep throughput and PPO on 1, 2 and 4 GPUs.
"""
