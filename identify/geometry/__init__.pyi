# The public face of calbench.identify.geometry: what code outside this room may import. At run time
# calbench.bench.core.face reads these lines and loads each name on first use.

from .chain import GRAVITY, UR10_DH, UR10_JOINTS, Chain, gravity_torques, rot, translation, ur10
from .fit import (
    MODELS,
    PRIORITY,
    GeometryFit,
    Validation,
    base_set,
    calibrate,
    extend_base,
    in_priority,
    initial_model,
    refresh_torques,
    split,
    tool_from_transform,
    validate,
)
from .mjcf import Arm, chain_from_mjcf, chain_mjcf, load_arm, write_chain_mjcf
from .model import GeometricModel, kind, parameter_names
from .run import AbsoluteReadings, absolute_readings, format_geometry, geometry_json, run_geometry

__all__ = [
    "AbsoluteReadings",
    "Arm",
    "GRAVITY",
    "MODELS",
    "PRIORITY",
    "UR10_DH",
    "UR10_JOINTS",
    "Chain",
    "GeometricModel",
    "GeometryFit",
    "Validation",
    "absolute_readings",
    "base_set",
    "calibrate",
    "chain_from_mjcf",
    "chain_mjcf",
    "extend_base",
    "format_geometry",
    "geometry_json",
    "gravity_torques",
    "in_priority",
    "initial_model",
    "kind",
    "load_arm",
    "parameter_names",
    "refresh_torques",
    "rot",
    "run_geometry",
    "split",
    "tool_from_transform",
    "translation",
    "ur10",
    "validate",
    "write_chain_mjcf",
]
