"""calbench.identify.core: what every estimator shares: observations, whitening, the forward model, least squares, identifiability."""

from calbench.bench.core import lazy_face

__getattr__, __dir__, __all__ = lazy_face(__name__, __file__)
