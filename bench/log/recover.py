"""`calbench recover`: rewrite a cut-short or damaged campaign log as a valid MCAP file.

A campaign killed with SIGKILL (or a crash, or power loss) leaves a file without its summary
and footer: calbench reads it up to its last finished pose, but other MCAP readers
(``make_reader``, ``rerun mcap``, Foxglove) refuse it. A damaged log (a flipped bit) is refused
by every calbench verb (bench/log/read.py). :func:`recover_log` writes a new file that every
reader opens and that bench/log/read.py accepts:

* every record that can be read is kept, in order, with its time (copied by
  bench/log/writer.py's :func:`copy_log`, with a summary and a footer);
* a pose is kept only when it is complete (its ``/campaign/pose_done`` marker is there) and all
  of it is trustworthy. A damaged record taints every pose that may have had messages in it: the
  poses in progress between the last marker before it and the first marker after it (a chunk
  ends at each marker, so usually just the one pose). A message that breaks its schema, a pose
  index outside the plan, a duplicate: the pose it sits among is dropped too, and the pose it
  names. Dropped and incomplete poses
  are named in the result and in a ``recovered`` metadata record, so the recovered log reports
  them as lost;
* messages on topics the reader does not decode (the Foxglove view) follow their pose.

It cannot recover a log whose ``/campaign/info`` message is damaged (CorruptLogError), and a
file that is not MCAP is an InputError: both exit status 2.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from mcap.records import Channel, Message, MessageIndex, Metadata

from calbench.bench.core import InputError

from .mcapscan import Cut, Damage, scan
from .read import (
    COMMAND_TOL,
    DECODED,
    END_METADATA,
    RECOVERED_METADATA,
    CorruptLogError,
    decode,
    message_problems,
    read_log,
)
from .records import pose_list
from .schema import REQUIRED_TOPICS
from .writer import copy_log


@dataclass
class Recovery:
    """What :func:`recover_log` kept and left out."""

    source: Path
    source_end: str  # "finished", "was cut short", ...
    complete_poses: list[int] = field(default_factory=list)
    dropped: dict[int, str] = field(default_factory=dict)  # pose -> why it was left out
    damage: list[str] = field(default_factory=list)  # damaged records, in words
    n_planned: int = 0
    notes: list[str] = field(default_factory=list)
    finished: bool = True  # the campaign itself ran to its end

    @property
    def lost_poses(self) -> list[int]:
        return sorted(set(range(self.n_planned)) - set(self.complete_poses))

    def summary(self) -> str:
        """One line for the command line."""
        text = (
            f"{len(self.complete_poses)} of {self.n_planned} planned poses kept"
            f" {pose_list(self.complete_poses)}"
            if self.complete_poses
            else f"no complete pose of {self.n_planned} planned"
        )
        if self.dropped:
            text += "; dropped " + ", ".join(
                f"pose {p} ({why})" for p, why in sorted(self.dropped.items())[:5]
            )
            text += "" if len(self.dropped) <= 5 else f" and {len(self.dropped) - 5} more"
        return f"{text}; the source {self.source_end}"


def _pose(m: Any) -> int | None:
    p = m.get("pose") if isinstance(m, dict) else None
    return p if isinstance(p, int) and not isinstance(p, bool) else None


class _Salvage:
    """Pass over the events of a log: which messages to keep (see the module docstring)."""

    def __init__(self, src: Path, events: list):
        self.src = src
        self.topics = {r.id: r.topic for r in events if isinstance(r, Channel)}
        self.n_poses: int | None = None
        self.n_joints: int | None = None
        self.reflectors: set[str] = set()  # the header's
        self.valid: set[int] = set()  # decoded messages that pass every check
        self.pose_of: dict[int, int] = {}  # event index -> pose of a valid message
        self.span_of: dict[int, int] = {}  # event index -> the marker closing its span
        self.done: dict[int, int] = {}  # pose -> event index of its marker
        self.bad: dict[int, str] = {}  # pose -> why it is left out
        self._span: list[int] = []
        self._poses: set[int] = set()
        self._taint: str | None = None
        self._seen: set[tuple] = set()
        closed = None  # after a damaged chunk: did it end a pose?
        for i, e in enumerate(events):
            if isinstance(e, Damage):
                self._taint = self._taint or f"damaged {e.record} at byte {e.offset}"
                closed = False if e.record == "Chunk" else None
            elif isinstance(e, MessageIndex):
                if closed is False and self.topics.get(e.channel_id) == "/campaign/pose_done":
                    closed = True
            else:
                if closed:  # the damaged chunk held a pose's marker:
                    self._close(None)  # that pose is lost, the next one is clean
                closed = None
                if isinstance(e, Message) and e.channel_id in self.topics:
                    self._message(i, e, self.topics[e.channel_id])

    def _message(self, i: int, e: Message, topic: str) -> None:
        if topic not in DECODED:
            if self._poses:  # inside a pose: it follows the pose
                self._span.append(i)
            return
        m, why = decode(topic, e.data, e.sequence)
        pose = _pose(m)
        if why is None:
            found = message_problems(topic, m, self.n_poses, self.n_joints)
            why = (
                f"{topic} {found[0].field}: expected {found[0].expected}".replace(" :", ":")
                if found
                else None
            )
        key = (topic, pose, *((m.get("state"), m.get("repeat")) if isinstance(m, dict) else ()))
        if why is None and key in self._seen:
            why = f"a second {topic} message"
        self._seen.add(key)
        if topic == "/campaign/info":
            if why is not None or self.n_poses is not None:
                raise CorruptLogError(
                    self.src,
                    "/campaign/info",
                    "one valid campaign info message to recover from",
                    why or "two",
                )
            self.n_poses = m["n_poses"]
            self.n_joints = m.get("n_joints")
            self.reflectors = set(m["reflectors"])
        if why is not None:  # it taints the pose it sits among, and its
            self._taint = self._taint or why  # own pose (when that is one of the plan)
            if pose is not None and (self.n_poses is None or 0 <= pose < self.n_poses):
                self.bad.setdefault(pose, why)
            return
        self.valid.add(i)
        if topic == "/campaign/pose" and self.n_joints is None:
            self.n_joints = len(m["q"])  # the first command fixes it (old logs)
        if pose is None:
            return
        self.pose_of[i] = pose
        self._span.append(i)
        self._poses.add(pose)
        if topic == "/campaign/pose_done":
            self.done[pose] = i
            self._close(i)

    def _close(self, marker: int | None) -> None:
        """End the span of messages at a pose_done ``marker`` (None: a marker lost in a damaged
        chunk); a damaged record in the span taints every pose with messages in it."""
        if self._taint:
            for p in self._poses:
                self.bad.setdefault(p, self._taint)
        if marker is not None:
            for j in self._span:
                self.span_of[j] = marker
        self._span, self._poses, self._taint = [], set(), None

    def complete(self, events: list) -> list[int]:
        """Poses with their marker, untainted, and all there and consistent (both commands, the
        same, and the load; readings that name the header's reflectors, one list per pose: what
        bench/log/read.py asks of a pose)."""
        have: dict[int, set] = {}
        q: dict[int, dict[str, list]] = {}
        lists: dict[int, set[tuple]] = {}
        for i, p in self.pose_of.items():
            m = events[i]
            topic = self.topics[m.channel_id]
            msg = json.loads(m.data) if topic in ("/campaign/pose", "/tracker/measurement") else {}
            state = msg.get("state") if topic == "/campaign/pose" else None
            have.setdefault(p, set()).add((topic, state))
            if topic == "/campaign/pose":
                q.setdefault(p, {})[state] = msg["q"]
            elif topic == "/tracker/measurement":
                lists.setdefault(p, set()).add(tuple(msg["reflectors"]))
        need = {("/campaign/pose", "unloaded"), ("/campaign/pose", "loaded"), ("/campaign/wrench", None)}
        for p in self.done:
            if p in self.bad:
                continue
            if not need <= have.get(p, set()):
                self.bad[p] = "its command or its load is missing"
            elif not np.allclose(q[p]["unloaded"], q[p]["loaded"], rtol=0, atol=COMMAND_TOL):
                self.bad[p] = "its command differs between the states"
            elif len(lists.get(p, ())) > 1 or any(set(n) - self.reflectors for n in lists.get(p, ())):
                self.bad[p] = "its readings name other reflectors than the header or each other"
        return sorted(p for p in self.done if p not in self.bad)


def recover_log(src: str | os.PathLike, dst: str | os.PathLike) -> Recovery:
    """Rewrite ``src`` as a valid MCAP file at ``dst`` (see the module docstring). Reads ``src``
    whole before ``dst`` is created."""
    src = Path(src)
    events = list(scan(src))  # InputError when src is not MCAP
    damage = [e for e in events if isinstance(e, Damage)]
    sal = _Salvage(src, events)
    if sal.n_poses is None:
        raise CorruptLogError(src, "/campaign/info", "a campaign info message to recover from", "none")
    for topic in REQUIRED_TOPICS:
        if topic not in sal.topics.values():
            raise CorruptLogError(src, topic, "a channel with this topic to recover from", "no such channel")
    complete = set(sal.complete(events))
    markers = {sal.done[p] for p in complete}
    # the data section's CRC covers every record: alone in failing, it points at one outside the
    # chunks and attachments (which have CRCs of their own), i.e. a metadata record
    metadata_ok = not damage or any(d.record not in ("DataEnd", "Statistics") for d in damage)
    index = {id(e): i for i, e in enumerate(events)}

    def keep(r: Any) -> bool:
        i = index[id(r)]
        if isinstance(r, Message):
            if i in sal.span_of:  # a pose's message: its pose decides
                return sal.span_of[i] in markers and (i not in sal.pose_of or sal.pose_of[i] in complete)
            if sal.topics.get(r.channel_id) in DECODED:
                return i in sal.valid and i not in sal.pose_of  # info, truth parameters
            return not _in_open_pose(i)
        if isinstance(r, Metadata):
            return metadata_ok and r.name != RECOVERED_METADATA
        return True  # attachments (a damaged one is a Damage)

    last_marker = max(sal.done.values(), default=-1)
    open_from = min((j for j in sal.pose_of if j > last_marker), default=len(events))

    def _in_open_pose(i: int) -> bool:
        """An undecoded message after the first message of a pose never finished: lost with it."""
        return i > open_from

    end, finished = _source_end(events, damage)
    rec = Recovery(
        src,
        end,
        finished=finished,
        complete_poses=sorted(complete),
        dropped={p: why for p, why in sorted(sal.bad.items()) if p < sal.n_poses},
        damage=[str(d) for d in damage],
        n_planned=sal.n_poses,
    )
    if not metadata_ok:
        rec.notes.append("the data section's CRC failed: the metadata records were left out")
    extra = {
        RECOVERED_METADATA: {
            "source": src.name,
            "source_end": rec.source_end,
            "campaign_finished": json.dumps(rec.finished),
            "dropped_poses": json.dumps(sorted(rec.dropped)),
            "damage": "; ".join(rec.damage)[:2000],
        }
    }
    copy_log(events, dst, keep=keep, metadata=extra)
    try:
        read_log(dst, include_truth=True)  # what was written must read: else no file
    except InputError:
        Path(dst).unlink(missing_ok=True)
        raise
    return rec


def _source_end(events: list, damage: list[Damage]) -> tuple[str, bool]:
    """How the source ended, as the end of "the source ...", and whether the campaign ran to its
    end (a damaged but finished log: yes)."""
    cut = any(isinstance(e, Cut) for e in events)
    end = next((e for e in events if isinstance(e, Metadata) and e.name == END_METADATA), None)
    status = end.metadata.get("status", "finished") if end is not None else "finished"
    words = []
    if damage:
        words.append(f"was damaged ({damage[0]})")
    if cut:
        words.append("was cut short (no footer)")
    if status != "finished":
        words.append(status + (f" ({end.metadata['reason']})" if end.metadata.get("reason") else ""))
    return " and ".join(words) or "finished", not cut and status == "finished"


__all__ = ["recover_log", "Recovery"]
