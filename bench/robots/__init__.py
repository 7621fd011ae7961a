"""calbench.bench.robots: robots from elsewhere: URDF import, its overlay, the robot check."""

from calbench.bench.core import lazy_face

__getattr__, __dir__, __all__ = lazy_face(__name__, __file__)
