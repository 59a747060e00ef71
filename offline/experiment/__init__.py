"""Offline experiments (docs/design.md §2.4): learner × scenario × dataset runs
(:mod:`offline.experiment.run`), in-graph evaluation, resumable programs, the offline scripts'
shared settings, one-learner runs and the chapter-7 reproduction with its table."""
