"""calbench.identify.compensate: compliance-error compensation: the joint commands at which the identified model's loaded tool lands on its target."""

from calbench.bench.core import lazy_face

__getattr__, __dir__, __all__ = lazy_face(__name__, __file__)
