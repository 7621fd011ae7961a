"""calbench.bench.model: the robot model: its description, parameters, MjModel wrapper, loop kinematics
and shapes; its hidden effects are the room bench/model/effects/."""

from calbench.bench.core import lazy_face

__getattr__, __dir__, __all__ = lazy_face(__name__, __file__)
