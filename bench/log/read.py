"""Reading a campaign log: the one reader every verb uses, with one policy.

A log is input, and nothing it says is trusted blindly. The policy (docs/contract.md, "MCAP log"):

* **Cut short** (a campaign killed or crashed; the file ends without its footer): the poses
  that carry a ``/campaign/pose_done`` marker are read, the others are lost, and the log says
  so (:attr:`CampaignLog.lost_poses`, :attr:`CampaignLog.end`, :meth:`CampaignLog.completeness`).
  A campaign interrupted with Ctrl-C leaves a finished file with a ``campaign_end`` record saying
  so; it reads the same way.
* **Anything else wrong is a corrupt log, refused whole** (:class:`CorruptLogError`, an
  InputError: exit status 2, one line naming the topic, the pose and the field): a damaged
  record (a chunk or attachment whose CRC fails, a record that cannot be decoded:
  bench/log/mcapscan.py), a message that is not JSON or breaks its topic's schema (a wrong type, a
  5-element ``q``, a missing ``visible``, NaN or Infinity anywhere: bench/log/schema.py), a pose
  index outside the plan (``n_poses`` of ``/campaign/info``), a reading whose lists disagree
  in length or whose visibility and nulls disagree, a reading naming a reflector the header does
  not list or another list than the pose's other readings, a covariance that is not symmetric
  positive definite, a message given twice, a complete pose without its command in both states
  (the same command) or its load. Nothing is computed with such a log; ``calbench recover``
  (bench/log/recover.py) writes a new file with the valid poses only, naming the others, which
  this reader then reads as a campaign with lost poses.

Refusing rather than silently dropping keeps every verb honest alike: identify, discover, view,
report and study all call :func:`read_log`, so they accept and refuse the same logs and report
lost poses in the same words.

``/truth/`` messages are skipped before decoding unless ``include_truth`` (the truth firewall);
when read, they are checked like the rest. Topics the reader does not use (the Foxglove view)
are not decoded. Log times are not interpreted, so logs of earlier versions (times from 1970)
read as before.
"""

from __future__ import annotations

import contextlib
import contextvars
import hashlib
import json
import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from mcap.records import Attachment, Channel, Footer, Message, Metadata

from calbench.bench.core import InputError

from .mcapscan import At, Cut, Damage, scan, scan_span
from .records import (
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
    TRUTH_PREFIX,
    Problem,
    problems,
)

END_METADATA = "campaign_end"  # how the campaign ended (bench/log/writer.py writes it)
RECOVERED_METADATA = "recovered"  # written by `calbench recover`
# a log this big shows its reading's progress (MB of the file checked) where a command asked
# for it (:func:`showing_progress`); smaller ones are read in seconds
PROGRESS_BYTES = 64 << 20
_PROGRESS: contextvars.ContextVar[Callable[[str], Any] | None] = contextvars.ContextVar(
    "calbench_log_progress", default=None
)


@contextlib.contextmanager
def showing_progress(make: Callable[[str], Any]) -> Iterator[None]:
    """Within, :func:`read_log` of a big log shows its progress on ``make(name)`` (a
    bench.core.Progress-like sink with start, update, close): the command line's way to say what
    a minutes-long read is doing without every verb passing a sink down."""
    token = _PROGRESS.set(make)
    try:
        yield
    finally:
        _PROGRESS.reset(token)


# Readings a log may hold for read_log to keep them in memory (~1 kB each with three reflectors);
# beyond, CampaignLog.measurements reads them again a pose at a time (LogReadings)
KEEP_READINGS = 50_000
RECOVER_HINT = "`calbench recover LOG --out FIXED.mcap` keeps its valid poses"
# the topics this reader decodes; the others (Foxglove's view) are passed by
DECODED = frozenset(SCHEMAS)
# relative asymmetry tolerated in a covariance (round-off of R D R^T in the writer is ~1e-16)
SYMMETRY_TOL = 1e-9
# a leading principal minor above this share of its scale is positive beyond round-off (~1e-15)
MINOR_MARGIN = 1e-9
# rad: a pose is one command, written in both states (JSON carries a float exactly; this is the
# same 1e-12 as identify/core/observations.py's check, far below any encoder's resolution)
COMMAND_TOL = 1e-12


class CorruptLogError(InputError):
    """A campaign log that is damaged or says something impossible; names where, and how to
    salvage it."""

    def __init__(self, file: object, key: str, expected: str, got: object = None):
        super().__init__(file, key, expected, got)
        self.args = (f"{self.args[0]} ({RECOVER_HINT})",)


# --------------------------------------------------------------------------- message checks


def _pose_of(m: Any) -> Any:
    return m.get("pose") if isinstance(m, dict) else None


JOINT_VECTORS = {"/campaign/pose": "q", "/truth/joints": "deflection", "/truth/parameters": "compliance"}


def message_problems(topic: str, m: Any, n_poses: int | None, n_joints: int | None = None) -> list[Problem]:
    """Every reason to refuse message ``m`` of ``topic``: its schema, then what a schema cannot
    say (the pose within the plan of ``n_poses``, one value per joint of ``n_joints`` in every
    command, deflection and compliance, a reading's lists agreeing, covariances symmetric
    positive definite, each reading's reflectors named once)."""
    found = problems(m, SCHEMAS[topic])
    if found:
        return found
    pose = _pose_of(m)
    if n_poses is not None and pose is not None and pose >= n_poses:
        return [
            Problem(
                "pose",
                f"a pose index of the plan (0..{n_poses - 1}; /campaign/info n_poses = {n_poses})",
                pose,
            )
        ]
    key = JOINT_VECTORS.get(topic)
    if key and n_joints is not None and len(m[key]) != n_joints:
        return [
            Problem(
                key, f"{n_joints} items, one per actuated joint as in every command", f"{len(m[key])} items"
            )
        ]
    if topic == "/tracker/measurement":
        return _measurement_problems(m)
    if topic == "/truth/reflectors" and len(m["position_world"]) != len(m["reflectors"]):
        return [
            Problem(
                "position_world", f"{len(m['reflectors'])} rows, one per reflector", len(m["position_world"])
            )
        ]
    return []


def _measurement_problems(m: dict) -> list[Problem]:
    """The first problem reflector by reflector: nulls where not visible, then a symmetric
    positive definite covariance."""
    n = len(m["reflectors"])
    if len(set(m["reflectors"])) != n:
        return [Problem("reflectors", "each reflector named once", m["reflectors"])]
    for key in ("position", "covariance", "visible"):
        if len(m[key]) != n:
            return [Problem(key, f"{n} entries, one per reflector", f"{len(m[key])} entries")]
    null = None  # the first reflector whose nulls disagree with visible
    for i, vis in enumerate(m["visible"]):
        for key in ("position", "covariance"):
            if (m[key][i] is not None) != vis:
                null = Problem(
                    f"{key}[{i}]",
                    "null exactly where visible is false",
                    m[key][i] if m[key][i] is None else f"a value with visible {vis}",
                )
                break
        if null is not None:
            n = i
            break
    for i in range(n):
        if m["visible"][i]:
            why = _covariance_problem(m["covariance"][i])
            if why:
                return [Problem(f"covariance[{i}]", "a symmetric positive definite 3x3 matrix", why)]
    return [] if null is None else [null]


def _covariance_problem(c: list) -> str | None:
    """What is wrong with a 3x3 covariance (lists of finite numbers: its schema), or None.

    Symmetric to SYMMETRY_TOL of its largest entry, and positive definite: no eigenvalue <= 0
    (numpy's eigvalsh of its symmetric part). Most covariances are plainly positive definite:
    their leading principal minors exceed MINOR_MARGIN times the largest entry's power, far
    beyond their round-off, so every eigenvalue is positive (Sylvester's criterion) and the
    eigenvalues need not be computed (~50 times slower in numpy for one 3x3)."""
    (a, b, d), (b2, e, f), (d2, f2, g) = c
    scale = max(abs(a), abs(b), abs(d), abs(b2), abs(e), abs(f), abs(d2), abs(f2), abs(g))
    if not scale > 0 or max(abs(b - b2), abs(d - d2), abs(f - f2)) > SYMMETRY_TOL * scale:
        return "an asymmetric or zero matrix"
    b, d, f = (b + b2) / 2, (d + d2) / 2, (f + f2) / 2
    m2 = a * e - b * b
    m3 = a * (e * g - f * f) - b * (b * g - f * d) + d * (b * f - e * d)
    if a > MINOR_MARGIN * scale and m2 > MINOR_MARGIN * scale**2 and m3 > MINOR_MARGIN * scale**3:
        return None
    sym = 0.5 * (np.asarray(c, dtype=float) + np.asarray(c, dtype=float).T)
    return "a matrix with an eigenvalue <= 0" if np.linalg.eigvalsh(sym).min() <= 0 else None


def _key(topic: str, m: Any, field_: str) -> str:
    pose = _pose_of(m)
    where = f" pose {pose}" if isinstance(pose, int) and not isinstance(pose, bool) else ""
    if isinstance(m, dict) and isinstance(m.get("state"), str) and topic != "/campaign/wrench":
        where += f" {m['state']}" + (f" repeat {m['repeat']}" if isinstance(m.get("repeat"), int) else "")
    return f"{topic}{where}" + (f": {field_}" if field_ else "")


def decode(topic: str, data: bytes, index: int) -> tuple[Any, str | None]:
    """(the JSON of one message, None), or (None, why it is not JSON)."""
    try:
        return json.loads(data), None
    except (ValueError, RecursionError) as e:  # JSONDecodeError and UnicodeDecodeError
        return None, f"message #{index} is not JSON ({type(e).__name__}: {str(e)[:80]})"


# --------------------------------------------------------------------------- the reader


@dataclass
class _Collected:
    """What the messages of a log say, while it is read."""

    info: dict | None = None
    poses: dict[int, dict[str, np.ndarray]] = field(default_factory=dict)
    wrenches: dict[int, WrenchRecord] = field(default_factory=dict)
    meas: list[MeasurementRecord] = field(default_factory=list)
    done: set[int] = field(default_factory=set)
    t_params: dict | None = None
    t_refl: dict[int, dict[str, TruthReflectors]] = field(default_factory=dict)
    t_joints: dict[int, dict[str, TruthJoints]] = field(default_factory=dict)
    seen: set[tuple] = field(default_factory=set)
    # readings: kept while there are at most KEEP_READINGS (meas), else only where each pose's
    # are (spans: the offsets of the first and last record holding them), how many, and when
    kept: bool = True
    spans: dict[int, list[int]] = field(default_factory=dict)
    counts: dict[int, int] = field(default_factory=dict)
    first_time: dict[int, int] = field(default_factory=dict)
    repeats: dict[tuple[int, str], list] = field(default_factory=dict)  # [n, set]: see once_reading
    lists: dict[int, list[str]] = field(default_factory=dict)  # each pose's first reflector list

    def once(self, key: tuple) -> bool:
        """True the first time ``key`` (topic and identity of a message) is met."""
        if key in self.seen:
            return False
        self.seen.add(key)
        return True

    def once_reading(self, pose: int, state: str, repeat: int) -> bool:
        """:meth:`once` for readings in a few bytes per pose and state: repeats 0..n-1 all met
        are one number n (a writer numbers them in order), others a set until the gap fills."""
        n_ahead = self.repeats.setdefault((pose, state), [0, set()])
        n, ahead = n_ahead
        if repeat < n or repeat in ahead:
            return False
        ahead.add(repeat)
        while n in ahead:
            ahead.discard(n)
            n += 1
        n_ahead[0] = n
        return True


def _nan_rows(rows: list, shape: tuple[int, ...]) -> np.ndarray:
    """Rows (lists, or None where not seen) as one array with NaN rows for the Nones."""
    if any(r is None for r in rows):
        nan = np.full(shape, np.nan).tolist()
        rows = [nan if r is None else r for r in rows]
    return np.array(rows, dtype=float).reshape(len(rows), *shape)


def _identity(topic: str, m: dict) -> tuple:
    return (topic, m.get("pose"), m.get("state"), m.get("repeat"))


def _take(c: _Collected, topic: str, m: dict, log_time: int) -> None:
    """File one valid message (checked by :func:`message_problems` and for duplicates)."""
    if topic == "/campaign/info":
        c.info = m
    elif topic == "/campaign/pose":
        c.poses.setdefault(m["pose"], {})[m["state"]] = np.asarray(m["q"], dtype=float)
    elif topic == "/campaign/wrench":
        c.wrenches[m["pose"]] = WrenchRecord(
            pose=m["pose"],
            force=np.asarray(m["force"], dtype=float),
            moment=np.asarray(m["moment"], dtype=float),
            site=m["site"],
            mass=m["mass"],
        )
    elif topic == "/tracker/measurement":
        if c.kept:
            c.meas.append(measurement_record(m, log_time))
            if len(c.meas) > KEEP_READINGS:  # from here on, read again pose by pose when asked
                c.kept, c.meas = False, []
    elif topic == "/campaign/pose_done":
        c.done.add(m["pose"])
    elif topic == "/truth/parameters":
        c.t_params = m
    elif topic == "/truth/reflectors":
        c.t_refl.setdefault(m["pose"], {})[m["state"]] = TruthReflectors(
            tuple(m["reflectors"]), np.asarray(m["position_world"], dtype=float)
        )
    elif topic == "/truth/joints":
        c.t_joints.setdefault(m["pose"], {})[m["state"]] = TruthJoints(
            np.asarray(m["qpos"], dtype=float), np.asarray(m["deflection"], dtype=float)
        )


def measurement_record(m: dict, log_time: int) -> MeasurementRecord:
    """One checked ``/tracker/measurement`` message as a record."""
    return MeasurementRecord(
        pose=m["pose"],
        state=m["state"],
        repeat=m["repeat"],
        reflectors=list(m["reflectors"]),
        position=_nan_rows(m["position"], (3,)),
        covariance=_nan_rows(m["covariance"], (3, 3)),
        visible=np.asarray(m["visible"], dtype=bool),
        time=int(log_time),
    )


def _note_reading(c: _Collected, m: dict, log_time: int, offset: int) -> None:
    """Where, when and how many readings of a pose the log holds."""
    p = m["pose"]
    span = c.spans.get(p)
    if span is None:
        c.spans[p] = [offset, offset]
    else:
        span[1] = offset
    c.counts[p] = c.counts.get(p, 0) + 1
    c.first_time[p] = min(c.first_time.get(p, log_time), log_time)


def _per_state(d: dict[int, dict[str, Any]], keep: set[int]) -> dict[int, PerState]:
    return {p: PerState(v.get("unloaded"), v.get("loaded")) for p, v in sorted(d.items()) if p in keep}


def _check_reflector_list(path: Path, header: list[str], first: dict[int, list[str]], m: dict) -> None:
    """A reading names reflectors of ``/campaign/info`` only, and the readings of one pose all
    name the same list (its rows are matched by position between states and repeats): ``first``
    holds each pose's first list."""
    names = first.setdefault(m["pose"], m["reflectors"])
    if m["reflectors"] == names and names is not m["reflectors"]:
        return  # the pose's list again: checked when first met
    key = _key("/tracker/measurement", m, "reflectors")
    unknown = [r for r in m["reflectors"] if r not in header]
    if unknown:
        raise CorruptLogError(
            path, key, f"reflectors that /campaign/info lists ({', '.join(header) or 'none'})", unknown
        )
    if m["reflectors"] != names:
        raise CorruptLogError(path, key, f"the list of the pose's first reading {names}", m["reflectors"])


def read_log(path: str | os.PathLike, include_truth: bool = False) -> CampaignLog:
    """Read and check a campaign log (see the module docstring for the policy): its complete
    poses, what was lost and how the log ended. Raises InputError when the file is missing or
    not MCAP, CorruptLogError (an InputError) when it is damaged or says something impossible.
    """
    path = Path(path)
    topics: dict[int, str] = {}
    c = _Collected()
    metadata: dict[str, dict] = {}
    scenario_att = mjcf_text = mjcf_sha256 = None
    saw_truth = cut = False
    n_poses: int | None = None
    n_joints: int | None = None
    pending: list[tuple[str, dict]] = []  # pose messages met before /campaign/info
    stamp = _stamp(path)
    offset = 0  # of the top-level record being read
    make = _PROGRESS.get()
    bar = make(f"calbench: checking {path.name}") if make and stamp[0] > PROGRESS_BYTES else None
    if bar is not None:
        bar.start(stamp[0] >> 20)
    shown = 0
    for rec in scan(path, marks=True):
        if isinstance(rec, At):
            offset = rec.offset
            if bar is not None and offset >> 20 > shown:
                bar.update(step=(offset >> 20) - shown)
                shown = offset >> 20
            continue
        if isinstance(rec, Damage):
            raise CorruptLogError(path, f"byte {rec.offset}", f"an undamaged {rec.record} record", rec.why)
        if isinstance(rec, Cut):
            cut = True
            break
        if isinstance(rec, Channel):
            topics[rec.id] = rec.topic
        elif isinstance(rec, Message):
            topic = topics.get(rec.channel_id)
            if topic is None or topic not in DECODED:
                continue
            if topic.startswith(TRUTH_PREFIX):
                saw_truth = True
                if not include_truth:
                    continue  # never decoded
            m, why = decode(topic, rec.data, rec.sequence)
            if why:
                raise CorruptLogError(path, topic, "JSON messages", why)
            found = message_problems(topic, m, n_poses, n_joints)
            if found:
                p = found[0]
                raise CorruptLogError(path, _key(topic, m, p.field), p.expected, p.got)
            if topic == "/campaign/pose" and n_joints is None:
                n_joints = len(m["q"])  # the first command fixes it (old logs)
            reading = topic == "/tracker/measurement"
            if not (
                c.once_reading(m["pose"], m["state"], m["repeat"]) if reading else c.once(_identity(topic, m))
            ):
                raise CorruptLogError(path, _key(topic, m, ""), "each message once", "a duplicate")
            if topic == "/campaign/info":
                n_poses = m["n_poses"]
                n_joints = m.get("n_joints", n_joints)
                for t, pm in pending:  # now the plan is known
                    found = message_problems(t, pm, n_poses, n_joints)
                    if found:
                        raise CorruptLogError(
                            path, _key(t, pm, found[0].field), found[0].expected, found[0].got
                        )
                    if t == "/tracker/measurement":
                        _check_reflector_list(path, m["reflectors"], c.lists, pm)
            elif n_poses is None and "pose" in m:
                pending.append((topic, m))
            if reading:
                if c.info is not None:
                    _check_reflector_list(path, c.info["reflectors"], c.lists, m)
                _note_reading(c, m, rec.log_time, offset)
            _take(c, topic, m, rec.log_time)
        elif isinstance(rec, Metadata):
            if rec.name == GROUND_TRUTH_METADATA:
                saw_truth = True
                if include_truth:
                    metadata[rec.name] = dict(rec.metadata)
            else:
                metadata.setdefault(rec.name, dict(rec.metadata))
        elif isinstance(rec, Attachment):
            if rec.media_type == "application/toml" and scenario_att is None:
                scenario_att = rec.data.decode("utf-8", "replace")
            elif rec.media_type == "application/xml" and mjcf_text is None:
                mjcf_text = rec.data.decode("utf-8", "replace")
                mjcf_sha256 = hashlib.sha256(rec.data).hexdigest()
        elif isinstance(rec, Footer):
            break

    if bar is not None:
        bar.close()
    present = set(topics.values())
    for topic in REQUIRED_TOPICS:
        if topic not in present:
            raise InputError(path, topic, "a channel with this topic in the campaign log", "no such channel")
    if c.info is None:
        raise InputError(path, "/campaign/info", "one campaign info message", "none")

    check_robot_hash(path, c.info, mjcf_sha256)
    complete = sorted(c.done)
    keep = set(complete)
    for p in complete:  # a complete pose is all there
        states = c.poses.get(p, {})
        if len(states) != 2:
            raise CorruptLogError(
                path,
                f"/campaign/pose pose {p}",
                "the command of a complete pose in both states",
                sorted(states) or "none",
            )
        if p not in c.wrenches:
            raise CorruptLogError(path, f"/campaign/wrench pose {p}", "the load of a complete pose", "none")
        if not np.allclose(states["unloaded"], states["loaded"], rtol=0, atol=COMMAND_TOL):
            raise CorruptLogError(
                path,
                f"/campaign/pose pose {p} loaded: q",
                "the command of the unloaded state (a pose is one command)",
                states["loaded"].tolist(),
            )
    truth = None
    if include_truth and saw_truth:
        t_meta = metadata.get(GROUND_TRUTH_METADATA) or {}
        t_params = c.t_params
        if t_params is None and "parameters" in t_meta:
            t_params, why = decode(GROUND_TRUTH_METADATA, t_meta["parameters"].encode(), 0)
            if why or problems(t_params, SCHEMAS["/truth/parameters"]):
                raise CorruptLogError(
                    path,
                    "ground_truth.parameters",
                    "the /truth/parameters message as JSON",
                    why or "other fields",
                )
        truth = CampaignTruth(
            parameters=_truth_parameters(path, t_params),
            reflectors=_per_state(c.t_refl, keep),
            joints=_per_state(c.t_joints, keep),
            scenario_text=t_meta.get("scenario_text"),
        )
    end, truncated = log_end(cut, metadata)
    scenario_text = (metadata.get(SCENARIO_METADATA) or {}).get("text")
    return CampaignLog(
        path=path,
        header=c.info,
        scenario_text=scenario_text if scenario_text is not None else scenario_att,
        mjcf_text=mjcf_text,
        poses=_per_state(c.poses, keep),
        wrenches={p: v for p, v in sorted(c.wrenches.items()) if p in keep},
        measurements=[m for m in c.meas if m.pose in keep]
        if c.kept
        else LogReadings(
            path,
            stamp,
            {i for i, t in topics.items() if t == "/tracker/measurement"},
            c.spans,
            c.counts,
            c.first_time,
            keep,
        ),
        complete_poses=complete,
        n_poses_planned=int(c.info["n_poses"]),
        truncated=truncated,
        truth=truth,
        end=end,
        dropped_poses=_dropped(metadata),
    )


def check_robot_hash(path: Path, info: dict, got: str | None) -> None:
    """The robot attachment is the MJCF whose SHA-256 ``/campaign/info`` records (logs written
    before the hash was recorded have none to check)."""
    want = info.get("robot_sha256")
    if want is None:
        return
    if got != want:
        raise CorruptLogError(
            path,
            f"attachment {info.get('robot', 'robot')!r}",
            f"the robot MJCF whose SHA-256 /campaign/info records ({want[:12]}...)",
            "no robot attachment" if got is None else f"another MJCF (SHA-256 {got[:12]}...)",
        )


def log_end(cut: bool, metadata: dict[str, dict]) -> tuple[str, bool]:
    """How the log ended, as a phrase ("finished", "the log was cut short: ..."), and whether
    the campaign stopped before its end."""
    rec = metadata.get(RECOVERED_METADATA)
    if rec is not None:
        return (
            f"the log was recovered by `calbench recover` from one that "
            f"{rec.get('source_end', 'was damaged')}",
            rec.get("campaign_finished") != "true",
        )
    if cut:
        return (
            "the log was cut short: the file ends without its footer (the campaign was killed or crashed)"
        ), True
    end = metadata.get(END_METADATA) or {}
    status = end.get("status", "finished")
    if status == "finished":
        return "finished", False
    return f"the campaign {status}" + (f" ({end['reason']})" if end.get("reason") else ""), True


def _dropped(metadata: dict[str, dict]) -> list[int]:
    text = (metadata.get(RECOVERED_METADATA) or {}).get("dropped_poses", "[]")
    try:
        v = json.loads(text)
    except ValueError:
        return []
    return [int(p) for p in v if isinstance(p, int)] if isinstance(v, list) else []


def _truth_parameters(path: Path, m: dict | None) -> TruthParameters | None:
    if m is None:
        return None
    try:
        return TruthParameters.from_message(m)
    except (KeyError, TypeError, ValueError) as e:
        raise CorruptLogError(
            path,
            "/truth/parameters",
            "compliance [one number per actuated joint] and compensator(s) {stiffness, preload}",
            str(e),
        ) from None


def _stamp(path: Path) -> tuple[int, int, int]:
    """What tells a file changed: its size, modification time and inode."""
    try:
        st = os.stat(path)
    except OSError:
        return (0, 0, 0)  # the scan says why the file cannot be read
    return (st.st_size, st.st_mtime_ns, st.st_ino)


class LogReadings:
    """The readings of a log's complete poses, read from the file again a pose at a time: what
    :func:`read_log` gives as ``CampaignLog.measurements`` when the log holds more than
    KEEP_READINGS, so that no verb holds a whole log of any size. The first read checked every
    message and noted where each pose's readings are (``spans``: offsets of the first and the
    last top-level record holding them); reading them again checks the chunks' CRCs and that the
    file is the one checked (size, time, inode). Iterating gives every reading in log order;
    :meth:`of` those of one pose and state (the last pose's are kept for its other state)."""

    def __init__(
        self,
        path: Path,
        stamp: tuple[int, int, int],
        channels: set[int],
        spans: dict[int, list[int]],
        counts: dict[int, int],
        first_time: dict[int, int],
        keep: set[int],
    ):
        self.path, self.stamp, self.channels = path, stamp, frozenset(channels)
        self.spans = {p: tuple(spans[p]) for p in sorted(keep) if p in spans}
        self.count = sum(counts.get(p, 0) for p in self.spans)
        self.first_time = min((first_time[p] for p in self.spans), default=None)
        self._last: tuple[int, dict[str, list[MeasurementRecord]]] | None = None

    def __len__(self) -> int:
        return self.count

    def __bool__(self) -> bool:
        return self.count > 0

    def _read(self, first: int, last: int, poses: set[int] | frozenset[int]) -> Iterator[MeasurementRecord]:
        if _stamp(self.path) != self.stamp:
            raise InputError(
                self.path, "file", "the log unchanged while it is read", "it changed since it was checked"
            )
        for rec in scan_span(self.path, first, last):
            if isinstance(rec, Damage):
                raise CorruptLogError(
                    self.path, f"byte {rec.offset}", f"an undamaged {rec.record} record", rec.why
                )
            if isinstance(rec, Message) and rec.channel_id in self.channels:
                m = json.loads(rec.data)
                if m["pose"] in poses:
                    yield measurement_record(m, rec.log_time)

    def __iter__(self) -> Iterator[MeasurementRecord]:
        if not self.spans:
            return iter(())
        first = min(a for a, _ in self.spans.values())
        last = max(b for _, b in self.spans.values())
        return self._read(first, last, frozenset(self.spans))

    def of(self, pose: int, state: str) -> list[MeasurementRecord]:
        """The readings of one pose and state, in log order (empty when none)."""
        if pose not in self.spans:
            return []
        if self._last is None or self._last[0] != pose:
            by: dict[str, list[MeasurementRecord]] = {}
            for m in self._read(*self.spans[pose], {pose}):
                by.setdefault(m.state, []).append(m)
            self._last = (pose, by)
        return list(self._last[1].get(state, ()))


def has_truth(path: str | os.PathLike) -> bool:
    """True when the log carries ground truth: a message on a ``/truth/`` topic or a
    ``ground_truth`` metadata record (read up to the first damage or the cut). A registered
    ``/truth/`` channel alone does not count: an imported log has the channels (one writer for
    every log) but no message on them."""
    truth_channels: set[int] = set()
    for rec in scan(Path(path)):
        if isinstance(rec, (Damage, Cut)):
            return False
        if isinstance(rec, Channel) and rec.topic.startswith(TRUTH_PREFIX):
            truth_channels.add(rec.id)
        elif isinstance(rec, Message) and rec.channel_id in truth_channels:
            return True
        elif isinstance(rec, Metadata) and rec.name == GROUND_TRUTH_METADATA:
            return True
    return False


__all__ = [
    "read_log",
    "has_truth",
    "message_problems",
    "decode",
    "log_end",
    "CorruptLogError",
    "LogReadings",
    "showing_progress",
    "KEEP_READINGS",
    "END_METADATA",
    "RECOVERED_METADATA",
    "DECODED",
]
