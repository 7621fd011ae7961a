# The public face of calbench.bench.view: what code outside this room may import. At run time
# calbench.bench.core.face reads these lines and loads each name on first use.

from .params import WIDTH
from .recording import (
    DEFAULT_MAGNIFY,
    Discovery,
    Summary,
    ViewerUnavailable,
    build_blueprint,
    check_magnify,
    default_rrd_path,
    geom_archetype,
    has_display,
    log_view,
    measured_deflections,
    open_hint,
    plan_view,
    recording_stream,
    spawn_recording,
    write_discovery_recording,
    write_recording,
)
from .scene import HALF_FOV_TAN, TRACKER_APART, framing
from .text import Legend, colour_name, legend

__all__ = [
    "DEFAULT_MAGNIFY",
    "Discovery",
    "HALF_FOV_TAN",
    "Legend",
    "Summary",
    "TRACKER_APART",
    "WIDTH",
    "build_blueprint",
    "check_magnify",
    "colour_name",
    "default_rrd_path",
    "framing",
    "geom_archetype",
    "has_display",
    "legend",
    "open_hint",
    "log_view",
    "measured_deflections",
    "plan_view",
    "ViewerUnavailable",
    "recording_stream",
    "spawn_recording",
    "write_discovery_recording",
    "write_recording",
]
