# The public face of calbench.bench.model: what code outside this room may import. At run time
# calbench.bench.core.face reads these lines and loads each name on first use.

from .description import DescriptionError, read_description, set_spec_names, spec_names
from .geoms import GeomShape, ReflectorPost, geom_shapes, reflector_posts, tendon_sites
from .loading import LOG_KEY, MODEL_FLAG, load_robot, log_robot
from .loop import (
    LOOP_TOL,
    constraint_basis,
    constraint_basis_stack,
    loop_gap,
    loop_jacobian,
    motor_forces,
    motor_jacobian,
    motor_jacobians,
)
from .params import (
    COMPLIANCE_UNIT,
    LEGACY_COMPENSATOR,
    MAX_COMPLIANCE,
    ParamLayout,
    Params,
    Spring,
    display_name,
    free_length_note,
    springs_from_message,
)
from .robot import LOOP_MARGIN, LOOP_MARGIN_ANGLE, Robot, ancestors

__all__ = [
    "LOG_KEY",
    "MODEL_FLAG",
    "load_robot",
    "log_robot",
    "display_name",
    "free_length_note",
    "DescriptionError",
    "GeomShape",
    "LEGACY_COMPENSATOR",
    "LOOP_MARGIN",
    "LOOP_MARGIN_ANGLE",
    "LOOP_TOL",
    "MAX_COMPLIANCE",
    "ParamLayout",
    "COMPLIANCE_UNIT",
    "Params",
    "ReflectorPost",
    "Robot",
    "Spring",
    "ancestors",
    "constraint_basis",
    "constraint_basis_stack",
    "geom_shapes",
    "loop_gap",
    "loop_jacobian",
    "motor_forces",
    "motor_jacobian",
    "motor_jacobians",
    "read_description",
    "reflector_posts",
    "set_spec_names",
    "spec_names",
    "springs_from_message",
    "tendon_sites",
]
