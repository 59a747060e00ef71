"""Training runs of :mod:`agents.ppo` and what is done with them (docs/design.md §2.3).

* :mod:`agents.run.spec` — :class:`~agents.run.spec.RunSpec` and the PPO presets;
* :mod:`agents.run.program` — the compiled, seed-vmapped program of a spec and its timing split;
* :mod:`agents.run.training` — :func:`~agents.run.training.run_training`, the chunked loop;
* :mod:`agents.run.directory` — a run directory's lock, its checks and ``run.json``;
* :mod:`agents.run.sweep_spec` / :mod:`agents.run.sweep` — packed sweeps: setups × policy kinds ×
  hyper-parameters × seeds in one program, what a sweep is and how it trains;
* :mod:`agents.run.logs` — progress bar, ``metrics.csv``, TensorBoard;
* :mod:`agents.run.curves` — learning curves as the thesis draws them;
* :mod:`agents.run.checkpoint` — orbax checkpoints of the whole state, verified by a SHA-256
  integrity record, with fallback to the newest intact step;
* :mod:`agents.run.loading` — a run directory back as a policy;
* :mod:`agents.run.evaluation` — checkpoints × setups × seeds × episodes in one compiled call;
* :mod:`agents.run.eval_report` — the evaluation report, its table and GIF;
* :mod:`agents.run.export` — a policy as a standalone :mod:`jax.export` blob;
* :mod:`agents.run.sim2sim` / :mod:`agents.run.sim2sim_mujoco` — an exported policy in MuJoCo's
  own simulator next to the MJX evaluation of the same scenes;
* :mod:`agents.run.ch6` — the chapter-6 study (train every policy class, Figs 6.2–6.4);
  :mod:`agents.run.ch6_study` — its hand-designed baseline, study record and stages.
"""
