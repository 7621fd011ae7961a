"""A readings table as the readings of a campaign log: per pose and state, one reading per
repeat with every reflector's row, built a pose at a time.

The table (bench/shopfloor/formats.py, in columns) is the only copy of the readings held for
the whole import; :class:`CampaignReadings` makes a pose's ``/tracker/measurement`` readings
(:class:`ImportedReading`, with covariances) when asked for them and keeps none, so the
registration (identify/shopfloor/tracker_pose.py) and the log writer
(bench/shopfloor/logcsv.py) each walk the campaign in bounded memory whatever its size: the
readings of one pose, not of the file.

Order. Poses are in the order they were measured: plan order, or, when the table has times, the
order of their first readings (:func:`measured_order`; a pose's readings must form one stretch
of time, unloaded before loaded). ImportedReadings of a pose and state are in time order (file order
without times): the k-th row of each reflector is reading k (bench.shopfloor.readings.group).

Covariance. A reading's row gets sigma^2 I where the table gives its ``sigma``, else the plan's
tracker noise model at the row's position (:func:`bench.tracker.noise_covariance`).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from calbench.bench.core import STATES, InputError
from calbench.bench.scenario import schedule
from calbench.bench.tracker import TrackerSpec, noise_covariance

from .formats import ReadingsTable
from .readings import group, iso8601


@dataclass(frozen=True)
class ImportedReading:
    """One ``/tracker/measurement`` to write: the k-th reading of every reflector of a pose and
    state (bench.readings.GroupedReading) with its covariances; it reads like a
    :class:`bench.tracker.Measurement` (tracker frame, NaN rows where not seen)."""

    repeat: int
    position: np.ndarray  # (n, 3) m
    covariance: np.ndarray  # (n, 3, 3) m^2
    visible: np.ndarray  # (n,) bool
    time: float  # s: the table's (its kind), or the campaign clock's


def reading_covariance(tracker: TrackerSpec, position: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """(..., n, 3, 3) covariance of readings' rows (..., n, 3) (tracker frame): sigma^2 I where
    the row gave a sigma, the tracker model's elsewhere; NaN for rows not seen."""
    cov = np.full((*position.shape[:-1], 3, 3), np.nan)
    seen = np.all(np.isfinite(position), axis=-1)
    given = seen & np.isfinite(sigma)
    model = seen & ~given
    if given.any():
        cov[given] = sigma[given, None, None] ** 2 * np.eye(3)
    if model.any():
        cov[model] = noise_covariance(tracker, position[model])
    return cov


def _time_as_written(table: ReadingsTable, t: float) -> str:
    """A reading's time in the file's own kind (ISO 8601 or seconds), for messages."""
    return iso8601(t) if table.absolute_time else f"{t:g} s"


def measured_order(table: ReadingsTable) -> list[int]:
    """Poses in the order they were measured (see the module docstring); InputError naming the
    row whose time breaks a campaign's order."""
    poses = table.poses()
    if not table.has_time:
        return poses
    n = max(poses) + 1
    t, pose = table.time, table.pose
    unloaded = table.state == STATES.index("unloaded")
    lo, hi = np.full(n, np.inf), np.full(n, -np.inf)
    np.minimum.at(lo, pose, t)
    np.maximum.at(hi, pose, t)
    last_u, first_l = np.full(n, -np.inf), np.full(n, np.inf)
    np.maximum.at(last_u, pose[unloaded], t[unloaded])
    np.minimum.at(first_l, pose[~unloaded], t[~unloaded])

    def first_row(mask: np.ndarray, when: float) -> int:
        """The first row (file order) of ``mask`` at time ``when``."""
        return int(np.flatnonzero(mask & (t == when))[0])

    for p in poses:
        if first_l[p] < last_u[p]:
            i = first_row((pose == p) & ~unloaded, first_l[p])
            j = first_row((pose == p) & unloaded, last_u[p])
            raise InputError(
                table.path,
                f"line {int(table.line[i])}, column time",
                f"the loaded readings of pose {p} after its unloaded ones (line "
                f"{int(table.line[j])} is unloaded and later)",
                _time_as_written(table, float(t[i])),
            )
    order = sorted(poses, key=lambda p: (lo[p], hi[p]))
    for a, b in zip(order, order[1:]):
        if lo[b] < hi[a]:
            i = first_row(pose == b, lo[b])
            raise InputError(
                table.path,
                f"line {int(table.line[i])}, column time",
                f"pose {b}'s readings after every reading of pose {a} (a campaign "
                "measures one pose at a time)",
                _time_as_written(table, float(t[i])),
            )
    return order


class CampaignReadings(Mapping[tuple[int, str], list[ImportedReading]]):
    """The table's readings per (pose, state), made when asked for (module docstring): every
    measured pose in measured order, both states (an empty list where a state has no reading).
    Reflector rows in ``names`` order. Every reading has a time: the table's, or, without a time
    column, the campaign clock's for these poses and readings (bench.scenario.schedule, s since
    the first reading)."""

    def __init__(self, table: ReadingsTable, names: list[str], tracker: TrackerSpec):
        self.table, self.names, self.tracker = table, list(names), tracker
        self.order = measured_order(table)
        self._rows = {(p, s): table.rows(p, s) for p in self.order for s in STATES}
        self.clock: dict | None = None
        if not table.has_time:
            repeats = {key: self._repeats(rows) for key, rows in self._rows.items()}
            self.clock = schedule(
                [(p, repeats[(p, "unloaded")], repeats[(p, "loaded")]) for p in self.order], len(names)
            )

    def _repeats(self, rows: np.ndarray) -> int:
        """ImportedReadings of one pose and state: the most rows of one reflector."""
        return int(np.bincount(self.table.point[rows]).max()) if len(rows) else 0

    def __len__(self) -> int:
        return len(self._rows)

    def __iter__(self) -> Iterator[tuple[int, str]]:
        return iter(self._rows)

    def __getitem__(self, key: tuple[int, str]) -> list[ImportedReading]:
        rows = self._rows[key]
        gs = group(self.table.subset(rows), self.names)
        if not gs:
            return []
        cov = reading_covariance(
            self.tracker, np.array([g.position for g in gs]), np.array([g.sigma for g in gs])
        )
        p, s = key
        return [
            ImportedReading(
                g.repeat,
                g.position,
                cov[k],
                g.visible,
                g.time if self.clock is None else self.clock[(p, s, g.repeat)],
            )
            for k, g in enumerate(gs)
        ]

    @cached_property
    def first_time(self) -> float:
        """The time of the first reading (each reading's time is its last row's; the clock's 0
        without a time column), found without making the readings."""
        if self.clock is not None:
            return min(self.clock.values(), default=0.0)
        times = [g.time for rows in self._rows.values() for g in group(self.table.subset(rows), self.names)]
        return min((t for t in times if t is not None), default=0.0)


ImportedReadings = Mapping[tuple[int, str], list[ImportedReading]]


def first_time(readings: ImportedReadings) -> float:
    """The time of the first of ``readings`` (any mapping of them; CampaignReadings knows it)."""
    if isinstance(readings, CampaignReadings):
        return readings.first_time
    return min((r.time for reps in readings.values() for r in reps), default=0.0)


def campaign_readings(table: ReadingsTable, names: list[str], tracker: TrackerSpec) -> CampaignReadings:
    """The table's rows as log readings per (pose, state) (:class:`CampaignReadings`)."""
    return CampaignReadings(table, names, tracker)


__all__ = [
    "ImportedReading",
    "ImportedReadings",
    "CampaignReadings",
    "reading_covariance",
    "measured_order",
    "campaign_readings",
    "first_time",
]
