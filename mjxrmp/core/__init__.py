"""RMP² itself (thesis §3.2): the RMP type, the pullback/resolve algorithm and its naive baseline.

* :mod:`~mjxrmp.core.rmp` — :class:`~mjxrmp.core.rmp.RMP`, an RMP in natural form ``[M, f]``;
* :mod:`~mjxrmp.core.rmp2` — RMP² (Algorithm 2): leaf RMPs pulled back through a task map by
  autodiff and resolved at the root (eq 3.10);
* :mod:`~mjxrmp.core.linalg` — the resolve's small symmetric positive-definite solve, written
  out entry by entry so that a GPU runs it in fused kernels;
* :mod:`~mjxrmp.core.naive` — the naive baseline differentiating every subtask on its own.
"""
