"""calbench.bench.view: the Rerun view of a campaign: what it draws, its pages, the parameter chart."""

from calbench.bench.core import lazy_face

__getattr__, __dir__, __all__ = lazy_face(__name__, __file__)
