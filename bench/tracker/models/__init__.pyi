# The public face of calbench.bench.tracker.models: what code outside this room may import. At run
# time calbench.bench.core.face reads these lines and loads each name on first use. The models
# themselves are found by bench/tracker/base.py (every module here, its MODEL), not through this face.

from .iso10360 import (
    Iso10360Tracker,
    correlated_covariance,
    correlated_marginal,
    draw_correlated,
    field_kernel,
    marginal_covariance,
)
from .isotropic import IsotropicTracker
from .spec import SpecTracker, describe_laws, spec_covariance

__all__ = [
    "Iso10360Tracker",
    "IsotropicTracker",
    "SpecTracker",
    "correlated_covariance",
    "correlated_marginal",
    "describe_laws",
    "draw_correlated",
    "field_kernel",
    "marginal_covariance",
    "spec_covariance",
]
