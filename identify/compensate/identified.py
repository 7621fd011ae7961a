"""The identified model a compensation runs on: the estimates and their full covariance from
``calbench identify --json`` (docs/contract.md, "JSON reports"), checked against the robot.

An identification of another robot is refused (InputError naming the JSON and the key): its
parameter names must be this robot's theta (bench/model/params.py: ``k1 … kN`` and one
stiffness and preload per compensator, in that order), and, when the report carries the robot's
geometry fingerprint (``robot_sha256``, written by identify from the geometry issue on), it
must be this robot's.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calbench.bench.core import InputError
from calbench.bench.log import IdentificationReport
from calbench.bench.model import Params, Robot

from .fingerprint import robot_sha256


@dataclass(frozen=True)
class IdentifiedParams:
    """theta (SI, in the robot's layout order), its covariance (n, n) and the layout's names."""

    names: tuple[str, ...]
    theta: np.ndarray
    covariance: np.ndarray
    source: str = ""

    def params(self, robot: Robot) -> Params:
        return robot.layout.params(self.theta)


def identified_from_report(rep: IdentificationReport, robot: Robot, source: object) -> IdentifiedParams:
    """The report's estimates and covariance for ``robot`` (InputError if they do not fit)."""
    names = tuple(p.name for p in rep.parameters)
    want = robot.layout.names
    label = robot.source.name if robot.source else "the robot"
    if names != want:
        raise InputError(
            source,
            "parameters",
            f"the parameters of {label} ({', '.join(want)}): an identification of another robot?",
            ", ".join(names),
        )
    fp = rep.details.get("robot_sha256")
    if fp is not None and fp != robot_sha256(robot):
        raise InputError(
            source, "robot_sha256", f"the geometry fingerprint of {label} ({robot_sha256(robot)})", fp
        )
    for i, p in enumerate(rep.parameters):
        if p.estimate is None:
            raise InputError(
                source,
                f"parameters[{i}].estimate",
                f"an identified value of {p.name} (the compensation needs every parameter: a plan "
                "that determines it, e.g. from calbench design)",
                p.reason or "null",
            )
    if rep.covariance is None:
        raise InputError(source, "covariance", f"the {len(want)}x{len(want)} covariance of the estimates")
    cov = np.array([[np.nan if x is None else x for x in row] for row in rep.covariance], dtype=float)
    if cov.shape != (len(want), len(want)) or not np.all(np.isfinite(cov)):
        raise InputError(
            source, "covariance", f"a finite {len(want)}x{len(want)} matrix of numbers", f"shape {cov.shape}"
        )
    theta = np.array([p.estimate for p in rep.parameters], dtype=float)
    if np.any(theta[robot.layout.compliance] <= 0):
        raise InputError(source, "parameters", "positive compliances k1 … kN", theta.tolist())
    return IdentifiedParams(names, theta, 0.5 * (cov + cov.T), str(source))


def read_identified(path: str | Path, robot: Robot) -> IdentifiedParams:
    """:func:`identified_from_report` of an ``identify --json`` file."""
    return identified_from_report(IdentificationReport.read(path), robot, path)


__all__ = ["IdentifiedParams", "identified_from_report", "read_identified"]
