"""`calbench discover LOG --geometry [--validate HELDOUT.mcap]`: discovery on a log's absolute readings.

What it reads is what `identify --geometry` reads (identify/geometry/run.py: the log without its
truth, each complete pose's commanded angles and mean unloaded reading of one flange point, with
the std the log's covariances give it; the robot from the log's MJCF or ``--model``, a serial
arm). The candidates are the registry's effects on absolute readings on that robot
(``discovery_library(robot, "absolute")``), the search is identify/discover/geometric.py's.
``--validate`` predicts another log's readings of the same point with the starting model and
with the model after each naming: the gap must shrink on poses the search never saw, not only
on the fitted ones. When an effect is named, the calibrated arm (the final model folded into a
chain: identify/geometry/mjcf.py) is written as a calbench MJCF, as discover writes its augmented
model.

Units: SI in the JSON (m, rad, rad/(N*m)).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from calbench.bench.core import InputError
from calbench.bench.log import read_log
from calbench.bench.model import Robot
from calbench.bench.model.effects import discovery_library
from calbench.identify.geometry import (
    Arm,
    absolute_readings,
    complete_model,
    initial_model,
    validate,
    write_calibrated,
)

from .geometric import AMBIGUOUS, UNEXPLAINED, Readings, discover_geometry, library
from .narrative import clean


def run_discover_geometry(
    log_path: str | Path,
    model: str | Path | None = None,
    validate_path: str | Path | None = None,
    out_model: str | Path | None = None,
    progress=None,
) -> dict:
    """The search on the log (module docstring); the report as a JSON-ready dict."""
    log_path = Path(log_path)
    log = read_log(log_path, include_truth=False)
    if model is None and not log.mjcf_text:
        raise InputError(
            log.path, "robot model", "an MJCF attachment in the log (or --model ROBOT.xml)", "none"
        )
    where = str(model) if model is not None else f"{log.path} (MJCF attachment)"
    data = absolute_readings(log)
    sigma = data.std if data.std is not None else data.sigma
    comp = complete_model(model, log.mjcf_text, where, data.point, data.q, data.y)
    robot = Robot.from_file(model) if model is not None else Robot.from_xml(log.mjcf_text)
    start, readings, cands = problem_of(comp.model, comp.bodies, robot, data.q, data.y, sigma)
    rep, fits = discover_geometry(start, readings, cands, progress=progress)
    rep.update(
        {
            "log": str(log_path),
            "model": str(model) if model is not None else "MJCF from the log",
            "point": data.point,
            "noise_sigma": float(np.mean(sigma)),
        }
    )
    if validate_path is not None:
        held = absolute_readings(read_log(validate_path, include_truth=False), data.point)
        if held.q.shape[1] != data.q.shape[1]:
            raise InputError(
                validate_path, "poses", f"{data.q.shape[1]} joint angles per pose", held.q.shape[1]
            )
        by_step = [{"model": lab, **validate(f.fit, held.q, held.y).as_dict()} for lab, f in fits]
        rep["validation"] = {**by_step[-1], "by_step": by_step, "log": str(validate_path)}
        del rep["validation"]["model"]
    if fits[-1][1].labels:
        path = Path(out_model) if out_model else log_path.with_name(log_path.stem + ".augmented.xml")
        rep["tracker_from_base"] = write_calibrated(path, fits[-1][1].fit, comp.name).tolist()
        rep["augmented_model"] = str(path)
    else:
        rep["augmented_model"] = None
    return rep


def geometric_problem(arm: Arm, robot: Robot, point: str, q: np.ndarray, y: np.ndarray, sigma):
    """(the nominal complete model registered on the readings, the readings with their gravity
    torques, the candidates on this robot) for one flange ``point`` read at q as y (tracker
    frame) with ``sigma`` (m: one number, (n,) or (n, 3))."""
    return problem_of(initial_model(arm.chain, q, y, arm.point(point)), arm.bodies, robot, q, y, sigma)


def problem_of(start, bodies, robot: Robot, q: np.ndarray, y: np.ndarray, sigma):
    """(the registered complete model ``start`` (model.py's chain, or statics.py's for a robot with
    a loop or a spring), the readings with their gravity torques, the candidates on this robot)."""
    cands = library(start, discovery_library(robot, "absolute"), bodies)
    return start, Readings(q, y, sigma, start.torques(q)), cands


def _label(step: dict) -> str:
    return step["effect"] + (f"[{step['detail']}]" if step.get("detail") else "")


def format_discover_geometry(rep: dict) -> str:
    """The story as a person reads it: each naming with its test and the RMS it leaves (and the
    held-out RMS), then what the readings cannot separate."""
    mm = 1e3
    held = {v["model"]: v for v in rep.get("validation", {}).get("by_step", [])}

    def tail(key: str) -> str:
        v = held.get(key)
        return f"; held-out RMS {v['position_rms'] * mm:.3f} mm" if v else ""

    st = rep["start_model"]
    springs = " + balancer springs" if any(p["effect"] == "compensator" for p in st["parameters"]) else ""
    lines = [
        f"discover --geometry: {rep['n_readings']} unloaded readings of {rep['point']} ({rep['log']})",
        f"start: registration + joint compliance under self-weight{springs}, fit RMS {st['rms'] * mm:.3f} mm "
        f"(chi2 {st['chi2']:.4g} for {st['dof']} dof, p = {st['p']:.2g}){tail('start')}",
    ]
    for s in rep["steps"]:
        if s["effect"] == UNEXPLAINED:
            lines.append("unexplained: no candidate explains the remaining misfit")
        elif s["effect"] == AMBIGUOUS:
            lines.append(f"ambiguous: {s['detail']} explain the misfit alike; neither is named")
        else:
            lines.append(
                f"named {_label(s)}: LR {s['lr']:.4g} for {s['k']} parameters (p = {s['p_lr']:.2g}, "
                f"level {s['alpha']:.2g}); fit RMS {s['rms_before'] * mm:.3f} -> {s['rms_after'] * mm:.3f} mm"
                f"{tail(_label(s))}"
            )
    if not rep["steps"]:
        lines.append("nothing named: every candidate's likelihood ratio stays within the noise")
    red = [r for r in rep["redundancies"] if r["as"]]
    if red:
        lines.append(
            f"{len(red)} parameters of the named effects are not separable (reduced to the base set):"
        )
        for r in red:
            terms = " ".join(f"{c:+.3g} {n}" for n, c in r["as"][:3])
            lines.append(f"  {r['parameter']} moves the readings as {terms}")
    if rep.get("augmented_model"):
        lines.append(f"calibrated model: {rep['augmented_model']}")
    return "\n".join(lines)


def discover_geometry_json(rep: dict) -> str:
    return json.dumps(clean(rep), indent=1, allow_nan=False) + "\n"


__all__ = [
    "geometric_problem",
    "problem_of",
    "run_discover_geometry",
    "format_discover_geometry",
    "discover_geometry_json",
]
