"""Campaign logs from and to the readings CSV: `calbench import` (once the tracker's pose is
known) and `calbench export`.

The log is an ordinary calbench log without truth, written by the same
:class:`bench.logformat.LogWriter` as a simulated campaign: the plan's text and the MJCF travel
in it, each measured pose gets its two commands, its load (the plan's wrench, or its payload
mass at the payload site) and one ``/tracker/measurement`` per reading, grouped from the CSV rows
(bench/shopfloor/readings.py: the k-th row of each reflector is reading k). ``/campaign/info`` carries the
tracker's pose (from the plan, or registered: identify/shopfloor/importer.py) and an ``imported`` record:
the file, its units and rows, and the registration.

A reading's covariance is its ``sigma`` column (sigma^2 I) when given, else the plan's tracker
noise model at the reading's position (:func:`bench.tracker.noise_covariance`).

Poses are written in the order they were measured: plan order, or, when the CSV has times, the
order of their first readings. With times, a pose's readings must form one stretch of time, its
unloaded readings before its loaded ones (how a campaign runs; it also keeps the deflections of
different poses independent for a drifting tracker): an InputError names the first row that
breaks this.

Times. A reading is stamped with its own time when the CSV has a time column (ISO 8601 as it
is, seconds counted from the plan's ``start_time``), and each pose's command, load and end a
few milliseconds around its readings; without times the log's campaign clock stamps them
(bench/scenario/timeline.py), the same schedule the readings are given here (bench.scenario.schedule),
so that a drifting tracker's covariance (bench/tracker/models/iso10360.py) sees the same timeline in the
registration and in identification.

Export (:func:`export_rows`) writes every visible reflector of every reading of a log's complete
poses, in log order, in the tracker frame; ``time`` is the reading's log time; ``sigma`` is
written when every reading's covariance is isotropic (sigma^2 I), which is then exactly what the
import reads back; otherwise the plan's tracker model gives the covariances again on import.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from calbench.bench.campaign import pose_load
from calbench.bench.core import ProgressSink, atomic_path, sink
from calbench.bench.log import CampaignLog, LogHeader, LogWriter
from calbench.bench.model import load_robot
from calbench.bench.scenario import NS, Plan, check_joint_limits
from calbench.bench.tracker import TrackerSpec

from .grouping import (
    ImportedReading,
    ImportedReadings,
    campaign_readings,
    first_time,
    measured_order,
    reading_covariance,
)
from .readings import Row, write_readings

TICK = 1_000_000  # ns: a pose's command, load and end stamped 1-3 ms around its readings


@dataclass(frozen=True)
class ImportSummary:
    """What an import wrote."""

    poses: list[int]  # poses written, in the order written
    lost: list[int]  # plan poses without a single reading
    one_state: list[int]  # poses measured in one state only (no deflection)
    rows: int
    readings: int  # /tracker/measurement messages


def write_imported_log(
    plan: Plan,
    readings: ImportedReadings,
    tracker: TrackerSpec,
    model: Path,
    out: Path,
    imported: dict,
    rows: int,
    time_origin: int | None = None,
    progress: ProgressSink | None = None,
) -> ImportSummary:
    """Write the log of ``readings`` (:func:`campaign_readings`, ``rows`` CSV rows) taken along
    ``plan`` with the tracker at ``tracker``'s pose, the robot described by the MJCF ``model``;
    ``imported`` goes into ``/campaign/info``. Everything is checked before the file exists.

    Times (module docstring): with ``time_origin`` (ns since 1970 of the readings' time zero:
    0 for ISO 8601 times, the plan's ``start_time`` for seconds) every reading is stamped at its
    own time and each pose's command, load and end a millisecond around its readings (TICK);
    without, the log's campaign clock stamps them (bench/scenario/timeline.py), which is the schedule the
    readings were given (bench.scenario.schedule)."""
    robot = load_robot(plan.path, "robot", path=model)  # as the import loaded it
    names = list(robot.reflector_names)
    check_joint_limits(plan, robot.limits())
    order = list(dict.fromkeys(p for p, _ in readings))
    loads = {p: pose_load(robot, plan, plan.poses[p]) for p in order}

    def at(t: float | None, shift: int = 0) -> int | None:
        return None if time_origin is None or t is None else time_origin + int(round(t * NS)) + shift

    start = plan.start_time
    if time_origin is not None and order:
        first = first_time(readings)
        start = min(start, datetime.fromtimestamp((at(first) - NS) / NS, tz=UTC))
    header = LogHeader(
        scenario_name=plan.name,
        scenario_text=plan.text,
        scenario_filename=plan.path.name,
        robot_filename=model.name,
        mjcf_text=model.read_text(encoding="utf-8"),
        reflectors=names,
        payload_site=robot.model.site(robot.payload_site).name,
        tracker=tracker.to_dict(),
        seed=int(plan.seed),
        n_poses=len(plan.poses),
        imported=imported,
        n_joints=robot.n_act,
        start_time=start,
    )
    n_read, one = 0, []
    bar = sink(progress)  # a pose at a time: only one pose's readings exist at once
    bar.start(len(order), "poses written")
    with LogWriter(out, header) as log:
        for p in order:
            q = plan.poses[p].q
            load, mass = loads[p]
            site = robot.model.site(load.site).name
            u, ld = readings[(p, "unloaded")], readings[(p, "loaded")]
            log.pose(p, "unloaded", q, at=at((u or ld)[0].time, -3 * TICK))
            for state, reads in (("unloaded", u), ("loaded", ld)):
                if state == "loaded":
                    t_load = ld[0].time if ld else None
                    log.wrench(
                        p,
                        load.force,
                        load.moment,
                        site,
                        mass,
                        at=at(t_load, -2 * TICK) if ld else at(u[-1].time, TICK),
                    )
                    log.pose(p, "loaded", q, at=at(t_load, -TICK) if ld else at(u[-1].time, 2 * TICK))
                for g in reads:
                    log.measurement(
                        p, state, g.repeat, names, g.position, g.covariance, g.visible, at=at(g.time)
                    )
                    n_read += 1
            log.pose_done(p, at=at((ld or u)[-1].time, 3 * TICK))
            if not (u and ld):
                one.append(p)
            bar.update()
    lost = sorted(set(range(len(plan.poses))) - set(order))
    return ImportSummary(order, lost, one, rows, n_read)


def isotropic_sigma(cov: np.ndarray) -> float | None:
    """sigma when ``cov`` (3, 3) is sigma^2 I to round-off, else None."""
    s2 = float(np.trace(cov)) / 3
    ok = s2 > 0 and np.allclose(cov, s2 * np.eye(3), rtol=0, atol=1e-9 * s2)
    return float(np.sqrt(s2)) if ok else None


def _visible_rows(log: CampaignLog, with_sigma: bool = True) -> Iterator[Row]:
    """Every visible reflector of every reading of ``log``'s complete poses, in log order, a
    reading at a time (a log of any size: its measurements may be read from the file)."""
    keep = set(log.complete_poses)
    for m in log.measurements:
        if m.pose not in keep:
            continue
        t = None if m.time is None else m.time / 1e9
        for i, name in enumerate(m.reflectors):
            if m.visible[i] and np.all(np.isfinite(m.position[i])):
                sigma = isotropic_sigma(m.covariance[i]) if with_sigma else None
                yield Row(m.pose, m.state, name, m.position[i].copy(), t, sigma)


def export_rows(log: CampaignLog) -> list[Row]:
    """Every visible reflector of every reading of ``log``'s complete poses (see the module
    docstring), in log order."""
    rows = list(_visible_rows(log))
    if rows and any(r.sigma is None for r in rows):
        rows = [Row(r.pose, r.state, r.point, r.position, r.time, None) for r in rows]
    return rows


def export_readings(log: CampaignLog, out: Path, units: str = "mm") -> int:
    """Write :func:`export_rows` of ``log`` as CSV to ``out`` (atomically) without holding them:
    one pass over the readings decides the columns (time, sigma), a second writes the rows.
    Returns the number of rows."""
    with_time = with_sigma = True
    rows = 0
    for r in _visible_rows(log):
        rows += 1
        with_time &= r.time is not None
        with_sigma &= r.sigma is not None
        if not (with_time or with_sigma):
            break
    with_time &= rows > 0
    with_sigma &= rows > 0
    with atomic_path(out) as tmp, open(tmp, "w", encoding="utf-8", newline="") as f:
        return write_readings(f, _visible_rows(log, with_sigma), units, with_time, with_sigma)


__all__ = [
    "ImportedReading",
    "ImportedReadings",
    "ImportSummary",
    "reading_covariance",
    "measured_order",
    "campaign_readings",
    "write_imported_log",
    "export_rows",
    "export_readings",
    "isotropic_sigma",
]
