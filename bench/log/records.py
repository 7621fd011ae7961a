"""A campaign log as read back: typed records of what the MCAP topics carry.

:func:`bench.logformat.read_log` decodes the JSON messages into these frozen dataclasses, so
the modules that use a log (identification, the viewer) read named fields, not nested dicts.
One record per topic family:

* ``/campaign/pose``        -> :class:`PerState` of the commanded q (rad) per pose;
* ``/campaign/wrench``      -> :class:`WrenchRecord` per pose;
* ``/tracker/measurement``  -> :class:`MeasurementRecord` per reading;
* ``/truth/...`` and the ``ground_truth`` record -> one :class:`CampaignTruth`, present only when
  the log was read with ``include_truth=True`` (the reader skips ``/truth/`` messages before
  decoding otherwise, so nothing here can carry the truth by accident).

Units: SI throughout (m, rad, N, N*m; covariances in m^2).
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path
from typing import Any, Generic, TypeVar

import numpy as np

from calbench.bench.core import STATES
from calbench.bench.model import Params, Spring, springs_from_message
from calbench.bench.tracker import TrackerSpec

T = TypeVar("T")


@dataclass(frozen=True)
class PerState(Generic[T]):
    """One value per load state of a pose; None where the log holds none."""

    unloaded: T | None = None
    loaded: T | None = None

    def get(self, state: str) -> T | None:
        if state not in STATES:
            raise ValueError(f"state must be one of {STATES}, got {state!r}")
        return getattr(self, state)

    def both(self) -> bool:
        return self.unloaded is not None and self.loaded is not None


@dataclass(frozen=True)
class MeasurementRecord:
    """One tracker reading: positions (n,3) m in the tracker frame with NaN rows where not
    visible, covariances (n,3,3) m^2 (NaN where not visible), visibility flags, and the
    message's log time (ns since 1970, when the reading was complete)."""

    pose: int
    state: str
    repeat: int
    reflectors: list[str]
    position: np.ndarray
    covariance: np.ndarray
    visible: np.ndarray
    time: int | None = None

    def in_order(self, names: Sequence[str]) -> MeasurementRecord:
        """This reading with its rows in ``names`` order; a reflector it does not list is not
        visible (NaN rows). Returns ``self`` when the order already matches."""
        if list(self.reflectors) == list(names):
            return self
        n = len(names)
        pos, cov, vis = np.full((n, 3), np.nan), np.full((n, 3, 3), np.nan), np.zeros(n, bool)
        row = {r: j for j, r in enumerate(self.reflectors)}
        for i, name in enumerate(names):
            j = row.get(name)
            if j is not None:
                pos[i], cov[i], vis[i] = self.position[j], self.covariance[j], self.visible[j]
        return replace(self, reflectors=list(names), position=pos, covariance=cov, visible=vis)


@dataclass(frozen=True)
class WrenchRecord:
    """The load of a pose's loaded state (``/campaign/wrench``), world frame."""

    pose: int
    force: np.ndarray  # (3,) N
    moment: np.ndarray  # (3,) N*m
    site: str  # MJCF site the wrench acts at
    mass: float | None  # kg when the load is a hanging payload, else None


@dataclass(frozen=True)
class TruthParameters:
    """The simulated robot's true parameters (``/truth/parameters``)."""

    compliance: np.ndarray  # (N,) rad/(N*m), motors 1..N
    springs: Mapping[str, Spring]  # compensator springs by tendon name
    effects: Mapping[str, Any]  # hidden effects, as the scenario's [truth.effects.*]

    @classmethod
    def from_message(cls, m: Mapping[str, Any]) -> TruthParameters:
        """Parse the JSON message; raises KeyError, TypeError or ValueError when malformed."""
        k = np.asarray(m["compliance"], dtype=float)
        if k.ndim != 1 or k.size == 0:
            raise ValueError(f"compliance: expected one number per actuated joint, got shape {k.shape}")
        return cls(k, springs_from_message(m), dict(m.get("effects") or {}))

    def params(self) -> Params:
        return Params(self.compliance, dict(self.springs))


@dataclass(frozen=True)
class TruthReflectors:
    """True reflector positions of one pose and state (``/truth/reflectors``)."""

    reflectors: tuple[str, ...]
    position_world: np.ndarray  # (n, 3) m


@dataclass(frozen=True)
class TruthJoints:
    """True equilibrium of one pose and state (``/truth/joints``)."""

    qpos: np.ndarray  # full MuJoCo qpos
    deflection: np.ndarray  # (N,) rad, motor-space deflection from the command


@dataclass(frozen=True)
class CampaignTruth:
    """Everything a simulated campaign knows that a real one would not (complete poses only).

    ``scenario_text`` is the original scenario, with its [truth] tables.
    """

    parameters: TruthParameters | None
    reflectors: dict[int, PerState[TruthReflectors]] = field(default_factory=dict)
    joints: dict[int, PerState[TruthJoints]] = field(default_factory=dict)
    scenario_text: str | None = None


@dataclass(frozen=True)
class CampaignLog:
    """A campaign log as read back: complete poses only.

    ``header`` is the ``/campaign/info`` message (its ``tracker`` parsed by
    :meth:`tracker_spec`). ``truncated`` is True when the campaign did not run to its end (the
    file has no footer, was interrupted, or was recovered from such a file); ``end`` says how the
    log ended, in words ("finished", "the campaign was interrupted (Ctrl-C) ..."); ``dropped_poses`` are the poses ``calbench recover`` found damaged and
    left out. ``truth`` is None unless read with ``include_truth=True`` and the log carries
    truth.
    """

    path: Path
    header: dict
    scenario_text: str | None
    mjcf_text: str | None
    poses: dict[int, PerState[np.ndarray]] = field(default_factory=dict)  # q (N,) rad
    wrenches: dict[int, WrenchRecord] = field(default_factory=dict)
    # every reading of the complete poses, in log order: a list, or for a log too big to hold
    # (bench/log/read.py KEEP_READINGS) a collection that reads them again a pose at a time
    # (LogReadings: iterate it, or ask readings(pose, state))
    measurements: Collection[MeasurementRecord] = field(default_factory=list)
    complete_poses: list[int] = field(default_factory=list)
    n_poses_planned: int = 0
    truncated: bool = False
    truth: CampaignTruth | None = None
    end: str = "finished"
    dropped_poses: list[int] = field(default_factory=list)

    @property
    def lost_poses(self) -> list[int]:
        """Planned poses the log does not hold complete."""
        return sorted(set(range(self.n_poses_planned)) - set(self.complete_poses))

    def completeness(self) -> str | None:
        """One line on what is missing, the same words for every verb; None when the campaign
        finished with every planned pose."""
        lost = self.lost_poses
        if not lost and not self.truncated:
            return None
        text = f"{len(self.complete_poses)} of {self.n_poses_planned} planned poses complete" + (
            f", {len(lost)} lost {pose_list(lost)}" if lost else ""
        )
        if self.dropped_poses:
            text += f" (damaged and dropped: {pose_list(self.dropped_poses)})"
        return f"{text}; {self.end}"

    def tracker_spec(self) -> TrackerSpec:
        """The tracker of the header (position m, yaw rad, noise model); InputError naming the
        log and the key when it is malformed."""
        return TrackerSpec.from_dict(self.header.get("tracker"), self.path, "/campaign/info.tracker")

    @cached_property
    def _by_state(self) -> dict[tuple[int, str], list[MeasurementRecord]]:
        out: dict[tuple[int, str], list[MeasurementRecord]] = {}
        for m in self.measurements:
            out.setdefault((m.pose, m.state), []).append(m)
        return out

    def readings(self, pose: int, state: str) -> list[MeasurementRecord]:
        """The readings of one pose and state, in log order (empty when none)."""
        of = getattr(self.measurements, "of", None)
        if of is not None:  # a log read a pose at a time
            return of(pose, state)
        return list(self._by_state.get((pose, state), ()))

    @property
    def first_reading_time(self) -> int | None:
        """When the first reading was complete (ns since 1970); None without readings or when
        one has no time."""
        if hasattr(self.measurements, "first_time"):
            return self.measurements.first_time  # type: ignore[attr-defined]
        times = [m.time for m in self.measurements]
        return None if not times or None in times else min(t for t in times if t is not None)


def pose_list(poses: Sequence[int]) -> str:
    """``[0, 1, 2, 5]`` as "[0-2, 5]": runs of consecutive poses shortened."""
    out: list[str] = []
    ps = sorted(poses)
    i = 0
    while i < len(ps):
        j = i
        while j + 1 < len(ps) and ps[j + 1] == ps[j] + 1:
            j += 1
        out.append(str(ps[i]) if j == i else f"{ps[i]}-{ps[j]}")
        i = j + 1
    return "[" + ", ".join(out) + "]"


__all__ = [
    "pose_list",
    "STATES",
    "PerState",
    "MeasurementRecord",
    "WrenchRecord",
    "TruthParameters",
    "TruthReflectors",
    "TruthJoints",
    "CampaignTruth",
    "CampaignLog",
]
