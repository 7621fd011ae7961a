"""The campaign log's topics and their JSON Schemas, and the one validator of messages.

Every channel of the log is ``message_encoding="json"`` with a real ``jsonschema`` schema (types,
required fields, array lengths), so any MCAP reader can decode it without calbench. The same
schemas are checked twice here: by the writer before a message is written
(bench/log/writer.py) and by the reader on every message it decodes (bench/log/read.py), which
therefore never computes with a message its schema rejects.

:func:`problems` returns structured findings (the field, what was expected, what was found) so the
reader can name the topic, the pose and the field in one line; :func:`validate` is the same as
text. Numbers must be finite: JSON has no NaN or Infinity, and a reader that accepts Python's
``NaN``/``Infinity`` literals would compute with them.

Units: SI throughout (m, rad, N, N*m; covariances in m^2).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from .records import STATES

TRUTH_PREFIX = "/truth/"
GROUND_TRUTH_METADATA = "ground_truth"
SCENARIO_METADATA = "scenario"
REQUIRED_TOPICS = ("/campaign/info", "/campaign/pose", "/campaign/wrench", "/tracker/measurement")

# ---------------------------------------------------------------------------------------------
# JSON Schemas, one per topic (draft 2020-12 subset: type, required, properties, items,
# minItems, maxItems, enum). Exposed so tools and tests can validate messages independently.
# ---------------------------------------------------------------------------------------------


def _num_array(n: int | None, desc: str = "") -> dict:
    """Schema of a fixed-length (n given) or free-length array of numbers."""
    s: dict[str, Any] = {"type": "array", "items": {"type": "number"}}
    if n is not None:
        s["minItems"] = n
        s["maxItems"] = n
    else:
        s["minItems"] = 1
    if desc:
        s["description"] = desc
    return s


def _obj(props: dict, required: Sequence[str] | None = None, title: str = "") -> dict:
    s: dict[str, Any] = {
        "type": "object",
        "properties": props,
        "required": list(props if required is None else required),
    }
    if title:
        s = {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": title, **s}
    return s


_POSE = {"type": "integer", "minimum": 0, "description": "pose index in the plan"}
_STATE = {"type": "string", "enum": list(STATES)}
_NAMES = {"type": "array", "items": {"type": "string"}}
_MAT3 = {"type": "array", "minItems": 3, "maxItems": 3, "items": _num_array(3)}
_SPRING = _obj(
    {"stiffness": {"type": "number", "description": "N/m"}, "preload": {"type": "number", "description": "m"}}
)

SCHEMAS: dict[str, dict] = {
    "/campaign/info": _obj(
        {
            "scenario_name": {"type": "string"},
            "robot": {"type": "string", "description": "MJCF file name"},
            "n_poses": {"type": "integer", "minimum": 0},
            "reflectors": _NAMES,
            "payload_site": {"type": "string"},
            "tracker": _obj(
                {
                    "position": _num_array(3, "m, world frame"),
                    "yaw": {"type": "number", "description": "rad about world z"},
                    "model": {"type": "string"},
                    "sigma": {"type": "number", "description": "m, per axis"},
                    "distance": _num_array(2, "ISO 10360-10 style [a m, b m/m]"),
                    "transverse": _num_array(2, "ISO 10360-10 style [a m, b m/m]"),
                    "rotation": {
                        "type": "array",
                        "minItems": 3,
                        "maxItems": 3,
                        "items": _num_array(3),
                        "description": "world-from-tracker rotation matrix, when the tracker was "
                        "registered (any orientation); yaw is then its heading",
                    },
                    "random": {
                        "type": "number",
                        "description": "iso10360: share of the 1-sigma that is independent noise",
                    },
                    "correlation_angle": {"type": "number", "description": "iso10360: rad"},
                    "correlation_range": {"type": "number", "description": "iso10360: m"},
                    "drift": _num_array(2, "iso10360: [a m, b m/m] per sqrt(hour)"),
                },
                required=("position", "yaw", "model", "sigma", "distance", "transverse"),
            ),
            "seed": {"type": "integer"},
            "calbench_version": {"type": "string"},
            "robot_sha256": {
                "type": "string",
                "description": "SHA-256 (hex) of the robot MJCF attachment, as written",
            },
            "n_joints": {
                "type": "integer",
                "minimum": 1,
                "description": "actuated joints: the length of every q and deflection",
            },
            "imported": {
                "type": "object",
                "description": "present when the log was made by "
                "`calbench import` from real readings: file, units, registration",
            },
        },
        required=(
            "scenario_name",
            "robot",
            "n_poses",
            "reflectors",
            "payload_site",
            "tracker",
            "seed",
            "calbench_version",
        ),
        title="calbench.CampaignInfo",
    ),
    "/campaign/pose": _obj(
        {
            "pose": _POSE,
            "state": _STATE,
            "q": _num_array(None, "rad, commanded, one per actuated joint (calbench:actuated order)"),
        },
        title="calbench.Pose",
    ),
    "/campaign/wrench": _obj(
        {
            "pose": _POSE,
            "state": {"type": "string", "enum": ["loaded"]},
            "force": _num_array(3, "N, world frame"),
            "moment": _num_array(3, "N*m, world frame"),
            "site": {"type": "string", "description": "MJCF site where the wrench is applied"},
            "mass": {"type": ["number", "null"], "description": "kg, hanging payload, or null"},
        },
        title="calbench.Wrench",
    ),
    "/tracker/measurement": _obj(
        {
            "pose": _POSE,
            "state": _STATE,
            "repeat": {"type": "integer", "minimum": 0},
            "reflectors": _NAMES,
            "position": {
                "type": "array",
                "items": {**_num_array(3), "type": ["array", "null"]},
                "description": "m, tracker frame; null when not visible",
            },
            "covariance": {
                "type": "array",
                "items": {**_MAT3, "type": ["array", "null"]},
                "description": "m^2; null when not visible",
            },
            "visible": {"type": "array", "items": {"type": "boolean"}},
        },
        title="calbench.TrackerMeasurement",
    ),
    "/campaign/pose_done": _obj({"pose": _POSE}, title="calbench.PoseDone"),
    "/truth/parameters": _obj(
        {
            "compliance": _num_array(None, "rad/(N*m), one per actuated joint"),
            "compensator": _SPRING,
            "compensators": {
                "type": "object",
                "additionalProperties": _SPRING,
                "description": "compensator tendons other than 'compensator', by name",
            },
            "effects": {"type": "object"},
        },
        required=("compliance", "effects"),
        title="calbench.TruthParameters",
    ),
    "/truth/reflectors": _obj(
        {
            "pose": _POSE,
            "state": _STATE,
            "reflectors": _NAMES,
            "position_world": {"type": "array", "items": _num_array(3), "description": "m"},
        },
        title="calbench.TruthReflectors",
    ),
    "/truth/joints": _obj(
        {
            "pose": _POSE,
            "state": _STATE,
            "qpos": _num_array(None, "full MuJoCo qpos at equilibrium"),
            "deflection": _num_array(
                None, "rad, motor-space deflection from the command, per actuated joint"
            ),
        },
        title="calbench.TruthJoints",
    ),
}
TOPICS = tuple(SCHEMAS)


# ---------------------------------------------------------------------------------------------
# validation (the subset the schemas above use)
# ---------------------------------------------------------------------------------------------

_JSON_TYPES = {
    "object": lambda v: isinstance(v, dict),
    "array": lambda v: isinstance(v, list),
    "string": lambda v: isinstance(v, str),
    "boolean": lambda v: isinstance(v, bool),
    "null": lambda v: v is None,
    "integer": lambda v: isinstance(v, int) and not isinstance(v, bool),
    "number": lambda v: isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v),
}
_TYPE_WORDS = {
    "object": "an object",
    "array": "an array",
    "string": "a string",
    "boolean": "true or false",
    "null": "null",
    "integer": "an integer",
    "number": "a finite number",
}


@dataclass(frozen=True)
class Problem:
    """One way a message breaks its schema: ``field`` is a path like ``position[0][2]`` (empty
    for the message itself), ``expected`` says what the schema wants, ``got`` what is there."""

    field: str
    expected: str
    got: Any = None

    def __str__(self) -> str:
        where = "$" + ("" if not self.field or self.field.startswith("[") else ".") + self.field
        return f"{where}: expected {self.expected}, got {self.got!r}"


def _got(v: Any) -> Any:
    """What a problem reports as found: the value itself when short, else its kind."""
    if isinstance(v, (dict, list)):
        return f"{'an object' if isinstance(v, dict) else 'an array'} of {len(v)}"
    if isinstance(v, str) and len(v) > 40:
        return v[:37] + "..."
    return v


def problems(instance: Any, schema: dict, where: str = "") -> list[Problem]:
    """Every problem of ``instance`` against ``schema`` (empty: valid). Supports type (and type
    lists), enum, minimum, required, properties, additionalProperties (a schema), items,
    minItems, maxItems. A valid message (nearly all of them) is recognised by the schema's
    compiled check (:func:`checker`) without building any finding."""
    if not where and checker(schema)(instance):
        return []
    return findings(instance, schema, where)


def findings(instance: Any, schema: dict, where: str = "") -> list[Problem]:
    """:func:`problems` by walking the schema: the slow path that names every field."""

    def sub(key) -> str:
        return f"{where}[{key}]" if isinstance(key, int) else (f"{where}.{key}" if where else key)

    types = schema.get("type")
    if types is not None:
        tl = [types] if isinstance(types, str) else list(types)
        if not any(_JSON_TYPES[t](instance) for t in tl):
            return [Problem(where, " or ".join(_TYPE_WORDS[t] for t in tl), _got(instance))]
    errs: list[Problem] = []
    if "enum" in schema and instance not in schema["enum"]:
        errs.append(Problem(where, "one of " + ", ".join(map(repr, schema["enum"])), _got(instance)))
    if "minimum" in schema and _JSON_TYPES["number"](instance) and instance < schema["minimum"]:
        errs.append(Problem(where, f"a number >= {schema['minimum']}", instance))
    if isinstance(instance, dict):
        for k in schema.get("required", []):
            if k not in instance:
                errs.append(Problem(sub(k), "this required field", "nothing"))
        for k, s in schema.get("properties", {}).items():
            if k in instance:
                errs += findings(instance[k], s, sub(k))
        extra = schema.get("additionalProperties")
        if isinstance(extra, dict):
            for k, v in instance.items():
                if k not in schema.get("properties", {}):
                    errs += findings(v, extra, sub(k))
    if isinstance(instance, list):
        lo, hi = schema.get("minItems"), schema.get("maxItems")
        if (lo is not None and len(instance) < lo) or (hi is not None and len(instance) > hi):
            n = f"{lo}" if lo == hi else f"{lo or 0}..{hi if hi is not None else ''}"
            errs.append(Problem(where, f"{n} items", f"{len(instance)} items"))
        if "items" in schema:
            for i, v in enumerate(instance):
                errs += findings(v, schema["items"], sub(i))
    return errs


# --------------------------------------------------------------------------- compiled checks
#
# The same rules as :func:`findings`, compiled once per schema into nested closures that only
# say valid or not: a log of millions of readings is checked by the writer and again by the
# reader, and walking the schema dict per value cost ~0.25 ms per reading (a 10^6-row import
# spent 2/3 of its time there). A message the check refuses goes to :func:`findings`, which
# names the field; tests/test_logformat.py holds the two to the same verdict on mutated messages.

_COMPILED: dict[int, tuple[dict, Any]] = {}  # id(schema) -> (the schema, kept alive; its check)


def _finite_number(v: Any) -> bool:
    t = type(v)
    return (
        (t is float and math.isfinite(v))
        or t is int
        or (t is not bool and isinstance(v, (int, float)) and math.isfinite(v))
    )


def _compile(schema: dict):
    """The check of one schema node: only the keywords it has, each a closure."""
    checks = []
    types = schema.get("type")
    if types is not None:
        tl = [types] if isinstance(types, str) else list(types)
        if tl == ["number"]:
            checks.append(_finite_number)
        elif len(tl) == 1:
            checks.append(_JSON_TYPES[tl[0]])
        else:
            f0, f1, *more = [_JSON_TYPES[t] for t in tl]
            checks.append(lambda v: f0(v) or f1(v) or any(f(v) for f in more))
    if "enum" in schema:
        enum = schema["enum"]
        checks.append(lambda v: v in enum)
    if "minimum" in schema:
        minimum = schema["minimum"]
        checks.append(lambda v: not _JSON_TYPES["number"](v) or v >= minimum)
    required = tuple(schema.get("required", ()))
    props = [(k, _compile(s)) for k, s in schema.get("properties", {}).items()]
    extra = schema.get("additionalProperties")
    if required or props or isinstance(extra, dict):
        names = set(schema.get("properties", {}))
        extra_ok = _compile(extra) if isinstance(extra, dict) else None

        def obj(v: Any) -> bool:
            if not isinstance(v, dict):
                return True
            for k in required:
                if k not in v:
                    return False
            for k, f in props:
                if k in v and not f(v[k]):
                    return False
            return extra_ok is None or all(extra_ok(x) for k, x in v.items() if k not in names)

        checks.append(obj)
    lo, hi = schema.get("minItems"), schema.get("maxItems")
    items = schema.get("items")
    if lo is not None or hi is not None or items is not None:
        lo_, hi_ = 0 if lo is None else lo, float("inf") if hi is None else hi
        if items is None:
            each = None
        elif set(items) <= {"type", "description"} and items.get("type") == "number":
            each = _finite_number  # a list of finite numbers
        else:
            each = _compile(items)

        def arr(v: Any) -> bool:
            if not isinstance(v, list):
                return True
            return lo_ <= len(v) <= hi_ and (each is None or all(map(each, v)))

        checks.append(arr)
    if len(checks) <= 1:
        return checks[0] if checks else (lambda v: True)
    c0, c1, *rest = checks
    if not rest:
        return lambda v: c0(v) and c1(v)
    return lambda v: c0(v) and c1(v) and all(f(v) for f in rest)


def checker(schema: dict):
    """``schema`` compiled into a function ``instance -> bool``: True exactly when
    :func:`problems` finds nothing (cached per schema object)."""
    hit = _COMPILED.get(id(schema))
    if hit is None or hit[0] is not schema:
        hit = _COMPILED[id(schema)] = (schema, _compile(schema))
    return hit[1]


def validate(instance: Any, schema: dict) -> list[str]:
    """Problems of ``instance`` against ``schema`` as text (empty list: valid)."""
    return [str(p) for p in problems(instance, schema)]


__all__ = [
    "TRUTH_PREFIX",
    "GROUND_TRUTH_METADATA",
    "SCENARIO_METADATA",
    "REQUIRED_TOPICS",
    "SCHEMAS",
    "TOPICS",
    "Problem",
    "problems",
    "checker",
    "findings",
    "validate",
]
