# The public face of calbench.bench.statics: what code outside this room may import. At run time
# calbench.bench.core.face reads these lines and loads each name on first use.

from .batched import BatchStatics, Equilibria, take_load
from .equilibrium import (
    LOOP_TOL,
    Equilibrium,
    Load,
    NewtonPoint,
    NewtonResult,
    StaticsError,
    StaticsSolver,
    ift_tangent,
    kkt_matrix,
    statics_options,
)

__all__ = [
    "BatchStatics",
    "Equilibria",
    "Equilibrium",
    "LOOP_TOL",
    "Load",
    "NewtonPoint",
    "NewtonResult",
    "StaticsError",
    "StaticsSolver",
    "ift_tangent",
    "kkt_matrix",
    "statics_options",
    "take_load",
]
