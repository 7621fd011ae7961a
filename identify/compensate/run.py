"""`calbench compensate` as one library call: the job, the identified model and the target in;
the commands, the per-point predictions and (on the bench) the true errors out, as the CSV and
the JSON of docs/contract.md ("Job file")."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calbench.bench.core import InputError, check_memory
from calbench.bench.model import MODEL_FLAG, Robot, load_robot
from calbench.bench.scenario import Scenario, load_scenario

from .batch import BATCH_MIN, compensate_batch
from .identified import IdentifiedParams, read_identified
from .job import Job, check_job, load_job
from .solve import TARGETS, Compensator, PointResult
from .toolpoint import with_tool
from .truth import TruePoint, apply_to_truth

# The points of one job move together (one parameter error moves them all), so a job's RMS z is
# about one chi variable of a few degrees of freedom: above 3 by chance with probability < 0.3 %
# when the model is right. Above it, the true robot has something the identified model lacks.
Z_EXCEEDED = 3.0


@dataclass(frozen=True)
class CompensationRequest:
    job: str | Path
    identified: str | Path
    target: str = "unloaded"
    model: str | Path | None = None  # default: the job's robot
    truth: str | Path | None = None  # a scenario whose true robot the commands are applied to
    batched: bool | None = (
        None  # stacked on mujoco.batch (identify/compensate/batch.py); None: from BATCH_MIN points
    )


@dataclass(frozen=True)
class Compensation:
    job: Job
    robot: Robot
    identified: IdentifiedParams
    target: str
    points: tuple[PointResult, ...]
    truth: tuple[TruePoint, ...] | None = None
    scenario: Scenario | None = None  # the true robot's, when the commands were applied to one

    @property
    def unreached(self) -> list[PointResult]:
        return [p for p in self.points if not p.converged]

    def commands_csv(self) -> str:
        """``point,q1,…,qN`` in degrees, one row per job point (a point not reached keeps its
        nominal command; the JSON and the exit status name it)."""
        n = self.robot.n_act
        rows = ["point," + ",".join(f"q{j + 1}" for j in range(n))]
        rows += [
            f"{p.index}," + ",".join(f"{x:.9f}" for x in np.round(np.degrees(p.command), 9) + 0.0)
            for p in self.points
        ]
        return "\n".join(rows) + "\n"

    def summary(self) -> dict:
        ok = [p for p in self.points if p.converged]
        out = {
            "n_points": len(self.points),
            "n_converged": len(ok),
            "unreached": [{"index": p.index, "reason": p.reason} for p in self.unreached],
            "predicted_deviation_rms_m": _rms([p.predicted_deviation_m for p in self.points]),
            "predicted_error_rms_m": _rms([p.predicted_error_std_m for p in ok]),
            "max_position_error_m": max((p.position_error_m for p in ok), default=None),
            "max_orientation_error_rad": max((p.orientation_error_rad for p in ok), default=None),
        }
        if self.truth is not None:
            after = [t.error_after_m for t in self.truth if math.isfinite(t.error_after_m)]
            before = [t.error_before_m for t in self.truth]
            out |= {
                "true_error_before_rms_m": _rms(before),
                "true_error_after_rms_m": _rms(after),
                "true_error_after_max_m": max(after, default=None),
                "removed_fraction": None
                if not after
                else 1.0
                - _rms(after)
                / _rms([t.error_before_m for t in self.truth if math.isfinite(t.error_after_m)]),
                "z_rms": _rms([t.z for t in self.truth if math.isfinite(t.z)]),
            }
            out["prediction_exceeded"] = out["z_rms"] is not None and out["z_rms"] > Z_EXCEEDED
        return out

    def to_dict(self) -> dict:
        truth = {t.index: t for t in self.truth} if self.truth is not None else {}
        points = []
        for p in self.points:
            d = {
                "index": p.index,
                "converged": p.converged,
                "reason": p.reason,
                "iterations": p.iterations,
                "nominal_deg": np.degrees(p.nominal).tolist(),
                "command_deg": np.degrees(p.command).tolist(),
                "target_position_m": _list(p.target_position),
                "predicted_deviation_m": _num(p.predicted_deviation_m),
                "predicted_orientation_deviation_rad": _num(p.predicted_orientation_deviation_rad),
                "position_error_m": _num(p.position_error_m),
                "orientation_error_rad": _num(p.orientation_error_rad),
                "predicted_error_std_m": _num(p.predicted_error_std_m),
                "predicted_position_covariance_m2": [_list(r) for r in p.position_covariance],
                "predicted_orientation_std_rad": _num(p.orientation_std_rad),
            }
            if p.index in truth:
                t = truth[p.index]
                d |= {
                    "true_error_before_m": _num(t.error_before_m),
                    "true_error_after_m": _num(t.error_after_m),
                    "true_orientation_error_before_rad": _num(t.orientation_before_rad),
                    "true_orientation_error_after_rad": _num(t.orientation_after_rad),
                    "z": _num(t.z),
                }
            points.append(d)
        return {
            "target": self.target,
            "job": str(self.job.path),
            "robot": str(self.robot.source or ""),
            "identified": self.identified.source,
            "points": points,
            "summary": self.summary(),
        }


def _num(x: float) -> float | None:
    return float(x) if x is not None and math.isfinite(x) else None


def _list(a) -> list:
    return [_num(float(x)) for x in a]


def _rms(xs) -> float | None:
    xs = [x for x in xs if x is not None and math.isfinite(x)]
    return float(math.sqrt(sum(x * x for x in xs) / len(xs))) if xs else None


POINT_BYTES = 16_000  # memory per job point (budget; ~12 kB measured)


def run_compensate(req: CompensationRequest) -> Compensation:
    """Read, check, compensate every job point and (with ``truth``) apply the commands to the
    scenario's true robot. InputError on any bad input, before any work."""
    if req.target not in TARGETS:
        raise InputError("--target", "target", "one of " + ", ".join(TARGETS), req.target)
    job = load_job(req.job)
    # memory: each point's command, solution, predictions and covariances, ~12 kB measured
    # (benchmarks/sizes_bench.py: +121 MB for 10^4 points; docs/reliability.md "Memory budgets")
    n = len(job.points)
    check_memory(n * POINT_BYTES, job.path, "point", f"{n:,} points at {POINT_BYTES} B each")
    robot = (
        load_robot(*MODEL_FLAG, path=req.model)
        if req.model is not None
        else load_robot(job.path, "robot", path=job.robot)
    )
    check_job(job, robot)
    ident = read_identified(req.identified, robot)
    scn = load_scenario(req.truth) if req.truth is not None else None
    comp = Compensator(with_tool(robot, job.tool), ident.params(robot), ident.covariance, req.target)
    batched = len(job.points) >= BATCH_MIN if req.batched is None else req.batched
    points = tuple(compensate_batch(comp, job.points) if batched else comp.path(job.points))
    truth = None
    if scn is not None:
        truth = tuple(apply_to_truth(scn, job, robot, list(points), req.target))
    return Compensation(job, robot, ident, req.target, points, truth, scn)


__all__ = ["Z_EXCEEDED", "CompensationRequest", "Compensation", "run_compensate"]
