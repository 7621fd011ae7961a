"""The readings format family: a file of real tracker readings in some form, read into the one
validated table `calbench import` works from (:class:`~.readings.ReadingsTable`), and the registry
of formats.

A format says which files it accepts (:attr:`ReadingsFormat.suffixes`, the ends of their names)
and reads one file's bytes, for a plan of ``n_poses`` poses whose robot has the reflector sites
``points``, with lengths in ``units`` where the file does not say. Every bad reading is an
InputError naming the file, the line and the column. The CSV form (bench/shopfloor/readings.py,
docs/contract.md "Tracker readings") is the one shipped; a module listed in :data:`BUILTIN` is
found on first use (its ``FORMAT``), and :data:`FORMATS`'s ``register`` adds one from outside
(a test, a notebook). A file no format claims by its name is read as CSV, as every file was
before there were formats. ``calbench export`` writes the CSV form.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path

import numpy as np

from calbench.bench.core import STATES, Family, FileFormat, InputError

BUILTIN = ("calbench.bench.shopfloor.readings",)  # modules whose FORMAT is registered on first use
DEFAULT = "csv"  # the format of a file no format claims by its name


@dataclass(frozen=True)
class Reading:
    """One row: a reflector seen once in one state of one pose (SI, tracker frame)."""

    line: int  # 1-based line in the file (a CSV's header is line 1)
    pose: int
    state: str
    point: str
    position: np.ndarray  # (3,) m, tracker frame
    time: float | None = None  # s: since the campaign's start, or since 1970 (UTC) when ``absolute``
    sigma: float | None = None  # m, per axis


# Bytes a row of a :class:`ReadingsTable` takes: line (4), pose (4), state (1), point (2),
# position (24), time (8), sigma (8). The table is kept in columns, not as row objects (a
# Reading with its position array is ~500 bytes), so a 10^6-row file holds ~51 MB.
ROW_BYTES = 4 + 4 + 1 + 2 + 24 + 8 + 8


@dataclass(frozen=True, eq=False)
class ReadingsTable:
    """A validated readings file, in columns (one entry per row, file order).

    ``point`` indexes ``points`` (the robot's reflector sites), ``state`` indexes STATES; ``time``
    and ``sigma`` are NaN where the file has none. :meth:`rows` gives rows as :class:`Reading`
    objects, for a few rows at a time."""

    path: Path
    units: str
    columns: tuple[str, ...]
    points: tuple[str, ...]
    line: np.ndarray  # (n,) uint32
    pose: np.ndarray  # (n,) int32
    state: np.ndarray  # (n,) int8, index into STATES
    point: np.ndarray  # (n,) int16, index into points
    position: np.ndarray  # (n, 3) m, tracker frame
    time: np.ndarray  # (n,) s (see Reading.time), NaN without a time column
    sigma: np.ndarray  # (n,) m, NaN where not given
    absolute_time: bool = False  # times are ISO 8601 (s since 1970) rather than campaign seconds

    @classmethod
    def from_readings(
        cls,
        path: Path,
        units: str,
        columns: tuple[str, ...],
        readings: Sequence[Reading],
        points: Sequence[str],
        absolute_time: bool = False,
    ) -> ReadingsTable:
        """The table of ``readings`` (row objects, e.g. from a format that builds them)."""
        pts = tuple(points)
        at = {name: i for i, name in enumerate(pts)}
        n = len(readings)
        return cls(
            Path(path),
            units,
            tuple(columns),
            pts,
            np.fromiter((r.line for r in readings), np.uint32, n),
            np.fromiter((r.pose for r in readings), np.int32, n),
            np.fromiter((STATES.index(r.state) for r in readings), np.int8, n),
            np.fromiter((at[r.point] for r in readings), np.int16, n),
            np.array([r.position for r in readings], dtype=float).reshape(n, 3),
            np.array([np.nan if r.time is None else r.time for r in readings], dtype=float),
            np.array([np.nan if r.sigma is None else r.sigma for r in readings], dtype=float),
            absolute_time,
        )

    def __len__(self) -> int:
        return len(self.line)

    @property
    def has_time(self) -> bool:
        return "time" in self.columns

    @property
    def has_sigma(self) -> bool:
        return "sigma" in self.columns

    @property
    def nbytes(self) -> int:
        """Bytes its columns hold (ROW_BYTES per row)."""
        return sum(
            a.nbytes
            for a in (self.line, self.pose, self.state, self.point, self.position, self.time, self.sigma)
        )

    def reading(self, i: int) -> Reading:
        """Row ``i`` as a :class:`Reading`."""
        t, s = float(self.time[i]), float(self.sigma[i])
        return Reading(
            int(self.line[i]),
            int(self.pose[i]),
            STATES[int(self.state[i])],
            self.points[int(self.point[i])],
            self.position[i].copy(),
            None if math.isnan(t) else t,
            None if math.isnan(s) else s,
        )

    @property
    def readings(self) -> tuple[Reading, ...]:
        """Every row as a :class:`Reading` (small tables: ~500 bytes a row)."""
        return tuple(self.reading(i) for i in range(len(self)))

    @cached_property
    def _groups(self) -> tuple[np.ndarray, dict[int, tuple[int, int]]]:
        """Row indices sorted by pose and state (then time when timed, then file order), and
        where each (pose, state) starts and ends in them (4 bytes a row)."""
        key = self.pose.astype(np.int64) * len(STATES) + self.state
        order = np.lexsort((self.time, key)) if self.has_time else np.argsort(key, kind="stable")
        k = key[order]
        starts = np.flatnonzero(np.r_[True, k[1:] != k[:-1]]) if len(k) else np.zeros(0, int)
        ends = np.r_[starts[1:], len(k)]
        spans = {int(k[a]): (int(a), int(b)) for a, b in zip(starts, ends)}
        return order.astype(np.int32), spans

    def poses(self) -> list[int]:
        """The poses with at least one reading, in plan order."""
        return sorted({k // len(STATES) for k in self._groups[1]})

    def rows(self, pose: int, state: str) -> np.ndarray:
        """Indices of the rows of one pose and state, in time order when timed (ties in file
        order), else in file order."""
        order, spans = self._groups
        a, b = spans.get(pose * len(STATES) + STATES.index(state), (0, 0))
        return order[a:b]

    def subset(self, idx: np.ndarray) -> ReadingsTable:
        """The table of rows ``idx`` (in that order)."""
        return replace(
            self,
            line=self.line[idx],
            pose=self.pose[idx],
            state=self.state[idx],
            point=self.point[idx],
            position=self.position[idx],
            time=self.time[idx],
            sigma=self.sigma[idx],
        )

    def of(self, pose: int, state: str) -> ReadingsTable:
        """The rows of one pose and state (:meth:`rows`) as a table."""
        return self.subset(self.rows(pose, state))


class ReadingsFormat(FileFormat, ABC):
    """One form of tracker readings (its ``name``, ``summary`` and ``suffixes``: FileFormat)."""

    @abstractmethod
    def read(
        self, path: Path, data: bytes, n_poses: int, points: Sequence[str], units: str = "mm"
    ) -> ReadingsTable:
        """The validated readings of the file ``path`` whose content is ``data`` (SI inside)."""

    def read_file(
        self, path: Path, n_poses: int, points: Sequence[str], units: str = "mm", progress=None
    ) -> ReadingsTable:
        """The validated readings of the file ``path``. This reads the whole file into memory and
        calls :meth:`read`; a format that can read a row at a time overrides it (the CSV form
        does: bounded memory for any size). ``progress`` (bench.core.ProgressSink, or None) is
        started with the file's size in MB and updated as they are read."""
        try:
            data = Path(path).read_bytes()
        except OSError as exc:
            raise InputError(path, "(file)", f"a readable {self.name.upper()} file", exc.strerror) from None
        return self.read(path, data, n_poses, points, units)


# the formats by name (FORMATS.members(), .register(...), .unregister(name), .for_path(path))
FORMATS: Family[ReadingsFormat] = Family("readings format", BUILTIN, "FORMAT", DEFAULT)
