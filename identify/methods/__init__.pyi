# The public face of calbench.identify.methods: what code outside this room may import. At run time
# calbench.bench.core.face reads these lines and loads each name on first use.

from .base import IdentifyOptions, Method, MethodResult, NotApplicable, Repeats
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
from .registry import (
    ALL,
    BOTH,
    all_methods,
    check_method,
    identify_help,
    method_named,
    method_names,
    montecarlo_choices,
    register_method,
    select_methods,
    unregister_method,
)
from .twostep import TwoStepError, linear_plan, step2_rows, two_step, two_step_applies
from .twostep_iterated import REL_STEP, SagMap, sensitivity, sensitivity_fd, two_step_iterated

__all__ = [
    "REL_STEP",
    "ALL",
    "BOTH",
    "IdentifyOptions",
    "Method",
    "MethodResult",
    "NotApplicable",
    "OneStep",
    "Repeats",
    "SagMap",
    "TwoStepError",
    "all_methods",
    "check_method",
    "dtheta_dphi",
    "fit_from",
    "generic_start",
    "identify_help",
    "linear_plan",
    "method_named",
    "method_names",
    "montecarlo_choices",
    "one_step",
    "register_method",
    "sanitize_start",
    "select_methods",
    "sensitivity",
    "sensitivity_fd",
    "step2_rows",
    "to_phi",
    "to_theta",
    "two_step",
    "two_step_applies",
    "two_step_iterated",
    "unregister_method",
    "valid_phi",
]
