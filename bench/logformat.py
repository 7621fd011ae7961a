"""The campaign log: one MCAP file of JSON messages, each topic with a JSON Schema.

Why this format
---------------
* Any MCAP reader (Foxglove, ``rerun mcap``, the ``mcap`` CLI) can open and decode the log
  without this project: every channel is ``message_encoding="json"`` with a real
  ``jsonschema`` schema (types, required fields, array lengths).
* Ground truth lives only on topics beginning with :data:`TRUTH_PREFIX` plus one metadata
  record named ``ground_truth`` (docs/contract.md, "MCAP log"). :func:`strip_truth` removes exactly
  those and leaves what a real campaign would have recorded. The scenario TOML carries the
  ``[truth]`` tables, so the copy stored in the non-truth part of the log has them removed
  (:func:`redact_truth`); the original text goes into the ``ground_truth`` record.
* Crash tolerance: chunks are small and :meth:`LogWriter.pose_done` closes the chunk in progress,
  so a campaign killed mid-way leaves a file whose complete poses are readable with a
  non-seeking reader. :func:`read_log` keeps only poses that carry a ``/campaign/pose_done``
  marker.
* Determinism: log times are synthetic (derived from pose, state and repeat), attachments carry
  time 0 and the MCAP header names the library versions only, so the same scenario and seed
  give a byte-identical file. The mcap ``Writer`` itself reads no clock (checked in mcap 1.6:
  only ``start(library=...)`` stores a free-form string, which we set ourselves).

Units: SI throughout (m, rad, N, N*m; covariances in m^2).
"""
from __future__ import annotations

import json
import math
import os
import re
import struct
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator, Mapping, Sequence

import numpy as np
from mcap.exceptions import McapError
from mcap.records import Attachment, Channel, Footer, Header, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from .campaignlog import (STATES, CampaignLog, CampaignTruth, MeasurementRecord, PerState,
                          TruthJoints, TruthParameters, TruthReflectors, WrenchRecord)
from .errors import InputError

TRUTH_PREFIX = "/truth/"
GROUND_TRUTH_METADATA = "ground_truth"
SCENARIO_METADATA = "scenario"
REQUIRED_TOPICS = ("/campaign/info", "/campaign/pose", "/tracker/measurement")
MCAP_MAGIC = b"\x89MCAP0\r\n"
_MAGIC_TEXT = "an MCAP file (magic bytes 89 4D 43 41 50 30 0D 0A)"

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
    s: dict[str, Any] = {"type": "object", "properties": props,
                         "required": list(props if required is None else required)}
    if title:
        s = {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": title, **s}
    return s


_POSE = {"type": "integer", "minimum": 0, "description": "pose index in the plan"}
_STATE = {"type": "string", "enum": list(STATES)}
_NAMES = {"type": "array", "items": {"type": "string"}}
_MAT3 = {"type": "array", "minItems": 3, "maxItems": 3, "items": _num_array(3)}
_SPRING = _obj({"stiffness": {"type": "number", "description": "N/m"},
                "preload": {"type": "number", "description": "m"}})

SCHEMAS: dict[str, dict] = {
    "/campaign/info": _obj({
        "scenario_name": {"type": "string"},
        "robot": {"type": "string", "description": "MJCF file name"},
        "n_poses": {"type": "integer", "minimum": 0},
        "reflectors": _NAMES,
        "payload_site": {"type": "string"},
        "tracker": _obj({
            "position": _num_array(3, "m, world frame"),
            "yaw": {"type": "number", "description": "rad about world z"},
            "model": {"type": "string"},
            "sigma": {"type": "number", "description": "m, per axis"},
            "distance": _num_array(2, "ISO 10360-10 style [a m, b m/m]"),
            "transverse": _num_array(2, "ISO 10360-10 style [a m, b m/m]"),
        }),
        "seed": {"type": "integer"},
        "calbench_version": {"type": "string"},
        "imported": {"type": "object", "description": "present when the log was made by "
                     "`calbench import` from real readings: file, units, registration"},
    }, required=("scenario_name", "robot", "n_poses", "reflectors", "payload_site", "tracker",
                 "seed", "calbench_version"), title="calbench.CampaignInfo"),
    "/campaign/pose": _obj({
        "pose": _POSE, "state": _STATE,
        "q": _num_array(None, "rad, commanded, one per actuated joint (calbench:actuated order)"),
    }, title="calbench.Pose"),
    "/campaign/wrench": _obj({
        "pose": _POSE,
        "state": {"type": "string", "enum": ["loaded"]},
        "force": _num_array(3, "N, world frame"),
        "moment": _num_array(3, "N*m, world frame"),
        "site": {"type": "string", "description": "MJCF site where the wrench is applied"},
        "mass": {"type": ["number", "null"], "description": "kg, hanging payload, or null"},
    }, title="calbench.Wrench"),
    "/tracker/measurement": _obj({
        "pose": _POSE, "state": _STATE,
        "repeat": {"type": "integer", "minimum": 0},
        "reflectors": _NAMES,
        "position": {"type": "array", "items": {**_num_array(3), "type": ["array", "null"]},
                     "description": "m, tracker frame; null when not visible"},
        "covariance": {"type": "array", "items": {**_MAT3, "type": ["array", "null"]},
                       "description": "m^2; null when not visible"},
        "visible": {"type": "array", "items": {"type": "boolean"}},
    }, title="calbench.TrackerMeasurement"),
    "/campaign/pose_done": _obj({"pose": _POSE}, title="calbench.PoseDone"),
    "/truth/parameters": _obj({
        "compliance": _num_array(None, "rad/(N*m), one per actuated joint"),
        "compensator": _SPRING,
        "compensators": {"type": "object", "additionalProperties": _SPRING,
                         "description": "compensator tendons other than 'compensator', by name"},
        "effects": {"type": "object"},
    }, required=("compliance", "effects"), title="calbench.TruthParameters"),
    "/truth/reflectors": _obj({
        "pose": _POSE, "state": _STATE, "reflectors": _NAMES,
        "position_world": {"type": "array", "items": _num_array(3), "description": "m"},
    }, title="calbench.TruthReflectors"),
    "/truth/joints": _obj({
        "pose": _POSE, "state": _STATE,
        "qpos": _num_array(None, "full MuJoCo qpos at equilibrium"),
        "deflection": _num_array(None, "rad, motor-space deflection from the command, per actuated joint"),
    }, title="calbench.TruthJoints"),
}
TOPICS = tuple(SCHEMAS)


# ---------------------------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------------------------


def _version() -> str:
    try:
        from importlib.metadata import version
        return version("calbench")
    except Exception:  # not installed (running from a checkout)
        return "0.0.0"


def _mcap_version() -> str:
    try:
        from importlib.metadata import version
        return version("mcap")
    except Exception:
        return "unknown"


def _floats(x: Any, shape: tuple[int, ...] | None, what: str) -> np.ndarray:
    """``x`` as a finite float64 array of the given shape (None: 1-D, any length)."""
    a = np.asarray(x, dtype=float)
    if shape is None:
        if a.ndim != 1 or a.size == 0:
            raise ValueError(f"{what}: expected a non-empty 1-D array, got shape {a.shape}")
    elif a.shape != shape:
        raise ValueError(f"{what}: expected shape {shape}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{what}: non-finite value in {a.tolist()}")
    return a


def _list(a: np.ndarray) -> list:
    """numpy array -> nested list of Python floats (json-serialisable, exact repr)."""
    return a.tolist()


def _state(state: str) -> str:
    if state not in STATES:
        raise ValueError(f"state must be one of {STATES}, got {state!r}")
    return state


def _pose_index(pose: Any) -> int:
    if isinstance(pose, bool) or int(pose) != pose or pose < 0:
        raise ValueError(f"pose must be a non-negative integer, got {pose!r}")
    return int(pose)


_HEADER_RE = re.compile(r"^\s*\[\[?\s*([^\[\]#]+?)\s*\]\]?\s*(#.*)?$")
_TRUTH_KEY_RE = re.compile(r"""^\s*(truth|"truth"|'truth')\s*(\.|=)""")


def redact_truth(scenario_text: str) -> str:
    """The scenario TOML without its ``[truth]`` / ``[truth.*]`` tables and top-level
    ``truth...`` keys, so that the scenario stored openly in the log reveals no ground truth.

    Line-based (comments and layout of the rest are kept); the result is checked by parsing
    both texts: it must equal the original minus its ``truth`` key. If that check fails (exotic
    TOML layout) the scenario is replaced by a comment rather than risk leaking the truth.
    """
    out: list[str] = []
    in_truth = False      # inside a [truth...] table
    at_top = True         # before the first table header (top-level keys)
    skipping_value = False  # skipping continuation lines of a multi-line top-level truth value
    depth = 0
    for line in scenario_text.splitlines(keepends=True):
        if skipping_value:
            depth += line.count("[") + line.count("{") - line.count("]") - line.count("}")
            if depth <= 0:
                skipping_value = False
            continue
        m = _HEADER_RE.match(line)
        if m and "=" not in line.split("#", 1)[0]:
            name = m.group(1).strip().strip("\"'")
            in_truth = name == "truth" or name.startswith(("truth.", '"truth".', "'truth'."))
            at_top = False
            if in_truth:
                continue
        elif in_truth:
            continue
        elif at_top and _TRUTH_KEY_RE.match(line):
            value = line.split("=", 1)[1] if "=" in line else ""
            depth = value.count("[") + value.count("{") - value.count("]") - value.count("}")
            skipping_value = depth > 0
            continue
        out.append(line)
    redacted = "".join(out)
    try:
        orig = tomllib.loads(scenario_text)
        orig.pop("truth", None)
        ok = tomllib.loads(redacted) == orig
    except tomllib.TOMLDecodeError:
        ok = False
    if not ok:
        return "# scenario text withheld: its [truth] tables could not be removed safely\n"
    return redacted


# ---------------------------------------------------------------------------------------------
# writer
# ---------------------------------------------------------------------------------------------


@dataclass
class LogHeader:
    """What the campaign knows before the first pose; becomes ``/campaign/info``, the
    ``scenario`` metadata and the two attachments.

    ``mjcf_text`` must be the robot model file the scenario names (the nominal model), not a
    model with the true parameters applied. ``tracker`` needs the keys of the
    ``/campaign/info`` schema (position [3] m, yaw rad, model, sigma m, distance [2],
    transverse [2]); extra keys are kept. ``n_poses`` (an addition to the brief) defaults to
    the number of ``[[pose]]`` entries of the scenario. ``imported`` (a log made by
    ``calbench import``) says from which file and with which registration. ``n_joints``, the
    robot's number of actuated joints, fixes the length of every q and deflection written
    (None: any length).
    """

    scenario_name: str
    scenario_text: str
    scenario_filename: str
    robot_filename: str
    mjcf_text: str
    reflectors: list[str]
    payload_site: str
    tracker: dict
    seed: int
    n_poses: int | None = None
    imported: dict | None = None
    n_joints: int | None = None

    def planned_poses(self) -> int:
        """Number of poses planned: ``n_poses`` or the scenario's ``[[pose]]`` count."""
        if self.n_poses is not None:
            return int(self.n_poses)
        try:
            return len(tomllib.loads(self.scenario_text).get("pose", []))
        except tomllib.TOMLDecodeError:
            return 0


def _time(pose: int | None, state: str | None = None, repeat: int | None = None,
          slot: int = 0) -> int:
    """Synthetic log time in ns: pose (p+1) s, state 0/100 ms, repeat (r+1) ms, slot ns.

    Deterministic by construction; the writer additionally keeps times strictly increasing.
    """
    if pose is None:
        return slot
    t = (pose + 1) * 1_000_000_000
    if state is not None:
        t += STATES.index(state) * 100_000_000
    if repeat is not None:
        t += (repeat + 1) * 1_000_000
    return t + slot


class LogWriter:
    """Writes one campaign log. Use as a context manager.

    Chunks are ``chunk_size`` bytes at most (small, default 16 KiB) and every
    :meth:`pose_done` ends the chunk in progress, so a crash loses at most the pose being
    measured. Each message is checked against its topic's schema before it is written, so a
    log never holds a message its own schema rejects.
    """

    def __init__(self, path: str | os.PathLike, header: LogHeader, chunk_size: int = 16 * 1024):
        self.path = Path(path)
        self._header = header
        self._last_time = -1
        self._seq: dict[str, int] = {}
        self._truth_params: dict | None = None
        self._joints = None if header.n_joints is None else (int(header.n_joints),)
        self._closed = True  # until the file is open
        h = header
        info = {
            "scenario_name": str(h.scenario_name),
            "robot": str(h.robot_filename),
            "n_poses": h.planned_poses(),
            "reflectors": [str(r) for r in h.reflectors],
            "payload_site": str(h.payload_site),
            "tracker": _jsonable(h.tracker),
            "seed": int(h.seed),
            "calbench_version": _version(),
        }
        if h.imported is not None:
            info["imported"] = _jsonable(h.imported)
        problems = validate(info, SCHEMAS["/campaign/info"])
        if problems:  # checked before the file is created, so a bad header leaves no file
            raise ValueError(f"/campaign/info: header does not match its schema: {problems}")
        public_scenario = redact_truth(h.scenario_text)
        self._file = open(self.path, "wb")
        self._closed = False
        self._writer = Writer(self._file, chunk_size=chunk_size,
                              compression=CompressionType.ZSTD)
        # The library string is the only free-form header field; mcap would put its own
        # version there. Ours names both versions and nothing time- or host-dependent.
        self._writer.start(profile="",
                           library=f"calbench/{_version()}; mcap-python/{_mcap_version()}")
        self._channels: dict[str, int] = {}
        self._extra_schemas: dict[str, dict] = {}
        self._schema_ids: dict[tuple[str, bytes], int] = {}
        for topic, schema in SCHEMAS.items():
            sid = self._writer.register_schema(
                name=schema["title"], encoding="jsonschema",
                data=json.dumps(schema, sort_keys=True).encode())
            self._channels[topic] = self._writer.register_channel(
                topic=topic, message_encoding="json", schema_id=sid)

        self._write("/campaign/info", info, _time(None, slot=0))
        self._writer.add_metadata(SCENARIO_METADATA,
                                  {"name": str(h.scenario_name), "text": public_scenario})
        self._writer.add_attachment(create_time=0, log_time=0,
                                    name=Path(h.scenario_filename).name,
                                    media_type="application/toml",
                                    data=public_scenario.encode())
        self._writer.add_attachment(create_time=0, log_time=0,
                                    name=Path(h.robot_filename).name,
                                    media_type="application/xml",
                                    data=h.mjcf_text.encode())
        self._sync()  # schemas, channels and info durable before the first pose

    # -- context manager ---------------------------------------------------------------------
    def __enter__(self) -> "LogWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self._abandon()

    # -- messages ----------------------------------------------------------------------------
    def _write(self, topic: str, msg: dict, nominal_time: int) -> None:
        if self._closed:
            raise RuntimeError(f"{self.path}: log already closed")
        problems = validate(msg, SCHEMAS.get(topic) or self._extra_schemas[topic])
        if problems:
            raise ValueError(f"{topic}: message does not match its schema: {problems}")
        t = max(nominal_time, self._last_time + 1)  # strictly increasing, still deterministic
        self._last_time = t
        seq = self._seq.get(topic, 0)
        self._seq[topic] = seq + 1
        data = json.dumps(msg, allow_nan=False, separators=(",", ":")).encode()
        self._writer.add_message(channel_id=self._channels[topic], log_time=t, data=data,
                                 publish_time=t, sequence=seq)

    # -- extra channels (the Foxglove topics of bench/foxglove.py) ----------------------------
    def add_channel(self, topic: str, schema_name: str, schema_text: str,
                    check: bool = True) -> None:
        """Register one more JSON channel whose messages follow the JSON Schema ``schema_text``
        (registered under ``schema_name``; channels with the same schema share one record).
        Contract topics cannot be re-registered. A topic under /truth/ is ground truth and
        :func:`strip_truth` removes it like the others. ``check=False`` skips the per-message
        check of :meth:`write`, for builders whose output a test validates instead."""
        if topic in self._channels:
            raise ValueError(f"{topic}: channel already registered")
        schema = json.loads(schema_text)
        data = json.dumps(schema, separators=(",", ":")).encode()
        sid = self._schema_ids.get((schema_name, data))
        if sid is None:
            sid = self._schema_ids[(schema_name, data)] = self._writer.register_schema(
                name=schema_name, encoding="jsonschema", data=data)
        self._channels[topic] = self._writer.register_channel(
            topic=topic, message_encoding="json", schema_id=sid)
        self._extra_schemas[topic] = schema if check else {}

    def next_time(self, nominal_time: int) -> int:
        """The log time (ns) a message written now at ``nominal_time`` gets: times are kept
        strictly increasing, so a message may carry its own log time (Foxglove stamps)."""
        return max(int(nominal_time), self._last_time + 1)

    def write(self, topic: str, msg: dict, log_time: int) -> None:
        """Write ``msg`` on a channel of :meth:`add_channel` at ``log_time`` (from
        :meth:`next_time`), after checking it against the channel's schema."""
        if topic not in self._extra_schemas:
            raise ValueError(f"{topic}: not an extra channel (add_channel first)")
        if self.next_time(log_time) != log_time:
            raise ValueError(f"{topic}: log time {log_time} is not after {self._last_time}")
        self._write(topic, msg, log_time)

    def pose(self, pose: int, state: str, q) -> None:
        """Commanded joint angles (rad, controller convention) of one pose and load state."""
        p, s = _pose_index(pose), _state(state)
        self._write("/campaign/pose",
                    {"pose": p, "state": s, "q": _list(_floats(q, self._joints, "q"))}, _time(p, s))

    def wrench(self, pose: int, force, moment, site: str, mass: float | None) -> None:
        """The load of the loaded state: force (N) and moment (N*m) in the world frame,
        applied at MJCF ``site``; ``mass`` (kg) when it is a hanging payload, else None."""
        p = _pose_index(pose)
        self._write("/campaign/wrench", {
            "pose": p, "state": "loaded",
            "force": _list(_floats(force, (3,), "force")),
            "moment": _list(_floats(moment, (3,), "moment")),
            "site": str(site),
            "mass": None if mass is None else float(mass),
        }, _time(p, "loaded", slot=1))

    def measurement(self, pose, state, repeat, reflectors, position, covariance,
                    visible) -> None:
        """One tracker reading of all reflectors: ``position`` (n,3) m in the tracker frame,
        NaN rows (or anything) where ``visible`` is False; ``covariance`` (n,3,3) m^2.
        Invisible reflectors are written as null."""
        p, s = _pose_index(pose), _state(state)
        r = _pose_index(repeat)
        names = [str(x) for x in reflectors]
        n = len(names)
        vis = np.asarray(visible, dtype=bool).reshape(-1)
        pos = np.asarray(position, dtype=float)
        cov = np.asarray(covariance, dtype=float)
        if vis.shape != (n,) or pos.shape != (n, 3) or cov.shape != (n, 3, 3):
            raise ValueError(f"measurement: expected visible ({n},), position ({n},3), "
                             f"covariance ({n},3,3); got {vis.shape}, {pos.shape}, {cov.shape}")
        pos_out: list = []
        cov_out: list = []
        for i in range(n):
            if vis[i]:
                pos_out.append(_list(_floats(pos[i], (3,), f"position[{names[i]}]")))
                cov_out.append(_list(_floats(cov[i], (3, 3), f"covariance[{names[i]}]")))
            else:
                pos_out.append(None)
                cov_out.append(None)
        self._write("/tracker/measurement", {
            "pose": p, "state": s, "repeat": r, "reflectors": names,
            "position": pos_out, "covariance": cov_out, "visible": [bool(v) for v in vis],
        }, _time(p, s, r))

    def truth_parameters(self, params: dict) -> None:
        """The simulated robot's true parameters (``/truth/parameters``); also written as the
        ``ground_truth`` metadata record when the log is closed."""
        msg = _jsonable(dict(params))
        msg.setdefault("effects", {})
        if self._joints is not None:
            _floats(msg.get("compliance"), self._joints, "compliance")
        self._write("/truth/parameters", msg, _time(None, slot=1))
        self._truth_params = msg

    def truth_reflectors(self, pose, state, reflectors, position_world) -> None:
        """True reflector positions (m, world frame) at the equilibrium of (pose, state)."""
        p, s = _pose_index(pose), _state(state)
        names = [str(x) for x in reflectors]
        pw = _floats(position_world, (len(names), 3), "position_world")
        self._write("/truth/reflectors", {"pose": p, "state": s, "reflectors": names,
                                          "position_world": _list(pw)},
                    _time(p, s, slot=90_000_000))

    def truth_joints(self, pose, state, qpos, deflection) -> None:
        """Full MuJoCo qpos at equilibrium and the motor-space deflection (rad, one per actuated
        joint) from the commanded angles."""
        p, s = _pose_index(pose), _state(state)
        self._write("/truth/joints", {
            "pose": p, "state": s, "qpos": _list(_floats(qpos, None, "qpos")),
            "deflection": _list(_floats(deflection, self._joints, "deflection")),
        }, _time(p, s, slot=91_000_000))

    def pose_done(self, pose: int) -> None:
        """Mark ``pose`` complete and make everything written so far durable.

        Chunk boundary: ``Writer.flush()`` (public in mcap >= 1.3) finalises the chunk in
        progress — compresses it, writes the Chunk record and its MessageIndex records — and
        flushes the stream; we then fsync. A reader of a file cut short later therefore sees
        this pose's marker and all its messages in complete chunks.
        """
        p = _pose_index(pose)
        self._write("/campaign/pose_done", {"pose": p}, _time(p, slot=900_000_000))
        self._sync()

    def _sync(self) -> None:
        flush = getattr(self._writer, "flush", None)
        if flush is not None:
            flush()
        else:  # mcap < 1.3 has no public flush: use the chunk finaliser it calls itself
            self._writer._Writer__finalize_chunk()  # type: ignore[attr-defined]
            self._writer._Writer__flush()  # type: ignore[attr-defined]
        self._file.flush()
        try:
            os.fsync(self._file.fileno())
        except OSError:  # e.g. a pipe or a file system without fsync
            pass

    def close(self) -> None:
        """Finish the file: ground_truth metadata (if truth was given), summary, footer.
        Calling it again does nothing."""
        if self._closed:
            return
        if self._truth_params is not None:
            self._writer.add_metadata(GROUND_TRUTH_METADATA, {
                "parameters": json.dumps(self._truth_params, sort_keys=True, allow_nan=False),
                "scenario_text": self._header.scenario_text,
            })
        self._writer.finish()
        self._closed = True
        self._file.close()

    def _abandon(self) -> None:
        """After an exception: keep the complete chunks already on disk, write what is buffered
        as one more chunk (its pose has no pose_done marker, so readers ignore it) and close
        the file without a footer, so it reads as truncated. Never raises."""
        if self._closed:
            return
        self._closed = True
        try:
            self._sync()
        except Exception:
            pass
        try:
            self._file.close()
        except Exception:
            pass


def _jsonable(x: Any) -> Any:
    """numpy scalars/arrays and tuples -> plain JSON types (recursively)."""
    if isinstance(x, Mapping):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.bool_):
        return bool(x)
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.floating):
        return float(x)
    return x


# ---------------------------------------------------------------------------------------------
# schema validation (the subset the schemas above use)
# ---------------------------------------------------------------------------------------------

_JSON_TYPES = {
    "object": lambda v: isinstance(v, dict),
    "array": lambda v: isinstance(v, list),
    "string": lambda v: isinstance(v, str),
    "boolean": lambda v: isinstance(v, bool),
    "null": lambda v: v is None,
    "integer": lambda v: isinstance(v, int) and not isinstance(v, bool),
    "number": lambda v: isinstance(v, (int, float)) and not isinstance(v, bool)
    and math.isfinite(v),
}


def validate(instance: Any, schema: dict, where: str = "$") -> list[str]:
    """Problems of ``instance`` against ``schema`` (empty list: valid). Supports type (and
    type lists), enum, minimum, required, properties, additionalProperties (a schema), items,
    minItems, maxItems."""
    errs: list[str] = []
    types = schema.get("type")
    if types is not None:
        tl = [types] if isinstance(types, str) else list(types)
        if not any(_JSON_TYPES[t](instance) for t in tl):
            return [f"{where}: expected {types}, got {type(instance).__name__}"]
    if "enum" in schema and instance not in schema["enum"]:
        errs.append(f"{where}: {instance!r} not in {schema['enum']}")
    if "minimum" in schema and _JSON_TYPES["number"](instance) and instance < schema["minimum"]:
        errs.append(f"{where}: {instance} < minimum {schema['minimum']}")
    if isinstance(instance, dict):
        for k in schema.get("required", []):
            if k not in instance:
                errs.append(f"{where}: missing required field {k!r}")
        for k, sub in schema.get("properties", {}).items():
            if k in instance:
                errs += validate(instance[k], sub, f"{where}.{k}")
        extra = schema.get("additionalProperties")
        if isinstance(extra, dict):
            for k, v in instance.items():
                if k not in schema.get("properties", {}):
                    errs += validate(v, extra, f"{where}.{k}")
    if isinstance(instance, list):
        if "minItems" in schema and len(instance) < schema["minItems"]:
            errs.append(f"{where}: {len(instance)} items < minItems {schema['minItems']}")
        if "maxItems" in schema and len(instance) > schema["maxItems"]:
            errs.append(f"{where}: {len(instance)} items > maxItems {schema['maxItems']}")
        if "items" in schema:
            for i, v in enumerate(instance):
                errs += validate(v, schema["items"], f"{where}[{i}]")
    return errs


# ---------------------------------------------------------------------------------------------
# reader
# ---------------------------------------------------------------------------------------------


try:
    from zstandard import ZstdError as _ZstdError
except ImportError:  # pragma: no cover - mcap's writer needs zstandard anyway
    class _ZstdError(Exception):
        pass

# What mcap raises when the stream ends inside a record: EndOfFile (a McapError) at a record
# boundary, struct.error for a cut fixed-size field, a zstd/lz4 error (RuntimeError for lz4) or
# UnicodeDecodeError (a ValueError) for a cut chunk body or string.
_TRUNCATION_ERRORS = (McapError, struct.error, ValueError, RuntimeError, _ZstdError)


def _records(path: Path) -> Iterator[Any]:
    """All records of an MCAP file in order, read without seeking; yields the string
    ``"TRUNCATED"`` last when the file ends before its footer (crash) or a record is cut.

    Raises InputError when the file is missing or not MCAP.
    """
    try:
        f = open(path, "rb")
    except OSError as e:
        raise InputError(path, "file", "a readable MCAP file", e.strerror) from None
    with f:
        magic = f.read(len(MCAP_MAGIC))
        if magic != MCAP_MAGIC:
            raise InputError(path, "file", _MAGIC_TEXT, magic.hex(" ") if magic else "empty")
        f.seek(0)
        reader = StreamReader(f, record_size_limit=1 << 31)
        it = reader.records
        while True:
            try:
                rec = next(it)
            except StopIteration:  # footer and closing magic read
                return
            except _TRUNCATION_ERRORS:
                # a cut-short record, chunk or compressed frame: everything before is complete
                yield "TRUNCATED"
                return
            yield rec


def _nan_rows(rows: list, shape: tuple[int, ...]) -> np.ndarray:
    out = np.full((len(rows), *shape), np.nan)
    for i, r in enumerate(rows):
        if r is not None:
            out[i] = np.asarray(r, dtype=float)
    return out


def _per_state(d: dict[int, dict[str, Any]], keep: set[int]) -> dict[int, PerState]:
    return {p: PerState(v.get("unloaded"), v.get("loaded")) for p, v in sorted(d.items())
            if p in keep}


def read_log(path: str | os.PathLike, include_truth: bool = False) -> CampaignLog:
    """Read a campaign log, keeping only poses with a ``/campaign/pose_done`` marker.

    Uses mcap's non-seeking ``StreamReader`` so a file cut short by a crash is read up to its
    last complete chunk. With ``include_truth=False`` messages on ``/truth/`` topics and the
    ``ground_truth`` metadata are skipped before any JSON decoding.
    """
    path = Path(path)
    topics: dict[int, str] = {}
    info: dict | None = None
    scenario_text = scenario_att = mjcf_text = None
    poses: dict[int, dict[str, np.ndarray]] = {}
    wrenches: dict[int, WrenchRecord] = {}
    meas: list[MeasurementRecord] = []
    done: set[int] = set()
    truncated = True
    t_params: dict | None = None
    t_meta: dict | None = None
    t_refl: dict[int, dict[str, TruthReflectors]] = {}
    t_joints: dict[int, dict[str, TruthJoints]] = {}
    saw_truth = False

    for rec in _records(path):
        if isinstance(rec, Channel):
            topics[rec.id] = rec.topic
        elif isinstance(rec, Message):
            topic = topics.get(rec.channel_id)
            if topic is None:
                continue
            if topic.startswith(TRUTH_PREFIX):
                saw_truth = True
                if not include_truth:
                    continue  # never decoded
            try:
                m = json.loads(rec.data)
            except (json.JSONDecodeError, UnicodeDecodeError) as e:
                raise InputError(path, topic, "a JSON message", str(e)) from None
            if topic == "/campaign/info":
                info = m
            elif topic == "/campaign/pose":
                poses.setdefault(m["pose"], {})[m["state"]] = np.asarray(m["q"], dtype=float)
            elif topic == "/campaign/wrench":
                wrenches[m["pose"]] = WrenchRecord(
                    pose=m["pose"], force=np.asarray(m["force"], dtype=float),
                    moment=np.asarray(m["moment"], dtype=float), site=m["site"], mass=m["mass"])
            elif topic == "/tracker/measurement":
                meas.append(MeasurementRecord(
                    pose=m["pose"], state=m["state"], repeat=m["repeat"],
                    reflectors=list(m["reflectors"]),
                    position=_nan_rows(m["position"], (3,)),
                    covariance=_nan_rows(m["covariance"], (3, 3)),
                    visible=np.asarray(m["visible"], dtype=bool), time=int(rec.log_time)))
            elif topic == "/campaign/pose_done":
                done.add(m["pose"])
            elif topic == "/truth/parameters":
                t_params = m
            elif topic == "/truth/reflectors":
                t_refl.setdefault(m["pose"], {})[m["state"]] = TruthReflectors(
                    tuple(m["reflectors"]), np.asarray(m["position_world"], dtype=float))
            elif topic == "/truth/joints":
                t_joints.setdefault(m["pose"], {})[m["state"]] = TruthJoints(
                    np.asarray(m["qpos"], dtype=float), np.asarray(m["deflection"], dtype=float))
        elif isinstance(rec, Metadata):
            if rec.name == GROUND_TRUTH_METADATA:
                saw_truth = True
                if include_truth:
                    t_meta = dict(rec.metadata)
            elif rec.name == SCENARIO_METADATA:
                scenario_text = rec.metadata.get("text")
        elif isinstance(rec, Attachment):
            if rec.media_type == "application/toml" and scenario_att is None:
                scenario_att = rec.data.decode("utf-8", "replace")
            elif rec.media_type == "application/xml" and mjcf_text is None:
                mjcf_text = rec.data.decode("utf-8", "replace")
        elif isinstance(rec, Footer):
            truncated = False

    present = set(topics.values())
    for topic in REQUIRED_TOPICS:
        if topic not in present:
            raise InputError(path, topic, "a channel with this topic in the campaign log",
                             "no such channel")
    if info is None:
        raise InputError(path, "/campaign/info", "one campaign info message", "none")

    complete = sorted(done)
    keep = set(complete)
    truth = None
    if include_truth and saw_truth:
        if t_params is None and t_meta and "parameters" in t_meta:
            t_params = json.loads(t_meta["parameters"])
        truth = CampaignTruth(
            parameters=_truth_parameters(path, t_params),
            reflectors=_per_state(t_refl, keep),
            joints=_per_state(t_joints, keep),
            scenario_text=(t_meta or {}).get("scenario_text"),
        )
    return CampaignLog(
        path=path, header=info,
        scenario_text=scenario_text if scenario_text is not None else scenario_att,
        mjcf_text=mjcf_text,
        poses=_per_state(poses, keep),
        wrenches={p: v for p, v in sorted(wrenches.items()) if p in keep},
        measurements=[m for m in meas if m.pose in keep],
        complete_poses=complete,
        n_poses_planned=int(info.get("n_poses", 0)),
        truncated=truncated,
        truth=truth,
    )


def _truth_parameters(path: Path, m: dict | None) -> TruthParameters | None:
    if m is None:
        return None
    try:
        return TruthParameters.from_message(m)
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(path, "/truth/parameters",
                         "compliance [one number per actuated joint] and compensator(s) {stiffness, preload}",
                         str(e)) from None


def has_truth(path: str | os.PathLike) -> bool:
    """True when the log has any ``/truth/`` channel or a ``ground_truth`` metadata record."""
    for rec in _records(Path(path)):
        if isinstance(rec, Channel) and rec.topic.startswith(TRUTH_PREFIX):
            return True
        if isinstance(rec, Metadata) and rec.name == GROUND_TRUTH_METADATA:
            return True
    return False


def strip_truth(src: str | os.PathLike, dst: str | os.PathLike,
                chunk_size: int = 16 * 1024) -> None:
    """Copy a log without its ``/truth/`` channels, their schemas and messages, and without
    the ``ground_truth`` metadata: what a real campaign would have recorded.

    Messages keep their times and sequence numbers; a chunk boundary follows each
    ``pose_done`` as in the original. A truncated source gives a truncated copy (no footer),
    so the copy reads as the same state of the campaign.
    """
    src, dst = Path(src), Path(dst)
    if src.resolve() == dst.resolve():
        raise ValueError(f"strip_truth: source and destination are the same file: {src}")
    records = list(_records(src))  # validates src before dst is created
    truncated = not any(isinstance(r, Footer) for r in records)
    schemas: dict[int, Schema] = {}
    new_schema: dict[int, int] = {}
    new_channel: dict[int, int] = {}
    done_channel = _channel_id_of(records, "/campaign/pose_done")
    with open(dst, "wb") as f:
        w = Writer(f, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        started = False
        for rec in records:
            if isinstance(rec, Header):
                w.start(profile=rec.profile, library=rec.library)
                started = True
            elif not started:
                continue
            elif isinstance(rec, Schema):
                schemas[rec.id] = rec
            elif isinstance(rec, Channel):
                if rec.topic.startswith(TRUTH_PREFIX) or rec.id in new_channel:
                    continue
                sid = 0
                if rec.schema_id:
                    if rec.schema_id not in new_schema:
                        s = schemas[rec.schema_id]
                        new_schema[rec.schema_id] = w.register_schema(s.name, s.encoding, s.data)
                    sid = new_schema[rec.schema_id]
                new_channel[rec.id] = w.register_channel(rec.topic, rec.message_encoding, sid,
                                                         dict(rec.metadata))
            elif isinstance(rec, Message):
                cid = new_channel.get(rec.channel_id)
                if cid is None:
                    continue
                w.add_message(cid, rec.log_time, rec.data, rec.publish_time, rec.sequence)
                if rec.channel_id == done_channel:
                    w.flush()  # same chunk boundaries as the writer: a pose ends a chunk
            elif isinstance(rec, Metadata):
                if rec.name != GROUND_TRUTH_METADATA:
                    w.add_metadata(rec.name, dict(rec.metadata))
            elif isinstance(rec, Attachment):
                w.add_attachment(rec.create_time, rec.log_time, rec.name, rec.media_type,
                                 rec.data)
        if truncated:
            w.flush()
        else:
            w.finish()


def _channel_id_of(records: list, topic: str) -> int | None:
    for r in records:
        if isinstance(r, Channel) and r.topic == topic:
            return r.id
    return None


__all__ = [
    "TRUTH_PREFIX", "SCHEMAS", "TOPICS", "LogHeader", "LogWriter", "MeasurementRecord",
    "CampaignLog", "CampaignTruth", "PerState", "WrenchRecord", "TruthParameters",
    "TruthReflectors", "TruthJoints", "read_log", "strip_truth", "has_truth", "redact_truth",
    "validate",
]
