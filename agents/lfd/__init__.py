"""Learning from demonstrations (thesis ch. 4.2 and 5; docs/design.md §2.3, §4.6).

* Settings: :mod:`agents.lfd.config`; shared optimisation rules: :mod:`agents.lfd.optim`.
* Stable first-order flow dynamics on LASA (§4.2): :mod:`agents.lfd.flow_field` (the field and
  its rollouts), :mod:`agents.lfd.flow_training`, :mod:`agents.lfd.fast_trig`, and the
  evaluation of ``scripts/lfd_lasa.py``: :mod:`agents.lfd.lasa_eval`.
* RMP² policies on the Franka demonstrations (ch. 5): :mod:`agents.lfd.samples` (data),
  :mod:`agents.lfd.policy` (the policy class, §5.3.1), :mod:`agents.lfd.strategies`
  (configuration-space, independent, joint, single-link), :mod:`agents.lfd.two_step` (§5.2),
  :mod:`agents.lfd.execution` (execution-time leaves and rollouts), and the evaluation of
  ``scripts/lfd_franka.py`` / ``scripts/lfd_franka_seeds.py``: :mod:`agents.lfd.franka_scenario`,
  :mod:`agents.lfd.franka_eval`, :mod:`agents.lfd.seeds`; figures: :mod:`agents.lfd.figures`.
"""
