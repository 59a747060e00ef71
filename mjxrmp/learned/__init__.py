"""Learned components of structured policies (thesis chapter 4, §5.2, §6.1.2).

* :mod:`~mjxrmp.learned.flows` — Euclideanizing flows, diffeomorphisms of coupling layers (§4.2.2);
* :mod:`~mjxrmp.learned.gds` — metric networks, the diffeomorphic potential, learned GDS leaves;
* :mod:`~mjxrmp.learned.rmps` — residual, direct, nominal + CLF and nominal-potential GDS leaves;
* :mod:`~mjxrmp.learned.nominal` — the nominal-trajectory potential (§4.3.1, eqs 4.8–4.11);
* :mod:`~mjxrmp.learned.nominal_fit` — its bias fit (eq 4.12) and the DTW nominal (§5.2.1);
* :mod:`~mjxrmp.learned.lsq` — exact jittable NNLS / LSI / LSEI solvers used by the fit.
"""
