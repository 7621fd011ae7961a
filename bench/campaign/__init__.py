"""calbench.bench.campaign: a calibration campaign: posed unloaded and loaded, measured, logged."""

from calbench.bench.core import lazy_face

__getattr__, __dir__, __all__ = lazy_face(__name__, __file__)
