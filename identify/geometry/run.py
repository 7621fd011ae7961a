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

from calbench.bench.core import InputError
from calbench.bench.log import read_log

from .fit import MODELS, calibrate, initial_model, validate
from .mjcf import load_arm, write_chain_mjcf
from .model import kind


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
    """The unloaded readings of ``point`` (default: the first reflector every measured pose saw)."""
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
    if point is None:
        common = [n for n in names if all(n in s for s in rows.values())]
        if not common:
            raise InputError(
                log.path, "/tracker/measurement", "one reflector seen unloaded in every pose", names
            )
        point = common[0]
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
    arm = load_arm(model, log.mjcf_text, f"{log.path} (MJCF attachment)")
    data = absolute_readings(log)
    start = initial_model(arm.chain, data.q, data.y, arm.point(data.point))
    fits = {name: calibrate(start, data.q, data.y, effects) for name, effects in MODELS.items()}
    fit = fits["geometry+compliance"]
    report: dict = {
        "method": "geometry",
        "log": str(log.path),
        "point": data.point,
        "n": len(data.q),
        "models": {name: {"fit_rms": f.rms, "parameters": len(f.free)} for name, f in fits.items()},
        "parameters": [
            {"name": n, "effect": kind(n), "value": float(fit.theta[i]), "std": float(sd)}
            for n, i, sd in zip(fit.names, fit.free, fit.std, strict=True)
        ],
        "not_identified": [n for i, n in enumerate(start.names) if i not in fit.free],
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
        chain, tool, base, comp = fit.calibrated()
        write_chain_mjcf(
            out_model,
            chain,
            tool,
            name=bytes(arm.model.names).split(b"\0")[0].decode() + "_calibrated",
            compliance=comp,
        )
        report["out_model"] = str(out_model)
        report["tracker_from_base"] = base.tolist()
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
