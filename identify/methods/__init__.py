"""calbench.identify.methods: the estimators: one-step, two-step, two-step iterated."""

from calbench.bench.core import lazy_face

__getattr__, __dir__, __all__ = lazy_face(__name__, __file__)
