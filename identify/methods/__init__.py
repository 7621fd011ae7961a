"""calbench.identify.methods: the estimator family (base), its one list (registry) and the estimators:
one-step, two-step (plain and weighted), two-step iterated."""

from calbench.bench.core import lazy_face

__getattr__, __dir__, __all__ = lazy_face(__name__, __file__)
