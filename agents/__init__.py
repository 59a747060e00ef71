"""Learners and their runs.

* :mod:`agents.ppo` — PPO (thesis §6.2.3) and the policy classes of thesis §6.2.2;
* :mod:`agents.run` — training runs: the loop, logs, checkpoints, loading, evaluation, export
  and the chapter-6 study;
* :mod:`agents.bench` — throughput benchmarks (RMP², environments, PPO);
* :mod:`agents.lfd` — learning from demonstrations (thesis §4.2 and chapter 5);
* :mod:`agents.brax_compat` — brax's own PPO trainer on our environments under current JAX.
"""
