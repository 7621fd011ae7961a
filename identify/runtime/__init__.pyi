# The public face of calbench.identify.runtime: what code outside this room may import. At run time
# calbench.bench.core.face reads these lines and loads each name on first use.

from .executor import IN_PROCESS, ClusterLost, Executor, InProcess, Interrupted, choose, open_executor
from .portable import PortableScenario, with_robot
from .threads import blas_threads

__all__ = [
    "blas_threads",
    "ClusterLost",
    "Executor",
    "IN_PROCESS",
    "InProcess",
    "Interrupted",
    "PortableScenario",
    "choose",
    "open_executor",
    "with_robot",
]
