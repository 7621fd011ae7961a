"""The exact Fisher information block of one candidate configuration (issue 4, §2).

Information. For one candidate with reflectors r, the deflection dp_r = x_r(loaded) -
x_r(unloaded) is the exact-statics one of identify/core/forward.py; its Jacobian with respect to u
comes from the implicit function theorem at both equilibria (``StaticsSolver.tangent``, exact
KKT matrix, d g / d theta from ``Robot.dforce_dtheta``), J_r = (J_site dq/dtheta)|loaded -
(...)|unloaded, times theta0 column-wise. The deflections' covariance Sigma is
bench.tracker.deflection_covariance's (the estimator's: Cov(reading unloaded) + Cov(reading
loaded) per reflector, 2 sigma^2 I for the isotropic tracker, one repeat; for a correlated
tracker, iso10360, also the error shared by the pose's readings, on the campaign clock). The
candidate's block is the whitened regressor R = L^-1 [J_r], L L^T = Sigma: rows = the 3
coordinates of each reflector (9 rows for 3 reflectors), columns = the p normalised parameters,
and the Fisher information of a plan is sum_i R_i^T R_i (with repeats n: n R_i^T R_i, exact
for independent readings; for a correlated tracker repeats do not average its correlated part
and this overstates what they add).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from calbench.bench.campaign import truth_params
from calbench.bench.model import motor_jacobian
from calbench.bench.scenario import Scenario, reading_times
from calbench.bench.statics import Equilibrium, Load, StaticsSolver
from calbench.bench.tracker import (
    deflection_covariance,
    measure,
    noise_covariance,
    to_tracker_frame,
    tracker_rotation,
)
from calbench.identify.core import analyze, explain, resolve

from .feasibility import Feasibility
from .settings import DesignSettings, nominal_robot

# --------------------------------------------------------------------------- information


@dataclass
class PoseInfo:
    q: np.ndarray
    wrench: np.ndarray  # (6,) world: payload weight or the pull
    kind: str
    block: np.ndarray  # (3 n_visible, p) whitened, normalised regressor
    visible: np.ndarray  # (n,) bool
    violations: list[str]
    dp: np.ndarray | None = None  # (n, 3) deflections (visible rows meaningful)


class InfoEngine:
    """Exact information of single poses on the design model (one per process)."""

    def __init__(self, scn: Scenario, settings: DesignSettings):
        self.scn = scn
        self.settings = settings
        self.robot = nominal_robot(scn)
        self.params0 = truth_params(scn, self.robot)
        self.theta0 = self.robot.layout.theta(self.params0)
        self.n_params = self.robot.layout.n
        self.solver = StaticsSolver(self.robot, tol=1e-10)
        self.feas = Feasibility(self.robot, scn, settings)
        self.settings = self.feas.settings  # min_height, min_radius scaled with the robot's reach
        self.rot = tracker_rotation(scn.tracker)
        self._js = np.zeros((3, self.robot.model.nv))
        self._jr = np.zeros((3, self.robot.model.nv))
        # the pose criterion's G for a compensation job (identify/compensate/criterion.py), in
        # place of the [work] pose's (plan.work_jacobian); set by run_design for --job
        self.job_jacobian: np.ndarray | None = None

    def load_for(self, wrench) -> Load:
        return Load.wrench(self.robot, wrench)

    def _dforce(self, e: Equilibrium) -> np.ndarray:
        """dg/dtheta at fixed q (nv, p) at equilibrium e, for the prior guess theta0."""
        rb = self.robot
        rb.set_command(e.command)
        rb.data.qpos[:] = e.qpos
        mujoco.mj_fwdPosition(rb.model, rb.data)
        return rb.dforce_dtheta(self.params0)

    def _site_jac(self, e: Equilibrium, load: Load | None) -> tuple[np.ndarray, np.ndarray]:
        """Reflector positions (n,3) and d position / d theta (n,3,p) at equilibrium e."""
        rb = self.robot
        tan = self.solver.tangent(e, load, self._dforce(e))
        m, d = rb.model, rb.data
        d.qpos[:] = e.qpos
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        pos = d.site_xpos[rb.reflector_sites].copy()
        jac = np.empty((len(rb.reflector_sites), 3, self.n_params))
        for i, s in enumerate(rb.reflector_sites):
            mujoco.mj_jacSite(m, d, self._js, None, int(s))
            jac[i] = self._js @ tan
        return pos, jac

    def sigma_dp_blocks(self, p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
        """(n, 3k, 3k): :meth:`sigma_dp` of n candidates at once (p0, p1: (n, k, 3), one reading
        per state); block diagonal by reflector, vectorised, unless the tracker's error is
        correlated (TrackerModel.correlated, iso10360: one candidate at a time)."""
        n, k = p0.shape[:2]
        if self.scn.tracker.error_model.correlated:
            return np.stack([self.sigma_dp(a, b) for a, b in zip(p0, p1)])
        spec = self.scn.tracker
        c = noise_covariance(spec, to_tracker_frame(spec, p0.reshape(-1, 3))) + noise_covariance(
            spec, to_tracker_frame(spec, p1.reshape(-1, 3))
        )
        c = (self.rot @ c @ self.rot.T).reshape(n, k, 3, 3)
        out = np.zeros((n, k, 3, k, 3))
        for i in range(k):
            out[:, i, :, i, :] = c[:, i]
        return out.reshape(n, 3 * k, 3 * k)

    def sigma_dp(self, p0: np.ndarray, p1: np.ndarray, repeats: int = 1) -> np.ndarray:
        """(3n, 3n) world covariance of the n deflections of one pose read ``repeats`` times per
        state on the campaign clock (bench.tracker.deflection_covariance: block diagonal by
        reflector unless the tracker's error is correlated)."""
        spec = self.scn.tracker
        n = len(p0)
        times = reading_times([repeats], n)
        reads = [[measure(spec, p, np.ones(n, bool), None)] * repeats for p in (p0, p1)]  # exact
        when = tuple([times[(0, s, r)] for r in range(repeats)] for s in ("unloaded", "loaded"))
        c = deflection_covariance(spec, reads[0], reads[1], np.arange(n), when)
        return np.einsum("ia,ranb,jb->rinj", self.rot, c, self.rot).reshape(3 * n, 3 * n)

    def pose(
        self,
        q,
        wrench,
        kind="vertical",
        e0: Equilibrium | None = None,
        require_all_visible=True,
        check=True,
        repeats: int = 1,
    ) -> PoseInfo:
        """Feasibility and the information block of one pose (the unloaded e0 may be reused)."""
        q = np.asarray(q, float)
        wrench = np.asarray(wrench, float)
        bad = self.feas.check_command(q) if check else []
        if check and any(r in bad for r in ("joint_limits", "degenerate_loop")):
            return PoseInfo(q, wrench, kind, np.zeros((0, self.n_params)), np.zeros(0, bool), bad)
        load = self.load_for(wrench)
        if e0 is None:
            e0 = self.solver.solve(q)
        e1 = self.solver.solve(q, load, warm=e0)
        if check:
            bad2, vis = self.feas.check_equilibria(e0, e1, require_all_visible)
            bad += [b for b in bad2 if b not in bad]
        else:
            vis = np.ones(len(self.robot.reflector_sites), bool)
        p0, j0 = self._site_jac(e0, None)
        p1, j1 = self._site_jac(e1, load)
        jac = (j1 - j0)[vis] * self.theta0  # normalised columns
        linv = np.linalg.inv(np.linalg.cholesky(self.sigma_dp(p0[vis], p1[vis], repeats)))
        block = linv @ jac.reshape(-1, self.n_params)
        return PoseInfo(q, wrench, kind, block, vis, bad, p1 - p0)

    def work_jacobian(self, q, wrench) -> np.ndarray:
        """G (3, p): d(payload-site deflection under the work wrench)/d(theta normalised)."""
        rb = self.robot
        load = self.load_for(wrench)
        e0 = self.solver.solve(np.asarray(q, float))
        e1 = self.solver.solve(np.asarray(q, float), load, warm=e0)
        out = []
        for e, ld in ((e0, None), (e1, load)):
            tan = self.solver.tangent(e, ld, self._dforce(e))
            m, d = rb.model, rb.data
            d.qpos[:] = e.qpos
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            mujoco.mj_jacSite(m, d, self._js, None, rb.payload_site)
            out.append(self._js @ tan)
        return (out[1] - out[0]) * self.theta0


# --------------------------------------------------------------------------- what a plan leaves unseen


def unseen_parameters(engine: InfoEngine, F: np.ndarray, q: np.ndarray, wrench: np.ndarray) -> dict[str, str]:
    """Each parameter that information F (p, p; parameters normalised by the prior, so the
    covariance F^-1 is relative) leaves undetermined, and why, in the words ``identify`` uses
    (identify/core/identifiability.py): structurally (analyze and explain: the rank of F at
    RANK_TOL, a zero column when no load turns a motor or no reflector moves with it) or
    statistically (resolve: a predicted std above MAX_RELATIVE_STD = 1 of the prior, so not even
    its sign is determined). ``q`` (n, joints) rad and ``wrench`` (n, 6) world N, N*m at the
    payload site: the plan's (or the candidates') commands and loads, for the facts the reasons
    need (each motor's load torque J_motor^T w at the rigid pose, paper eq. 12; the motor axes
    along gravity; the compensator joint's distinct angles). A k_i that no load turns but that F
    still sees faintly (the links' own weights, moved by the load's sag) is named for the torque.
    Empty when F determines every parameter."""
    F = 0.5 * (F + F.T)
    lam, vec = np.linalg.eigh(F)
    jw = (vec * np.sqrt(np.clip(lam, 0.0, None))) @ vec.T  # any factor of F has its rank and columns
    rb = engine.robot
    ident = analyze(jw, rb.layout.names)
    resolve(ident, np.ones(len(F)), held_covariance(F, ident.identifiable))
    if ident.identifiable.all():
        return {}
    facts = _plan_facts(rb, np.atleast_2d(q), np.atleast_2d(wrench))
    reasons = explain(ident, rb.layout, facts)
    for i, name in enumerate(ident.names):
        j = i if i < rb.n_act else -1
        if name in reasons and j >= 0 and ident.unresolved is not None and ident.unresolved[i]:
            if not facts["motor_torque_seen"][j]:
                rel = 100 * ident.relative_std[i]
                reasons[name] = (
                    f"no pose's load puts a torque on motor {j + 1} (the plan sees k{j + 1} only through "
                    f"the links' own weights moved by the load: to +-{rel:,.0f} %)"
                    if rel < 1e6
                    else f"no pose's load puts a torque on motor {j + 1} (the plan sees k{j + 1} only through "
                    f"the links' own weights moved by the load: to +-{rel:.1e} %)"
                )
    return reasons


def held_covariance(F: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """(p, p): F^-1 over the ``keep`` parameters with the others held (NaN there), from F's
    eigen-decomposition, so that a direction F sees only to working precision (a payload on a
    wrist axis: 1e-10 of the others) gets its honest, enormous variance, and one it does not see
    at all an infinite one. (A Cholesky inverse gives no answer for either, and taking no answer
    for "determined" let design write a plan that leaves k6 unseen.)"""
    p = len(F)
    cov = np.full((p, p), np.nan)
    idx = np.flatnonzero(keep)
    if idx.size == 0:
        return cov
    lam, vec = np.linalg.eigh(0.5 * (F + F.T)[np.ix_(idx, idx)])
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(lam > 0, 1.0 / np.where(lam > 0, lam, 1.0), np.inf)
        sub = (vec * inv) @ vec.T
        v2 = vec**2
        sub[np.diag_indices(idx.size)] = np.where(v2 > 0, v2 * inv, 0.0).sum(axis=1)
    cov[np.ix_(idx, idx)] = sub
    return cov


def _plan_facts(rb, q: np.ndarray, wrench: np.ndarray) -> dict:
    """identify/core's explain's facts for commands q and loads wrench (unseen_parameters)."""
    m, d = rb.model, mujoco.MjData(rb.model)
    g = m.opt.gravity / max(np.linalg.norm(m.opt.gravity), 1e-300)
    tau = np.zeros((len(q), rb.n_act))
    vertical = np.ones(rb.n_act, bool)
    for i, (qi, w) in enumerate(zip(q, wrench)):
        d.qpos[:] = rb.rigid_qpos(qi)
        mujoco.mj_fwdPosition(m, d)
        tau[i] = motor_jacobian(rb, d, rb.payload_site).T @ w
        vertical &= np.abs(d.xaxis[rb.act_joint] @ g) > 1 - 1e-9
    try:
        joint = rb.compensator_joint(0) if rb.description.compensators else None
    except ValueError:
        joint = None
    fmax = max(np.abs(wrench[:, :3]).max(), 1e-300)
    return {
        "motor_torque_seen": np.abs(tau).max(axis=0) > 1e-9 * max(np.abs(tau).max(), 1e-300),
        "loads_vertical": bool(np.all(np.abs(wrench[:, :2]) <= 1e-9 * fmax)),
        "vertical_axes": vertical,
        "compensator_joint": joint,
        "n_distinct_q2": 0 if joint is None else len(np.unique(np.round(q[:, joint], 9))),
    }
