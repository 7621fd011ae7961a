"""The robot model identification and discovery fit (the user's MJCF, ``--model``, or the one
the log carries: bench.model.log_robot) checked to name every site the observations use.
Geometry only: every elastic value in it is overwritten by the estimator's own parameters."""

from __future__ import annotations

import mujoco

from calbench.bench.core import InputError
from calbench.bench.model import Robot

from .observations import Observations


def check_sites(robot: Robot, obs: Observations, where) -> None:
    for p in obs.poses:
        for name in (p.site, *p.reflectors):
            if mujoco.mj_name2id(robot.model, mujoco.mjtObj.mjOBJ_SITE, name) < 0:
                raise InputError(where, f"site {name!r}", "a site of this name in the robot model", "none")


__all__ = ["check_sites"]
