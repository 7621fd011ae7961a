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

from dataclasses import dataclass, field

import mujoco
import numpy as np

from .errors import StaticsError
from .loop import constraint_basis
from .robot import Robot

# Loop closed by us; contacts and joint-range stops play no part in the statics (ranges are
# controller limits, checked on the command).
_DISABLE = (
    int(mujoco.mjtDisableBit.mjDSBL_EQUALITY)
    | int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    | int(mujoco.mjtDisableBit.mjDSBL_LIMIT)
)


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
    factor: np.ndarray | None = field(default=None, repr=False, compare=False)  # KKT inverse, warm starts
    stalls: int = 0           # times the cheap matrix stalled and the exact one was used


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

    def __init__(self, robot: Robot, tol: float = 1e-10, max_iter: int = 30, fd_step: float = 1e-7):
        self.robot = robot
        self.tol = tol
        self.max_iter = max_iter
        self.fd_step = fd_step
        m = robot.model
        self._jp = np.zeros((3, m.nv))
        self._jr = np.zeros((3, m.nv))
        self._ja = np.zeros((3, m.nv))
        self._jb = np.zeros((3, m.nv))
        self._dfdq = np.zeros((m.nv, m.nv))

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
        warm: Equilibrium | None = None,
    ) -> Equilibrium:
        """Static equilibrium at command q (rad) under gravity and an optional load.

        qpos0 starts the iteration elsewhere than the rigid pose; `warm` (an equilibrium of the
        same command, e.g. the unloaded one) starts at its qpos AND reuses its factorised KKT
        matrix, which differs from the new one only by the load's curvature."""
        if warm is not None:
            qpos0 = warm.qpos
        robot = self.robot
        m = robot.model
        q = np.asarray(q, dtype=float)
        robot.set_command(q)
        saved_gravity = m.opt.gravity.copy()
        if not gravity:
            m.opt.gravity[:] = 0.0
        try:
            return self._solve(q, load, robot.rigid_qpos(q) if qpos0 is None else qpos0.copy(),
                               warm.factor if warm is not None else None)
        finally:
            m.opt.gravity[:] = saved_gravity

    def _basis(self, qpos) -> np.ndarray:
        """Orthonormal basis of the loop's independent constraint directions (2 of 3: planar)."""
        self._forward(qpos)
        _, jc = self._loop()
        return constraint_basis(jc)

    def _kkt(self, qpos, load, lam, basis, r, jc_r) -> np.ndarray:
        """KKT matrix [[A, J_c^T], [J_c, 0]] with A = d(g + J_c^T lam)/dq by forward differences."""
        nv = self.robot.model.nv
        nc = basis.shape[1]
        a = np.empty((nv, nv))
        for j in range(nv):
            qp = qpos.copy()
            qp[j] += self.fd_step
            rj, _, _ = self._lagrangian_grad(qp, load, lam, basis)
            a[:, j] = (rj - r) / self.fd_step
        kkt = np.zeros((nv + nc, nv + nc))
        kkt[:nv, :nv] = a
        kkt[:nv, nv:] = jc_r.T
        kkt[nv:, :nv] = jc_r
        return kkt

    def _stiffness_kkt(self, qpos, jc_r) -> np.ndarray:
        """KKT matrix with A from MuJoCo's own finite-differenced inverse dynamics (one C call):
        d(bias - passive)/dq holds every spring, the tendon and gravity's geometric stiffness;
        it lacks only the load's and the loop force's curvature (~1 % here), which the chord
        iteration absorbs."""
        m, d = self.robot.model, self.robot.data
        nv = m.nv
        d.qpos[:] = qpos
        d.qvel[:] = 0.0
        d.qacc[:] = 0.0
        flags = m.opt.disableflags
        m.opt.disableflags = flags | _DISABLE
        try:
            mujoco.mjd_inverseFD(m, d, self.fd_step, 0, self._dfdq, None, None, None, None, None, None)
        finally:
            m.opt.disableflags = flags
        nc = jc_r.shape[0]
        kkt = np.zeros((nv + nc, nv + nc))
        kkt[:nv, :nv] = -self._dfdq.T
        kkt[:nv, nv:] = jc_r.T
        kkt[nv:, :nv] = jc_r
        return kkt

    def _solve(self, q, load, qpos, lu=None) -> Equilibrium:
        """Newton on the KKT system with MuJoCo's inverse-dynamics derivative as the matrix (one
        C call), refreshed on the first two iterations and then reused: it lacks only the load's
        and the loop force's curvature (~1e-3 of the stiffness here), so the steps still gain
        ~3 digits each. Should it stall, the full finite-difference matrix takes over."""
        nv = self.robot.model.nv
        basis = self._basis(qpos)
        lam = np.zeros(basis.shape[1])
        scale = 1.0
        res_norm = np.inf
        prev = np.inf
        fresh = 0 if lu is None else 2  # a warm factor counts as already refreshed
        stalls = 0
        it = 0
        for it in range(1, self.max_iter + 1):
            r, c, jc_r = self._lagrangian_grad(qpos, load, lam, basis)
            scale = max(scale, float(np.abs(self.robot.data.qfrc_bias).max()))
            res_norm = float(np.abs(r).max())
            c_r = basis.T @ c
            if res_norm <= self.tol * scale and np.abs(c_r).max() <= 1e-12:
                break
            if not np.isfinite(res_norm):
                raise StaticsError(f"statics diverged at command {np.degrees(q).round(3).tolist()} deg")
            try:
                if res_norm > 0.2 * prev:  # stalled: take the exact (finite-difference) matrix
                    lu = np.linalg.inv(self._kkt(qpos, load, lam, basis, r, jc_r))
                    stalls += 1
                elif fresh < 2:  # the big first steps move the stiffness; later ones barely do
                    lu = np.linalg.inv(self._stiffness_kkt(qpos, jc_r))
                    fresh += 1
            except np.linalg.LinAlgError:
                raise StaticsError(
                    f"singular stiffness (KKT) matrix at command {np.degrees(q).round(3).tolist()} deg: "
                    "a degenerate configuration (is the parallelogram flat?)") from None
            prev = res_norm
            # the inverse of a 10x10 KKT matrix (condition ~1e7) is accurate to ~1e-9 relative:
            # ample for Newton steps, whose errors the next residual corrects
            step = -(lu @ np.concatenate([r, c_r]))
            qpos = qpos + step[:nv]
            lam = lam + step[nv:]
        self._forward(qpos)
        c, _ = self._loop()
        grav = float(np.abs(self.robot.data.qfrc_bias).max())
        return Equilibrium(
            qpos=qpos.copy(),
            command=q.copy(),
            deflection=qpos[self.robot.act_qpos] - q,
            lam=lam,
            residual=res_norm,
            gravity_scale=grav,
            loop_violation=float(np.linalg.norm(c)),
            iterations=it,
            factor=lu,
            stalls=stalls,
        )

    # -- linearization at a solution --------------------------------------------------------
    def tangent(self, eq: Equilibrium, load: Load | None, dforce: np.ndarray, gravity: bool = True) -> np.ndarray:
        """dq/dtheta at an equilibrium by the implicit function theorem.

        dforce (nv, p): derivative of the generalized force g with respect to p parameters at
        fixed q. The loop stays closed: [[A, J_c^T], [J_c, 0]] [dq; dlam] = [-dforce; 0].
        Returns (nv, p). The robot's command and parameters must be those of `eq`.
        """
        m = self.robot.model
        saved = m.opt.gravity.copy()
        if not gravity:
            m.opt.gravity[:] = 0.0
        try:
            self.robot.set_command(eq.command)
            basis = self._basis(eq.qpos)
            r, _, jc_r = self._lagrangian_grad(eq.qpos, load, eq.lam, basis)
            kkt = self._kkt(eq.qpos, load, eq.lam, basis, r, jc_r)
        finally:
            m.opt.gravity[:] = saved
        nv = m.nv
        rhs = np.zeros((kkt.shape[0], dforce.shape[1]))
        rhs[:nv] = -dforce
        return np.linalg.solve(kkt, rhs)[:nv]
