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
import os
import re
from array import array
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from calbench.bench.core import STATES, InputError, ProgressSink, check_memory, sink

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


def group(rows: ReadingsTable, names: Sequence[str]) -> list[GroupedReading]:
    """Rows of one pose and state (:meth:`ReadingsTable.of`) as log readings: the k-th row of
    each reflector (in the table's order) forms reading k, rows in ``names`` order."""
    n, m = len(names), len(rows)
    at = {name: i for i, name in enumerate(names)}
    col = (
        np.array([at.get(p, -1) for p in rows.points], dtype=np.int64)[rows.point] if m else np.zeros(0, int)
    )
    # k: how many rows of the same reflector come before each row
    k = np.zeros(m, dtype=np.int64)
    for i in range(n):
        mine = np.flatnonzero(col == i)
        k[mine] = np.arange(len(mine))
    count = int(k.max()) + 1 if m else 0
    pos = np.full((count, n, 3), np.nan)
    sig = np.full((count, n), np.nan)
    vis = np.zeros((count, n), bool)
    when = np.full((count, n), np.nan)
    ok = col >= 0
    pos[k[ok], col[ok]] = rows.position[ok]
    sig[k[ok], col[ok]] = rows.sigma[ok]
    vis[k[ok], col[ok]] = True
    when[k[ok], col[ok]] = rows.time[ok]
    out = []
    for j in range(count):
        t = when[j][vis[j]]
        t = t[np.isfinite(t)]
        out.append(GroupedReading(j, pos[j], vis[j], sig[j], float(t.max()) if len(t) else None))
    return out


# --------------------------------------------------------------------------- reading


def _where(line: int, column: str) -> str:
    return f"line {line}, column {column}"


def _number(path: Path, line: int, column: str, text: str) -> float:
    try:
        x = float(text)
    except ValueError:
        raise InputError(path, _where(line, column), "a number", text.strip()) from None
    if not math.isfinite(x):
        raise InputError(path, _where(line, column), "a finite number", text.strip())
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


MB = 1 << 20  # progress counts the file in these


def _lines(f, progress, size: int) -> Iterator[str]:
    """The text lines of the binary file ``f`` (UTF-8, a leading BOM dropped; a line ends at
    \\n, \\r\\n or a lone \\r), reporting the MB read to ``progress``. Decoded a line at a
    time, so a byte that is not UTF-8 is named by its line."""
    done = 0
    for k, raw in enumerate(f):
        if not k:
            raw = raw.removeprefix(b"\xef\xbb\xbf")
        elif not k & 4095:
            now = min(f.tell(), size) // MB
            if now > done:
                progress.update(step=now - done)
                done = now
        text = raw.decode("utf-8")
        if "\r" in text[:-2]:
            yield from LONE_CR.split(text)  # old Mac line ends
        else:
            yield text
    progress.update(step=max(-(-size // MB) - done, 0))


LONE_CR = re.compile(r"(?<=\r)(?!\n|$)")


# Memory of a table row while the file is read (formats.ROW_BYTES = 51 in the columns, ~6 %
# spare as they grow, the (pose, state) index's 4 and the transients of the copied-row check and
# of that index, ~24): tests/test_sizes.py holds the reader to it.
TABLE_BYTES_PER_ROW = 100
SAMPLE = 1 << 16  # bytes of the file's start read to estimate its rows


def check_fits(path: Path, f, size: int) -> None:
    """Refuse up front a file whose table would not fit in memory: its rows estimated from the
    bytes per line of its first SAMPLE bytes (the open text file ``f`` is rewound)."""
    head = f.read(SAMPLE)
    f.seek(0)
    if not head:
        return
    lines = head.count(b"\n") or head.count(b"\r") or 1
    rows = size * lines / len(head)
    check_memory(
        rows * TABLE_BYTES_PER_ROW,
        path,
        "(file)",
        f"~{rows:,.0f} rows at {TABLE_BYTES_PER_ROW} B each (its first {len(head):,} bytes hold {lines:,} lines)",
    )


def read_readings(
    path: str | Path,
    n_poses: int,
    points: Sequence[str],
    units: str = "mm",
    text: str | None = None,
    progress: ProgressSink | None = None,
) -> ReadingsTable:
    """Read and validate a readings CSV for a plan of ``n_poses`` poses whose robot has the
    reflector sites ``points`` (see the module docstring for every rule). ``text`` is the
    file's content when already read; otherwise the file is read a line at a time into the
    table's columns (formats.ROW_BYTES a row: a 10^6-row file in ~51 MB, never the whole text),
    with ``progress`` started with its size in MB."""
    path = Path(path)
    if units not in UNITS:
        raise InputError("--units", "units", " or ".join(UNITS), units)
    if text is not None:
        return _read(
            path,
            io.StringIO(text[1:] if text.startswith("\ufeff") else text, newline=""),
            n_poses,
            points,
            units,
        )
    bar = sink(progress)
    try:
        f = open(path, "rb")
        size = os.fstat(f.fileno()).st_size
    except OSError as exc:
        raise InputError(path, "(file)", "a readable UTF-8 CSV file", exc.strerror or str(exc)) from None
    with f:
        check_fits(path, f, size)
        bar.start(max(-(-size // MB), 1), "reading " + path.name)
        return _read(path, _lines(f, bar, size), n_poses, points, units)


def _read(path: Path, lines: Iterable[str], n_poses: int, points: Sequence[str], units: str) -> ReadingsTable:
    scale = UNITS[units]
    rows = csv.reader(lines)
    try:
        try:
            fields = next(rows)
        except StopIteration:
            raise InputError(path, "line 1", "a header row: " + ",".join(REQUIRED), "an empty file") from None
        except csv.Error as exc:
            raise InputError(path, "line 1", "a CSV header row", str(exc)) from None
        columns = _header(path, fields)
        col = {name: i for i, name in enumerate(columns)}
        i_pose, i_state, i_point, i_x, i_y, i_z = (col[c] for c in REQUIRED)
        i_time, i_sigma = col.get("time"), col.get("sigma")
        point_at = {name: i for i, name in enumerate(points)}
        state_at = {s: i for i, s in enumerate(STATES)}
        lo, hi = SIGMA_RANGE
        # the table's columns, grown a row at a time (array.array: ~6 % spare, no per-row object)
        c_line, c_pose, c_state = array("I"), array("i"), array("b")
        c_point, c_pos, c_time, c_sigma = array("h"), array("d"), array("d"), array("d")
        absolute: bool | None = None
        ncol = len(columns)
        for values in rows:
            line = rows.line_num
            if len(values) != ncol:
                if not any(v.strip() for v in values):
                    continue  # blank lines
                raise InputError(
                    path,
                    f"line {line}",
                    f"{ncol} fields as in the header ({','.join(columns)})",
                    f"{len(values)} fields",
                )
            text = values[i_pose]
            try:
                pose = int(text)
            except ValueError:
                if not any(v.strip() for v in values):
                    continue
                raise InputError(
                    path, _where(line, "pose"), "a 0-based pose index (an integer)", text.strip()
                ) from None
            if not 0 <= pose < n_poses:
                raise InputError(
                    path,
                    _where(line, "pose"),
                    f"a pose of the plan: an index in 0..{n_poses - 1}",
                    text.strip(),
                )
            text = values[i_state].strip()
            state = state_at.get(text.lower())
            if state is None:
                raise InputError(path, _where(line, "state"), "unloaded or loaded", text or "an empty cell")
            text = values[i_point].strip()
            point = point_at.get(text)
            if point is None:
                raise InputError(
                    path,
                    _where(line, "point"),
                    "a reflector site of the robot: " + ", ".join(points),
                    text or "an empty cell",
                )
            x = _number(path, line, "x", values[i_x]) * scale
            y = _number(path, line, "y", values[i_y]) * scale
            z = _number(path, line, "z", values[i_z]) * scale
            rng = math.sqrt(x * x + y * y + z * z)
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
            t = math.nan
            if i_time is not None:
                t, is_abs = _time(path, line, values[i_time].strip())
                if absolute is None:
                    absolute = is_abs
                elif is_abs != absolute:
                    raise InputError(
                        path,
                        _where(line, "time"),
                        "the same kind of time in every row ("
                        + ("ISO 8601 date-times" if absolute else "seconds")
                        + ")",
                        values[i_time].strip(),
                    )
            sigma = math.nan
            if i_sigma is not None:
                sigma = _number(path, line, "sigma", values[i_sigma]) * scale
                if not lo <= sigma <= hi:
                    raise InputError(
                        path,
                        _where(line, "sigma"),
                        f"a 1-sigma from {lo / scale:g} to {hi / scale:g} {units}",
                        values[i_sigma].strip(),
                    )
            c_line.append(line)
            c_pose.append(pose)
            c_state.append(state)
            c_point.append(point)
            c_pos.append(x)
            c_pos.append(y)
            c_pos.append(z)
            c_time.append(t)
            c_sigma.append(sigma)
    except csv.Error as exc:
        raise InputError(path, f"line {rows.line_num}", "valid CSV", str(exc)) from None
    except UnicodeDecodeError as exc:
        raise InputError(path, f"line {rows.line_num + 1}", "UTF-8 text", str(exc)) from None
    if not c_line:
        raise InputError(path, "line 2", "at least one reading after the header", "none")
    table = ReadingsTable(
        path,
        units,
        columns,
        tuple(points),
        np.frombuffer(c_line, np.uint32),
        np.frombuffer(c_pose, np.int32),
        np.frombuffer(c_state, np.int8),
        np.frombuffer(c_point, np.int16),
        np.frombuffer(c_pos, np.float64).reshape(-1, 3),
        np.frombuffer(c_time, np.float64),
        np.frombuffer(c_sigma, np.float64),
        bool(absolute),
    )
    copied = copied_row(table)
    if copied is not None:
        j, i = copied
        state = STATES[int(table.state[j])]
        raise InputError(
            path,
            _where(int(table.line[j]), "state"),
            f"a {state} reading that differs from the "
            f"{STATES[int(table.state[i])]} one (line {int(table.line[i])} has the same x, y, z: a row "
            "copied into both states?)",
            state,
        )
    return table


def copied_row(table: ReadingsTable) -> tuple[int, int] | None:
    """A row whose pose, point and x, y, z equal those of an earlier row in the other state (a
    row copied into both states: two real readings never agree to the last digit), as (its
    index, the earlier row's), the first such row in the file; None when there is none.
    Sorted, not hashed: a few bytes a row, whatever the file's size."""
    n = len(table)
    if n < 2:
        return None
    pos = table.position
    order = np.lexsort((table.line, pos[:, 2], pos[:, 1], pos[:, 0], table.point, table.pose))
    same = np.ones(n - 1, bool)  # sorted row i + 1 has the key of sorted row i
    for column in (table.pose, table.point, pos[:, 0], pos[:, 1], pos[:, 2]):
        c = column[order]
        same &= c[1:] == c[:-1]
        del c
    twins = np.flatnonzero(same)  # few: only rows that share a key with the one before
    del same
    if not len(twins):
        return None
    # the first row of each twin's key: walk back over the run of equal keys
    starts = np.setdiff1d(twins, twins + 1)  # sorted positions where a run of twins begins
    run_start = starts[np.searchsorted(starts, twins, side="right") - 1]
    later, first = order[twins + 1], order[run_start]
    bad = np.flatnonzero(table.state[later] != table.state[first])
    if not len(bad):
        return None
    k = bad[np.argmin(table.line[later[bad]])]
    return int(later[k]), int(first[k])


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
    with_time = bool(rows) and all(r.time is not None for r in rows)
    with_sigma = bool(rows) and all(r.sigma is not None for r in rows)
    buf = io.StringIO()
    write_readings(buf, rows, units, with_time, with_sigma)
    return buf.getvalue()


def write_readings(f, rows: Iterable[Row], units: str, with_time: bool, with_sigma: bool) -> int:
    """Write the CSV of ``rows`` (:func:`readings_csv`'s form, the columns chosen by the caller)
    to the text file ``f`` a row at a time; returns the number of rows."""
    scale = 1.0 / UNITS[units]
    digits = 6 if units == "mm" else 9
    w = csv.writer(f, lineterminator="\n")
    w.writerow(REQUIRED + (("time",) if with_time else ()) + (("sigma",) if with_sigma else ()))
    n = 0
    for r in rows:
        xyz = [f"{v * scale:.{digits}f}" for v in r.position]
        extra = ([iso8601(r.time)] if with_time else []) + (
            [f"{r.sigma * scale:.{digits}f}"] if with_sigma else []  # type: ignore[operator]
        )
        w.writerow([r.pose, r.state, r.point, *xyz, *extra])
        n += 1
    return n


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

    def read_file(
        self, path: Path, n_poses: int, points: Sequence[str], units: str = "mm", progress=None
    ) -> ReadingsTable:
        return read_readings(path, n_poses, points, units, progress=progress)


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
    "copied_row",
    "Row",
    "CsvReadings",
    "FORMAT",
    "readings_csv",
    "write_readings",
    "iso8601",
]
