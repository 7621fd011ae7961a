# The public face of calbench.identify.methods: what code outside this room may import. At run time
# calbench.bench.core.face reads these lines and loads each name on first use.

from .onestep import (
    OneStep,
    dtheta_dphi,
    fit_from,
    generic_start,
    one_step,
    sanitize_start,
    to_phi,
    to_theta,
    valid_phi,
)
from .twostep import TwoStepError, linear_plan, step2_rows, two_step, two_step_applies
from .twostep_iterated import SagMap, sensitivity, two_step_iterated

__all__ = [
    "OneStep",
    "SagMap",
    "TwoStepError",
    "dtheta_dphi",
    "fit_from",
    "generic_start",
    "linear_plan",
    "one_step",
    "sanitize_start",
    "sensitivity",
    "step2_rows",
    "to_phi",
    "to_theta",
    "two_step",
    "two_step_applies",
    "two_step_iterated",
    "valid_phi",
]
