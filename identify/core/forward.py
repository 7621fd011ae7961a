"""The exact forward model dp(theta) of a campaign and its Jacobian (implicit function theorem).

theta = [k1..kN, then K_C, s0 per compensator] in SI (the robot's ``layout``, bench/model/params.py):
actuator compliances (rad/(N*m), paper eq. 1), compensator stiffness (N/m) and preload length
(m, eq. 8). For each pose the unloaded and loaded static
equilibria are solved on the robot's MJCF with theta written into it (``Robot.set_params``: the
MJCF's own stiffness values are overwritten, never read), and

    dp_jr(theta) = x_r(q_loaded(theta)) - x_r(q_unloaded(theta))

This is paper eq. (17) solved exactly (gravity of all links and mass compensators, the load's
and gravity's geometric stiffness H00 of eq. 18, the compensators' eqs. 7-9 as MuJoCo tendons,
the loops closed as hard constraints) instead of its linearisation eqs. (19)-(22).

The equilibrium itself is bench/statics/equilibrium.py's, the one definition (residual, Newton, its
tolerances, the implicit-function tangent); d g / d theta is ``Robot.dforce_dtheta``. This module
keeps only what is the estimator's own: a cache per (pose, state), warm starts, the stiffness
matrix it hands to the statics' Newton, and the evaluation loop.

Precision. Equilibria are solved to bench.statics' criterion: a force residual of tol x
max|gravity force| (tol = 1e-10, ~1e-5 N*m here: ~1e-11 rad, ~3e-11 m at a reflector, about 1e-6
of the tracker's sigma) and a loop gap of 1e-12 m.

Speed. The first evaluation solves every equilibrium with :meth:`StaticsSolver.solve` from the
rigid configuration. Later evaluations warm-start from the last solution, moved by the
first-order prediction tangent x (theta - theta_cached) when a Jacobian was computed, and run
:meth:`StaticsSolver.newton` with a KKT matrix split as A = A_base + S(theta): S holds the
springs, known analytically (-1/k_i on motor i; -K_C (t t^T + (L - s0) H_L) for each tendon
with t = dL/dq and H_L its Hessian), A_base everything else (gravity's and the load's geometric
stiffness, the loop's constraint curvature), taken once by finite differences and reused.
Convergence is judged on the exact residual, so the reuse only affects the convergence rate,
never the solution. These warm evaluations run for all (pose, state) equilibria at once on
bench/statics/batched.py (the same Newton, stacked; a row it cannot converge goes through the
scalar fallbacks; the re-takes below stacked too), unless the model holds more than
Robot.set_params writes and the batch's copy of the model would not see it (a subclass that
syncs what it writes and stacks its own springs and force columns runs stacked too: discovery's
effects, identify/discover/fit.py). The Jacobian dq/dtheta (``bench.statics.ift_tangent``)
uses the same KKT matrix at the solution, so A_base must be taken near it: where the solution
has moved more than KKT_QTOL from where A_base was taken, A_base (and H_L) is re-taken at the
solution before the tangent (about two evaluations' time).
Without that, a fit that wandered far (a far-off start) left A_base taken there, and later
Jacobians were wrong: on a designed 7-pose KR 270 plan, 170 % in the balancer's columns after
the noise-free fit's excursion, so every Monte Carlo run converged to a point ~1 sigma from the
maximum-likelihood estimate (Gauss-Newton's fixed point with a wrong Jacobian) and the preload's
spread came out 1.75x its reported std. The relative Jacobian error is ~1.1 x the configuration
change in rad (measured on that plan's balancer columns, the worst), so KKT_QTOL = 1e-3 rad
keeps it near 1e-3 (checked against finite differences in tests/test_identify_forward.py): over
60 Monte Carlo runs of that plan and of the paper's, estimates within 5e-4 sd and stds within
3e-4 of re-taking A_base at every solution (1e-2 rad: 4e-3 sd), below the Monte Carlo's own
stopping tolerance of 1e-2 sd.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from calbench.bench.core import CalbenchError
from calbench.bench.model import MAX_COMPLIANCE, Robot
from calbench.bench.statics import (
    BatchStatics,
    Load,
    NewtonPoint,
    NewtonResult,
    StaticsError,
    StaticsSolver,
    ift_tangent,
    kkt_matrix,
    statics_options,
    take_load,
)

from .observations import Observations

KKT_QTOL = 1e-3  # rad: A_base is re-taken at a solution that moved more than this from where it was taken


class NoEquilibrium(CalbenchError, RuntimeError):
    """A pose of the fit has no static equilibrium at the parameters tried: the pose, its command
    and the likely cause in one line (exit status 2). Also a RuntimeError, so an estimator's
    trial step that meets it is rejected as before; at the fit's start it reaches the user."""

    FAR = MAX_COMPLIANCE  # rad/(N*m): beyond any joint, the fit's bound (bench/scenario/plausible.py)

    def __init__(self, robot: Robot, des: PoseDesign, theta):
        theta = np.asarray(theta, float)
        n = robot.n_act
        names = robot.layout.names
        soft = [f"{names[i]} = {theta[i] * 1e6:.3g} urad/(N*m)" for i in range(n) if theta[i] > self.FAR]
        if soft:
            cause = (
                f"the fit reached compliances no robot has ({', '.join(soft)}): the measured deflections "
                "are far larger than the loads can make; likely a unit slip in what was measured or "
                "typed (readings, reflector positions, the payload, a tracker sigma in m for um) or "
                "readings of another robot"
            )
        else:
            cause = (
                "the command may be near a singular configuration, or the compensator spring "
                "(stiffness, preload) cannot hold the arm at these parameters"
            )
        values = ", ".join(f"{k} = {v:.3g}" for k, v in zip(names, theta))
        q = [round(float(np.degrees(x)), 2) for x in des.q]
        super().__init__(f"pose {des.index} (q = {q} deg): no static equilibrium at {values}: {cause}")
        self.pose = des.index


@dataclass(frozen=True)
class PoseDesign:
    """The known inputs of one pose as model indices: command, load, reflector sites."""

    index: int
    q: np.ndarray
    load: Load
    sites: np.ndarray  # reflector site ids, rows of this pose's dp


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
        out.append(
            PoseDesign(
                p.index, np.asarray(p.q, float), load, np.array([site(r) for r in p.reflectors], dtype=int)
            )
        )
    return out


class _Eq:
    """Cache of one (pose, state) equilibrium: warm start and the reusable KKT pieces
    (h_len: the compensator tendons' length Hessians, (C, nv, nv))."""

    __slots__ = ("qpos", "lam", "basis", "a_base", "h_len", "theta", "tangent", "q_kkt")

    def __init__(self, qpos, lam, basis, a_base, h_len):
        self.qpos, self.lam, self.basis, self.a_base, self.h_len = qpos, lam, basis, a_base, h_len
        self.q_kkt = np.array(qpos, dtype=float)  # where a_base and h_len were taken
        self.theta = None  # parameters of the cached solution
        self.tangent = None  # d[qpos; lam]/d theta there (when a Jacobian was computed)


class ForwardModel:
    """dp(theta) and d dp/d theta for a fixed campaign design on one robot model.

    Not thread-safe (owns the robot's MjData). ``evaluate`` returns (dp (M,3), jac (M,3,P) or
    None) with rows in design order (poses, then their reflectors); theta's first
    ``n_base`` entries are the robot's layout (bench/model/params.py). It leaves the unloaded
    reflectors' world positions and their Jacobian, same rows, in ``unloaded`` (the tracker's
    registration, identify/shopfloor/tracker_pose.py, fits them).
    """

    BATCHED = True  # default of ``batched`` (benchmarks switch it to time the scalar loop)

    def __init__(
        self,
        robot: Robot,
        design: list[PoseDesign],
        tol: float = 1e-10,
        max_iter: int = 12,
        fd_step: float = 1e-7,
        batched: bool | None = None,
    ):
        self.robot = robot
        # warm evaluations of every equilibrium at once (_evaluate_stacked)
        self.batched = self.BATCHED if batched is None else batched
        self._batch: BatchStatics | None = None
        self.design = design
        self.max_iter = max_iter  # warm-started Newton steps before A_base is re-taken
        self.statics = StaticsSolver(robot, tol=tol, fd_step=fd_step)
        self.nv = robot.model.nv
        self._js = np.zeros((3, self.nv))
        self._cache: list[tuple[_Eq, _Eq]] | None = None
        self.n_obs = int(sum(len(d.sites) for d in design))
        self.act_dof = robot.act_dof
        self.stats = {
            "evaluations": 0,
            "newton_iterations": 0,
            "refreshes": 0,
            "fallbacks": 0,
            "retakes": 0,
            "cold_retries": 0,
        }
        self.layout = robot.layout
        self.n_base = self.layout.n
        # a subclass appending parameters (identify/discover/fit.py) sets a larger n_params
        self.n_params = self.n_base
        self._kc = self.layout.stiffness_index
        self._s0 = self.layout.preload_index
        self._p_kkt: np.ndarray | None = None  # parameters beyond the base A_base was taken at
        self._params = None  # the base parameters last written (Params)
        self.unloaded: tuple[np.ndarray, np.ndarray | None] | None = None  # x0 (M,3), d x0/d theta

    # Newton iterations after which a stalling chord step gives up (A_base is then re-taken);
    # a subclass whose stiffness matrix is exact but for A_base may allow more
    stall_limit = 2

    def write(self, theta: np.ndarray) -> None:
        """Put theta into the robot model (a subclass writes its extra parameters too)."""
        self._params = self.layout.params(theta[: self.n_base])
        self.robot.set_params(self._params)

    def _dforce(self, theta: np.ndarray) -> np.ndarray:
        """d g / d theta at fixed q (nv, n_params) for the equilibrium held in data and the
        parameters last written (theta)."""
        return self.robot.dforce_dtheta(self._params)

    # -- the stiffness matrix A = A_base + S(theta) ---------------------------------------------
    def _moments(self) -> np.ndarray:
        """(C, nv) the compensator tendons' moments dL/dq at the pose held in data."""
        rb = self.robot
        return np.array([rb.tendon_moment(None, c) for c in range(len(rb.tendons))]).reshape(-1, self.nv)

    def _spring_part(self, theta, t: np.ndarray, h_len) -> np.ndarray:
        """S(theta): the springs' part of d(g)/dq at the pose held in data (t (C, nv) = dL/dq
        there, h_len (C, nv, nv) the tendons' length Hessians)."""
        length = self.robot.data.ten_length[self.robot.tendons]
        return self._springs(theta, t[None], length[None], h_len[None])[0]

    def _springs(self, theta, t: np.ndarray, length: np.ndarray, h_len: np.ndarray) -> np.ndarray:
        """S(theta) of n poses (n, nv, nv) from their tendon moments t (n, C, nv), lengths (n, C)
        and length Hessians (n, C, nv, nv): -1/k_i on motor i, -K_C (t t^T + (L - s0) H_L) per
        compensator."""
        s = np.zeros((len(t), self.nv, self.nv))
        for c in range(len(self.robot.tendons)):
            kc, s0 = theta[self._kc[c]], theta[self._s0[c]]
            s -= kc * (t[:, c, :, None] * t[:, c, None, :] + (length[:, c] - s0)[:, None, None] * h_len[:, c])
        s[:, self.act_dof, self.act_dof] -= 1.0 / theta[: self.layout.n_joints]
        return s

    def _stiffness(self, eq: _Eq, theta) -> np.ndarray:
        """A = A_base + S(theta) at the pose held in data."""
        return eq.a_base + self._spring_part(theta, self._moments(), eq.h_len)

    def _kkt_fd(self, qpos, load, lam, basis, theta) -> tuple[np.ndarray, np.ndarray]:
        """A_base = A_fd - S(theta) and the tendons' length Hessians H_L, by forward differences
        (the statics' exact matrix, the tendon moments differenced at the same points)."""
        st, nv = self.statics, self.nv
        r = st.residual(qpos, load, lam, basis).r
        t0 = self._moments()
        h = np.empty((len(t0), nv, nv))

        def tap(j: int) -> None:
            h[:, :, j] = (self._moments() - t0) / st.fd_step

        a = st.stiffness_fd(qpos, load, lam, basis, r, tap=tap)
        h = 0.5 * (h + h.transpose(0, 2, 1))
        st.forward(qpos, velocity=False)  # data back at qpos for S
        return a - self._spring_part(theta, t0, h), h

    def _retake(self, eq: _Eq, qpos, load, lam, basis, theta) -> None:
        """A_base and H_L of ``eq`` taken afresh at ``qpos`` (data left there, command set)."""
        eq.a_base, eq.h_len = self._kkt_fd(qpos, load, lam, basis, theta)
        eq.q_kkt = np.array(qpos, dtype=float)

    def _stale(self, eq: _Eq, qpos) -> bool:
        """Whether A_base was taken more than KKT_QTOL from ``qpos`` (module docstring)."""
        return float(np.max(np.abs(np.asarray(qpos) - eq.q_kkt))) > KKT_QTOL

    # -- equilibria -----------------------------------------------------------------------------
    def _adopt(self, qpos, load, theta) -> _Eq:
        """A cache entry at an equilibrium qpos: basis, multipliers by least squares, KKT parts."""
        st = self.statics
        basis = st.basis(qpos)
        res = st.residual(qpos, load, np.zeros(basis.shape[1]), basis)
        lam = -np.linalg.lstsq(res.jc_r.T, res.r, rcond=None)[0]
        a_base, h = self._kkt_fd(qpos, load, lam, basis, theta)
        return _Eq(qpos.copy(), lam, basis, a_base, h)

    def _init_cache(self, theta) -> None:
        """Cold solves by the bench's solver from the rigid configuration, then adopted."""
        cache = []
        for d in self.design:
            e0 = self.statics.solve(d.q)
            e1 = self.statics.solve(d.q, d.load, warm=e0)
            if not (e0.acceptable and e1.acceptable):  # e.g. a loop gone degenerate under theta
                raise NoEquilibrium(self.robot, d, theta)
            self.robot.set_command(d.q)
            cache.append((self._adopt(e0.qpos, None, theta), self._adopt(e1.qpos, d.load, theta)))
        self._cache = cache

    def _newton(self, eq: _Eq, load, theta) -> NewtonResult | None:
        """The statics' Newton from the cached equilibrium with A = A_base + S(theta); None when
        it does not converge (A_base too stale)."""
        qpos, lam = eq.qpos.copy(), eq.lam.copy()
        nv = self.nv
        if eq.tangent is not None and eq.theta is not None:
            # first-order prediction of the new equilibrium from the cached tangent
            step = eq.tangent @ (theta - eq.theta)
            qpos += step[:nv]
            lam += step[nv:]

        def stiffness(p: NewtonPoint) -> np.ndarray | None:
            if p.stalled and p.iteration > self.stall_limit:
                return None  # still stalling: A_base is stale, the caller re-takes it
            return self._stiffness(eq, theta)

        try:
            sol = self.statics.newton(qpos, lam, eq.basis, load, stiffness, max_iter=self.max_iter)
        except StaticsError:
            return None
        if not sol.converged:
            return None
        self.stats["newton_iterations"] += sol.iterations
        return sol

    def _solve(self, des: PoseDesign, load, eq: _Eq, theta, refresh: bool) -> NewtonResult:
        """Equilibrium of one (pose, state): warm Newton, then with a re-taken A_base, then a
        cold solve adopted into the cache. Raises RuntimeError when all three fail."""
        if refresh:  # the effects' springs live in A_base: re-take it
            self._retake(eq, eq.qpos, load, eq.lam, eq.basis, theta)
        sol = self._newton(eq, load, theta)
        if sol is None:
            self.stats["refreshes"] += 1
            eq.tangent = None
            self._retake(eq, eq.qpos, load, eq.lam, eq.basis, theta)
            sol = self._newton(eq, load, theta)
        if sol is None:
            self.stats["fallbacks"] += 1
            e = self.statics.solve(des.q, load, qpos0=eq.qpos)
            self.robot.set_command(des.q)
            new = self._adopt(e.qpos, load, theta)
            eq.qpos, eq.lam, eq.basis, eq.a_base, eq.h_len, eq.q_kkt = (
                new.qpos,
                new.lam,
                new.basis,
                new.a_base,
                new.h_len,
                new.q_kkt,
            )
            eq.tangent = None
            sol = self._newton(eq, load, theta)
            if sol is None:
                raise NoEquilibrium(self.robot, des, theta)
        return sol

    def evaluate(self, theta, jacobian: bool = True):
        """dp (M,3) and, with ``jacobian``, d dp / d theta (M,3,P): P = n_params, the robot's
        parameters plus any a subclass appends (discovery's effects). Parameters beyond the
        robot's enter the stiffness matrix A_base, so it is re-taken when they change.

        Warm evaluations start from the equilibria cached at the last parameters. Where those are
        far (a profile or a fit from springs 100 times softer took the model there), Newton from
        them can fail where the parameters do have an equilibrium: met on the FANUC, the model
        evaluated back at its estimate after its spring's profile at +-4.5 std. So a warm
        evaluation that finds no equilibrium is retried once from cold (the bench's solver from
        the rigid configuration, as the first evaluation); only a cold one's NoEquilibrium is
        final."""
        try:
            return self._evaluate(theta, jacobian)
        except NoEquilibrium:
            if self._cache is None:
                raise
            self.stats["cold_retries"] += 1
            self.forget()
            return self._evaluate(theta, jacobian)

    def forget(self) -> None:
        """Forget the cached equilibria: the next evaluation solves from the rigid configuration,
        as the first does (4-6x a warm evaluation's time). Where the statics have more than one
        equilibrium (a softening joint cubic), a warm start from far parameters can land on another
        branch than the one the loads reach from rest (identify/discover/aliasing.py's EXACT)."""
        self._cache, self._p_kkt = None, None

    def _evaluate(self, theta, jacobian: bool = True):
        theta = np.asarray(theta, dtype=float)
        npar = self.n_params
        nb = self.n_base
        if (
            theta.shape != (npar,)
            or not np.all(np.isfinite(theta))
            or np.any(theta[: self.layout.n_joints] <= 0)
        ):
            raise ValueError(f"theta must be {npar} finite values with positive compliances, got {theta}")
        robot = self.robot
        m, d = robot.model, robot.data
        self.write(theta)  # ValueError for invalid effect values
        self.stats["evaluations"] += 1
        dp = np.empty((self.n_obs, 3))
        jac = np.empty((self.n_obs, 3, npar)) if jacobian else None
        x0 = np.empty((self.n_obs, 3))
        j0 = np.empty((self.n_obs, 3, npar)) if jacobian else None
        with statics_options(robot):
            if self._cache is None:
                self._init_cache(theta)
                self._p_kkt = theta[nb:].copy()
            refresh = self._p_kkt is None or not np.array_equal(self._p_kkt, theta[nb:])
            if self._stacked(refresh):
                return self._evaluate_stacked(theta, jacobian)
            row = 0
            for des, pair in zip(self.design, self._cache):
                robot.set_command(des.q)
                n = len(des.sites)
                pos, jsite = [], []
                for load, eq in zip((None, des.load), pair):
                    sol = self._solve(des, load, eq, theta, refresh)
                    eq.qpos, eq.lam, eq.theta, eq.tangent = sol.qpos, sol.lam, theta.copy(), None
                    pos.append(d.site_xpos[des.sites].copy())
                    if jacobian:  # data holds the solution (Newton's last residual)
                        if self._stale(eq, sol.qpos):
                            self.stats["retakes"] += 1
                            self._retake(eq, sol.qpos, load, sol.lam, eq.basis, theta)
                        kkt = kkt_matrix(self._stiffness(eq, theta), sol.jc_r)
                        eq.tangent = ift_tangent(kkt, self._dforce(theta))
                        dq = eq.tangent[: self.nv]
                        js = np.empty((n, 3, npar))
                        for i, s in enumerate(des.sites):
                            mujoco.mj_jacSite(m, d, self._js, None, int(s))
                            js[i] = self._js @ dq
                        jsite.append(js)
                dp[row : row + n] = pos[1] - pos[0]
                x0[row : row + n] = pos[0]
                if jacobian:
                    jac[row : row + n] = jsite[1] - jsite[0]
                    j0[row : row + n] = jsite[0]
                row += n
            self._p_kkt = theta[nb:].copy()
        self.unloaded = (x0, j0)
        return dp, jac

    # -- every (pose, state) at once --------------------------------------------------------------
    # model fields the batch's copy must be given after each write (a subclass writing more
    # adds them: discovery's effects write every spring value)
    sync_fields: tuple[str, ...] = Robot.PARAM_FIELDS

    def _stacked(self, refresh: bool) -> bool:
        """Warm evaluations run stacked on bench/statics/batched.py, unless the model holds more than
        Robot.set_params writes (a subclass's own parameters and write), which the batch's copy
        of the model would not see; a subclass that syncs what it writes (``sync_fields``) and
        stacks its springs and force columns (``_springs_stack``, ``_dforce_stack``) says so
        here (discovery's AugmentedForward)."""
        return (
            self.batched
            and not refresh
            and self.n_params == self.n_base
            and type(self).write is ForwardModel.write
            and type(self)._dforce is ForwardModel._dforce
        )

    def _springs_stack(self, theta, bs: BatchStatics, ids: np.ndarray, qpos, q, h_len) -> np.ndarray:
        """S(theta) (n, nv, nv) at the poses the batch holds for simulations ids (qpos, commands
        q, the tendons' length Hessians h_len)."""
        robot = self.robot
        return self._springs(
            theta, self._moments_stack(bs.ten_j[ids]), bs.ten_length[ids][:, robot.tendons], h_len
        )

    def _moments_stack(self, ten_j: np.ndarray) -> np.ndarray:
        """:meth:`_moments` of n configurations (n, C, nv) from their stacked ten_J."""
        return self.robot.tendon_moments_stack(ten_j)

    def _kkt_fd_stack(self, theta, bs: BatchStatics, ids, qpos, q, load, lam, basis):
        """:meth:`_kkt_fd` of the batch's simulations ids at once (commands set, the same
        forward differences as bench/statics' stiffness_at, the tendon moments differenced at
        the same points); the batch is left at qpos."""
        h, nv = self.statics.fd_step, self.nv
        r0 = bs.residual(ids, qpos, load, lam, basis).r
        t0 = self._moments_stack(bs.ten_j[ids])
        a = np.empty((len(ids), nv, nv))
        h_len = np.empty((*t0.shape, nv))
        for j in range(nv):
            qp = qpos.copy()
            qp[:, j] += h
            a[:, :, j] = (bs.residual(ids, qp, load, lam, basis).r - r0) / h
            h_len[..., j] = (self._moments_stack(bs.ten_j[ids]) - t0) / h
        h_len = 0.5 * (h_len + h_len.transpose(0, 1, 3, 2))
        bs.forward(ids, qpos)  # the batch back at qpos for S
        return a - self._springs_stack(theta, bs, ids, qpos, q, h_len), h_len

    def _dforce_stack(self, theta, bs: BatchStatics, ids: np.ndarray, qpos, q) -> np.ndarray:
        """d g / d theta at fixed q (n, nv, n_params) of the solutions the batch holds."""
        return self.robot.dforce_dtheta_stack(self._params, qpos, q, bs.ten_j[ids], bs.ten_length[ids])

    def _evaluate_stacked(self, theta, jacobian: bool):
        """evaluate()'s loop for all (pose, state) equilibria at once: the same warm Newton (the
        cached solution moved by its tangent, A = A_base + S(theta), giving up on a row that
        still stalls after ``stall_limit`` steps), rows it did not converge through the scalar _solve (its
        re-taken A_base and cold fallbacks), then the same IFT tangents, stacked. Inside
        statics_options, the cache initialised."""
        robot, nv = self.robot, self.nv
        rows = [
            (des, load, eq)
            for des, pair in zip(self.design, self._cache)
            for load, eq in zip((None, des.load), pair)
        ]
        n = len(rows)
        if self._batch is None:
            self._batch = BatchStatics(self.statics, nsim=n, nthread=1)
        bs = self._batch
        bs.sync(*self.sync_fields)
        q = np.array([des.q for des, _, _ in rows])
        zero = np.zeros(3)
        load = Load(
            np.array([zero if ld is None else ld.force for _, ld, _ in rows]),
            np.array([zero if ld is None else ld.moment for _, ld, _ in rows]),
            np.array([robot.payload_site if ld is None else ld.site for _, ld, _ in rows]),
        )
        qpos = np.array([eq.qpos for *_, eq in rows])
        lam = np.array([eq.lam for *_, eq in rows])
        pred = [i for i, (*_, eq) in enumerate(rows) if eq.tangent is not None and eq.theta is not None]
        if pred:  # first-order prediction from the cached tangents
            step = np.einsum(
                "kij,kj->ki",
                np.array([rows[i][2].tangent for i in pred]),
                theta - np.array([rows[i][2].theta for i in pred]),
            )
            qpos[pred] += step[:, :nv]
            lam[pred] += step[:, nv:]
        basis = np.array([eq.basis for *_, eq in rows])
        a_base = np.array([eq.a_base for *_, eq in rows])
        h_len = np.array([eq.h_len for *_, eq in rows])

        def springs(ids, qp) -> np.ndarray:
            """S(theta) at the poses qp the batch holds for simulations ids."""
            return self._springs_stack(theta, bs, ids, qp, q[ids], h_len[ids])

        def stiffness(idx, qp, lm, r, stalled, iteration):
            return a_base[idx] + springs(idx, qp), stalled & (iteration > self.stall_limit)

        sol = bs.newton(q, qpos, basis, load, lam=lam, stiffness=stiffness, max_iter=self.max_iter)
        self.stats["newton_iterations"] += int(sol.iterations[sol.converged].sum())
        qpos, lam = sol.qpos, sol.lam
        for i in np.flatnonzero(~sol.converged):  # rare: the scalar path's fallbacks
            des, ld, eq = rows[i]
            robot.set_command(des.q)
            one = self._solve(des, ld, eq, theta, False)
            qpos[i], lam[i] = one.qpos, one.lam
            a_base[i], h_len[i], basis[i] = eq.a_base, eq.h_len, eq.basis
        for i, (*_, eq) in enumerate(rows):
            eq.qpos, eq.lam, eq.theta, eq.tangent = qpos[i], lam[i], theta.copy(), None
        # the tangent needs A_base at the solution: _stale's test, every row at once
        moved = np.abs(qpos - np.array([eq.q_kkt for *_, eq in rows])).max(axis=1) > KKT_QTOL
        stale = np.flatnonzero(moved) if jacobian else np.zeros(0, int)
        if len(stale):  # _retake of every stale row at once
            self.stats["retakes"] += len(stale)
            ids = stale
            a_base[ids], h_len[ids] = self._kkt_fd_stack(
                theta, bs, ids, qpos[ids], q[ids], take_load(load, ids), lam[ids], basis[ids]
            )
            for i in stale:
                eq = rows[i][2]
                eq.a_base, eq.h_len, eq.q_kkt = a_base[i].copy(), h_len[i].copy(), np.array(qpos[i])
        # the solutions' forward pass (positions, tendon, J_c), then the tangents
        res = bs.residual(np.arange(n), qpos, load, lam, basis)
        ids = np.arange(n)
        pos = bs.site_xpos[ids]
        dp = np.empty((self.n_obs, 3))
        jac = None
        if jacobian:
            kkt = kkt_matrix(a_base + springs(ids, qpos), res.jc_r)
            tangent = ift_tangent(kkt, self._dforce_stack(theta, bs, ids, qpos, q))
            for i, (*_, eq) in enumerate(rows):
                eq.tangent = tangent[i]
            used = np.unique(np.concatenate([des.sites for des in self.design]))
            jsite = np.stack([bs.site_jacobian(ids, int(s)) for s in used], axis=1) @ tangent[:, None, :nv]
            jac = np.empty((self.n_obs, 3, self.n_params))
        x0 = np.empty((self.n_obs, 3))
        j0 = np.empty((self.n_obs, 3, self.n_params)) if jacobian else None
        row = 0
        for k, des in enumerate(self.design):
            m = len(des.sites)
            dp[row : row + m] = pos[2 * k + 1, des.sites] - pos[2 * k, des.sites]
            x0[row : row + m] = pos[2 * k, des.sites]
            if jacobian:
                cols = np.searchsorted(used, des.sites)
                jac[row : row + m] = jsite[2 * k + 1, cols] - jsite[2 * k, cols]
                j0[row : row + m] = jsite[2 * k, cols]
            row += m
        self._p_kkt = theta[self.n_base :].copy()
        self.unloaded = (x0, j0)
        return dp, jac


__all__ = ["PoseDesign", "ForwardModel", "design_from_observations"]
