"""`calbench identify LOG --geometry`: the complete model from a campaign's absolute readings.

What it reads (never a ``/truth/`` topic: the log is read with ``include_truth=False``): every
complete pose's commanded angles and, for each load state (unloaded and loaded) and each
reflector seen, the mean of its readings, in the tracker's frame (:func:`campaign_readings`).
A loaded reading carries its pose's load (``/campaign/wrench``: a mass's weight or a wrench at a
site): a known second force term in the model's statics (model.py :class:`~.model.Rows`), so
the compliances come from the loaded/unloaded pairs and from the robot's own weight across poses.
Each reflector is its own point (three ``tool_frame`` numbers each). The robot is the log's MJCF
or ``--model``: a serial arm whose last joint carries the reflectors and the load (model.py), or
any calbench robot through its statics (statics.py). The fit is :func:`fit.calibrate` for the
three models of :data:`fit.MODELS`; the report is the complete one's, whose fit is repeated
with the torques at its own deflected pose (:func:`fit.refresh_torques`; a serial arm's only).
``--validate`` predicts another log's readings of the same points (same robot and tracker
station); ``--out-model`` writes the calibrated robot as a calbench MJCF (a serial arm as :func:`mjcf.chain_mjcf`: the
chain, its masses, the points and the load site; the original's geoms are not carried over).

Units: SI in the JSON (m, rad, rad/(N*m)).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calbench.bench.core import STATES, InputError, write_text
from calbench.bench.log import read_log
from calbench.bench.model import Robot

from .fit import MODELS, GeometryFit, calibrate, initial_model, refresh_torques, validate
from .mjcf import load_arm, write_chain_mjcf
from .model import GeometricModel, Rows, kind
from .statics import StaticsModel, calibrated_xml, statics_model


@dataclass(frozen=True)
class AbsoluteReadings:
    """One point's unloaded readings: pose indices, commanded angles, tracker-frame positions."""

    point: str
    poses: np.ndarray  # (n,) plan indices
    q: np.ndarray  # (n, dof) rad
    y: np.ndarray  # (n, 3) m, tracker frame, the mean of the pose's repeats
    sigma: float  # m per axis, the tracker's nominal
    std: np.ndarray | None = None  # (n, 3) m, each mean reading's std per axis, from the log's covariances
    rows: Rows | None = None  # each reading's point and load (campaign_readings); None: q, unloaded, point
    points: tuple[str, ...] = ()  # the points rows.point indexes

    @property
    def design(self) -> Rows | np.ndarray:
        """What the model reads besides theta: ``rows`` where there are, else ``q``."""
        return self.q if self.rows is None else self.rows

    @property
    def n_loaded(self) -> int:
        return 0 if self.rows is None else int(np.sum(self.rows.loaded))


def absolute_readings(log, point: str | None = None) -> AbsoluteReadings:
    """The unloaded readings of ``point`` (default: the first reflector every measured pose saw,
    or, where none is, the one seen in the most poses: a big arm hides some reflectors in some
    poses), in the poses that saw it."""
    rows: dict[int, dict[str, list[np.ndarray]]] = {}
    var: dict[int, dict[str, list[np.ndarray]]] = {}
    names: list[str] = []
    for p in log.complete_poses:
        seen: dict[str, list[np.ndarray]] = {}
        for m in log.readings(p, "unloaded"):
            for i, name in enumerate(m.reflectors):
                if m.visible[i]:
                    seen.setdefault(name, []).append(m.position[i])
                    var.setdefault(p, {}).setdefault(name, []).append(np.diagonal(m.covariance[i]))
                    if name not in names:
                        names.append(name)
        if seen:
            rows[p] = seen
    if point is None:  # the first of those seen unloaded in the most poses (all, where one is)
        if not names:
            raise InputError(log.path, "/tracker/measurement", "unloaded readings of a reflector", names)
        seen = {n: sum(n in s for s in rows.values()) for n in names}
        point = max(names, key=lambda n: seen[n])
    poses = [p for p, s in rows.items() if point in s]
    if len(poses) < 10:
        raise InputError(log.path, f"reflector {point}", "unloaded readings in at least 10 poses", len(poses))
    q = np.array([log.poses[p].unloaded for p in poses])
    y = np.array([np.mean(rows[p][point], axis=0) for p in poses])
    # the mean of m repeats: its variance is the readings' mean variance over m
    std = np.array([np.sqrt(np.mean(var[p][point], axis=0) / len(var[p][point])) for p in poses])
    ok = bool(np.all(np.isfinite(std)) and np.all(std > 0))
    return AbsoluteReadings(
        point, np.array(poses), q, y, float(log.tracker_spec().sigma), std if ok else None
    )


def campaign_readings(log, points: tuple[str, ...] | None = None, states=STATES) -> AbsoluteReadings:
    """Every complete pose's readings in each of ``states`` of each of ``points`` (default: every
    reflector seen in at least 3 readings, in the log's order), one reading per pose, state and
    point (the mean of its repeats, its std from the log's covariances), with the pose's load on
    its loaded readings (``/campaign/wrench``, world frame: the robot base's)."""
    rec: list[tuple[int, str, str]] = []  # (pose, state, point)
    pos: dict[tuple[int, str, str], list[np.ndarray]] = {}
    var: dict[tuple[int, str, str], list[np.ndarray]] = {}
    names: list[str] = []
    for p in log.complete_poses:
        for state in states:
            if state == "loaded" and p not in log.wrenches:
                continue
            for m in log.readings(p, state):
                for i, name in enumerate(m.reflectors):
                    if not m.visible[i]:
                        continue
                    key = (p, state, name)
                    if key not in pos:
                        rec.append(key)
                        pos[key], var[key] = [], []
                    pos[key].append(m.position[i])
                    var[key].append(np.diagonal(m.covariance[i]))
                    if name not in names:
                        names.append(name)
    if points is None:
        points = tuple(n for n in names if sum(k[2] == n for k in rec) >= 3)
    rec = [k for k in rec if k[2] in points]
    if len({k[0] for k in rec}) < 10:
        raise InputError(
            log.path,
            "/tracker/measurement",
            f"readings of {', '.join(points) or 'a reflector'} in at least 10 poses",
            len({k[0] for k in rec}),
        )
    n = len(rec)
    q = np.array([log.poses[p].get(state) for p, state, _ in rec])
    force, moment, mass = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n)
    sites = []
    for i, (p, state, _) in enumerate(rec):
        w = log.wrenches.get(p) if state == "loaded" else None
        if w is not None:
            force[i], moment[i], mass[i] = w.force, w.moment, w.mass or 0.0
        sites.append(w.site if w is not None else "")
    rows = Rows(q, np.array([points.index(k[2]) for k in rec]), force, moment, tuple(sites), mass)
    y = np.array([np.mean(pos[k], axis=0) for k in rec])
    std = np.array([np.sqrt(np.mean(var[k], axis=0) / len(var[k])) for k in rec])
    ok = bool(np.all(np.isfinite(std)) and np.all(std > 0))
    return AbsoluteReadings(
        points[0], np.array([k[0] for k in rec]), q, y, float(log.tracker_spec().sigma),
        std if ok else None, rows, tuple(points),
    )  # fmt: skip


@dataclass(frozen=True)
class Complete:
    """The complete model of one robot registered on a point's readings, and what names it."""

    model: GeometricModel | StaticsModel
    bodies: tuple[str, ...]  # the bodies the actuated joints turn, in order
    name: str  # the MJCF's model name


def complete_model(path, xml: str | None, where: str, point, q, y: np.ndarray) -> Complete:
    """A serial arm's numpy chain (model.py), or, for a robot with a kinematic loop or a
    compensator spring, the statics model (statics.py), registered on readings y at q (an array,
    or :class:`~.model.Rows` of several points and loads). ``point``: one point's name, or the
    points ``q`` indexes."""
    points = (point,) if isinstance(point, str) else tuple(point)
    try:
        robot = Robot.from_file(path) if path is not None else Robot.from_xml(xml, where)
    except ValueError as e:
        raise InputError(where, "MJCF", "a model MuJoCo compiles", str(e).splitlines()[0]) from None
    name = bytes(robot.model.names).split(b"\0")[0].decode()
    if robot.loops or len(robot.tendons):
        m = statics_model(path, xml, points, q, y, where)
        return Complete(m, m.bodies, name)
    arm = load_arm(path, xml, where)
    sites = {s: arm.point(s) for s in sorted(set(getattr(q, "site", ()))) if s}  # where loads act
    tools = np.array([arm.point(p) for p in points])
    tool = tools[0] if isinstance(point, str) else tools
    return Complete(initial_model(arm.chain, q, y, tool, points, sites), arm.bodies, name)


def value(model, i: int, theta: np.ndarray) -> float:
    """Parameter i of theta as reported (statics.py's compliances are deltas from a start)."""
    return model.value(i, theta) if hasattr(model, "value") else float(theta[i])


def springs(model, theta: np.ndarray) -> dict:
    """Each compensator's fitted stiffness (N/m) and preload length (m), where the model has any."""
    if not getattr(model, "tendons", ()):
        return {}
    ks = model.springs(theta).reshape(-1, 2)
    return {
        t: {"stiffness": float(k), "preload": float(s0)} for t, (k, s0) in zip(model.tendons, ks, strict=True)
    }


def write_calibrated(path: str | Path, fit: GeometryFit, name: str) -> np.ndarray:
    """The calibrated robot as a calbench MJCF at ``path``; returns the tracker-from-base transform."""
    if isinstance(fit.model, StaticsModel):
        write_text(Path(path), calibrated_xml(fit.model, fit.theta))
        return fit.model.base(fit.theta)
    chain, tool, base, comp = fit.calibrated()
    m = fit.model
    points = dict(zip(m.points, np.atleast_2d(tool), strict=True)) if m.points else None
    load = next(iter(m.sites.items()), None)
    if load is not None and points and load[0] in points:
        load = (load[0], points[load[0]])  # the load hangs at a reflector: its calibrated place
    write_chain_mjcf(
        path,
        chain,
        np.atleast_2d(tool)[0],
        name=name + "_calibrated",
        compliance=comp,
        sites=points,
        payload=load,
    )
    return base


def run_geometry(
    log_path: str | Path,
    model: str | Path | None = None,
    validate_path: str | Path | None = None,
    out_model: str | Path | None = None,
    states: tuple[str, ...] = STATES,
) -> dict:
    """Fit the three models to the log; the report as a JSON-ready dict (see the module docstring).
    ``states``: the load states whose readings it reads (default both; ``("unloaded",)``: the
    robot's own weight alone, as benchmarks/geometry_loaded_bench.py compares)."""
    log = read_log(log_path, include_truth=False)
    if model is None and not log.mjcf_text:
        raise InputError(
            log.path, "robot model", "an MJCF attachment in the log (or --model ROBOT.xml)", "none"
        )
    data = campaign_readings(log, states=states)
    where = str(model) if model is not None else f"{log.path} (MJCF attachment)"
    robot = complete_model(model, log.mjcf_text, where, data.points, data.rows, data.y)
    start = robot.model
    fits = {name: calibrate(start, data.rows, data.y, effects) for name, effects in MODELS.items()}
    # the serial arm's torques at its own deflected pose (the weight and the loads at q + c tau:
    # what the bench's statics solves); statics.py's are its equilibria already
    fits["geometry+compliance"], _ = refresh_torques(fits["geometry+compliance"], data.rows, data.y)
    fit = fits["geometry+compliance"]
    report: dict = {
        "method": "geometry",
        "log": str(log.path),
        "point": data.point,
        "points": list(data.points),
        "n": len(data.q),
        "n_loaded": data.n_loaded,
        "models": {name: {"fit_rms": f.rms, "parameters": len(f.free)} for name, f in fits.items()},
        "parameters": [
            {"name": n, "effect": kind(n), "value": value(start, i, fit.theta), "std": float(sd)}
            for n, i, sd in zip(fit.names, fit.free, fit.std, strict=True)
        ],
        "not_identified": [n for i, n in enumerate(start.names) if i not in fit.free],
        "springs": springs(start, fit.theta),
        "tracker_sigma": data.sigma,
    }
    if validate_path is not None:
        held = campaign_readings(read_log(validate_path, include_truth=False), data.points, states)
        if held.q.shape[1] != data.q.shape[1]:
            raise InputError(
                validate_path, "poses", f"{data.q.shape[1]} joint angles per pose", held.q.shape[1]
            )
        by_model = {name: validate(f, held.rows, held.y) for name, f in fits.items()}
        report["validation"] = {
            "position_rms": by_model["geometry+compliance"].rms,
            "max": by_model["geometry+compliance"].max,
            "n": by_model["geometry+compliance"].n,
            "mean": by_model["geometry+compliance"].mean,
            "by_model": {name: v.as_dict() for name, v in by_model.items()},
        }
    if out_model is not None:
        report["tracker_from_base"] = write_calibrated(out_model, fit, robot.name).tolist()
        report["out_model"] = str(out_model)
    return report


def format_geometry(rep: dict) -> str:
    """The report as a person reads it: the models' errors in mm, the parameters in um and urad."""
    loaded = rep.get("n_loaded", 0)
    kinds = f"{rep['n'] - loaded} unloaded and {loaded} loaded" if loaded else f"{rep['n']} unloaded"
    points = ", ".join(rep.get("points") or [rep["point"]])
    lines = [f"geometry from {kinds} readings of {points} ({rep['log']})"]
    lines.append(f"{'model':<22}{'params':>7}{'fit RMS':>12}{'held-out RMS':>15}{'max':>10}")
    held = rep.get("validation", {}).get("by_model", {})
    for name, m in rep["models"].items():
        v = held.get(name)
        tail = f"{v['position_rms'] * 1e3:>12.3f} mm{v['max'] * 1e3:>7.3f} mm" if v else ""
        lines.append(f"{name:<22}{m['parameters']:>7}{m['fit_rms'] * 1e3:>9.3f} mm{tail}")
    lines.append(
        f"{len(rep['not_identified'])} parameters not identified by this plan (the base set: docs/geometry.md)"
    )
    return "\n".join(lines)


def geometry_json(rep: dict) -> str:
    return json.dumps(rep, indent=1) + "\n"
