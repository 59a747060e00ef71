"""mjxrmp: RMP² and structured robot policies as pure, jittable JAX functions.

Importing the package sets the XLA:CPU flag MJX needs on CPU (docs/design.md §5.2) before any
computation runs. The short names below are the public entry points of the README's API tour.

* :mod:`mjxrmp.core` — the RMP type, RMP² (pullback and resolve) and the naive baseline;
* :mod:`mjxrmp.leaves` — hand-designed, GDS, RMP²-CLF and point-robot leaf RMPs;
* :mod:`mjxrmp.learned` — flows, learned metrics and leaves, the nominal-trajectory potential;
* :mod:`mjxrmp.robots` — the 3-link and Franka kinematics and their MJCF models;
* :mod:`mjxrmp.policies` — the hand-designed RMP² policies of the reaching environments;
* :mod:`mjxrmp.residual` — the residual RMP policy split into state-only parts and its learned
  leaf;
* :mod:`mjxrmp.geometry` — point–obstacle distances;
* :mod:`mjxrmp.metrics` — trajectory-comparison metrics (RMSE, DTW, Fréchet, swept area);
* :mod:`mjxrmp.data` — the LASA and Franka demonstration data sets;
* :mod:`mjxrmp.studies` — simulation studies of the thesis (Figs 3.2 and 3.3);
* :mod:`mjxrmp.results` — ``summary.json`` files and the reports rendered from them;
* :mod:`mjxrmp.config` — frozen parameter dataclasses and the shared config validators;
* :mod:`mjxrmp.atomic` — atomic file writes;
* :mod:`mjxrmp.divergence` — the divergence guards every trainer runs (``DivergenceError``).
"""

from mjxrmp._xla import configure_cpu_flags

configure_cpu_flags()

from mjxrmp import geometry, policies, robots  # noqa: E402
from mjxrmp.core import rmp2  # noqa: E402
from mjxrmp.core.rmp import RMP, natural  # noqa: E402

__all__ = [
    "RMP",
    "atomic",
    "config",
    "core",
    "data",
    "divergence",
    "geometry",
    "learned",
    "leaves",
    "metrics",
    "natural",
    "policies",
    "residual",
    "results",
    "rmp2",
    "robots",
    "studies",
]
