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


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """3-vector cross product (np.cross costs ~50 us of argument handling per call)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def constraint_basis(jc: np.ndarray) -> np.ndarray:
    """Orthonormal basis (3, 2 or 3) of the loop's independent constraint directions.

    A planar loop's gap has no component along its hinge axes, so J_c (3, nv) has rank 2 and its
    Gram matrix's null direction is the largest cross product of two of its rows; a KKT system
    on the two remaining directions stays regular. A spatial loop keeps all three.
    """
    gram = jc @ jc.T
    cands = [_cross(gram[0], gram[1]), _cross(gram[0], gram[2]), _cross(gram[1], gram[2])]
    n = max(cands, key=lambda v: v @ v)
    nn = np.sqrt(n @ n)
    if nn == 0.0 or np.abs(gram @ (n / nn)).max() > 1e-9 * np.abs(gram).max():
        return np.eye(3)
    n /= nn
    a = _cross(n, np.array([1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0]))
    a /= np.sqrt(a @ a)
    return np.column_stack([a, _cross(n, a)])


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
