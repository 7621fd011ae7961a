"""calbench.identify.shopfloor: real readings in: the import and the tracker's pose."""

from calbench.bench.core import lazy_face

__getattr__, __dir__, __all__ = lazy_face(__name__, __file__)
