"""calbench.bench — the virtual test bench: robot model, exact statics, laser tracker,
calibration campaigns and their MCAP log.

Its face (``__init__.pyi``) names what a notebook calls, each name re-exported from its room:
``from calbench.bench import load_scenario, run_campaign, read_log``."""

from calbench.bench.core import lazy_face

__getattr__, __dir__, __all__ = lazy_face(__name__, __file__)
