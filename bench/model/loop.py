"""Closed-loop kinematics: the loop gap, its constraint basis, and the motor map.

A kinematic loop is a pair of sites that must coincide (``Robot.loops``: the ``connect``
equalities named by the robot description, e.g. a parallelogram's rod end and its anchor). Its gap c(q) = x_a - x_b and Jacobian J_c = J_a - J_b are defined once,
in :func:`loop_gap`: the statics (bench/statics/equilibrium.py, paper eq. 17) hold c = 0 as a hard
constraint, and this module maps motor motion onto the loop manifold.

Paper §3.4: a loop's stiffness must be modelled through the Jacobian with respect to the motors
(the FANUC's crank, motor 3), not the passive joints (its elbow). On the loop manifold c(q) = 0 the passive joints follow the
motors: J_c,a dq_a + J_c,p dq_p = 0, so dq = N dq_a with N = [I; -J_c,p^+ J_c,a] (rows ordered
as MuJoCo's dofs). A motor-space Jacobian of any point is then J_site N.
"""

from __future__ import annotations

from typing import Protocol

import mujoco
import numpy as np


class Looped(Protocol):
    """What these functions need of a robot (bench.model.Robot has it): its model, its loops as
    (site a, site b) id pairs, and which dofs the motors drive and which follow."""

    model: mujoco.MjModel
    loops: tuple[tuple[int, int], ...]
    act_dof: np.ndarray
    passive_dof: np.ndarray
    n_act: int


# m, a closed loop's gap (bench/statics/equilibrium.py: the same ~1e-12 rad x a metre-long link)
LOOP_TOL = 1e-12


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """3-vector cross product (np.cross costs ~50 us of argument handling per call)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def loop_gap(
    robot: Looped, data: mujoco.MjData, jac: np.ndarray | None = None, scratch: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Gap c (3L,) and Jacobian J_c (3L, nv) of the robot's L loops, rows ordered loop by loop.

    Each loop contributes x_a - x_b (m) and J_a - J_b; the position stage (and mj_comPos, as
    for any mj_jacSite) must be current in ``data``. ``jac`` (3L, nv) and ``scratch`` (3, nv),
    if given, are filled instead of allocated (the statics' hot path); J_c is then ``jac``."""
    m = robot.model
    jc = np.empty((3 * len(robot.loops), m.nv)) if jac is None else jac
    jb = np.empty((3, m.nv)) if scratch is None else scratch
    xpos = data.site_xpos
    gaps = []
    for i, (a, b) in enumerate(robot.loops):
        ja = jc[3 * i : 3 * i + 3]
        mujoco.mj_jacSite(m, data, ja, None, a)
        mujoco.mj_jacSite(m, data, jb, None, b)
        ja -= jb
        gaps.append(xpos[a] - xpos[b])
    if not gaps:  # a serial robot
        return np.zeros(0), jc
    return (gaps[0] if len(gaps) == 1 else np.concatenate(gaps)), jc


def _loop_basis(jc: np.ndarray) -> np.ndarray:
    """Basis (3, 2 or 3) of one loop's independent constraint directions."""
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


def constraint_basis(jc: np.ndarray) -> np.ndarray:
    """Orthonormal basis (3L, r) of the loops' independent constraint directions, block by loop.

    A planar loop's gap has no component along its hinge axes, so its J_c (3, nv) has rank 2 and
    its Gram matrix's null direction is the largest cross product of two of its rows; a KKT
    system on the two remaining directions stays regular. A spatial loop keeps all three.
    Loops are reduced one at a time (enough while no two loops constrain the same motion).
    """
    if jc.shape[0] == 3:
        return _loop_basis(jc)
    blocks = [_loop_basis(jc[i : i + 3]) for i in range(0, jc.shape[0], 3)]
    out = np.zeros((jc.shape[0], sum(b.shape[1] for b in blocks)))
    col = 0
    for i, b in enumerate(blocks):
        out[3 * i : 3 * i + 3, col : col + b.shape[1]] = b
        col += b.shape[1]
    return out


def constraint_basis_stack(jc: np.ndarray) -> np.ndarray:
    """:func:`constraint_basis` of a stack of configurations: jc (n, 3L, nv) -> (n, 3L, r).

    The same construction, vectorised over the stack (bench/statics/batched.py). A loop is
    reduced to two directions only when it is planar in every configuration of the stack (as
    the parallelogram always is); otherwise all three are kept, and the configurations where
    it is in fact planar get a singular KKT matrix, which the batched solver reports as failed.
    """
    n = jc.shape[0]
    blocks = []
    for i in range(0, jc.shape[1], 3):
        gram = np.einsum("nik,njk->nij", jc[:, i : i + 3], jc[:, i : i + 3])
        cands = np.stack(
            [
                np.cross(gram[:, 0], gram[:, 1]),
                np.cross(gram[:, 0], gram[:, 2]),
                np.cross(gram[:, 1], gram[:, 2]),
            ],
            axis=1,
        )
        pick = np.einsum("nkj,nkj->nk", cands, cands).argmax(axis=1)
        nrm = cands[np.arange(n), pick]
        nn = np.sqrt(np.einsum("nj,nj->n", nrm, nrm))
        with np.errstate(invalid="ignore", divide="ignore"):
            nrm = nrm / nn[:, None]
            off = np.abs(np.einsum("nij,nj->ni", gram, nrm)).max(axis=1)
        planar = (nn > 0.0) & (off <= 1e-9 * np.abs(gram).max(axis=(1, 2)))
        if not planar.all():
            blocks.append(np.broadcast_to(np.eye(3), (n, 3, 3)))
            continue
        e = np.where((np.abs(nrm[:, 0]) < 0.9)[:, None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
        a = np.cross(nrm, e)
        a /= np.sqrt(np.einsum("nj,nj->n", a, a))[:, None]
        blocks.append(np.stack([a, np.cross(nrm, a)], axis=2))
    out = np.zeros((n, jc.shape[1], sum(b.shape[2] for b in blocks)))
    col = 0
    for i, b in enumerate(blocks):
        out[:, 3 * i : 3 * i + 3, col : col + b.shape[2]] = b
        col += b.shape[2]
    return out


def loop_jacobian(robot: Looped, data: mujoco.MjData) -> np.ndarray:
    """J_c (3L, nv) alone (see :func:`loop_gap`)."""
    return loop_gap(robot, data)[1]


def motor_map(robot: Looped, data: mujoco.MjData) -> np.ndarray:
    """N (nv, n_act): joint velocities per unit motor velocity with the loops kept closed."""
    m = robot.model
    jc = loop_jacobian(robot, data)
    act, pas = robot.act_dof, robot.passive_dof
    n = np.zeros((m.nv, robot.n_act))
    n[act, np.arange(robot.n_act)] = 1.0
    if len(pas):
        n[pas, :] = -np.linalg.pinv(jc[:, pas], rcond=1e-10) @ jc[:, act]
    return n


def motor_jacobian(robot: Looped, data: mujoco.MjData, site: int) -> np.ndarray:
    """(6, n_act) motor-space Jacobian [position; rotation] of a site, loops closed (paper J_p,
    eq. 12)."""
    m = robot.model
    jp, jr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    mujoco.mj_jacSite(m, data, jp, jr, site)
    n = motor_map(robot, data)
    return np.vstack([jp @ n, jr @ n])


def motor_jacobians(robot: Looped, data: mujoco.MjData, sites) -> list[np.ndarray]:
    """:func:`motor_jacobian` of several sites at one configuration, the motor map taken once
    (the same numbers: only the repeated loop-closure solve is saved)."""
    m = robot.model
    n = motor_map(robot, data)
    out = []
    for site in sites:
        jp, jr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
        mujoco.mj_jacSite(m, data, jp, jr, site)
        out.append(np.vstack([jp @ n, jr @ n]))
    return out


def motor_forces(robot: Looped, data: mujoco.MjData, qfrc: np.ndarray) -> np.ndarray:
    """Generalized forces mapped to the motors by virtual work: N^T qfrc."""
    return motor_map(robot, data).T @ qfrc
