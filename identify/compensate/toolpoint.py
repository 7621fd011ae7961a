"""The tool point on a robot: a site the statics can load and the compensation can aim.

A job's tool may be any point fixed in a body (docs/contract.md, "Job file"); MuJoCo applies and
measures things at sites, so :func:`with_tool` recompiles the robot's MJCF (or, for a truth
robot with hidden effects, its edited MJCF) with one extra site there and copies the elastic
values the original model held. A site adds no mass, joint or constraint: the physics is the
same model's (tests/test_compensate.py compares the equilibria).
"""

from __future__ import annotations

from typing import NamedTuple

import mujoco
import numpy as np

from calbench.bench.model import Robot
from calbench.bench.model.effects import load_spec

from .job import Tool

TOOL_SITE = "calbench_tool"
# the model fields that hold elastic values (Robot.set_params, the joint_nonlinearity effect)
_ELASTIC = (*Robot.PARAM_FIELDS, "jnt_stiffnesspoly")


class ToolRobot(NamedTuple):
    robot: Robot
    site: int  # the tool site's id


def with_tool(robot: Robot, tool: Tool) -> ToolRobot:
    """``robot`` with the tool as a site (the same robot when the tool is a site already)."""
    m = robot.model
    if tool.body is None:
        name = tool.site
        site = robot.flange_site if name is None else mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, name)
        return ToolRobot(robot, int(site))
    xml = robot.to_xml() if hasattr(robot, "to_xml") else None
    if xml is None and robot.source is None:
        raise ValueError("with_tool: a robot read from a file, or one that can write its MJCF (to_xml)")
    spec = load_spec(xml if xml is not None else robot.source)
    spec.body(tool.body).add_site(name=TOOL_SITE, pos=np.asarray(tool.pos, dtype=float).tolist())
    if xml is not None:
        spec.compiler.savecompiled = False
    out = Robot(spec.compile(), robot.source)
    for f in _ELASTIC:
        getattr(out.model, f)[:] = getattr(m, f)
    return ToolRobot(out, int(mujoco.mj_name2id(out.model, mujoco.mjtObj.mjOBJ_SITE, TOOL_SITE)))


def tool_pose(robot: Robot, site: int, qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World position (3,) and orientation (3, 3) of the site at configuration qpos."""
    m, d = robot.model, robot.data
    d.qpos[:] = qpos
    mujoco.mj_kinematics(m, d)
    return d.site_xpos[site].copy(), d.site_xmat[site].reshape(3, 3).copy()


def tool_jacobian(robot: Robot, site: int, qpos: np.ndarray) -> np.ndarray:
    """(6, nv): d[position; rotation vector]/dq of the site at qpos (world frame)."""
    m, d = robot.model, robot.data
    d.qpos[:] = qpos
    mujoco.mj_kinematics(m, d)
    mujoco.mj_comPos(m, d)
    jac = np.zeros((6, m.nv))
    mujoco.mj_jacSite(m, d, jac[:3], jac[3:], site)
    return jac


def rotation_error(r: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Rotation vector (3,) of r target^T, world frame: how far r is turned from target (rad)."""
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, (r @ target.T).ravel())
    vel = np.zeros(3)
    mujoco.mju_quat2Vel(vel, quat, 1.0)
    return vel


__all__ = ["TOOL_SITE", "ToolRobot", "with_tool", "tool_pose", "tool_jacobian", "rotation_error"]
