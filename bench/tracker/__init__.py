"""calbench.bench.tracker: the laser tracker: frames, noise models, visibility, a campaign's readings."""

from calbench.bench.core import lazy_face

__getattr__, __dir__, __all__ = lazy_face(__name__, __file__)
