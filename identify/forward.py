"""The exact forward model dp(theta) of a campaign and its Jacobian (implicit function theorem).

theta = [k1..k6, K_C, s0] in SI: actuator compliances (rad/(N*m), paper eq. 1), compensator
stiffness (N/m) and preload length (m, eq. 8). For each pose the unloaded and loaded static
equilibria are solved on the robot's MJCF with theta written into it (``Robot.set_params``: the
MJCF's own stiffness values are overwritten, never read), and

    dp_jr(theta) = x_r(q_loaded(theta)) - x_r(q_unloaded(theta))

This is paper eq. (17) solved exactly (gravity of all links and mass compensators, the load's
and gravity's geometric stiffness H00 of eq. 18, the compensator's eqs. 7-9 as a MuJoCo tendon,
the parallelogram closed as a hard constraint) instead of its linearisation eqs. (19)-(22).

Precision. Equilibria are solved to a force residual of tol x max|gravity force| (tol = 1e-10,
~1e-5 N*m here: ~1e-11 rad, ~3e-11 m at a reflector, about 1e-6 of the tracker's sigma; the
bench's StaticsSolver uses 1e-12, which costs one more Newton step per equilibrium and buys
nothing at 20 um).

Speed. The first evaluation solves every equilibrium with :class:`bench.statics.StaticsSolver`
from the rigid configuration. Later evaluations warm-start from the last solution, moved by the
first-order prediction tangent x (theta - theta_cached) when a Jacobian was computed, and use a
KKT matrix split as A = A_base + S(theta): S holds the springs, known analytically
(-1/k_i on motor i; -K_C (t t^T + (L - s0) H_L) for the tendon with t = dL/dq and H_L its
Hessian), A_base everything else (gravity's and the load's geometric stiffness, the loop's
constraint curvature), taken once by finite differences and reused. Convergence is judged on the
exact residual (StaticsSolver's criterion), so the reuse only affects the convergence
rate, never the solution. The Jacobian dq/dtheta = -KKT^-1 [dg/dtheta; 0] (as in
``StaticsSolver.tangent``) uses the same KKT matrix at the solution; A_base's staleness is of the
order of the configuration change since it was taken (<1e-4 rad) times gravity's share of the
stiffness (~1e-2), i.e. a relative Jacobian error far below 1e-5 (checked against finite
differences in tests/test_identify_forward.py).
"""
from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from calbench.bench.loop import constraint_basis
from calbench.bench.robot import Params, Robot
from calbench.bench.statics import Load, StaticsSolver

from .observations import Observations

PARAM_NAMES = ("k1", "k2", "k3", "k4", "k5", "k6", "compensator_stiffness", "compensator_preload")
PARAM_UNITS = ("rad/(N*m)",) * 6 + ("N/m", "m")
NP = len(PARAM_NAMES)
_DISABLE = int(mujoco.mjtDisableBit.mjDSBL_EQUALITY) | int(mujoco.mjtDisableBit.mjDSBL_CONTACT)


def to_params(theta: np.ndarray) -> Params:
    theta = np.asarray(theta, dtype=float)
    return Params(theta[:6].copy(), float(theta[6]), float(theta[7]))


@dataclass(frozen=True)
class PoseDesign:
    """The known inputs of one pose as model indices: command, load, reflector sites."""

    index: int
    q: np.ndarray
    load: Load
    sites: np.ndarray          # reflector site ids, rows of this pose's dp


def design_from_observations(robot: Robot, obs: Observations) -> list[PoseDesign]:
    """Resolve the observations' site names on ``robot`` (ValueError naming a missing one)."""
    m = robot.model
    out = []

    def site(name: str) -> int:
        i = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, name)
        if i < 0:
            raise ValueError(f"the robot model has no site named {name!r}")
        return i

    for p in obs.poses:
        load = Load(np.asarray(p.force, float), np.asarray(p.moment, float), site(p.site))
        out.append(PoseDesign(p.index, np.asarray(p.q, float), load,
                              np.array([site(r) for r in p.reflectors], dtype=int)))
    return out


class _Eq:
    """Cache of one (pose, state) equilibrium: warm start and the reusable KKT pieces."""

    __slots__ = ("qpos", "lam", "basis", "a_base", "h_len", "theta", "tangent")

    def __init__(self, qpos, lam, basis, a_base, h_len):
        self.qpos, self.lam, self.basis, self.a_base, self.h_len = qpos, lam, basis, a_base, h_len
        self.theta = None      # parameters of the cached solution
        self.tangent = None    # d[qpos; lam]/d theta there (when a Jacobian was computed)


class ForwardModel:
    """dp(theta) and d dp/d theta for a fixed campaign design on one robot model.

    Not thread-safe (owns the robot's MjData). ``evaluate`` returns (dp (M,3), jac (M,3,8) or
    None) with rows in design order (poses, then their reflectors).
    """

    def __init__(self, robot: Robot, design: list[PoseDesign], tol: float = 1e-10,
                 max_iter: int = 12, fd_step: float = 1e-7):
        self.robot = robot
        self.design = design
        self.tol = tol
        self.max_iter = max_iter
        self.fd_step = fd_step
        m = robot.model
        nv = m.nv
        self.nv = nv
        self._jp = np.zeros((3, nv))
        self._jr = np.zeros((3, nv))
        self._ja = np.zeros((3, nv))
        self._jb = np.zeros((3, nv))
        self._js = np.zeros((3, nv))
        self._cache: list[tuple[_Eq, _Eq]] | None = None
        self.n_obs = int(sum(len(d.sites) for d in design))
        self.act_dof = robot.act_dof
        self.stats = {"evaluations": 0, "newton_iterations": 0, "refreshes": 0, "fallbacks": 0}
        self._p_kkt: np.ndarray | None = None     # parameters beyond the eight A_base was taken at

    n_params = NP   # a subclass appending parameters (identify/discover_fit.py) overrides it

    def write(self, theta: np.ndarray) -> None:
        """Put theta into the robot model (a subclass writes its extra parameters too)."""
        self.robot.set_params(to_params(theta[:NP]))

    # -- MuJoCo pieces ---------------------------------------------------------------------------
    def _forward(self, qpos: np.ndarray, velocity: bool = True) -> None:
        m, d = self.robot.model, self.robot.data
        d.qpos[:] = qpos
        mujoco.mj_fwdPosition(m, d)
        if velocity:
            mujoco.mj_fwdVelocity(m, d)

    def _tendon_moment(self) -> np.ndarray:
        """(nv,) dense dL/dq of the compensator tendon (MuJoCo stores ten_J sparsely)."""
        return self.robot.tendon_moment()

    def _basis(self, qpos) -> np.ndarray:
        """Orthonormal basis of the loop's independent constraint rows (as bench/statics.py)."""
        self._forward(qpos, velocity=False)
        a, b = self.robot.loop_sites
        m, d = self.robot.model, self.robot.data
        mujoco.mj_jacSite(m, d, self._ja, None, a)
        mujoco.mj_jacSite(m, d, self._jb, None, b)
        return constraint_basis(self._ja - self._jb)

    def _adopt(self, qpos, load, theta) -> _Eq:
        """A cache entry at an equilibrium qpos: basis, multipliers by least squares, KKT parts."""
        basis = self._basis(qpos)
        r, _, jc_r = self._residual(qpos, load, np.zeros(basis.shape[1]), basis)
        lam = -np.linalg.lstsq(jc_r.T, r, rcond=None)[0]
        a_base, h = self._kkt_fd(qpos, load, lam, basis, theta)
        return _Eq(qpos.copy(), lam, basis, a_base, h)

    def _residual(self, qpos, load: Load | None, lam, basis):
        """r = g + J_c^T lam (nv), c_r (nc), J_c reduced (nc, nv); g as in bench/statics.py."""
        m, d = self.robot.model, self.robot.data
        self._forward(qpos)
        g = d.qfrc_passive - d.qfrc_bias
        if load is not None:
            mujoco.mj_jacSite(m, d, self._jp, self._jr, load.site)
            g = g + self._jp.T @ load.force + self._jr.T @ load.moment
        a, b = self.robot.loop_sites
        mujoco.mj_jacSite(m, d, self._ja, None, a)
        mujoco.mj_jacSite(m, d, self._jb, None, b)
        jc_r = basis.T @ (self._ja - self._jb)
        c_r = basis.T @ (d.site_xpos[a] - d.site_xpos[b])
        return g + jc_r.T @ lam, c_r, jc_r

    def _spring_part(self, theta, qpos_t: np.ndarray, h_len) -> np.ndarray:
        """S(theta): the springs' part of d(g)/dq at the pose held in data (t, L current)."""
        nv = self.nv
        s = np.zeros((nv, nv))
        s[self.act_dof, self.act_dof] = -1.0 / theta[:6]
        if self.robot.tendon >= 0:
            t = qpos_t
            length = float(self.robot.data.ten_length[self.robot.tendon])
            s -= theta[6] * (np.outer(t, t) + (length - theta[7]) * h_len)
        return s

    def _kkt_fd(self, qpos, load, lam, basis, theta) -> tuple[np.ndarray, np.ndarray]:
        """A_base = A_fd - S(theta) and the tendon length Hessian H_L, by forward differences."""
        nv = self.nv
        r, _, _ = self._residual(qpos, load, lam, basis)
        t0 = self._tendon_moment()
        a = np.empty((nv, nv))
        h = np.empty((nv, nv))
        for j in range(nv):
            qp = qpos.copy()
            qp[j] += self.fd_step
            rj, _, _ = self._residual(qp, load, lam, basis)
            a[:, j] = (rj - r) / self.fd_step
            h[:, j] = (self._tendon_moment() - t0) / self.fd_step
        h = 0.5 * (h + h.T)
        self._residual(qpos, load, lam, basis)  # data back at qpos for S
        return a - self._spring_part(theta, t0, h), h

    def _kkt(self, eq: _Eq, theta, jc_r) -> np.ndarray:
        nv = self.nv
        nc = jc_r.shape[0]
        k = np.zeros((nv + nc, nv + nc))
        k[:nv, :nv] = eq.a_base + self._spring_part(theta, self._tendon_moment(), eq.h_len)
        k[:nv, nv:] = jc_r.T
        k[nv:, :nv] = jc_r
        return k

    def _dforce(self, theta, qpos, command) -> np.ndarray:
        """d g / d theta at fixed q (nv, 8), for the pose held in data."""
        g = np.zeros((self.nv, NP))
        dq = qpos[self.robot.act_qpos] - command
        g[self.act_dof, np.arange(6)] = dq / theta[:6] ** 2
        if self.robot.tendon >= 0:
            t = self._tendon_moment()
            length = float(self.robot.data.ten_length[self.robot.tendon])
            g[:, 6] = -(length - theta[7]) * t
            g[:, 7] = theta[6] * t
        return g

    # -- equilibria -----------------------------------------------------------------------------
    def _init_cache(self, theta) -> None:
        """Cold solves by the bench's solver from the rigid configuration, then adopted."""
        solver = StaticsSolver(self.robot)
        cache = []
        for d in self.design:
            e0 = solver.solve(d.q)
            e1 = solver.solve(d.q, d.load, qpos0=e0.qpos)
            self.robot.set_command(d.q)
            self._enable()
            cache.append((self._adopt(e0.qpos, None, theta), self._adopt(e1.qpos, d.load, theta)))
        self._cache = cache

    def _enable(self) -> None:
        self.robot.model.opt.disableflags |= _DISABLE

    def _newton(self, eq: _Eq, command, load, theta, scale_floor: float = 1.0):
        """Chord Newton from the cached equilibrium; returns (qpos, lam, jc_r) or None."""
        qpos, lam = eq.qpos.copy(), eq.lam.copy()
        nv = self.nv
        if eq.tangent is not None and eq.theta is not None:
            # first-order prediction of the new equilibrium from the cached tangent
            step = eq.tangent @ (theta - eq.theta)
            qpos += step[:nv]
            lam += step[nv:]
        kkt = None
        prev = np.inf
        for it in range(self.max_iter):
            r, c_r, jc_r = self._residual(qpos, load, lam, eq.basis)
            scale = max(scale_floor, float(np.abs(self.robot.data.qfrc_bias).max()))
            res = float(np.abs(r).max())
            if res <= self.tol * scale and float(np.abs(c_r).max()) <= 1e-13:
                self.stats["newton_iterations"] += it
                return qpos, lam, jc_r
            if not np.isfinite(res) or (it > 0 and res > 0.5 * prev):
                if it > 2:
                    return None
                kkt = None  # poor contraction: re-assemble at the current point
            prev = res
            if kkt is None:
                kkt = np.linalg.inv(self._kkt(eq, theta, jc_r))
            step = -kkt @ np.concatenate([r, c_r])
            qpos = qpos + step[:nv]
            lam = lam + step[nv:]
        return None

    def evaluate(self, theta, jacobian: bool = True):
        """dp (M,3) and, with ``jacobian``, d dp / d theta (M,3,P): P = n_params, the eight
        parameters plus any a subclass appends (discovery's effects). Parameters beyond the
        eight enter the stiffness matrix A_base, so it is re-taken when they change."""
        theta = np.asarray(theta, dtype=float)
        npar = self.n_params
        if theta.shape != (npar,) or not np.all(np.isfinite(theta)) or np.any(theta[:6] <= 0):
            raise ValueError(f"theta must be {npar} finite values with positive compliances, got {theta}")
        robot = self.robot
        m, d = robot.model, robot.data
        self.write(theta)                             # ValueError for invalid effect values
        self.stats["evaluations"] += 1
        dp = np.empty((self.n_obs, 3))
        jac = np.empty((self.n_obs, 3, npar)) if jacobian else None
        flags = m.opt.disableflags
        d.qvel[:] = 0.0
        try:
            if self._cache is None:
                self._init_cache(theta)
                self._p_kkt = theta[NP:].copy()
            self._enable()
            refresh = self._p_kkt is None or not np.array_equal(self._p_kkt, theta[NP:])
            row = 0
            for des, pair in zip(self.design, self._cache):
                robot.set_command(des.q)
                n = len(des.sites)
                pos, jsite = [], []
                for load, eq in zip((None, des.load), pair):
                    if refresh:   # the effects' springs live in A_base: re-take it
                        eq.a_base, eq.h_len = self._kkt_fd(eq.qpos, load, eq.lam, eq.basis, theta)
                    sol = self._newton(eq, des.q, load, theta)
                    if sol is None:
                        self.stats["refreshes"] += 1
                        eq.tangent = None
                        eq.a_base, eq.h_len = self._kkt_fd(eq.qpos, load, eq.lam, eq.basis, theta)
                        sol = self._newton(eq, des.q, load, theta)
                    if sol is None:
                        self.stats["fallbacks"] += 1
                        m.opt.disableflags = flags
                        e = StaticsSolver(robot).solve(des.q, load, qpos0=eq.qpos)
                        self._enable()
                        robot.set_command(des.q)
                        new = self._adopt(e.qpos, load, theta)
                        eq.qpos, eq.lam, eq.basis, eq.a_base, eq.h_len = (
                            new.qpos, new.lam, new.basis, new.a_base, new.h_len)
                        eq.tangent = None
                        sol = self._newton(eq, des.q, load, theta)
                        if sol is None:
                            raise RuntimeError(f"pose {des.index}: no static equilibrium at theta={theta}")
                    qpos, lam, jc_r = sol
                    eq.qpos, eq.lam, eq.theta, eq.tangent = qpos, lam, theta.copy(), None
                    pos.append(d.site_xpos[des.sites].copy())
                    if jacobian:
                        kkt = self._kkt(eq, theta, jc_r)
                        rhs = np.zeros((kkt.shape[0], npar))
                        rhs[: self.nv] = -self._dforce(theta, qpos, des.q)
                        tan = np.linalg.solve(kkt, rhs)
                        eq.tangent = tan
                        dq = tan[: self.nv]
                        js = np.empty((n, 3, npar))
                        for i, s in enumerate(des.sites):
                            mujoco.mj_jacSite(m, d, self._js, None, int(s))
                            js[i] = self._js @ dq
                        jsite.append(js)
                dp[row: row + n] = pos[1] - pos[0]
                if jacobian:
                    jac[row: row + n] = jsite[1] - jsite[0]
                row += n
            self._p_kkt = theta[NP:].copy()
        finally:
            m.opt.disableflags = flags
        return dp, jac


__all__ = ["PARAM_NAMES", "PARAM_UNITS", "NP", "PoseDesign", "ForwardModel",
           "design_from_observations", "to_params"]
