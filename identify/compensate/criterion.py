"""The design criterion of a compensation job (issue 26, "Design for the job"): how well a plan
serves the compensation of a given path.

After compensation the true tool misses its target at job point i by G_i (theta - theta_hat)
(identify/compensate/solve.py), so a plan whose identification has covariance C leaves the mean
squared error (1/n) sum_i trace(G_i C G_i^T) = trace(G C G^T) with G the n points' G_i stacked
and divided by sqrt(n): the I-optimal criterion (average prediction variance over the job),
which is the form ``calbench design --criterion pose`` already minimises for one [work] pose
(identify/design/criteria.py). :func:`job_design_jacobian` gives that G at the design's prior,
in the design's normalised parameters (each column times its prior value), so the design's
pose measure becomes the job's mean squared compensation error, m^2.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from calbench.bench.core import InputError
from calbench.bench.model import Params, Robot, load_robot

from .batch import BATCH_MIN, compensate_batch
from .job import check_job, load_job
from .solve import Compensator
from .toolpoint import with_tool


def job_design_jacobian(job_path: str | Path, robot: Robot, params0: Params) -> np.ndarray:
    """G (3n, p) of the job at the prior ``params0`` of ``robot`` (the design's), normalised:
    columns times theta0, rows over sqrt(n). InputError when the job is not for this robot or a
    point cannot be compensated at the prior (named)."""
    job = load_job(job_path)
    mine = load_robot(job.path, "robot", path=job.robot)
    label = robot.source.name if robot.source else "the scenario's robot"
    if mine.description.actuated != robot.description.actuated or mine.layout != robot.layout:
        raise InputError(
            job.path, "robot", f"the scenario's robot ({label}: same joints and springs)", job.robot.name
        )
    check_job(job, mine)
    theta0 = robot.layout.theta(params0)
    comp = Compensator(with_tool(mine, job.tool), params0, np.eye(len(theta0)))
    res = compensate_batch(comp, job.points) if len(job.points) >= BATCH_MIN else comp.path(job.points)
    bad = [r for r in res if not r.converged]
    if bad:
        raise InputError(
            job.path,
            f"point[{bad[0].index}]",
            "a point the compensation reaches at the design's prior",
            bad[0].reason,
        )
    g = np.concatenate([r.dpos_dtheta for r in res]) * theta0[None, :]
    return g / math.sqrt(len(res))


__all__ = ["job_design_jacobian"]
