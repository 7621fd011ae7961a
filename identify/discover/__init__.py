"""calbench.identify.discover — the discrepancy workflow: where the model and the measurements
disagree, and which physical effect is missing.

fit (the candidate library and fitting a model with effects in the loop), search (the global,
multi-start fit of one candidate), stats (diagnostics), decide (the likelihood-ratio tests and
near-ties), uncertainty (what a fit determines), aliasing (what a fit cannot see), story (what a
person reads), workflow (the whole `calbench discover`).
"""

from calbench.bench.core import lazy_face

__getattr__, __dir__, __all__ = lazy_face(__name__, __file__)
