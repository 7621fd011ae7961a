"""calbench.bench.log: the campaign log (MCAP) and the identification report: written, read, scanned, recovered."""

from calbench.bench.core import lazy_face

__getattr__, __dir__, __all__ = lazy_face(__name__, __file__)
