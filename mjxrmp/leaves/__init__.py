"""Leaf RMPs (thesis §3.2.1–3.2.7, docs/design.md §4.1).

* :mod:`~mjxrmp.leaves.hand_designed` — the RMPflow goal, collision, joint-limit and damping
  leaves on subtask families;
* :mod:`~mjxrmp.leaves.gds` — geometric dynamical systems and their curvature terms (§3.2.3–3.2.5);
* :mod:`~mjxrmp.leaves.clf` — RMP²-CLF leaves with a CLF guarantee (§3.2.6, eqs 3.29–3.32);
* :mod:`~mjxrmp.leaves.point_robot` — GDS leaves of the 2-D point-robot examples (§3.2.7).
"""
