"""Closed-loop kinematics: the map from the six motor angles to every joint of the robot.

Paper §3.4: the parallelogram's stiffness must be modelled through the Jacobian with respect to
the crank (motor 3), not the elbow. On the loop manifold c(q) = 0 the passive joints follow the
motors: J_c,a dq_a + J_c,p dq_p = 0, so dq = N dq_a with N = [I; -J_c,p^+ J_c,a] (rows ordered
as MuJoCo's dofs). A motor-space Jacobian of any point is then J_site N.
"""
from __future__ import annotations

import mujoco
import numpy as np

from .robot import Robot


def loop_jacobian(robot: Robot, data: mujoco.MjData) -> np.ndarray:
    """J_c (3, nv): derivative of the loop gap (rod end minus anchor); kinematics must be current."""
    m = robot.model
    ja, jb = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    a, b = robot.loop_sites
    mujoco.mj_jacSite(m, data, ja, None, a)
    mujoco.mj_jacSite(m, data, jb, None, b)
    return ja - jb


def motor_map(robot: Robot, data: mujoco.MjData) -> np.ndarray:
    """N (nv, 6): joint velocities per unit motor velocity with the loop kept closed."""
    m = robot.model
    jc = loop_jacobian(robot, data)
    act, pas = robot.act_dof, m.jnt_dofadr[robot.passive_joint]
    n = np.zeros((m.nv, 6))
    n[act, np.arange(6)] = 1.0
    n[pas, :] = -np.linalg.pinv(jc[:, pas], rcond=1e-10) @ jc[:, act]
    return n


def motor_jacobian(robot: Robot, data: mujoco.MjData, site: int) -> np.ndarray:
    """(6, 6) motor-space Jacobian [position; rotation] of a site, loop closed (paper J_p, eq. 12)."""
    m = robot.model
    jp, jr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    mujoco.mj_jacSite(m, data, jp, jr, site)
    n = motor_map(robot, data)
    return np.vstack([jp @ n, jr @ n])


def motor_forces(robot: Robot, data: mujoco.MjData, qfrc: np.ndarray) -> np.ndarray:
    """Generalized forces mapped to the six motors by virtual work: N^T qfrc."""
    return motor_map(robot, data).T @ qfrc
