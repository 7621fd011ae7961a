"""calbench.identify.report: what a person reads: the identify table and JSON, the HTML report."""

from calbench.bench.core import lazy_face

__getattr__, __dir__, __all__ = lazy_face(__name__, __file__)
