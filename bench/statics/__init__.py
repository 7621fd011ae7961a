"""calbench.bench.statics: exact static equilibrium of the closed-loop robot, one command or many at once."""

from calbench.bench.core import lazy_face

__getattr__, __dir__, __all__ = lazy_face(__name__, __file__)
