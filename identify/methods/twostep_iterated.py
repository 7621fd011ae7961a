"""The paper's two-step method with its Jacobians re-taken at the sagged pose (`--method
two-step-iterated`).

Why. Eqs. (19)-(22) linearise at the commanded pose (identify/methods/twostep.py): the parameters are
unknown, so is the deflection. The shipped compensator is stiff (K_C = 2.6e6 N/m: up to
2.7e5 N*m at q2 = 120 deg) and sags J2 by 1.0-1.8 deg under gravity alone. At the middle q2 of
Table 5 (35 deg) the upper arm stands nearly vertical, where the payload's torque on motor 2 is
small and that sag changes it by ~25 %: the aggregated stiffness K_2 there is off by as much,
and step 2 (exactly determined by three q2) turns it into a NEGATIVE spring on noise-free data:
K_C = -3.16e6 N/m against a truth of +2.6e6 (tests/test_identify_plans.py). The linear model
itself is not the problem: at the TRUE sagged pose its error (H00 of eq. 18 and the
nonlinearity over the deflection) is below 0.8 sigma (identify/study/montecarlo.py's oracle row).

What. The sag of the compensator's joint is the unknown of a fixed point: for sags d (one per
distinct q2 of the plan, in rad), take the linear model at the commanded pose with that joint
turned by d (the loops closed, bench/model/robot.py's rigid_qpos), estimate theta(d) by the two-step
method, solve the unloaded static equilibrium of every pose with theta(d) written into the
estimator's own model (bench/statics/equilibrium.py) and read the sag it predicts, D(d); the estimate is
theta(d*) with D(d*) = d*. Re-taking the Jacobians at the sag of the previous estimate
(d <- D(d)) is the plain way to that point, but on this robot it diverges: D's slope along the
120 deg group is ~3.6 (measured along the line from the commanded to the true sag), so the
iteration oscillates away, and from the paper's own estimate it wanders between spurious fixed
points. So the fixed point is solved by Newton's method on R(d) = D(d) - d (Jacobian S G - I, the
derivatives below, updated by Broyden's rank-one rule after each step and re-taken when its step
fails; the step halved while |R| does not decrease, down to MIN_ALPHA), from d = 0 (the plain
method's pose), to |R| < TOL rad. A run whose |R| stops falling (SLOW_STEPS steps gaining less
than SLOW) sits at a minimum of |R| that is no root: it ends unconverged. An estimate the statics cannot use (a non-positive
compliance, a parameter step 2 did not give) takes identify/methods/onestep.py's generic value for that
equilibrium only. Nothing but the observations and the MJCF's geometry is read, as in the plain
method.

Uncertainty. The sag d* moves with the readings, so the linear solve's covariance (the pose
held fixed) is too small (k1's std by ~2x in a Monte Carlo). The reported covariance carries
d*'s share by the implicit function theorem: with L = dtheta/dy at fixed d (the linear solve's
delta method, C = L Sigma L^T), G = dtheta/dd, S = dD/dtheta and R(d) = D(theta(d)) - d,
dtheta*/dy = A L with A = I - G (S G - I)^-1 S, so cov = A C A^T (:func:`sensitivity`).
S comes from the statics' implicit-function tangent at each pose's unloaded equilibrium
(dq/dtheta = -K^-1 dg/dtheta, bench.statics; the compensator joint's row, averaged per q2 group),
G from central differences (STEP) of the linear solve, only the moved group's poses re-evaluated.
Until issue 23, S was central differences of re-solved equilibria (2 P solves of every pose, 90 %
of a Monte Carlo run's 0.28 s); :func:`sensitivity_fd` keeps that way as the reference the tangent
is tested against (tests/test_identify_plans.py: stds equal to 5e-5).

Speed. The equilibria of every pose are solved at once (bench.statics.BatchStatics), from the
last evaluation's poses with a chord matrix (the exact one at a reference, plus the springs'
change); the step-1 regressors of all poses are stacked on the same batch. On the paper
campaign a converged Monte Carlo run costs ~8 map evaluations (docs/performance.md).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import mujoco
import numpy as np

from calbench.bench.model import Robot
from calbench.bench.statics import (
    BatchStatics,
    Equilibria,
    Equilibrium,
    StaticsError,
    StaticsSolver,
    ift_tangent,
    kkt_matrix,
)
from calbench.identify.core import Observations, Whitener

from .base import IdentifyOptions, Method, MethodResult, Repeats
from .onestep import generic_start
from .twostep import (
    REQUIREMENT,
    PoseRows,
    TwoStepResult,
    group_q2,
    plan_from_rows,
    two_step,
    two_step_applies,
    two_step_result,
)

TOL = 1e-9  # rad: the fixed point's residual (1e-7 of the 1-2 deg sag)
STEP = 1e-6  # rad: forward-difference step of the Newton Jacobian
REL_STEP = 1e-5  # relative central-difference step of dD/dtheta (a compliance or a spring)
MAX_NEWTON = 20
# |R| falling by less than this factor on SLOW_STEPS accepted steps in a row: no root there (runs
# of a Monte Carlo whose noise leaves the map without a fixed point near the start stall at a
# minimum of |R| of 0.2-0.7 deg and used to spend the 20 iterations' line searches on it)
SLOW, SLOW_STEPS = 0.9, 3
MIN_ALPHA = 0.03  # the line search halves the Newton step down to this fraction
# Jacobians taken per solve: converged Monte Carlo runs of the paper plan take at most two (their
# chord from the exact readings' solve, Broyden-updated, rarely fails); runs whose map has no
# fixed point near the start fail chord after chord, wandering to sags of tens of degrees
MAX_JACOBIANS = 4


@dataclass
class _Reference:
    """Where SagMap's chord matrices come from: equilibria at parameters theta whose exact
    matrix A, tendon moments and tangent d[q; lam]/dtheta (n, nv + nc, P) were taken."""

    theta: np.ndarray
    params: object
    a: np.ndarray
    moments: tuple
    tangent: np.ndarray


class SagMap:
    """d -> (theta(d), D(d)) for one robot and plan (module docstring). ``white``: the
    observations' whitener when the caller has it (the Monte Carlo's runs do); ``warm``: a map of
    the same robot and plan (other readings) whose pose rows, equilibria and chord reference
    this one starts from (they depend on the readings only through the sags and parameters they
    were taken at, which every use checks)."""

    def __init__(
        self,
        robot: Robot,
        obs: Observations,
        weighted: bool,
        white: Whitener | None = None,
        warm: SagMap | None = None,
    ):
        self.robot, self.obs, self.weighted = robot, obs, weighted
        self.joint = two_step_applies(robot)
        self.white = Whitener.from_observations(obs) if white is None else white
        self.generic = generic_start(robot, obs)
        q = np.array([p.q[self.joint] for p in obs.poses])
        self.group, _ = group_q2(q)
        self.n = int(self.group.max()) + 1
        self.col = robot.act_qpos[self.joint]
        self.dof = robot.act_dof[self.joint]
        self.q = np.array([p.q for p in obs.poses], dtype=float)
        self.evaluations = 0
        site = lambda n: mujoco.mj_name2id(robot.model, mujoco.mjtObj.mjOBJ_SITE, n)  # noqa: E731
        self.sites = [[site(p.site)] + [site(r) for r in p.reflectors] for p in obs.poses]
        self._rows: tuple[np.ndarray, list[PoseRows]] | None = None  # the last d's pose rows
        self._equilibria: tuple[np.ndarray, list] | None = None  # the last sag's (theta, equilibria)
        self._batch: BatchStatics | None = None
        self._ref: _Reference | None = None  # the chord's reference (:meth:`_reference`)
        self._thread = threading.get_ident()
        if warm is not None:  # the same plan's caches (read only): a Monte Carlo run from the exact one
            self._rows, self._equilibria, self._ref = warm._rows, warm._equilibria, warm._ref
            if warm._thread == self._thread:  # a batch is not thread-safe
                self._batch = warm._batch

    def configuration(self, pose, sag: float) -> np.ndarray:
        """The rigid closed-loop configuration of a pose with the compensator joint turned by sag."""
        q = np.array(pose.q, dtype=float)
        q[self.joint] += sag
        return self.robot.rigid_qpos(q)

    def configurations(self, d: np.ndarray) -> dict[int, np.ndarray]:
        return {p.index: self.configuration(p, d[g]) for p, g in zip(self.obs.poses, self.group)}

    def rows(self, d: np.ndarray) -> list[PoseRows]:
        """Each pose's step-1 rows at sags d; the poses of groups whose sag did not change since
        the last call are reused (each pose's rows depend on its own configuration only)."""
        last = self._rows
        new = [k for k, g in enumerate(self.group) if last is None or last[0][g] != d[g]]
        out = list(last[1]) if last is not None else [None] * len(self.group)
        for k, r in zip(new, self._stacked_rows(new, d)):
            out[k] = r
        self._rows = (np.array(d, dtype=float), out)
        return out

    def _stacked_rows(self, poses: list[int], d: np.ndarray) -> list[PoseRows]:
        """:func:`pose_rows` of the poses (indices into obs.poses) at sags d, their kinematics
        and motor maps stacked on the batch (the same quantities; MuJoCo's site Jacobians formed
        from the joint frames, bench.statics.BatchStatics.site_jacobian)."""
        if not poses:
            return []
        rb, bs = self.robot, self.batch()
        qpos = np.array([self.configuration(self.obs.poses[k], d[self.group[k]]) for k in poses])
        ids = bs.place(qpos)
        n = len(ids)
        g = rb.model.opt.gravity / max(np.linalg.norm(rb.model.opt.gravity), 1e-300)
        vertical = np.abs(bs.joint_axes(ids, rb.act_joint) @ g) > 1 - 1e-9
        nmap = np.zeros((n, rb.model.nv, rb.n_act))
        nmap[:, rb.act_dof, np.arange(rb.n_act)] = 1.0
        if len(rb.passive_dof):
            jc = bs.loop_gap(ids)[1]
            nmap[:, rb.passive_dof, :] = (
                -np.linalg.pinv(jc[:, :, rb.passive_dof], rcond=1e-10) @ jc[:, :, rb.act_dof]
            )
        jac = {}
        for site in {s for k in poses for s in self.sites[k]}:
            jp, jr = bs.site_jacobian(ids, site, rotation=True)
            jac[site] = (jp @ nmap, jr @ nmap)
        out = []
        for i, k in enumerate(poses):
            p = self.obs.poses[k]
            load, *refl = self.sites[k]
            tau = jac[load][0][i].T @ p.force + jac[load][1][i].T @ p.moment
            cols = np.array([jac[r][0][i] * tau[None, :] for r in refl]).reshape(-1, 3, rb.n_act)
            out.append(PoseRows(cols, tau, vertical[i]))
        return out

    def batch(self) -> BatchStatics:
        """The stacked statics and kinematics of the plan's poses (one simulation per pose)."""
        if self._batch is None:
            self._batch = BatchStatics(StaticsSolver(self.robot), nsim=len(self.q), nthread=1)
        return self._batch

    def estimate(self, d: np.ndarray) -> TwoStepResult:
        q2 = np.array([p.q[self.joint] for p in self.obs.poses])
        for k, g in enumerate(self.group):
            q2[k] += d[g]
        lp = plan_from_rows(self.robot, self.obs, self.rows(d), q2)
        return two_step(self.robot, self.obs, self.weighted, lp=lp, white=self.white)

    def usable(self, theta: np.ndarray) -> np.ndarray:
        """theta for the statics: NaN entries and non-positive compliances take the generic
        values (a compensator's pair together); a spring rate of either sign is kept."""
        return np.where(self.replaced(theta), self.generic, theta)

    def replaced(self, theta: np.ndarray) -> np.ndarray:
        """(P,) bool: the entries :meth:`usable` replaces by the generic values."""
        lay = self.robot.layout
        theta = np.asarray(theta, dtype=float)
        bad = ~np.isfinite(theta)
        bad[lay.compliance] |= theta[lay.compliance] <= 0
        for kc, s0 in zip(lay.stiffness_index, lay.preload_index):
            if bad[kc] or bad[s0]:
                bad[kc] = bad[s0] = True
        return bad

    def group_means(self, per_pose: np.ndarray) -> np.ndarray:
        """(n, ...) the mean over each q2 group of per-pose rows (n_poses, ...)."""
        return np.array([per_pose[self.group == g].mean(axis=0) for g in range(self.n)])

    def sag(self, theta: np.ndarray) -> np.ndarray:
        """The compensator joint's unloaded sag per q2 group (mean over its poses), rad, of the
        robot with theta written in (its own parameters restored): every pose's equilibrium at
        once (bench.statics' BatchStatics, from the last call's poses), those it does not accept
        one by one (StaticsSolver). StaticsError: no equilibrium."""
        rb = self.robot
        saved = rb.params()
        rb.set_params(rb.layout.params(self.usable(theta)))
        try:
            eqs = self._solve()
        finally:
            rb.set_params(saved)
        self._equilibria = (np.array(theta, dtype=float), eqs)
        qpos = eqs.qpos if isinstance(eqs, Equilibria) else np.array([e.qpos for e in eqs])
        return self.group_means(qpos[:, self.col] - self.q[:, self.joint])

    def _solve(self) -> Equilibria | list[Equilibrium]:
        """The unloaded equilibria of every pose at the parameters the robot holds: Newton from
        the last call's equilibria with a chord matrix (:meth:`_chord`), else cold (the exact
        matrices assembled there); the poses the batch does not accept one by one."""
        bs = self.batch()
        bs.sync(*Robot.PARAM_FIELDS)
        last = self._equilibria[1] if self._equilibria is not None else None
        if isinstance(last, Equilibria) and last.acceptable.all() and self._ref is not None:
            # from the last equilibria moved by the reference's tangent, a chord matrix
            step = self.robot.layout.theta(self.robot.params()) - self.usable(self._equilibria[0])
            move = np.einsum("nkp,p->nk", self._ref.tangent, step)
            nv = self.robot.model.nv
            factor = np.linalg.inv(kkt_matrix(self._chord(), last.jc_r))
            eqs = bs.newton(
                self.q, last.qpos + move[:, :nv], last.basis, None, lam=last.lam + move[:, nv:], factor=factor
            )
            if eqs.stalls.any() and eqs.acceptable.all():  # the chord's reference is too far: renew it
                self._ref = self._reference(eqs)
        else:
            eqs = bs.solve(self.q)
            if eqs.acceptable.all():  # the reference of the next solves' chords
                self._ref = self._reference(eqs)
        if eqs.acceptable.all():
            return eqs
        solver = StaticsSolver(self.robot)
        return [solver.solve(q) for q in self.q]

    def _reference(self, eqs: Equilibria) -> _Reference:
        """The chord's reference at the equilibria of the parameters the robot (and the batch)
        holds: the exact A, the tendons' moments and Hessians, the full tangent d[q; lam]/dtheta."""
        bs, params = self.batch(), self.robot.params()
        a = bs.stiffness(eqs, None)
        tangent = ift_tangent(kkt_matrix(a, eqs.jc_r), bs.dforce(eqs, params))
        return _Reference(self.robot.layout.theta(params), params, a, self._moments(eqs), tangent)

    def _moments(self, eqs: Equilibria) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The compensators' tendon moments t = dL/dq (n, C, nv), lengths L (n, C) and Hessians
        H_L = dt/dq (n, C, nv, nv, forward differences of t, the solver's fd_step) at the
        equilibria."""
        bs, rb = self.batch(), self.robot
        tendons = list(rb.tendons)
        ids = bs.at(eqs)
        t, length = rb.tendon_moments_stack(bs.ten_j[ids]), bs.ten_length[ids][:, tendons].copy()
        h = np.empty(t.shape + (rb.model.nv,))
        step = bs.solver.fd_step
        for j in range(rb.model.nv):
            qp = eqs.qpos.copy()
            qp[:, j] += step
            ids = bs.place(qp)
            h[..., j] = (rb.tendon_moments_stack(bs.ten_j[ids]) - t) / step
        return t, length, h

    def _chord(self) -> np.ndarray:
        """A (n, nv, nv) for the parameters the robot holds: the exact matrix of the reference
        equilibria plus the springs' change, -1/k on each motor and -(dK_C t t^T + d(K_C (L -
        s0)) H_L) for each compensator at the reference poses (their move since left out: a
        chord; the solution is judged on the exact residual)."""
        ref, p1, rb = self._ref, self.robot.params(), self.robot
        p0, a0, (t, length, h) = ref.params, ref.a, ref.moments
        a = a0.copy()
        a[:, rb.act_dof, rb.act_dof] -= 1.0 / np.asarray(p1.compliance) - 1.0 / np.asarray(p0.compliance)
        for c, name in enumerate(rb.description.compensators):
            s0, s1 = p0.springs[name], p1.springs[name]
            a -= (s1.stiffness - s0.stiffness) * np.einsum("ni,nj->nij", t[:, c], t[:, c])
            tension = s1.stiffness * (length[:, c] - s1.preload) - s0.stiffness * (length[:, c] - s0.preload)
            a -= tension[:, None, None] * h[:, c]
        return a

    def sag_tangent(self, theta: np.ndarray) -> np.ndarray:
        """S = dD/dtheta (n, P) by the implicit function theorem at each pose's unloaded
        equilibrium (bench.statics' tangent with Robot.dforce_dtheta; the equilibria of the last
        :meth:`sag` when it was of this theta); zero in the entries :meth:`usable` replaces."""
        theta = np.asarray(theta, dtype=float)
        if self._equilibria is None or not np.array_equal(self._equilibria[0], theta, equal_nan=True):
            self.sag(theta)
        eqs = self._equilibria[1]
        rb = self.robot
        saved = rb.params()
        params = rb.layout.params(self.usable(theta))
        rb.set_params(params)
        try:
            if isinstance(eqs, Equilibria):
                bs = self._batch
                bs.sync(*Robot.PARAM_FIELDS)
                self._ref = self._reference(eqs)
                dq = self._ref.tangent[:, self.dof]
            else:
                solver = StaticsSolver(rb)
                dq = []
                for e in eqs:
                    rb.set_command(e.command)
                    solver.forward(e.qpos, velocity=False)
                    dq.append(solver.tangent(e, None, rb.dforce_dtheta(params))[self.dof])
                dq = np.array(dq)
        finally:
            rb.set_params(saved)
        s = self.group_means(dq)
        s[:, self.replaced(theta)] = 0.0
        return s

    def residual(self, d: np.ndarray) -> tuple[np.ndarray, TwoStepResult]:
        self.evaluations += 1
        est = self.estimate(d)
        return self.sag(est.theta) - d, est


def linear_sensitivity(sm: SagMap, d: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """G = dtheta/dd (P, n) of the linear solve at fixed readings: central differences (STEP)
    of its regressors' geometry, only the poses of the group whose sag moves re-evaluated."""
    g = np.zeros((len(ok), sm.n))
    for k in range(sm.n):
        e = np.zeros(sm.n)
        e[k] = STEP
        tp, tm = sm.estimate(d + e).theta, sm.estimate(d - e).theta
        g[:, k] = np.where(ok, (tp - tm) / (2 * STEP), 0.0)
    sm.rows(d)  # back to d's rows (cached: the next estimate at d is cheap)
    return g


def newton_jacobian(sm: SagMap, d: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """dR/dd = S G - I (n, n) at sags d with the linear solve's theta (module docstring)."""
    ok = np.isfinite(theta)
    s = sm.sag_tangent(theta)
    s[:, ~ok] = 0.0
    return s @ linear_sensitivity(sm, d, ok) - np.eye(sm.n)


def sensitivity(sm: SagMap, d: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """A = dtheta*/dtheta at fixed d (module docstring, Uncertainty): (P,P), identity on the
    parameters the linear solve did not give. G by :func:`linear_sensitivity`, S = dD/dtheta
    by the statics' implicit-function tangent (:meth:`SagMap.sag_tangent`)."""
    ok = np.isfinite(theta)
    g = linear_sensitivity(sm, d, ok)
    s = sm.sag_tangent(theta)
    s[:, ~ok] = 0.0
    return _fixed_point_map(g, s)


def sensitivity_fd(sm: SagMap, d: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """:func:`sensitivity` with S by central differences of the predicted sag in each identified
    parameter (REL_STEP of its size): the reference the tangent is checked against (tests), at
    2 x P statics solves of every pose."""
    ok = np.isfinite(theta)
    g = linear_sensitivity(sm, d, ok)
    s = np.zeros((sm.n, len(theta)))
    for j in np.flatnonzero(ok):
        h = REL_STEP * max(abs(theta[j]), 1e-300)
        tp, tm = theta.copy(), theta.copy()
        tp[j] += h
        tm[j] -= h
        s[:, j] = (sm.sag(tp) - sm.sag(tm)) / (2 * h)
    return _fixed_point_map(g, s)


def _fixed_point_map(g: np.ndarray, s: np.ndarray) -> np.ndarray:
    """A = I - G (S G - I)^-1 S (module docstring, Uncertainty)."""
    jd = s @ g - np.eye(s.shape[0])  # dR/dd at the fixed point
    return np.eye(g.shape[0]) - g @ np.linalg.solve(jd, s)


def two_step_iterated(
    robot: Robot,
    obs: Observations,
    weighted: bool = False,
    *,
    tol: float = TOL,
    max_newton: int = MAX_NEWTON,
    start: np.ndarray | None = None,
    jacobian: np.ndarray | None = None,
    uncertainty: bool = True,
    white: Whitener | None = None,
    warm: SagMap | None = None,
    sag_map: SagMap | None = None,
) -> TwoStepResult:
    """The two-step estimate at the self-consistent sagged pose (module docstring). ``start``:
    initial sags per q2 group (default 0: the commanded pose); ``jacobian``: dR/dd to reuse
    (chord steps, e.g. the Monte Carlo's noise-free one; re-taken when a chord step does not
    lower |R|); ``uncertainty``: carry the sag's share into the covariance (module docstring;
    False keeps the pose-held-fixed covariance); ``white``, ``warm``: :class:`SagMap`'s;
    ``sag_map``: the map to use (left as the solve leaves it, e.g. to warm others). ``step2``
    records the sags, the Newton iterations, map evaluations, the last Jacobian and whether
    |R| < tol."""
    sm = SagMap(robot, obs, weighted, white, warm) if sag_map is None else sag_map
    d = np.zeros(sm.n) if start is None else np.array(start, dtype=float)
    r, est = sm.residual(d)
    history = [{"sag_deg": np.degrees(d).tolist(), "residual_deg": np.degrees(r).tolist()}]
    converged = bool(np.abs(r).max() < tol)
    jac = None if jacobian is None else np.asarray(jacobian, dtype=float)
    it, slow, stalled, fresh = 0, 0, False, 0
    while not converged and it < max_newton:
        it += 1
        chord = jac is not None
        if not chord:
            if fresh == MAX_JACOBIANS:  # every chord fails here: no root the Newton can reach
                stalled = True
                break
            jac, fresh = newton_jacobian(sm, d, est.theta), fresh + 1
        step = -np.linalg.lstsq(jac, r, rcond=None)[0]
        alpha = 1.0
        # a chord's full step that does not lower |R|: re-take the Jacobian rather than search
        while alpha > (0.5 if chord else MIN_ALPHA):
            try:
                r_new, est_new = sm.residual(d + alpha * step)
            except StaticsError:
                alpha /= 2
                continue
            if np.linalg.norm(r_new) < np.linalg.norm(r):
                break
            alpha /= 2
        else:
            if chord:  # a stale chord: re-take the Jacobian and try again
                jac = None
                continue
            break
        dd, dr = alpha * step, r_new - r
        jac = jac + np.outer(dr - jac @ dd, dd) / (dd @ dd)  # Broyden's update of the chord
        slow = slow + 1 if np.linalg.norm(r_new) > SLOW * np.linalg.norm(r) else 0
        d, r, est = d + dd, r_new, est_new
        history.append({"sag_deg": np.degrees(d).tolist(), "residual_deg": np.degrees(r).tolist()})
        converged = bool(np.abs(r).max() < tol)
        if slow >= SLOW_STEPS and not converged:  # a minimum of |R| that is not a root
            stalled = True
            break
    covariance = "the pose held fixed (too small: module docstring)"
    if converged and uncertainty:
        try:
            a = sensitivity(sm, d, est.theta)
        except (StaticsError, np.linalg.LinAlgError) as exc:  # a step off a usable robot
            covariance += f"; the sag's share not computed: {exc}"
        else:
            ok = np.isfinite(est.theta)
            c = np.where(np.isfinite(est.cov), est.cov, 0.0)
            cov = a @ c @ a.T
            cov[~ok, :] = np.nan
            cov[:, ~ok] = np.nan
            est.cov = cov
            covariance = "with the sag's share"
    est.step2 = dict(
        est.step2,
        linearised_at="the self-consistent sagged pose",
        sag_rad=d.tolist(),
        covariance=covariance,
        newton_iterations=it,
        map_evaluations=sm.evaluations,
        converged=converged,
        stalled=stalled,
        history=history,
        jacobian=None if jac is None else jac.tolist(),
    )
    return est


__all__ = [
    "two_step_iterated",
    "sensitivity",
    "sensitivity_fd",
    "linear_sensitivity",
    "SagMap",
    "TOL",
    "STEP",
    "REL_STEP",
    "MAX_NEWTON",
]


# --------------------------------------------------------------------------- the family's face


def estimate_two_step_iterated(robot: Robot, obs: Observations, options: IdentifyOptions) -> MethodResult:
    """`calbench identify --method two-step-iterated`: :func:`two_step_iterated` from the commanded pose."""
    return two_step_result(two_step_iterated(robot, obs), "two-step-iterated", robot)


def repeat_two_step_iterated(robot: Robot, obs0: Observations, white0: Whitener) -> Repeats:
    """The Monte Carlo's iterated two-step: every run starts at the exact readings' sag, with
    their Newton Jacobian as its chord (:func:`two_step_iterated`'s ``start`` and ``jacobian``)
    and their map's pose rows and equilibria (``warm``)."""
    sm0 = SagMap(robot, obs0, False, white0)
    it0 = two_step_iterated(robot, obs0, sag_map=sm0)
    sag, jac = it0.step2["sag_rad"], it0.step2["jacobian"]

    def run(obs: Observations, white: Whitener) -> MethodResult:
        est = two_step_iterated(robot, obs, start=sag, jacobian=jac, white=white, warm=sm0)
        return two_step_result(est, "two-step-iterated", robot)

    return Repeats(two_step_result(it0, "two-step-iterated", robot), run)


TWO_STEP_ITERATED = Method(
    "two-step-iterated",
    estimate_two_step_iterated,
    summary="the same with its Jacobians re-taken at the pose sagged by its own estimate",
    applies=two_step_applies,
    requirement=REQUIREMENT,
    repeat=repeat_two_step_iterated,
    seconds_per_run=0.05,  # in-process, per Monte Carlo run on the paper campaign (measured)
    in_both=False,  # ~5x the one-step per run: `montecarlo --method all` or by name
)

__all__ += ["estimate_two_step_iterated", "repeat_two_step_iterated", "TWO_STEP_ITERATED"]
