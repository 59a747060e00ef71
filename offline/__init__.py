"""Offline reinforcement learning on the reaching tasks (thesis chapters 7–8, docs/design.md §2.4):
datasets (:mod:`offline.data`), learners and their registry (:mod:`offline.learners`), runs and
chapter-7 tables (:mod:`offline.experiment`) and the chapter-8 survival-instinct studies
(:mod:`offline.survival`)."""
