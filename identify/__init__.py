"""calbench.identify — elastostatic identification, experiment design and the discrepancy
workflow. Builds on `bench`; never imported by it.

Its face (``__init__.pyi``) names what a notebook calls, each name re-exported from its room:
``from calbench.identify import run_identify, run_montecarlo, run_discover``."""

from calbench.bench.core import lazy_face

__getattr__, __dir__, __all__ = lazy_face(__name__, __file__)
