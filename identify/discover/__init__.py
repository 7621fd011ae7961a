"""calbench.identify.discover — the discrepancy workflow: where the model and the measurements
disagree, and which physical effect is missing.

fit (the candidate library and fitting a model with effects in the loop), stats (diagnostics
and the model-selection statistics), workflow (the whole `calbench discover`).
"""
from .fit import DISCOVERY_EFFECTS, AugmentedForward, Fit, library
from .workflow import UNEXPLAINED, discover, story

__all__ = ["DISCOVERY_EFFECTS", "AugmentedForward", "Fit", "library", "UNEXPLAINED", "discover", "story"]
