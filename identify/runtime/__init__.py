"""calbench.identify.runtime: where pieces of work run: this process or Dask, and what travels to a worker."""

from calbench.bench.core import lazy_face

__getattr__, __dir__, __all__ = lazy_face(__name__, __file__)
