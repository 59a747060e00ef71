"""Thesis studies that are simulations of fixed policies (no learning).

* :mod:`~mjxrmp.studies.ch3` — Figs 3.2 and 3.3 (§3.2.7): RMP²-CLF vs RMPflow-GDS goal
  attractors on 2-D point robots, their simulation, metrics and ``fig3_3.json`` record;
* :mod:`~mjxrmp.studies.ch3_figures` — the two figures (needs matplotlib).
"""
