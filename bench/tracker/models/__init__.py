"""calbench.bench.tracker.models: the tracker error models, one file each (its name the model's)."""

from calbench.bench.core import lazy_face

__getattr__, __dir__, __all__ = lazy_face(__name__, __file__)
