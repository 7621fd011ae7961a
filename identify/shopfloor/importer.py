"""`calbench import`: real tracker readings (CSV) along a plan become a calbench campaign log.

Steps, each validated before any output exists:
1. the plan (bench.scenario.load_plan: a scenario without ``[truth]``), the robot's MJCF (the
   plan's, or ``--model``) and the readings, in the format that accepts the file's name (CSV by
   default, bench/shopfloor/readings.py; bench/shopfloor/formats.py): bad rows name line and column;
2. the tracker's pose: the plan's ``[tracker] position``/``yaw`` when given, else registered
   from the readings (identify/shopfloor/tracker_pose.py);
3. the log (bench/shopfloor/logcsv.py), written atomically: an ordinary log without truth that
   ``identify``, ``discover``, ``view`` and ``report`` read like a simulated one. Its
   ``/campaign/info`` says it was imported, from which file (name and SHA-256), in which units,
   and with which tracker pose (the plan's, or the registration with its residual and
   uncertainty).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path

from calbench.bench.core import InputError, ProgressSink, atomic_path
from calbench.bench.model import MODEL_FLAG, Robot, load_robot
from calbench.bench.scenario import Plan, check_joint_limits, check_plan, load_plan, start_ns
from calbench.bench.shopfloor import (
    FORMATS,
    ImportSummary,
    ReadingsTable,
    campaign_readings,
    write_imported_log,
)
from calbench.bench.tracker import TrackerSpec

from .tracker_pose import TrackerRegistration, check_placed, fit_tracker_pose


@dataclass
class ImportResult:
    """What ``calbench import`` did: the log's summary, where the tracker stood, warnings."""

    out: Path
    plan: Plan
    table: ReadingsTable
    tracker: TrackerSpec
    summary: ImportSummary
    imported: dict
    registration: TrackerRegistration | None = None
    warnings: list[str] = field(default_factory=list)


def plan_robot(plan: Plan, model: Path | None) -> tuple[Robot, Path]:
    """The robot the readings were taken on: ``model`` or the plan's MJCF (InputError when it
    does not load), its poses checked against the joint limits."""
    path = Path(model) if model is not None else plan.robot
    robot = (
        load_robot(*MODEL_FLAG, path=path) if model is not None else load_robot(plan.path, "robot", path=path)
    )
    check_joint_limits(plan, robot.limits())
    check_plan(plan, robot)
    return robot, path


def file_sha256(path: Path) -> str:
    """The SHA-256 of a file, read a MB at a time (the readings file may be gigabytes)."""
    try:
        with open(path, "rb") as f:
            return hashlib.file_digest(f, "sha256").hexdigest()
    except OSError as exc:
        raise InputError(path, "(file)", "a readable file", exc.strerror or str(exc)) from None


def import_readings(
    csv_path: str | Path,
    plan_path: str | Path,
    out: str | Path,
    units: str = "mm",
    model: str | Path | None = None,
    read_progress: ProgressSink | None = None,
    write_progress: ProgressSink | None = None,
) -> ImportResult:
    """Import ``csv_path`` taken along ``plan_path`` into the log ``out`` (module docstring).
    ``read_progress`` is shown the file's MB as they are read, ``write_progress`` the poses as
    they are written."""
    csv_path, out = Path(csv_path), Path(out)
    plan = load_plan(plan_path)
    robot, model_path = plan_robot(plan, None if model is None else Path(model))
    fmt = FORMATS.for_path(csv_path)  # by the file's name; CSV unless a format claims it
    names = list(robot.reflector_names)
    table = fmt.read_file(csv_path, len(plan.poses), names, units, progress=read_progress)
    digest = file_sha256(csv_path)
    readings = campaign_readings(table, names, plan.tracker)
    registration = None
    if plan.tracker_placed:
        tracker = plan.tracker
        check_placed(plan, model_path, readings, table, tracker)
    else:
        registration = fit_tracker_pose(plan, model_path, readings, table, plan.tracker)
        tracker = plan.tracker.placed(registration.fit.position, registration.fit.rotation)
    imported = {
        "source": csv_path.name,
        "sha256": digest,
        "units": units,
        "rows": len(table),
        "tracker_pose": "plan" if registration is None else "registered",
        "registration": None if registration is None else registration.as_dict(),
    }
    origin = None if not table.has_time else 0 if table.absolute_time else start_ns(plan.start_time)
    with atomic_path(out) as tmp:
        summary = write_imported_log(
            plan, readings, tracker, model_path, tmp, imported, len(table), origin, progress=write_progress
        )
    return ImportResult(
        out,
        plan,
        table,
        tracker,
        summary,
        imported,
        registration,
        [] if registration is None else list(registration.warnings),
    )


__all__ = ["ImportResult", "import_readings", "plan_robot"]
