"""calbench.bench.model: the robot model: its description, parameters, MjModel wrapper, loop kinematics, shapes, effects."""

from calbench.bench.core import lazy_face

__getattr__, __dir__, __all__ = lazy_face(__name__, __file__)
