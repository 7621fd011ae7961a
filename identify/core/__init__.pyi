# The public face of calbench.identify.core: what code outside this room may import. At run time
# calbench.bench.core.face reads these lines and loads each name on first use.

from .forward import ForwardModel, NoEquilibrium, PoseDesign, design_from_observations
from .identifiability import (
    OUTLIER_SIGMA,
    Identifiability,
    analyze,
    explain,
    outliers,
    resolve,
    whiten_factors,
)
from .leastsq import Fit, at_bounds, covariance, levenberg_marquardt, svd_step
from .model import check_sites
from .observations import Observations, PoseObservation, from_campaign, from_log, pose_observation
from .profile import (
    FAR_SIGMAS,
    PROFILE_LOW,
    PROFILE_SIGMAS,
    Profile,
    Valley,
    profile_check,
    quadratic,
    valley_check,
)
from .rigid import RigidFit, fit_rigid, non_collinear, rotation_exp
from .tolerances import (
    DISCOVER_RANK_TOL,
    GEOMETRY_RANK_TOL,
    MAX_RELATIVE_STD,
    NULL_TOL,
    RANK_TOL,
    RELATIVE_RANK_TOL,
    ZERO_COLUMN_TOL,
)
from .whitening import Whitener

__all__ = [
    "DISCOVER_RANK_TOL",
    "GEOMETRY_RANK_TOL",
    "NULL_TOL",
    "RELATIVE_RANK_TOL",
    "ZERO_COLUMN_TOL",
    "Fit",
    "ForwardModel",
    "Identifiability",
    "MAX_RELATIVE_STD",
    "NoEquilibrium",
    "OUTLIER_SIGMA",
    "Observations",
    "PROFILE_SIGMAS",
    "PROFILE_LOW",
    "FAR_SIGMAS",
    "PoseDesign",
    "PoseObservation",
    "Profile",
    "RANK_TOL",
    "RigidFit",
    "Whitener",
    "analyze",
    "at_bounds",
    "check_sites",
    "covariance",
    "design_from_observations",
    "explain",
    "fit_rigid",
    "from_campaign",
    "from_log",
    "levenberg_marquardt",
    "non_collinear",
    "outliers",
    "pose_observation",
    "profile_check",
    "valley_check",
    "Valley",
    "quadratic",
    "resolve",
    "rotation_exp",
    "svd_step",
    "whiten_factors",
]
