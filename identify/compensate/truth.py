"""On the bench: the compensated commands applied to the TRUE robot of a scenario (its truth,
hidden effects included), and the true error at every job point before and after.

The true target is the true robot's own (``unloaded``: its tool at the nominal command without
the job's load; ``rigid``: the rigid pose), the true tool position its loaded equilibrium
(bench.statics, the same solver the campaign simulates with) at the nominal command (before)
and at the compensated one (after). Nothing here feeds back into the compensation: the
commands are computed from the identified model alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from calbench.bench.campaign import truth_robot
from calbench.bench.core import InputError, StaticsError
from calbench.bench.model import Robot
from calbench.bench.scenario import Scenario
from calbench.bench.statics import Load, StaticsSolver

from .job import Job, JobPoint
from .solve import PointResult
from .toolpoint import ToolRobot, rotation_error, tool_pose, with_tool


@dataclass(frozen=True)
class TruePoint:
    """The true robot at one job point (m, rad; nan where the point was not compensated)."""

    index: int
    error_before_m: float
    error_after_m: float
    orientation_before_rad: float
    orientation_after_rad: float
    z: float  # |error after| / predicted_error_std_m


def true_robot(scn: Scenario, job: Job, user_robot: Robot) -> ToolRobot:
    """The scenario's true robot with the job's tool; InputError when it is not the job's robot
    (other actuated joints or reflectors: the user's model may be an augmented one, with more
    joints, so the geometry's fingerprint is not asked to match)."""
    truth = truth_robot(scn)
    same = (
        truth.description.actuated == user_robot.description.actuated
        and truth.reflector_names == user_robot.reflector_names
    )
    label = user_robot.source.name if user_robot.source else "the job's robot"
    if not same:
        raise InputError(
            scn.path, "robot", f"the job's robot ({label}: same joints and reflectors)", scn.robot.name
        )
    try:
        return with_tool(truth, job.tool)
    except (KeyError, ValueError) as exc:
        raise InputError(scn.path, "robot", f"a robot with the job's tool ({job.tool})", str(exc)) from None


class TruthBench:
    """Loaded equilibria of the true robot at any command."""

    def __init__(self, tool: ToolRobot, target: str):
        self.robot, self.site = tool
        self.target_kind = target
        self.solver = StaticsSolver(self.robot)

    def load(self, p: JobPoint) -> Load:
        if p.payload is not None:
            return Load.mass(self.robot, p.payload)
        return Load(np.array(p.wrench[:3]), np.array(p.wrench[3:]), self.site)

    def pose(self, u: np.ndarray, load: Load | None) -> tuple[np.ndarray, np.ndarray]:
        eq = self.solver.solve(u, load)
        if not eq.acceptable:
            raise StaticsError(f"the true robot has no equilibrium at {np.degrees(u).round(3).tolist()} deg")
        return tool_pose(self.robot, self.site, eq.qpos)

    def target(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if self.target_kind == "rigid":
            return tool_pose(self.robot, self.site, self.robot.rigid_qpos(q))
        return self.pose(q, None)

    def point(self, p: JobPoint, res: PointResult) -> TruePoint:
        nan = float("nan")
        load = self.load(p)
        pos_t, rot_t = self.target(np.asarray(p.q))
        pos, rot = self.pose(np.asarray(p.q), load)
        before, obefore = np.linalg.norm(pos - pos_t), np.linalg.norm(rotation_error(rot, rot_t))
        after = oafter = z = nan
        if res.converged:
            pos, rot = self.pose(res.command, load)
            after, oafter = np.linalg.norm(pos - pos_t), np.linalg.norm(rotation_error(rot, rot_t))
            std = res.predicted_error_std_m
            z = after / std if std > 0 else math.inf
        return TruePoint(res.index, float(before), float(after), float(obefore), float(oafter), float(z))


def apply_to_truth(
    scn: Scenario, job: Job, user_robot: Robot, results: list[PointResult], target: str
) -> list[TruePoint]:
    """The true error at every job point before and after compensation (:class:`TruePoint`)."""
    bench = TruthBench(true_robot(scn, job, user_robot), target)
    return [bench.point(p, r) for p, r in zip(job.points, results)]


__all__ = ["TruePoint", "TruthBench", "apply_to_truth", "true_robot"]
