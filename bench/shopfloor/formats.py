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

from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calbench.bench.core import Family, FileFormat

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


@dataclass(frozen=True)
class ReadingsTable:
    """A validated readings file."""

    path: Path
    units: str
    columns: tuple[str, ...]
    readings: tuple[Reading, ...]
    absolute_time: bool = False  # times are ISO 8601 (s since 1970) rather than campaign seconds

    @property
    def has_time(self) -> bool:
        return "time" in self.columns

    @property
    def has_sigma(self) -> bool:
        return "sigma" in self.columns

    def poses(self) -> list[int]:
        """The poses with at least one reading, in plan order."""
        return sorted({r.pose for r in self.readings})

    def of(self, pose: int, state: str) -> list[Reading]:
        """The rows of one pose and state, in time order when timed, else in file order."""
        rows = [r for r in self.readings if r.pose == pose and r.state == state]
        if self.has_time:
            rows.sort(key=lambda r: (r.time, r.line))
        return rows


class ReadingsFormat(FileFormat, ABC):
    """One form of tracker readings (its ``name``, ``summary`` and ``suffixes``: FileFormat)."""

    @abstractmethod
    def read(
        self, path: Path, data: bytes, n_poses: int, points: Sequence[str], units: str = "mm"
    ) -> ReadingsTable:
        """The validated readings of the file ``path`` whose content is ``data`` (SI inside)."""


# the formats by name (FORMATS.members(), .register(...), .unregister(name), .for_path(path))
FORMATS: Family[ReadingsFormat] = Family("readings format", BUILTIN, "FORMAT", DEFAULT)
