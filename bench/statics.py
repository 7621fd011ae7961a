"""Exact static equilibrium of the closed-loop robot: Newton on MuJoCo's force balance.

The equilibrium solves paper eq. (17) in its generalized form,

    g(q) + J_c(q)^T lam = 0,   c(q) = 0,
    g(q) = qfrc_spring(q) - qfrc_bias(q; qvel=0) + J_site(q)^T W,

where c is the parallelogram loop gap (rod end minus anchor) held as a HARD constraint: MuJoCo's
own equality constraints are soft and would open the loop by millimetres under load
(PHYSICS.md), so they are switched off and the loop is closed here by a KKT-Newton iteration.
g includes the virtual joint springs (eq. 1), the compensator tendon (eqs. 7-9), gravity of
every body (links, the mass compensators m1 and m2) and the external wrench W at a site. The
Jacobian of the KKT system is taken by finite differences of g + J_c^T lam, so gravity's and
the load's geometric stiffness (H00 in eq. 18) is included exactly.

The planar loop gives one identically-zero constraint row (along the J2 axis); it is removed
by an SVD of J_c at every iteration, so the KKT matrix stays regular.
"""
from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from .robot import Robot

_DISABLE = int(mujoco.mjtDisableBit.mjDSBL_EQUALITY) | int(mujoco.mjtDisableBit.mjDSBL_CONTACT)


@dataclass(frozen=True)
class Equilibrium:
    """A solved static pose. Lengths in m, angles in rad, forces in N and N*m."""

    qpos: np.ndarray          # full MuJoCo qpos at equilibrium
    command: np.ndarray       # (6,) commanded controller angles
    deflection: np.ndarray    # (6,) actuated joint angle minus command (the VJM spring deflections)
    lam: np.ndarray           # loop constraint forces in the reduced constraint basis
    residual: float           # max |g + J_c^T lam| over all dofs, N*m
    gravity_scale: float      # max |gravity generalized force| over dofs at the solution, N*m
    loop_violation: float     # |c(q)|, m
    iterations: int


@dataclass(frozen=True)
class Load:
    """An external wrench in the world frame applied at a site (force at the site, moment)."""

    force: np.ndarray
    moment: np.ndarray
    site: int

    @staticmethod
    def mass(robot: Robot, mass: float, gravity: float = 9.81) -> "Load":
        return Load(np.array([0.0, 0.0, -mass * gravity]), np.zeros(3), robot.payload_site)

    @staticmethod
    def wrench(robot: Robot, w: np.ndarray) -> "Load":
        w = np.asarray(w, dtype=float)
        return Load(w[:3].copy(), w[3:].copy(), robot.payload_site)


class StaticsSolver:
    """Reusable solver bound to one Robot (it owns scratch buffers; not thread-safe)."""

    def __init__(self, robot: Robot, tol: float = 1e-12, max_iter: int = 30, fd_step: float = 1e-7):
        self.robot = robot
        self.tol = tol
        self.max_iter = max_iter
        self.fd_step = fd_step
        m = robot.model
        self._jp = np.zeros((3, m.nv))
        self._jr = np.zeros((3, m.nv))
        self._ja = np.zeros((3, m.nv))
        self._jb = np.zeros((3, m.nv))

    # -- pieces -------------------------------------------------------------------------
    def _forward(self, qpos: np.ndarray) -> None:
        m, d = self.robot.model, self.robot.data
        d.qpos[:] = qpos
        d.qvel[:] = 0.0
        flags = m.opt.disableflags
        m.opt.disableflags = flags | _DISABLE
        try:
            mujoco.mj_fwdPosition(m, d)
            mujoco.mj_fwdVelocity(m, d)
        finally:
            m.opt.disableflags = flags

    def _force(self, load: Load | None) -> np.ndarray:
        """g(q) at the pose in data: springs - gravity + load (generalized forces)."""
        m, d = self.robot.model, self.robot.data
        g = d.qfrc_passive - d.qfrc_bias
        if load is not None:
            mujoco.mj_jacSite(m, d, self._jp, self._jr, load.site)
            g = g + self._jp.T @ load.force + self._jr.T @ load.moment
        return g

    def _loop(self) -> tuple[np.ndarray, np.ndarray]:
        """Loop gap c (3,) and its Jacobian J_c (3, nv)."""
        m, d = self.robot.model, self.robot.data
        a, b = self.robot.loop_sites
        mujoco.mj_jacSite(m, d, self._ja, None, a)
        mujoco.mj_jacSite(m, d, self._jb, None, b)
        return d.site_xpos[a] - d.site_xpos[b], self._ja - self._jb

    def _lagrangian_grad(self, qpos, load, lam, basis):
        self._forward(qpos)
        g = self._force(load)
        c, jc = self._loop()
        jc_r = basis.T @ jc
        return g + jc_r.T @ lam, c, jc_r

    # -- solve --------------------------------------------------------------------------
    def solve(
        self,
        q: np.ndarray,
        load: Load | None = None,
        qpos0: np.ndarray | None = None,
        gravity: bool = True,
    ) -> Equilibrium:
        """Static equilibrium at command q (rad) under gravity and an optional load."""
        robot = self.robot
        m = robot.model
        q = np.asarray(q, dtype=float)
        robot.set_command(q)
        saved_gravity = m.opt.gravity.copy()
        if not gravity:
            m.opt.gravity[:] = 0.0
        try:
            return self._solve(q, load, robot.rigid_qpos(q) if qpos0 is None else qpos0.copy())
        finally:
            m.opt.gravity[:] = saved_gravity

    def _solve(self, q, load, qpos) -> Equilibrium:
        m = self.robot.model
        nv = m.nv
        self._forward(qpos)
        _, jc = self._loop()
        u, s, _ = np.linalg.svd(jc, full_matrices=False)
        basis = u[:, s > 1e-9 * s[0]]
        lam = np.zeros(basis.shape[1])
        nc = basis.shape[1]
        kkt = np.zeros((nv + nc, nv + nc))
        scale = 1.0
        res_norm = np.inf
        it = 0
        for it in range(1, self.max_iter + 1):
            r, c, jc_r = self._lagrangian_grad(qpos, load, lam, basis)
            scale = max(scale, float(np.abs(self.robot.data.qfrc_bias).max()))
            res_norm = float(np.abs(r).max())
            c_r = basis.T @ c
            if res_norm <= self.tol * scale and np.abs(c_r).max() <= 1e-13:
                break
            # d(g + J_c^T lam)/dq by forward differences (qpos == qvel space: hinges only)
            a = np.empty((nv, nv))
            for j in range(nv):
                qp = qpos.copy()
                qp[j] += self.fd_step
                rj, _, _ = self._lagrangian_grad(qp, load, lam, basis)
                a[:, j] = (rj - r) / self.fd_step
            kkt[:nv, :nv] = a
            kkt[:nv, nv:] = jc_r.T
            kkt[nv:, :nv] = jc_r
            step = np.linalg.solve(kkt, -np.concatenate([r, c_r]))
            qpos = qpos + step[:nv]
            lam = lam + step[nv:]
        self._forward(qpos)
        c, _ = self._loop()
        # the gravity scale at the solution, for a relative residual
        grav = self._gravity_scale(qpos)
        return Equilibrium(
            qpos=qpos.copy(),
            command=q.copy(),
            deflection=qpos[self.robot.act_qpos] - q,
            lam=lam,
            residual=res_norm,
            gravity_scale=grav,
            loop_violation=float(np.linalg.norm(c)),
            iterations=it,
        )

    def _gravity_scale(self, qpos) -> float:
        self._forward(qpos)
        return float(np.abs(self.robot.data.qfrc_bias).max())
