# The public face of calbench.bench.tracker: what code outside this room may import. At run time
# calbench.bench.core.face reads these lines and loads each name on first use.

from .base import (
    DEFAULT_DISTANCE,
    DEFAULT_MODEL,
    DEFAULT_SIGMA,
    DEFAULT_TRANSVERSE,
    TrackerModel,
    TrackerSpec,
    register_tracker_model,
    tracker_model,
    tracker_models,
    unregister_tracker_model,
)
from .instrument import (
    BLOCKING_GROUPS,
    MeanReading,
    Measurement,
    deflection_covariance,
    mean_reading,
    measure,
    noise_covariance,
    sight_lines,
    to_tracker_frame,
    to_world_frame,
    tracker_rotation,
    unoccluded,
    visible_sites,
)
from .measuring import measure_campaign

__all__ = [
    "BLOCKING_GROUPS",
    "DEFAULT_DISTANCE",
    "DEFAULT_MODEL",
    "DEFAULT_SIGMA",
    "DEFAULT_TRANSVERSE",
    "MeanReading",
    "Measurement",
    "TrackerModel",
    "TrackerSpec",
    "deflection_covariance",
    "mean_reading",
    "measure",
    "measure_campaign",
    "noise_covariance",
    "register_tracker_model",
    "sight_lines",
    "to_tracker_frame",
    "to_world_frame",
    "tracker_model",
    "tracker_models",
    "tracker_rotation",
    "unoccluded",
    "unregister_tracker_model",
    "visible_sites",
]
