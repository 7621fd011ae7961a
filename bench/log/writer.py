"""The campaign log: one MCAP file of JSON messages, each topic with a JSON Schema.

Why this format
---------------
* Any MCAP reader (Foxglove, ``rerun mcap``, the ``mcap`` CLI) can open and decode the log
  without this project: every channel is ``message_encoding="json"`` with a real
  ``jsonschema`` schema (types, required fields, array lengths: bench/log/schema.py).
* Ground truth lives only on topics beginning with :data:`TRUTH_PREFIX` plus one metadata
  record named ``ground_truth`` (docs/contract.md, "MCAP log"). :func:`strip_truth` removes exactly
  those and leaves what a real campaign would have recorded. The scenario TOML carries the
  ``[truth]`` tables, so the copy stored in the non-truth part of the log has them removed
  (:func:`redact_truth`); the original text goes into the ``ground_truth`` record.
* Crash tolerance: chunks are small and :meth:`LogWriter.pose_done` closes the chunk in progress,
  so a campaign killed mid-way leaves a file whose complete poses are readable with a
  non-seeking reader (bench/log/read.py, the one reader, keeps only poses that carry a
  ``/campaign/pose_done`` marker; ``calbench recover`` rewrites such a file with its footer).
  An exception inside the writer's ``with`` block, Ctrl-C included, finishes the file properly
  (summary and footer, so every MCAP reader opens it) with a ``campaign_end`` metadata record
  saying how the campaign ended; Ctrl-C and SIGTERM are deferred while mcap's writer changes
  its state (:class:`SignalGuard`), so they land between two messages, never inside one.
* Integrity: chunk and attachment CRCs (mcap's defaults) and the data section CRC, so a
  damaged byte is found (bench/log/mcapscan.py).
* Time: messages are stamped by the campaign's clock from the scenario's ``start_time``, in
  causal order (bench/scenario/timeline.py); a message may also carry an explicit time (an imported log).
* Determinism: the clock is synthetic, attachments carry the start time and the MCAP header
  names the library versions only, so the same scenario and seed give a byte-identical file.
  The mcap ``Writer`` itself reads no clock (checked in mcap 1.6: only
  ``start(library=...)`` stores a free-form string, which we set ourselves).

Units: SI throughout (m, rad, N, N*m; covariances in m^2).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import signal
import threading
import tomllib
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from mcap.records import Attachment, Channel, Header, Message, Metadata, Schema
from mcap.writer import CompressionType, Writer

from calbench.bench.core import WriteError, refused_write
from calbench.bench.scenario import (
    DEFAULT_START,
    LOAD_S,
    MOVE_S,
    UNLOAD_S,
    CampaignClock,
    reading_seconds,
    start_ns,
)

from .mcapscan import MAGIC as MCAP_MAGIC
from .mcapscan import Cut, Damage, scan
from .read import END_METADATA, CorruptLogError, has_truth, read_log
from .records import (
    STATES,
    CampaignLog,
    CampaignTruth,
    MeasurementRecord,
    PerState,
    TruthJoints,
    TruthParameters,
    TruthReflectors,
    WrenchRecord,
)
from .schema import (
    GROUND_TRUTH_METADATA,
    REQUIRED_TOPICS,
    SCENARIO_METADATA,
    SCHEMAS,
    TOPICS,
    TRUTH_PREFIX,
    validate,
)

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
    in_truth = False  # inside a [truth...] table
    at_top = True  # before the first table header (top-level keys)
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
    (None: any length). ``start_time`` (an aware datetime) is when the campaign starts, default
    bench/scenario/timeline.py's DEFAULT_START.
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
    start_time: Any = None

    def planned_poses(self) -> int:
        """Number of poses planned: ``n_poses`` or the scenario's ``[[pose]]`` count."""
        if self.n_poses is not None:
            return int(self.n_poses)
        try:
            return len(tomllib.loads(self.scenario_text).get("pose", []))
        except tomllib.TOMLDecodeError:
            return 0


class SignalGuard:
    """Ctrl-C (SIGINT) and SIGTERM wait while mcap's writer changes its state.

    A KeyboardInterrupt raised inside mcap's writer can leave a chunk written without its
    message indexes reset, and the file finished afterwards then indexes messages its last chunk
    does not hold: a damaged log. Blocking the signals in the main thread is not enough (another
    thread, e.g. a BLAS worker, can take the signal and Python raises it in the main thread all
    the same), so while a writer is open its own handler stands in front of the previous one:
    inside :meth:`critical` it only notes the signal, which the previous handler then gets as
    soon as the critical block ends; outside it passes the signal on at once. Main thread only
    (Python sets handlers there); elsewhere it does nothing."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.depth = 0
        self.pending: int | None = None
        self.previous: dict[int, Any] = {}

    def install(self) -> None:
        if threading.current_thread() is not threading.main_thread():
            return
        for s in self.SIGNALS:
            self.previous[s] = signal.getsignal(s)
            signal.signal(s, self._handle)

    def uninstall(self) -> None:
        for s, h in self.previous.items():
            signal.signal(s, h)
        self.previous = {}

    @contextlib.contextmanager
    def critical(self):
        self.depth += 1
        try:
            yield
        finally:
            self.depth -= 1
            if self.depth == 0 and self.pending is not None:
                signum, self.pending = self.pending, None
                self._deliver(signum, None)

    def _handle(self, signum, frame) -> None:
        if self.depth:
            self.pending = signum
        else:
            self._deliver(signum, frame)

    def _deliver(self, signum, frame) -> None:
        h = self.previous.get(signum, signal.SIG_DFL)
        if callable(h):
            h(signum, frame)
        elif h == signal.SIG_DFL:
            if signum == signal.SIGINT:
                raise KeyboardInterrupt
            self.uninstall()  # the default action: end the process
            os.kill(os.getpid(), signum)


class LogWriter:
    """Writes one campaign log. Use as a context manager.

    Chunks are ``chunk_size`` bytes at most (small, default 16 KiB) and every
    :meth:`pose_done` ends the chunk in progress, so a crash loses at most the pose being
    measured. Each message is checked against its topic's schema before it is written, so a
    log never holds a message its own schema rejects.

    Times: called in the campaign's causal order (pose, unloaded readings, wrench, loaded pose
    and readings, pose_done), the messages are stamped by bench/scenario/timeline.py's clock; each
    method also takes ``at`` (ns since 1970) for a log whose times are known (an import).
    Times are kept strictly increasing.
    """

    def __init__(self, path: str | os.PathLike, header: LogHeader, chunk_size: int = 16 * 1024):
        self.path = Path(path)
        self._header = header
        self._last_time = -1
        self._seq: dict[str, int] = {}
        self._truth_params: dict | None = None
        self._joints = None if header.n_joints is None else (int(header.n_joints),)
        self._closed = True  # until the file is open
        self._done = 0
        h = header
        self.clock = CampaignClock(start_ns(h.start_time or DEFAULT_START))
        info = {
            "scenario_name": str(h.scenario_name),
            "robot": str(h.robot_filename),
            "n_poses": h.planned_poses(),
            "reflectors": [str(r) for r in h.reflectors],
            "payload_site": str(h.payload_site),
            "tracker": _jsonable(h.tracker),
            "seed": int(h.seed),
            "calbench_version": _version(),
            # the robot attachment's SHA-256: the reader refuses a log whose MJCF is another one
            "robot_sha256": hashlib.sha256(h.mjcf_text.encode()).hexdigest(),
        }
        if h.n_joints is not None:
            info["n_joints"] = int(h.n_joints)
        if h.imported is not None:
            info["imported"] = _jsonable(h.imported)
        problems = validate(info, SCHEMAS["/campaign/info"])
        if problems:  # checked before the file is created, so a bad header leaves no file
            raise ValueError(f"/campaign/info: header does not match its schema: {problems}")
        public_scenario = redact_truth(h.scenario_text)
        self._file = open(self.path, "wb")
        self._closed = False
        self._guard = SignalGuard()
        self._guard.install()
        self._writer = Writer(
            self._file, chunk_size=chunk_size, compression=CompressionType.ZSTD, enable_data_crcs=True
        )
        # The library string is the only free-form header field; mcap would put its own
        # version there. Ours names both versions and nothing time- or host-dependent.
        self._writer.start(profile="", library=f"calbench/{_version()}; mcap-python/{_mcap_version()}")
        self._channels: dict[str, int] = {}
        self._extra_schemas: dict[str, dict] = {}
        self._schema_ids: dict[tuple[str, bytes], int] = {}
        for topic, schema in SCHEMAS.items():
            sid = self._writer.register_schema(
                name=schema["title"], encoding="jsonschema", data=json.dumps(schema, sort_keys=True).encode()
            )
            self._channels[topic] = self._writer.register_channel(
                topic=topic, message_encoding="json", schema_id=sid
            )

        t0 = self.clock.start
        self._write("/campaign/info", info, t0)
        self._writer.add_metadata(SCENARIO_METADATA, {"name": str(h.scenario_name), "text": public_scenario})
        self._writer.add_attachment(
            create_time=t0,
            log_time=t0,
            name=Path(h.scenario_filename).name,
            media_type="application/toml",
            data=public_scenario.encode(),
        )
        self._writer.add_attachment(
            create_time=t0,
            log_time=t0,
            name=Path(h.robot_filename).name,
            media_type="application/xml",
            data=h.mjcf_text.encode(),
        )
        self._sync()  # schemas, channels and info durable before the first pose

    # -- context manager ---------------------------------------------------------------------
    def __enter__(self) -> LogWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            try:
                self.close()
            except OSError as err:  # the footer did not fit: the finished poses are on disk
                self._abandon()
                cause = refused_write(err)
                if cause is None:
                    raise
                raise WriteError(self.path, cause, f"the log keeps its {self._done} finished poses") from None
            return
        # Ctrl-C or an error: finish the file anyway, so that every MCAP reader opens it; the
        # pose in progress has no pose_done marker and stays out of every campaign read.
        if issubclass(exc_type, KeyboardInterrupt):
            status, reason = "was interrupted", "Ctrl-C"
        else:
            status, reason = "stopped on an error", f"{exc_type.__name__}: {str(exc)[:200]}"
        try:
            self.close(status, f"{reason} after {self._done} complete poses")
        except Exception:  # noqa: BLE001  e.g. the disk is full: keep what is on disk
            self._abandon()
        cause = refused_write(exc)
        if cause is not None:  # the disk filled (or went read-only) mid-campaign: say what is kept
            kept = (
                f"the log keeps its {self._done} finished poses "
                f"(read it as it is, or `calbench recover {self.path} --out FIXED.mcap`)"
            )
            raise WriteError(self.path, cause, kept) from None

    # -- messages ----------------------------------------------------------------------------
    def _write(self, topic: str, msg: dict, nominal_time: int) -> None:
        if self._closed:
            raise RuntimeError(f"{self.path}: log already closed")
        problems = validate(msg, SCHEMAS.get(topic) or self._extra_schemas[topic])
        if problems:
            raise ValueError(f"{topic}: message does not match its schema: {problems}")
        t = max(nominal_time, self._last_time + 1)  # strictly increasing, still deterministic
        self._last_time = t
        self.clock.now = max(self.clock.now, t)  # the next step lasts from here
        seq = self._seq.get(topic, 0)
        self._seq[topic] = seq + 1
        data = json.dumps(msg, allow_nan=False, separators=(",", ":")).encode()
        with self._guard.critical():
            self._writer.add_message(
                channel_id=self._channels[topic], log_time=t, data=data, publish_time=t, sequence=seq
            )

    # -- extra channels (the Foxglove topics of bench/log/foxglove.py) ----------------------------
    def add_channel(self, topic: str, schema_name: str, schema_text: str, check: bool = True) -> None:
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
                name=schema_name, encoding="jsonschema", data=data
            )
        self._channels[topic] = self._writer.register_channel(
            topic=topic, message_encoding="json", schema_id=sid
        )
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

    def pose(self, pose: int, state: str, q, at: int | None = None) -> None:
        """Commanded joint angles (rad, controller convention) of one pose and load state.
        The unloaded command starts the pose: the robot then drives there and settles."""
        p, s = _pose_index(pose), _state(state)
        self._write(
            "/campaign/pose",
            {"pose": p, "state": s, "q": _list(_floats(q, self._joints, "q"))},
            self.clock.at(at),
        )
        if s == "unloaded":
            self.clock.advance(MOVE_S)

    def wrench(self, pose: int, force, moment, site: str, mass: float | None, at: int | None = None) -> None:
        """The load of the loaded state: force (N) and moment (N*m) in the world frame,
        applied at MJCF ``site``; ``mass`` (kg) when it is a hanging payload, else None.
        Stamped when the load hangs still."""
        p = _pose_index(pose)
        t = self.clock.at(at) if at is not None else self.clock.advance(LOAD_S)
        self._write(
            "/campaign/wrench",
            {
                "pose": p,
                "state": "loaded",
                "force": _list(_floats(force, (3,), "force")),
                "moment": _list(_floats(moment, (3,), "moment")),
                "site": str(site),
                "mass": None if mass is None else float(mass),
            },
            t,
        )

    def measurement(
        self, pose, state, repeat, reflectors, position, covariance, visible, at: int | None = None
    ) -> None:
        """One tracker reading of all reflectors: ``position`` (n,3) m in the tracker frame,
        NaN rows (or anything) where ``visible`` is False; ``covariance`` (n,3,3) m^2.
        Invisible reflectors are written as null. Stamped when the reading is complete."""
        p, s = _pose_index(pose), _state(state)
        r = _pose_index(repeat)
        names = [str(x) for x in reflectors]
        n = len(names)
        t = self.clock.at(at) if at is not None else self.clock.advance(reading_seconds(n))
        vis = np.asarray(visible, dtype=bool).reshape(-1)
        pos = np.asarray(position, dtype=float)
        cov = np.asarray(covariance, dtype=float)
        if vis.shape != (n,) or pos.shape != (n, 3) or cov.shape != (n, 3, 3):
            raise ValueError(
                f"measurement: expected visible ({n},), position ({n},3), "
                f"covariance ({n},3,3); got {vis.shape}, {pos.shape}, {cov.shape}"
            )
        pos_out: list = []
        cov_out: list = []
        for i in range(n):
            if vis[i]:
                pos_out.append(_list(_floats(pos[i], (3,), f"position[{names[i]}]")))
                cov_out.append(_list(_floats(cov[i], (3, 3), f"covariance[{names[i]}]")))
            else:
                pos_out.append(None)
                cov_out.append(None)
        self._write(
            "/tracker/measurement",
            {
                "pose": p,
                "state": s,
                "repeat": r,
                "reflectors": names,
                "position": pos_out,
                "covariance": cov_out,
                "visible": [bool(v) for v in vis],
            },
            t,
        )

    def truth_parameters(self, params: dict) -> None:
        """The simulated robot's true parameters (``/truth/parameters``); also written as the
        ``ground_truth`` metadata record when the log is closed."""
        msg = _jsonable(dict(params))
        msg.setdefault("effects", {})
        if self._joints is not None:
            _floats(msg.get("compliance"), self._joints, "compliance")
        self._write("/truth/parameters", msg, self.clock.now)
        self._truth_params = msg

    def truth_reflectors(self, pose, state, reflectors, position_world) -> None:
        """True reflector positions (m, world frame) at the equilibrium of (pose, state)."""
        p, s = _pose_index(pose), _state(state)
        names = [str(x) for x in reflectors]
        pw = _floats(position_world, (len(names), 3), "position_world")
        self._write(
            "/truth/reflectors",
            {"pose": p, "state": s, "reflectors": names, "position_world": _list(pw)},
            self.clock.now,
        )

    def truth_joints(self, pose, state, qpos, deflection) -> None:
        """Full MuJoCo qpos at equilibrium and the motor-space deflection (rad, one per actuated
        joint) from the commanded angles."""
        p, s = _pose_index(pose), _state(state)
        self._write(
            "/truth/joints",
            {
                "pose": p,
                "state": s,
                "qpos": _list(_floats(qpos, None, "qpos")),
                "deflection": _list(_floats(deflection, self._joints, "deflection")),
            },
            self.clock.now,
        )

    def pose_done(self, pose: int, at: int | None = None) -> None:
        """Mark ``pose`` complete (stamped when the load is off) and make everything written
        so far durable.

        Chunk boundary: ``Writer.flush()`` (public in mcap >= 1.3) finalises the chunk in
        progress — compresses it, writes the Chunk record and its MessageIndex records — and
        flushes the stream; we then fsync. A reader of a file cut short later therefore sees
        this pose's marker and all its messages in complete chunks.
        """
        p = _pose_index(pose)
        t = self.clock.at(at) if at is not None else self.clock.advance(UNLOAD_S)
        self._write("/campaign/pose_done", {"pose": p}, t)
        self._sync()
        self._done += 1

    def _sync(self) -> None:
        with self._guard.critical():
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

    def close(self, status: str = "finished", reason: str = "") -> None:
        """Finish the file: the ``campaign_end`` record (``status`` "finished", "was
        interrupted", ...; ``reason`` in words), the ground_truth metadata (if truth was given),
        summary, footer. Calling it again does nothing."""
        if self._closed:
            return
        with self._guard.critical():
            self._writer.add_metadata(
                END_METADATA, {"status": status, "reason": reason, "complete_poses": str(self._done)}
            )
            if self._truth_params is not None:
                self._writer.add_metadata(
                    GROUND_TRUTH_METADATA,
                    {
                        "parameters": json.dumps(self._truth_params, sort_keys=True, allow_nan=False),
                        "scenario_text": self._header.scenario_text,
                    },
                )
            self._writer.finish()
            self._closed = True
            self._file.close()
            self._guard.uninstall()

    def _abandon(self) -> None:
        """When the file cannot be finished: keep the complete chunks already on disk, write
        what is buffered as one more chunk (its pose has no pose_done marker, so readers ignore
        it) and close the file without a footer, so it reads as cut short. Never raises."""
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
        self._guard.uninstall()


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


def copy_log(
    records: Iterable[Any],
    dst: str | os.PathLike,
    *,
    keep_topic: Callable[[str], bool] = lambda t: True,
    keep: Callable[[Any], bool] = lambda r: True,
    metadata: Mapping[str, Mapping[str, str]] = (),
    finish: bool = True,
    chunk_size: int = 16 * 1024,
) -> None:
    """Write ``records`` (as :func:`bench.mcapscan.scan` yields them, Damage and Cut skipped) to
    a new MCAP file: channels whose topic passes ``keep_topic`` (with their schemas), and the
    messages, metadata and attachments that pass ``keep``; then the extra ``metadata`` records.
    Messages keep their times and sequence numbers; a chunk ends after each ``pose_done`` as in
    the writer. ``finish=False`` leaves the copy without a footer (a cut-short copy of a
    cut-short log)."""
    schemas: dict[int, Schema] = {}
    new_schema: dict[int, int] = {}
    new_channel: dict[int, int] = {}
    topics: dict[int, str] = {}
    with open(dst, "wb") as f:
        w = Writer(f, chunk_size=chunk_size, compression=CompressionType.ZSTD, enable_data_crcs=True)
        started = False
        for rec in records:
            if isinstance(rec, Header) and not started:
                w.start(profile=rec.profile, library=rec.library)
                started = True
            elif not started or isinstance(rec, (Damage, Cut)):
                continue
            elif isinstance(rec, Schema):
                schemas.setdefault(rec.id, rec)
            elif isinstance(rec, Channel):
                topics.setdefault(rec.id, rec.topic)
                if not keep_topic(rec.topic) or rec.id in new_channel:
                    continue
                sid = 0
                if rec.schema_id and rec.schema_id in schemas:
                    if rec.schema_id not in new_schema:
                        sc = schemas[rec.schema_id]
                        new_schema[rec.schema_id] = w.register_schema(sc.name, sc.encoding, sc.data)
                    sid = new_schema[rec.schema_id]
                new_channel[rec.id] = w.register_channel(
                    rec.topic, rec.message_encoding, sid, dict(rec.metadata)
                )
            elif isinstance(rec, Message):
                cid = new_channel.get(rec.channel_id)
                if cid is None or not keep(rec):
                    continue
                w.add_message(cid, rec.log_time, rec.data, rec.publish_time, rec.sequence)
                if topics.get(rec.channel_id) == "/campaign/pose_done":
                    w.flush()  # same chunk boundaries as the writer: a pose ends a chunk
            elif isinstance(rec, Metadata):
                if keep(rec):
                    w.add_metadata(rec.name, dict(rec.metadata))
            elif isinstance(rec, Attachment):
                if keep(rec):
                    w.add_attachment(rec.create_time, rec.log_time, rec.name, rec.media_type, rec.data)
        if not started:
            w.start(profile="", library=f"calbench/{_version()}; mcap-python/{_mcap_version()}")
        for name, md in dict(metadata).items():
            w.add_metadata(name, dict(md))
        if finish:
            w.finish()
        else:
            w.flush()


def strip_truth(src: str | os.PathLike, dst: str | os.PathLike, chunk_size: int = 16 * 1024) -> None:
    """Copy a log without its ``/truth/`` channels, their schemas and messages, and without
    the ``ground_truth`` metadata: what a real campaign would have recorded.

    Messages keep their times and sequence numbers; a chunk boundary follows each
    ``pose_done`` as in the original. A cut-short source gives a cut-short copy (no footer),
    so the copy reads as the same state of the campaign. A damaged source is refused
    (CorruptLogError) before ``dst`` is created.
    """
    src, dst = Path(src), Path(dst)
    if src.resolve() == dst.resolve():
        raise ValueError(f"strip_truth: source and destination are the same file: {src}")
    records = list(scan(src))  # validates src before dst is created
    for r in records:
        if isinstance(r, Damage):
            raise CorruptLogError(src, f"byte {r.offset}", f"an undamaged {r.record} record", r.why)
    copy_log(
        records,
        dst,
        keep_topic=lambda t: not t.startswith(TRUTH_PREFIX),
        keep=lambda r: not (isinstance(r, Metadata) and r.name == GROUND_TRUTH_METADATA),
        finish=not any(isinstance(r, Cut) for r in records),
        chunk_size=chunk_size,
    )


__all__ = [
    "TRUTH_PREFIX",
    "SCHEMAS",
    "TOPICS",
    "LogHeader",
    "LogWriter",
    "MeasurementRecord",
    "CampaignLog",
    "CampaignTruth",
    "PerState",
    "WrenchRecord",
    "TruthParameters",
    "TruthReflectors",
    "TruthJoints",
    "read_log",
    "strip_truth",
    "has_truth",
    "redact_truth",
    "validate",
    "copy_log",
    "MCAP_MAGIC",
    "REQUIRED_TOPICS",
    "GROUND_TRUTH_METADATA",
    "SCENARIO_METADATA",
]
