"""Offline datasets (docs/design.md §2.4): the :class:`~offline.data.dataset.Dataset` pytree and its
checksummed files, host-side and in-graph operations, collection inside the compiled graph with
D4RL-style recipes (:mod:`offline.data.collect`) and the PLfO scenarios of thesis §7.4
(:mod:`offline.data.scenarios`)."""
