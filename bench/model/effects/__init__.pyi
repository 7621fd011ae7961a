# The public face of calbench.bench.model.effects: what code outside this room may import. At run
# time calbench.bench.core.face reads these lines and loads each name on first use. The effects
# themselves are found by registry.py (every module here registers its own), not through this face.

from .apply import EffectRobot, apply_effects, augmented_xml, load_spec
from .base import UNIT_PRIORS, Effect, Field, ObservationRows, Prior, read_table
from .base_tilt import base_compliance
from .cubic_drive import joint_nonlinearity
from .drift import tracker_drift
from .edits import RIGID_COMPLIANCE
from .geometric import (
    base_frame,
    body_quat,
    frame_error,
    joint_offset,
    link_geometry,
    tool_frame,
    turned_frame,
)
from .link_springs import link_compliance
from .registry import (
    DISCOVERY_OPTIONS,
    GEOMETRY_OPTIONS,
    REGISTRY,
    TRUTH_SCHEMAS,
    discovery_library,
    effect_from_truth,
    priors,
    register_effect,
    unregister_effect,
)
from .spring_compensator import compensator, without_compensator
from .tool_mount import tool_compliance

__all__ = [
    "DISCOVERY_OPTIONS",
    "Effect",
    "EffectRobot",
    "Field",
    "GEOMETRY_OPTIONS",
    "Prior",
    "REGISTRY",
    "RIGID_COMPLIANCE",
    "ObservationRows",
    "TRUTH_SCHEMAS",
    "UNIT_PRIORS",
    "apply_effects",
    "augmented_xml",
    "base_compliance",
    "compensator",
    "discovery_library",
    "effect_from_truth",
    "joint_nonlinearity",
    "link_compliance",
    "load_spec",
    "priors",
    "read_table",
    "register_effect",
    "base_frame",
    "body_quat",
    "frame_error",
    "joint_offset",
    "link_geometry",
    "tool_compliance",
    "tool_frame",
    "turned_frame",
    "tracker_drift",
    "unregister_effect",
    "without_compensator",
]
