"""mjxrmp: RMP² and structured robot policies as pure, jittable JAX functions.

Importing the package sets the XLA:CPU flag MJX needs on CPU (DESIGN §8.2) before any
computation runs.
"""

from mjxrmp._xla import configure_cpu_flags

configure_cpu_flags()

from mjxrmp import clf, gds, geometry, leaves, policies, rmp2, robots  # noqa: E402
from mjxrmp.rmp import RMP, natural  # noqa: E402

__all__ = ["RMP", "clf", "gds", "geometry", "leaves", "natural", "policies", "rmp2", "robots"]
