"""Offline learners (thesis chapter 7, docs/design.md §2.4, §4.5): the learner interface
(:mod:`offline.learners.base`), ATAC / PSPI, MAHALO, the PLfO baselines, BC / BCO, inverse
dynamics, IQL, CQL, their networks and actors, and the registry of learner builders
(:mod:`offline.learners.registry`)."""
