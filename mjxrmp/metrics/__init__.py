"""Trajectory-comparison metrics for learning from demonstrations (thesis chapters 4–5).

* :mod:`~mjxrmp.metrics.trajectory` — the public front: every metric and :func:`all_metrics`;
* :mod:`~mjxrmp.metrics.resampling` — input checks and normalised-time resampling;
* :mod:`~mjxrmp.metrics.pointwise` — RMSE, mean and final-point error, distance to paths;
* :mod:`~mjxrmp.metrics.warping` — DTW (with warping path) and discrete Fréchet distances;
* :mod:`~mjxrmp.metrics.area` — swept error area between 2-D trajectories.
"""
