"""Exact static equilibrium of the closed-loop robot: Newton on MuJoCo's force balance.

The one definition of an equilibrium in calbench (the simulator's and the estimator's).
It solves paper eq. (17) in its generalized form,

    r(q, lam) = g(q) + J_c(q)^T B lam = 0,   B^T c(q) = 0,
    g(q) = qfrc_spring(q) - qfrc_bias(q; qvel=0) + J_site(q)^T W,

where c is the loops' gap (bench/model/loop.py: site 1 minus site 2 of each) held as a HARD constraint: MuJoCo's
own equality constraints are soft and would open the loop by millimetres under load
(PHYSICS.md), so they are switched off (:func:`statics_options`) and the loop is closed here by a
KKT-Newton iteration. g includes the virtual joint springs (eq. 1), the compensator tendon
(eqs. 7-9), gravity of every body (links and mass compensators; the model's own
``<option gravity>``) and the external wrench W at a site. B is an orthonormal basis of the
loop's independent constraint directions (bench.loop.constraint_basis: the planar loop's third
row is identically zero and would make the KKT matrix singular), taken once per solve.

Building blocks, public so that every equilibrium in the project is this one:

* :meth:`StaticsSolver.residual`: r, the reduced gap B^T c and B^T J_c at (q, lam);
* :meth:`StaticsSolver.stiffness_fd` (A = dr/dq by forward differences: exact, gravity's and the
  load's geometric stiffness H00 of eq. 18 included) and
  :meth:`StaticsSolver.stiffness_inverse_dynamics` (MuJoCo's mjd_inverseFD, one C call, lacks the
  load's and the loop force's curvature); :func:`kkt_matrix` assembles [[A, J^T], [J, 0]];
* :meth:`StaticsSolver.newton`: chord Newton with a pluggable matrix provider (the bench's
  :meth:`StaticsSolver.solve` uses the two above; identify/core/forward.py supplies
  A = A_base + S(theta));
* :func:`ift_tangent`: d[q; lam]/dtheta by the implicit function theorem.

Newton's constants, one set for every caller (the bench's; identify/core/forward.py had drifted to
0.5 and 1e-13). Convergence: max|r| <= tol x max(1, max|qfrc_bias|) (the gravity scale at the
start; tol = 1e-10 by default: ~1e-5 N*m here, ~1e-11 rad, ~3e-11 m at a reflector, 1e-6 of the
tracker's sigma) and max|B^T c| <= LOOP_TOL = 1e-12 m, the same ~1e-12 rad times a metre-long
link: a tighter gap buys nothing the force criterion does not already limit. A chord matrix is
re-assembled when a step contracts the residual by less than CONTRACTION = 0.2: the bench's
remedy, the exact matrix, costs nv + 1 residuals and pays off once the chord gains less than
~0.35 per step (then the ~5 digits a solve needs take more chord steps than nv + 3), so it is
taken early, for quadratic convergence. Measured on this robot (paper
campaign, 600 random feasible equilibria, the estimator over +-40 % parameter moves): neither
constant ever fires, 0.2/0.5 and 1e-12/1e-13 give identical step counts. With springs 10 x
softer 0.2 takes 16 % fewer steps than 0.5 and leaves no solve unconverged (0.5: one).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import NamedTuple

import mujoco
import numpy as np

from calbench.bench.core import StaticsError
from calbench.bench.model import LOOP_TOL, Robot, constraint_basis, loop_gap

# The loop is closed by us; contacts and joint-range stops play no part in the statics (ranges
# are controller limits, checked on the command).
DISABLE_FLAGS = (
    int(mujoco.mjtDisableBit.mjDSBL_EQUALITY)
    | int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    | int(mujoco.mjtDisableBit.mjDSBL_LIMIT)
)
# MuJoCo's bound on a position (mjMAXVAL): past it, or at NaN, mj_forward warns "simulation is
# unstable", writes MUJOCO_LOG.TXT into the working folder and resets the data to qpos0; Newton
# stops before handing it such a point
MJ_MAXVAL = 1e10
CONTRACTION = 0.2  # a step gaining less than this factor re-assembles the chord matrix


@contextmanager
def statics_options(robot: Robot, gravity: bool = True) -> Iterator[None]:
    """The robot as the statics see it: DISABLE_FLAGS set, the joints at rest (qvel = 0) and,
    with ``gravity=False``, zero gravity; the options are restored on exit. Every building
    block below expects to run inside it."""
    model = robot.model
    robot.data.qvel[:] = 0.0
    flags = model.opt.disableflags
    saved = model.opt.gravity.copy()
    model.opt.disableflags = flags | DISABLE_FLAGS
    if not gravity:
        model.opt.gravity[:] = 0.0
    try:
        yield
    finally:
        model.opt.disableflags = flags
        model.opt.gravity[:] = saved


@dataclass(frozen=True)
class Equilibrium:
    """A solved static pose. Lengths in m, angles in rad, forces in N and N*m."""

    qpos: np.ndarray  # full MuJoCo qpos at equilibrium
    command: np.ndarray  # (n_act,) commanded controller angles
    deflection: np.ndarray  # (n_act,) actuated joint angle minus command (the VJM spring deflections)
    lam: np.ndarray  # loop constraint forces in the reduced constraint basis
    residual: float  # max |g + J_c^T lam| over all dofs, N*m
    gravity_scale: float  # max |gravity generalized force| over dofs at the solution, N*m
    loop_violation: float  # |c(q)|, m
    iterations: int  # Newton steps taken
    factor: np.ndarray | None = field(default=None, repr=False, compare=False)  # KKT inverse, warm starts
    stalls: int = 0  # times the cheap matrix stalled and the exact one was used
    basis: np.ndarray | None = field(default=None, repr=False, compare=False)  # the basis of lam

    @property
    def acceptable(self) -> bool:
        """Converged for a campaign's or a design's purposes (:func:`equilibrium_acceptable`)."""
        return bool(equilibrium_acceptable(self.residual, self.gravity_scale, self.loop_violation))


def equilibrium_acceptable(residual, gravity_scale, loop_violation):
    """The acceptance rule of an equilibrium, elementwise over arrays of solves: residual within
    1e-8 of the gravity scale and loop closed to 1 nm (100 x looser than the solver's own
    tolerance, so only a solve that failed trips it)."""
    return (np.asarray(residual) <= 1e-8 * np.maximum(gravity_scale, 1.0)) & (
        np.asarray(loop_violation) <= 1e-9
    )


@dataclass(frozen=True)
class Load:
    """An external wrench in the world frame applied at a site (force at the site, moment)."""

    force: np.ndarray
    moment: np.ndarray
    site: int

    @staticmethod
    def mass(robot: Robot, mass: float) -> Load:
        """A mass hanging at the payload site, its weight under the model's gravity."""
        return Load(robot.weight(mass), np.zeros(3), robot.payload_site)

    @staticmethod
    def wrench(robot: Robot, w: np.ndarray) -> Load:
        w = np.asarray(w, dtype=float)
        return Load(w[:3].copy(), w[3:].copy(), robot.payload_site)


class Residual(NamedTuple):
    r: np.ndarray  # (nv,) g + J_c^T B lam, N*m
    c_r: np.ndarray  # (nc,) B^T c, m
    jc_r: np.ndarray  # (nc, nv) B^T J_c


class NewtonPoint(NamedTuple):
    """What a matrix provider is handed: the iterate (data holds its forward pass)."""

    qpos: np.ndarray
    lam: np.ndarray
    residual: Residual
    iteration: int  # steps taken so far
    stalled: bool  # the last step contracted the residual by less than CONTRACTION


# (point) -> A = d r / d q (nv, nv) at point.qpos, or None to give up (the caller has a better plan)
StiffnessProvider = Callable[[NewtonPoint], "np.ndarray | None"]


class NewtonResult(NamedTuple):
    qpos: np.ndarray
    lam: np.ndarray
    jc_r: np.ndarray  # B^T J_c at qpos
    residual: float  # max |r|, N*m
    iterations: int  # steps taken
    converged: bool
    factor: np.ndarray | None  # the last KKT inverse
    stalls: int  # matrices assembled because the previous one stalled


def kkt_matrix(a: np.ndarray, jc_r: np.ndarray) -> np.ndarray:
    """[[A, J^T], [J, 0]] with A = d r / d q (nv, nv) and J = B^T J_c (nc, nv); leading
    dimensions (a stack of solves, bench/statics/batched.py) carry through."""
    nv, nc = a.shape[-1], jc_r.shape[-2]
    k = np.zeros(a.shape[:-2] + (nv + nc, nv + nc))
    k[..., :nv, :nv] = a
    k[..., :nv, nv:] = np.swapaxes(jc_r, -1, -2)
    k[..., nv:, :nv] = jc_r
    return k


def ift_tangent(kkt: np.ndarray, dforce: np.ndarray) -> np.ndarray:
    """d[q; lam]/dtheta (nv + nc, p) at an equilibrium by the implicit function theorem.

    dforce (nv, p): d g / d theta at fixed q (e.g. bench.robot.Robot.dforce_dtheta). The loop
    stays closed: [[A, J^T], [J, 0]] [dq; dlam] = [-dforce; 0]. Leading dimensions of both
    (a stack of equilibria) carry through."""
    nv = dforce.shape[-2]
    rhs = np.zeros(dforce.shape[:-2] + (kkt.shape[-1], dforce.shape[-1]))
    rhs[..., :nv, :] = -dforce
    return np.linalg.solve(kkt, rhs)


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
        self._jc = np.zeros((3 * len(robot.loops), m.nv))
        self._jb = np.zeros((3, m.nv))
        self._dfdq = np.zeros((m.nv, m.nv))

    # -- building blocks (inside statics_options) ----------------------------------------
    def forward(self, qpos: np.ndarray, velocity: bool = True) -> None:
        """Put qpos in data and run MuJoCo's position (and velocity: passive and bias forces)
        stage."""
        m, d = self.robot.model, self.robot.data
        d.qpos[:] = qpos
        mujoco.mj_fwdPosition(m, d)
        if velocity:
            mujoco.mj_fwdVelocity(m, d)

    def force(self, load: Load | None) -> np.ndarray:
        """g(q) at the pose in data: springs - gravity + load (generalized forces)."""
        m, d = self.robot.model, self.robot.data
        g = d.qfrc_passive - d.qfrc_bias
        if load is not None:
            mujoco.mj_jacSite(m, d, self._jp, self._jr, load.site)
            g = g + self._jp.T @ load.force + self._jr.T @ load.moment
        return g

    def basis(self, qpos: np.ndarray) -> np.ndarray:
        """Orthonormal basis B of the loops' independent constraint directions at qpos."""
        self.forward(qpos, velocity=False)
        return constraint_basis(loop_gap(self.robot, self.robot.data, self._jc, self._jb)[1])

    def residual(self, qpos: np.ndarray, load: Load | None, lam: np.ndarray, basis: np.ndarray) -> Residual:
        """r = g + J_c^T B lam, B^T c and B^T J_c at qpos (data left at qpos)."""
        self.forward(qpos)
        g = self.force(load)
        c, jc = loop_gap(self.robot, self.robot.data, self._jc, self._jb)
        jc_r = basis.T @ jc
        return Residual(g + jc_r.T @ lam, basis.T @ c, jc_r)

    def stiffness_fd(
        self, qpos, load, lam, basis, r0: np.ndarray | None = None, tap: Callable[[int], None] | None = None
    ) -> np.ndarray:
        """A = d r / d q (nv, nv) by forward differences (step fd_step): the exact matrix.

        r0: r at qpos if already known. tap(j), if given, runs after column j's forward pass
        (data at qpos + fd_step e_j), to difference another quantity at the same points."""
        nv = self.robot.model.nv
        if r0 is None:
            r0 = self.residual(qpos, load, lam, basis).r
        a = np.empty((nv, nv))
        for j in range(nv):
            qp = qpos.copy()
            qp[j] += self.fd_step
            a[:, j] = (self.residual(qp, load, lam, basis).r - r0) / self.fd_step
            if tap is not None:
                tap(j)
        return a

    def stiffness_inverse_dynamics(self, qpos: np.ndarray) -> np.ndarray:
        """A from MuJoCo's own finite-differenced inverse dynamics (one C call):
        d(bias - passive)/dq holds every spring, the tendon and gravity's geometric stiffness;
        it lacks only the load's and the loop force's curvature (~1e-3 of it here,
        tests/test_statics.py), which a chord iteration absorbs."""
        m, d = self.robot.model, self.robot.data
        d.qpos[:] = qpos
        d.qvel[:] = 0.0
        d.qacc[:] = 0.0
        mujoco.mjd_inverseFD(m, d, self.fd_step, 0, self._dfdq, None, None, None, None, None, None)
        return -self._dfdq.T

    def newton(
        self,
        qpos: np.ndarray,
        lam: np.ndarray,
        basis: np.ndarray,
        load: Load | None,
        stiffness: StiffnessProvider,
        *,
        factor: np.ndarray | None = None,
        refresh: int = 1,
        max_iter: int | None = None,
    ) -> NewtonResult:
        """Chord Newton on the KKT system from (qpos, lam) (module docstring: tolerances).

        The matrix comes from ``stiffness``: on each of the first ``refresh`` iterations (a
        given ``factor``, a KKT inverse kept from an earlier solve, counts as all of them) and
        whenever a step stalled; otherwise the last one is reused. The provider returning None
        ends the iteration unconverged. Raises StaticsError when the iterate is not finite or
        the KKT matrix is singular. At most max_iter (default self.max_iter) steps."""
        max_iter = self.max_iter if max_iter is None else max_iter
        nv = self.robot.model.nv
        d = self.robot.data
        fresh = 0 if factor is None else refresh
        stalls = 0
        prev = np.inf
        it = 0
        res = self.residual(qpos, load, lam, basis)
        # the gravity scale at the start: it moves by ~1e-3 over a solve
        force_tol = self.tol * max(1.0, float(np.abs(d.qfrc_bias).max()))
        while True:
            res_norm = float(np.abs(res.r).max())
            if res_norm <= force_tol and float(np.abs(res.c_r).max(initial=0.0)) <= LOOP_TOL:
                return NewtonResult(qpos, lam, res.jc_r, res_norm, it, True, factor, stalls)
            if not math.isfinite(res_norm):
                raise StaticsError(f"statics diverged at command {self._command_deg()} deg")
            if it == max_iter:
                break
            stalled = res_norm > CONTRACTION * prev
            if stalled or fresh < refresh:
                a = stiffness(NewtonPoint(qpos, lam, res, it, stalled))
                if a is None:
                    break
                stalls += stalled
                fresh += not stalled
                try:
                    factor = np.linalg.inv(kkt_matrix(a, res.jc_r))
                except np.linalg.LinAlgError:
                    raise StaticsError(
                        f"singular stiffness (KKT) matrix at command {self._command_deg()} deg: "
                        "a degenerate configuration (is a kinematic loop degenerate?)"
                    ) from None
            prev = res_norm
            # the inverse of a 10x10 KKT matrix (condition ~1e7) is accurate to ~1e-9 relative:
            # ample for Newton steps, whose errors the next residual corrects
            step = -(factor @ np.concatenate([res.r, res.c_r]))
            qpos = qpos + step[:nv]
            lam = lam + step[nv:]
            it += 1
            if not np.all(np.abs(qpos) < MJ_MAXVAL):  # NaN too: MuJoCo would warn and reset
                raise StaticsError(f"statics diverged at command {self._command_deg()} deg")
            res = self.residual(qpos, load, lam, basis)
        return NewtonResult(qpos, lam, res.jc_r, res_norm, it, False, factor, stalls)

    def _command_deg(self) -> list:
        rb = self.robot
        return np.degrees(rb.model.qpos_spring[rb.act_qpos]).round(3).tolist()

    # -- whole solves ----------------------------------------------------------------------
    def solve(
        self,
        q: np.ndarray,
        load: Load | None = None,
        qpos0: np.ndarray | None = None,
        gravity: bool = True,
        warm: Equilibrium | None = None,
    ) -> Equilibrium:
        """Static equilibrium at command q (rad) under gravity and an optional load.

        Newton with MuJoCo's inverse-dynamics derivative as the matrix (one C call), refreshed
        on the first two iterations and then reused: it lacks only the load's and the loop
        force's curvature (~1e-3 of the stiffness here), so the steps still gain ~3 digits
        each. Should it stall, the exact finite-difference matrix takes over.
        qpos0 starts the iteration elsewhere than the rigid pose; `warm` (an equilibrium of the
        same command, e.g. the unloaded one) starts at its qpos AND reuses its factorised KKT
        matrix and constraint basis; the matrix differs from the new one only by the load's
        curvature."""
        robot = self.robot
        q = np.asarray(q, dtype=float)
        robot.set_command(q)
        if warm is not None:
            qpos0 = warm.qpos
        qpos = robot.rigid_qpos(q) if qpos0 is None else np.array(qpos0, dtype=float)

        with statics_options(robot, gravity):
            # a warm factor belongs to the warm solve's constraint basis: keep both
            basis = warm.basis if warm is not None and warm.basis is not None else self.basis(qpos)

            def stiffness(p: NewtonPoint) -> np.ndarray:
                if p.stalled:
                    return self.stiffness_fd(p.qpos, load, p.lam, basis, p.residual.r)
                return self.stiffness_inverse_dynamics(p.qpos)

            sol = self.newton(
                qpos,
                np.zeros(basis.shape[1]),
                basis,
                load,
                stiffness,
                factor=None if warm is None else warm.factor,
                refresh=2,
            )
            self.forward(sol.qpos)
            c, _ = loop_gap(robot, robot.data)
            grav = float(np.abs(robot.data.qfrc_bias).max())
        return Equilibrium(
            qpos=sol.qpos.copy(),
            command=q.copy(),
            deflection=sol.qpos[robot.act_qpos] - q,
            lam=sol.lam,
            residual=sol.residual,
            gravity_scale=grav,
            loop_violation=float(np.linalg.norm(c)),
            iterations=sol.iterations,
            factor=sol.factor,
            stalls=sol.stalls,
            basis=basis,
        )

    def tangent(
        self, eq: Equilibrium, load: Load | None, dforce: np.ndarray, gravity: bool = True
    ) -> np.ndarray:
        """dq/dtheta (nv, p) at an equilibrium (:func:`ift_tangent` with the exact matrix).

        dforce (nv, p): d g / d theta at fixed q. The robot's parameters must be those of `eq`.
        """
        robot = self.robot
        with statics_options(robot, gravity):
            robot.set_command(eq.command)
            basis = self.basis(eq.qpos) if eq.basis is None else eq.basis
            res = self.residual(eq.qpos, load, eq.lam, basis)
            a = self.stiffness_fd(eq.qpos, load, eq.lam, basis, res.r)
        return ift_tangent(kkt_matrix(a, res.jc_r), dforce)[: robot.model.nv]


__all__ = [
    "DISABLE_FLAGS",
    "LOOP_TOL",
    "CONTRACTION",
    "MJ_MAXVAL",
    "StaticsError",
    "statics_options",
    "Equilibrium",
    "equilibrium_acceptable",
    "Load",
    "Residual",
    "NewtonPoint",
    "NewtonResult",
    "StiffnessProvider",
    "kkt_matrix",
    "ift_tangent",
    "StaticsSolver",
]
