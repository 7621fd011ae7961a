"""`calbench identify LOG --geometry`: the complete model from a campaign's absolute readings.

What it reads (never a ``/truth/`` topic: the log is read with ``include_truth=False``): every
complete pose's commanded angles and the mean of its unloaded readings of one reflector (the
first the log lists that every such pose saw, e.g. ``probe`` of a probe series imported with
``calbench import``), in the tracker's frame. The robot is the log's MJCF or ``--model``; it must
be a serial arm whose last joint carries that reflector. The fit is :func:`fit.calibrate` for the
three models of :data:`fit.MODELS`; the report is the complete one's. ``--validate`` predicts
another log's readings of the same point (same robot and tracker station); ``--out-model`` writes
the calibrated arm as a calbench MJCF (:func:`mjcf.chain_mjcf`: the chain, its masses and the
probe; the original's geoms are not carried over).

Loaded readings are not used yet: a plan's load, seen from absolute readings, is a second
gravity term this slice does not model.

Units: SI in the JSON (m, rad, rad/(N*m)).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calbench.bench.core import InputError, write_text
from calbench.bench.log import read_log
from calbench.bench.model import Robot

from .fit import MODELS, GeometryFit, calibrate, initial_model, validate
from .mjcf import load_arm, write_chain_mjcf
from .model import GeometricModel, kind
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


@dataclass(frozen=True)
class Complete:
    """The complete model of one robot registered on a point's readings, and what names it."""

    model: GeometricModel | StaticsModel
    bodies: tuple[str, ...]  # the bodies the actuated joints turn, in order
    name: str  # the MJCF's model name


def complete_model(path, xml: str | None, where: str, point: str, q: np.ndarray, y: np.ndarray) -> Complete:
    """A serial arm's numpy chain (model.py), or, for a robot with a kinematic loop or a
    compensator spring, the statics model (statics.py), registered on readings y at q."""
    try:
        robot = Robot.from_file(path) if path is not None else Robot.from_xml(xml, where)
    except ValueError as e:
        raise InputError(where, "MJCF", "a model MuJoCo compiles", str(e).splitlines()[0]) from None
    name = bytes(robot.model.names).split(b"\0")[0].decode()
    if robot.loops or len(robot.tendons):
        m = statics_model(path, xml, point, q, y, where)
        return Complete(m, m.bodies, name)
    arm = load_arm(path, xml, where)
    return Complete(initial_model(arm.chain, q, y, arm.point(point)), arm.bodies, name)


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
    write_chain_mjcf(path, chain, tool, name=name + "_calibrated", compliance=comp)
    return base


def run_geometry(
    log_path: str | Path,
    model: str | Path | None = None,
    validate_path: str | Path | None = None,
    out_model: str | Path | None = None,
) -> dict:
    """Fit the three models to the log; the report as a JSON-ready dict (see the module docstring)."""
    log = read_log(log_path, include_truth=False)
    if model is None and not log.mjcf_text:
        raise InputError(
            log.path, "robot model", "an MJCF attachment in the log (or --model ROBOT.xml)", "none"
        )
    data = absolute_readings(log)
    where = str(model) if model is not None else f"{log.path} (MJCF attachment)"
    robot = complete_model(model, log.mjcf_text, where, data.point, data.q, data.y)
    start = robot.model
    fits = {name: calibrate(start, data.q, data.y, effects) for name, effects in MODELS.items()}
    fit = fits["geometry+compliance"]
    report: dict = {
        "method": "geometry",
        "log": str(log.path),
        "point": data.point,
        "n": len(data.q),
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
        held = absolute_readings(read_log(validate_path, include_truth=False), data.point)
        if held.q.shape[1] != data.q.shape[1]:
            raise InputError(
                validate_path, "poses", f"{data.q.shape[1]} joint angles per pose", held.q.shape[1]
            )
        by_model = {name: validate(f, held.q, held.y) for name, f in fits.items()}
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
    lines = [f"geometry from {rep['n']} unloaded readings of {rep['point']} ({rep['log']})"]
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
