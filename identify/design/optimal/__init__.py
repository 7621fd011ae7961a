"""calbench.identify.design.optimal: optimal design on given information blocks (criteria,
exchange, the certificate's bound, the choice of M rows), knowing nothing of robots."""

from calbench.bench.core import lazy_face

__getattr__, __dir__, __all__ = lazy_face(__name__, __file__)
