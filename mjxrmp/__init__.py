"""mjxrmp: RMP² and structured robot policies as pure, jittable JAX functions.

Importing the package sets the XLA:CPU flag MJX needs on CPU (docs/design.md §5.2) before any
computation runs. The short names below are the public entry points of the README's API tour.
"""

from mjxrmp._xla import configure_cpu_flags

configure_cpu_flags()

from mjxrmp import geometry, policies, robots  # noqa: E402
from mjxrmp.core import rmp2  # noqa: E402
from mjxrmp.core.rmp import RMP, natural  # noqa: E402

__all__ = ["RMP", "geometry", "natural", "policies", "rmp2", "robots"]
