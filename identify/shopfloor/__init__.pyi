# The public face of calbench.identify.shopfloor: what code outside this room may import. At run time
# calbench.bench.core.face reads these lines and loads each name on first use.

from .importer import import_readings
from .tracker_pose import rigid_points

__all__ = ["import_readings", "rigid_points"]
