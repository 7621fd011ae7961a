"""calbench.bench.core: the bench's plumbing: errors, checked outputs, progress, shipped files, display units."""

from .face import lazy_face

__getattr__, __dir__, __all__ = lazy_face(__name__, __file__)
