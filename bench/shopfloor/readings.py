"""Tracker readings as CSV: the form `calbench export` writes, and `calbench import`'s default.

The form (docs/contract.md, "Tracker readings"), what tracker software (SpatialAnalyzer,
PolyWorks, Tracker Pilot, ...) exports, reduced to one table:

    pose,state,point,x,y,z[,time][,sigma]

* a header row naming the columns (any order; ``time`` and ``sigma`` optional, nothing else);
* ``pose``: the 0-based index of the plan's ``[[pose]]``; ``state``: ``unloaded`` or ``loaded``;
  ``point``: the reflector's site name in the MJCF;
* ``x, y, z``: the reflector in the tracker's own frame (origin at the tracker head), in
  millimetres, or metres with ``units="m"``;
* several rows with the same pose, state and point are repeats; a reflector with no row was not
  seen;
* ``time``: seconds since the campaign's start, or an ISO 8601 date-time with a UTC offset (one
  kind per file); ``sigma``: the reading's own per-axis 1-sigma (same unit as x, y, z), its
  independent error (for an isotropic or spec tracker all of it).

Every bad row is an InputError naming the file, the line and the column (exit 2): an unknown
point, a pose outside the plan, a missing or unknown state, a non-number, a position whose range
from the tracker is absurd (the unit is wrong: a tracker measures from MIN_RANGE to MAX_RANGE), a
sigma outside SIGMA_RANGE, a loaded reading identical to an unloaded one (a copied row: 700 kg
moves a reflector by millimetres, and two real readings never agree to the last digit).

Units: SI inside (m, s); mm only in the file.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from calbench.bench.core import STATES, InputError

from .formats import Reading, ReadingsFormat, ReadingsTable

REQUIRED = ("pose", "state", "point", "x", "y", "z")
OPTIONAL = ("time", "sigma")
UNITS = {"mm": 1e-3, "m": 1.0}
# A laser tracker's measuring range: from the closest a reflector can be tracked (the Leica AT960
# and FARO Vantage data sheets start at 0.8 m and 0.6 m; 0.3 m leaves room) to 100 m (the AT960's
# 160 m diameter). A file in metres read as millimetres puts a robot 3 m away at 3 mm, one in
# millimetres read as metres at 3 km: both are refused.
MIN_RANGE = 0.3  # m
MAX_RANGE = 100.0  # m
# A reading's 1-sigma: from 0.1 um (below any tracker's resolution) to 1 mm (no tracker reading
# is that poor; a sigma in um read as mm lands here).
SIGMA_RANGE = (1e-7, 1e-3)  # m
EPOCH = datetime(1970, 1, 1, tzinfo=UTC)


@dataclass(frozen=True)
class GroupedReading:
    """The k-th reading of every reflector of one pose and state: one ``/tracker/measurement``.

    Rows of reflectors with fewer than k + 1 rows are not visible (NaN)."""

    repeat: int
    position: np.ndarray  # (n, 3) m, tracker frame, NaN where not seen
    visible: np.ndarray  # (n,) bool
    sigma: np.ndarray  # (n,) m, NaN where not given or not seen
    time: float | None  # s (the table's time kind): when the last of its rows was read


def group(rows: Sequence[Reading], names: Sequence[str]) -> list[GroupedReading]:
    """Rows of one pose and state as log readings: the k-th row of each reflector (in the given
    order) forms reading k."""
    per = {n: [r for r in rows if r.point == n] for n in names}
    count = max((len(v) for v in per.values()), default=0)
    out = []
    for k in range(count):
        n = len(names)
        pos, vis, sig = np.full((n, 3), np.nan), np.zeros(n, bool), np.full(n, np.nan)
        times = []
        for i, name in enumerate(names):
            if k < len(per[name]):
                r = per[name][k]
                pos[i], vis[i] = r.position, True
                sig[i] = np.nan if r.sigma is None else r.sigma
                if r.time is not None:
                    times.append(r.time)
        out.append(GroupedReading(k, pos, vis, sig, max(times) if times else None))
    return out


# --------------------------------------------------------------------------- reading


def _where(line: int, column: str) -> str:
    return f"line {line}, column {column}"


def _number(path: Path, line: int, column: str, text: str) -> float:
    try:
        x = float(text)
    except ValueError:
        raise InputError(path, _where(line, column), "a number", text) from None
    if not math.isfinite(x):
        raise InputError(path, _where(line, column), "a finite number", text)
    return x


def _time(path: Path, line: int, text: str) -> tuple[float, bool]:
    """(seconds, absolute): a number of seconds since the campaign's start, or ISO 8601."""
    try:
        x = float(text)
    except ValueError:
        pass
    else:
        if not math.isfinite(x) or x < 0:
            raise InputError(
                path,
                _where(line, "time"),
                "seconds >= 0 since the campaign's start or an ISO 8601 date-time",
                text,
            )
        return x, False
    try:
        when = datetime.fromisoformat(text.strip().replace("Z", "+00:00"))
    except ValueError:
        raise InputError(
            path,
            _where(line, "time"),
            "seconds since the campaign's start or an ISO "
            "8601 date-time with a UTC offset, e.g. 2026-01-05T08:12:30.5Z",
            text,
        ) from None
    if when.tzinfo is None or when.utcoffset() is None:
        raise InputError(
            path,
            _where(line, "time"),
            "an ISO 8601 date-time with a UTC offset (Z or +hh:mm: the offset says which clock)",
            text,
        )
    return (when - EPOCH).total_seconds(), True


def _header(path: Path, fields: list[str]) -> tuple[str, ...]:
    names = tuple(f.strip().lower() for f in fields)
    for i, name in enumerate(names):
        col = f"column {i + 1}"
        if name not in REQUIRED + OPTIONAL:
            raise InputError(
                path, f"line 1, {col}", "a column named one of " + ", ".join(REQUIRED + OPTIONAL), fields[i]
            )
        if name in names[:i]:
            raise InputError(path, f"line 1, {col}", "each column once", fields[i])
    missing = [c for c in REQUIRED if c not in names]
    if missing:
        raise InputError(
            path,
            "line 1",
            "a header row with the columns " + ",".join(REQUIRED) + " (optional: time, sigma)",
            ",".join(fields),
        )
    return names


def read_readings(
    path: str | Path, n_poses: int, points: Sequence[str], units: str = "mm", text: str | None = None
) -> ReadingsTable:
    """Read and validate a readings CSV for a plan of ``n_poses`` poses whose robot has the
    reflector sites ``points`` (see the module docstring for every rule). ``text`` is the
    file's content when already read."""
    path = Path(path)
    if units not in UNITS:
        raise InputError("--units", "units", " or ".join(UNITS), units)
    scale = UNITS[units]
    if text is None:
        try:
            text = path.read_text(encoding="utf-8-sig")
        except (OSError, UnicodeDecodeError) as exc:
            raise InputError(path, "(file)", "a readable UTF-8 CSV file", str(exc)) from None
    elif text.startswith("\ufeff"):
        text = text[1:]
    rows = csv.reader(io.StringIO(text, newline=""))
    try:
        fields = next(rows)
    except StopIteration:
        raise InputError(path, "line 1", "a header row: " + ",".join(REQUIRED), "an empty file") from None
    except csv.Error as exc:
        raise InputError(path, "line 1", "a CSV header row", str(exc)) from None
    columns = _header(path, fields)
    col = {name: i for i, name in enumerate(columns)}
    known = set(points)
    out: list[Reading] = []
    absolute: bool | None = None
    seen: dict[tuple[int, str, tuple[float, float, float]], tuple[str, int]] = {}
    try:
        for values in rows:
            line = rows.line_num
            if not any(v.strip() for v in values):
                continue  # blank lines
            if len(values) != len(columns):
                raise InputError(
                    path,
                    f"line {line}",
                    f"{len(columns)} fields as in the header ({','.join(columns)})",
                    f"{len(values)} fields",
                )
            cell = {name: values[i].strip() for name, i in col.items()}
            try:
                pose = int(cell["pose"])
            except ValueError:
                raise InputError(
                    path, _where(line, "pose"), "a 0-based pose index (an integer)", cell["pose"]
                ) from None
            if not 0 <= pose < n_poses:
                raise InputError(
                    path,
                    _where(line, "pose"),
                    f"a pose of the plan: an index in 0..{n_poses - 1}",
                    cell["pose"],
                )
            state = cell["state"].lower()
            if state not in STATES:
                raise InputError(
                    path, _where(line, "state"), "unloaded or loaded", cell["state"] or "an empty cell"
                )
            point = cell["point"]
            if point not in known:
                raise InputError(
                    path,
                    _where(line, "point"),
                    "a reflector site of the robot: " + ", ".join(points),
                    point or "an empty cell",
                )
            xyz = np.array([_number(path, line, c, cell[c]) for c in ("x", "y", "z")]) * scale
            rng = float(np.linalg.norm(xyz))
            if not MIN_RANGE <= rng <= MAX_RANGE:
                other = "m" if units == "mm" else "mm"
                raise InputError(
                    path,
                    _where(line, "x"),
                    f"a reflector {MIN_RANGE:g} to "
                    f"{MAX_RANGE:g} m from the tracker (x, y, z in {units}; is the "
                    f"file in {other}? --units {other})",
                    f"{rng:.4g} m away",
                )
            t = None
            if "time" in col:
                t, is_abs = _time(path, line, cell["time"])
                if absolute is None:
                    absolute = is_abs
                elif is_abs != absolute:
                    raise InputError(
                        path,
                        _where(line, "time"),
                        "the same kind of time in every row ("
                        + ("ISO 8601 date-times" if absolute else "seconds")
                        + ")",
                        cell["time"],
                    )
            sigma = None
            if "sigma" in col:
                sigma = _number(path, line, "sigma", cell["sigma"]) * scale
                lo, hi = SIGMA_RANGE
                if not lo <= sigma <= hi:
                    raise InputError(
                        path,
                        _where(line, "sigma"),
                        f"a 1-sigma from {lo / scale:g} to {hi / scale:g} {units}",
                        cell["sigma"],
                    )
            key = (pose, point, tuple(float(v) for v in xyz))
            twin = seen.setdefault(key, (state, line))
            if twin[0] != state:
                raise InputError(
                    path,
                    _where(line, "state"),
                    f"a {state} reading that differs from the "
                    f"{twin[0]} one (line {twin[1]} has the same x, y, z: a row copied "
                    "into both states?)",
                    state,
                )
            out.append(Reading(line, pose, state, point, xyz, t, sigma))
    except csv.Error as exc:
        raise InputError(path, f"line {rows.line_num}", "valid CSV", str(exc)) from None
    if not out:
        raise InputError(path, "line 2", "at least one reading after the header", "none")
    return ReadingsTable(path, units, columns, tuple(out), bool(absolute))


# --------------------------------------------------------------------------- writing


@dataclass(frozen=True)
class Row:
    """One row to write (SI): the export side of :class:`Reading`."""

    pose: int
    state: str
    point: str
    position: np.ndarray  # (3,) m, tracker frame
    time: float | None = None  # s since 1970 (UTC): written as ISO 8601
    sigma: float | None = None  # m


def iso8601(seconds: float) -> str:
    """Seconds since 1970 (UTC) as ISO 8601 with microseconds and a Z."""
    when = datetime.fromtimestamp(seconds, tz=UTC)
    return when.isoformat(timespec="microseconds").replace("+00:00", "Z")


def readings_csv(rows: Iterable[Row], units: str = "mm") -> str:
    """The CSV text of ``rows``. Positions with 6 decimals of the unit (1 nm in mm): far below
    any tracker's noise, so a round trip loses nothing that matters. The ``time`` column is
    written when every row has a time, ``sigma`` when every row has one."""
    rows = list(rows)
    scale = 1.0 / UNITS[units]
    digits = 6 if units == "mm" else 9
    with_time = bool(rows) and all(r.time is not None for r in rows)
    with_sigma = bool(rows) and all(r.sigma is not None for r in rows)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(REQUIRED + (("time",) if with_time else ()) + (("sigma",) if with_sigma else ()))
    for r in rows:
        xyz = [f"{v * scale:.{digits}f}" for v in r.position]
        extra = ([iso8601(r.time)] if with_time else []) + (
            [f"{r.sigma * scale:.{digits}f}"] if with_sigma else []
        )
        w.writerow([r.pose, r.state, r.point, *xyz, *extra])
    return buf.getvalue()


class CsvReadings(ReadingsFormat):
    """The CSV form (this module): :func:`read_readings` behind the readings format interface."""

    name = "csv"
    summary = "pose,state,point,x,y,z[,time][,sigma] (docs/contract.md, 'Tracker readings')"
    suffixes = (".csv",)

    def read(
        self, path: Path, data: bytes, n_poses: int, points: Sequence[str], units: str = "mm"
    ) -> ReadingsTable:
        try:
            text = data.decode("utf-8-sig")
        except UnicodeDecodeError as exc:
            raise InputError(path, "(file)", "a UTF-8 CSV file", str(exc)) from None
        return read_readings(path, n_poses, points, units, text=text)


FORMAT = CsvReadings()

__all__ = [
    "REQUIRED",
    "OPTIONAL",
    "UNITS",
    "MIN_RANGE",
    "MAX_RANGE",
    "SIGMA_RANGE",
    "Reading",
    "ReadingsTable",
    "GroupedReading",
    "group",
    "read_readings",
    "Row",
    "CsvReadings",
    "FORMAT",
    "readings_csv",
    "iso8601",
]
