"""calbench.bench.shopfloor: readings from a real tracker: the readings CSV and logs made from it."""

from calbench.bench.core import lazy_face

__getattr__, __dir__, __all__ = lazy_face(__name__, __file__)
