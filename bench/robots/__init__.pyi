# The public face of calbench.bench.robots: what code outside this room may import. At run time
# calbench.bench.core.face reads these lines and loads each name on first use.

from .check import DEFAULT_MASS, check_robot, default_tracker, grid
from .density import is_closed, mesh_moments
from .importer import IMPORTERS, Conversion, RobotImporter, import_robot
from .overlay import load_overlay
from .urdf import CONTINUOUS_RANGE, PLACEHOLDER_STIFFNESS, convert, read_urdf

__all__ = [
    "IMPORTERS",
    "Conversion",
    "RobotImporter",
    "import_robot",
    "CONTINUOUS_RANGE",
    "DEFAULT_MASS",
    "PLACEHOLDER_STIFFNESS",
    "check_robot",
    "convert",
    "default_tracker",
    "grid",
    "is_closed",
    "mesh_moments",
    "load_overlay",
    "read_urdf",
]
