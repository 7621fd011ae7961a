# The public face of calbench.bench.tracker: what code outside this room may import. At run time
# calbench.bench.core.face reads these lines and loads each name on first use.

from .instrument import (
    BLOCKING_GROUPS,
    MeanReading,
    Measurement,
    mean_reading,
    measure,
    noise_covariance,
    sight_lines,
    spec_covariance,
    to_tracker_frame,
    to_world_frame,
    tracker_rotation,
    unoccluded,
    visible_sites,
)
from .iso10360 import (
    correlated_covariance,
    correlated_marginal,
    deflection_covariance,
    draw_correlated,
    field_kernel,
    marginal_covariance,
)
from .measuring import measure_campaign, reading_times, schedule

__all__ = [
    "BLOCKING_GROUPS",
    "MeanReading",
    "Measurement",
    "correlated_covariance",
    "correlated_marginal",
    "deflection_covariance",
    "draw_correlated",
    "field_kernel",
    "marginal_covariance",
    "mean_reading",
    "measure",
    "measure_campaign",
    "noise_covariance",
    "reading_times",
    "schedule",
    "sight_lines",
    "spec_covariance",
    "to_tracker_frame",
    "to_world_frame",
    "tracker_rotation",
    "unoccluded",
    "visible_sites",
]
