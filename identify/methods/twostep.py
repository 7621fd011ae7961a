"""The paper's two-step identification (Klimchik, Magid & Pashkevich 2016, §4).

Where it applies (:func:`two_step_applies`): the paper's robot has one spring compensator, on
J2, and a parallelogram. Step 1 is the linear VJM model of any robot (loops enter through the
motor-space Jacobians, §3.4); step 2 separates ONE compensator from the stiffness of the joint
it spans, through the triangle geometry of eqs. 21-22. So the method applies to a robot with
at most one compensator tendon, spanning exactly one actuated hinge (written "J2" and "q2"
below, as in the paper: the compensator's joint, whatever its index; a serial robot without a
compensator has step 1 only). Other robots (two or more compensators, a spring across several
joints) are refused with :class:`TwoStepError`; the one-step estimator handles every robot.

Step 1 (eqs. 19-20, built on eq. 4). At the nominal unloaded configuration of pose j (the
rigid closed-loop pose at the command: the parameters are unknown, so is the deflection) the
loop-closed motor-space Jacobians J_r (reflector r) and J_L (load site) give, for each motor i,
the generalised force the wrench W = [F; M] puts on it, tau_ji = J_L,i^T W, and the linear model

    dp_jr = sum_i J_r,i[:3] k_i tau_ji = B_jr k,   column i of B_jr = J_r,i[:3] * tau_ji.

This is eq. (4) (A_j = J_j J_j^T W) generalised to a load point other than the measured point,
positions only (eq. 2); on the FANUC motor 3 is the crank (§3.4: the Jacobian is taken with
respect to it). The compensator joint's k2 is split per distinct q2 (values equal within 1e-6 rad
form one group): k = [k1, k2_1..k2_m, k3..kN]. Unlike eq. (20), which is unweighted, every dp is weighted by its tracker covariance
(identical to eq. 20 for an isotropic tracker with equal repeats); cov(k) = (B^T Sigma^-1 B)^-1.

Step 2 (eqs. 21-22, with the sin^2 correction of PHYSICS.md and the compensator angle of the
model, psi = q2 + offset measured from the MJCF sites). With K_2i = 1/k2_i,

    K_2i = K_theta2 + K_C l_c l_2 eta(psi_i),  eta = (1 - s0/s) cos psi + s0 l_c l_2 sin^2 psi / s^3
    C_i  = [1, l_c l_2 cos psi_i, l_c l_2 (l_c l_2 sin^2 psi_i / s_i^3 - cos psi_i / s_i)]

fitted for x = [K_theta2, K_C, s0 K_C]; k2 = 1/K_theta2, s0 = x_3 / x_2. Two variants:
``weighted=False`` is the paper's eq. (21) (ordinary LS); ``weighted=True`` uses the step-1
covariance of the K_2i (delta method, correlations kept) as GLS weights. With exactly three
distinct q2 (the paper's plan) step 2 is exactly determined and the two coincide. The reported
covariance of both propagates step 1's full covariance through step 2 (delta method).

What the linear model leaves out: gravity's and the load's geometric stiffness (H00, eq. 18),
the Jacobian's change over the gravity deflection, and the compensator's nonlinearity over the
deflection. The one-step estimator (identify/methods/onestep.py) has none of these approximations.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import mujoco
import numpy as np

from calbench.bench.model import Robot, motor_jacobians
from calbench.identify.core import Identifiability, Observations, Whitener, analyze, explain

from .base import IdentifyOptions, Method, MethodResult, NotApplicable, Repeats

Q2_GROUP_TOL = 1e-6  # rad
REQUIREMENT = "a robot with at most one compensator, across one actuated hinge (paper §4)"


class TwoStepError(NotApplicable):
    """The robot is outside what the two-step method models (see the module docstring)."""


def two_step_applies(robot: Robot) -> int | None:
    """The compensator joint's index (controller order; None without a compensator) when the
    two-step method applies to the robot; TwoStepError saying why not otherwise."""
    names = robot.description.compensators
    if len(names) > 1:
        raise TwoStepError(
            f"the two-step method (paper §4, eqs. 19-22) separates one compensator "
            f"spring; this robot has {len(names)} ({', '.join(names)}): use the one-step method"
        )
    if not names:
        return None
    try:
        return robot.compensator_joint(0)
    except ValueError as exc:
        raise TwoStepError(
            f"the two-step method (paper §4, eqs. 21-22) needs the compensator across one "
            f"actuated hinge: {exc}; use the one-step method"
        ) from None


def group_q2(q2: np.ndarray, tol: float = Q2_GROUP_TOL) -> tuple[np.ndarray, np.ndarray]:
    """Group labels (n,) and the group values (m,) of q2 angles equal within ``tol``."""
    values: list[float] = []
    labels = np.empty(len(q2), dtype=int)
    for i, v in enumerate(q2):
        for g, u in enumerate(values):
            if abs(v - u) <= tol:
                labels[i] = g
                break
        else:
            values.append(float(v))
            labels[i] = len(values) - 1
    return labels, np.array(values)


@dataclass
class LinearPlan:
    """Step 1's regressors: per observation row (M,3,N) motor columns J_r,i[:3] tau_i.
    "q2" is the compensator joint's angle (``joint``; None and no groups without one)."""

    cols: np.ndarray  # (M, 3, N): dp = sum_i cols[:, :, i] k_i
    tau: np.ndarray  # (n_poses, N) motor torques of each pose's load
    q2_group: np.ndarray  # (n_poses,) group label
    q2_values: np.ndarray  # (m,) distinct q2
    rows_pose: np.ndarray  # (M,) index into obs.poses of each observation row
    joint: int | None = None  # the compensator's joint (controller order)
    vertical: np.ndarray | None = None  # (N,) motor axis along gravity at every pose


@dataclass
class PoseRows:
    """One pose's share of a LinearPlan: its reflectors' motor columns and its load's torques."""

    cols: np.ndarray  # (n_refl, 3, N)
    tau: np.ndarray  # (N,)
    vertical: np.ndarray  # (N,) bool: the motor axis along gravity at this pose


def pose_rows(robot: Robot, data: mujoco.MjData, pose, qpos: np.ndarray) -> PoseRows:
    """Step 1's regressors of one pose (eq. 19) at the configuration ``qpos``."""
    m = robot.model
    site = lambda n: mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, n)  # noqa: E731
    g = m.opt.gravity / max(np.linalg.norm(m.opt.gravity), 1e-300)
    data.qpos[:] = qpos
    mujoco.mj_fwdPosition(m, data)
    vertical = np.abs(data.xaxis[robot.act_joint] @ g) > 1 - 1e-9
    jl, *jrs = motor_jacobians(robot, data, [site(pose.site)] + [site(r) for r in pose.reflectors])
    tau = jl.T @ np.concatenate([pose.force, pose.moment])
    cols = np.array([jr[:3] * tau[None, :] for jr in jrs]).reshape(-1, 3, robot.n_act)
    return PoseRows(cols, tau, vertical)


def plan_from_rows(
    robot: Robot, obs: Observations, rows: list[PoseRows], q2_at: np.ndarray | None = None
) -> LinearPlan:
    """The LinearPlan of the poses' rows (in obs.poses order). ``q2_at`` (n_poses,): the
    compensator angle of each pose's configuration, when it is not the command (group means)."""
    try:
        joint = two_step_applies(robot)
    except TwoStepError:  # step 1's regressors hold for any robot; no k is split then
        joint = None
    n_act = robot.n_act
    vertical = np.ones(n_act, bool)
    for r in rows:
        vertical &= r.vertical
    if joint is None:
        labels, values = np.zeros(len(obs.poses), dtype=int), np.zeros(0)
    else:
        labels, values = group_q2(np.array([p.q[joint] for p in obs.poses]))
        if q2_at is not None:  # the compensator angle at the given configurations (group means)
            values = np.array([q2_at[labels == g].mean() for g in range(len(values))])
    return LinearPlan(
        np.concatenate([r.cols for r in rows]) if rows else np.zeros((0, 3, n_act)),
        np.array([r.tau for r in rows]).reshape(-1, n_act),
        labels,
        values,
        np.array([k for k, r in enumerate(rows) for _ in range(len(r.cols))], dtype=int),
        joint,
        vertical,
    )


def linear_plan(robot: Robot, obs: Observations, qpos: dict | None = None) -> LinearPlan:
    """Motor torques and reflector motor Jacobians at each pose's rigid configuration.

    ``qpos`` (pose index -> full qpos) replaces the rigid configuration: a diagnostic only (the
    Monte Carlo's "oracle" variant evaluates the linear model at the TRUE unloaded equilibrium,
    with the compensator angle at the true q2 of each group, to separate the cost of the sag
    from the cost of H00); identification never passes it.
    """
    d = mujoco.MjData(robot.model)
    at = {p.index: robot.rigid_qpos(p.q) for p in obs.poses} if qpos is None else qpos
    rows = [pose_rows(robot, d, p, at[p.index]) for p in obs.poses]
    q2_at = None
    if qpos is not None and rows:
        try:
            joint = two_step_applies(robot)
        except TwoStepError:
            joint = None
        if joint is not None:
            q2_at = np.array([qpos[p.index][robot.act_qpos[joint]] for p in obs.poses])
    return plan_from_rows(robot, obs, rows, q2_at)


def plan_facts(robot: Robot, obs: Observations, lp: LinearPlan | None = None) -> dict:
    """Structural facts used to explain unidentifiable parameters."""
    lp = lp or linear_plan(robot, obs)
    tau = np.abs(lp.tau)
    seen = tau.max(axis=0) > 1e-9 * max(tau.max(), 1e-300) if tau.size else np.zeros(robot.n_act, bool)
    forces = np.array([p.force for p in obs.poses])
    moments = np.array([p.moment for p in obs.poses])
    fmax = max(np.abs(forces).max(), 1e-300)
    vertical = bool(
        np.all(np.abs(forces[:, :2]) <= 1e-9 * fmax) and np.all(np.abs(moments[:, 2]) <= 1e-9 * fmax)
    )
    return {
        "motor_torque_seen": seen,
        "loads_vertical": vertical,
        "vertical_axes": lp.vertical,
        "compensator_joint": lp.joint,
        "n_distinct_q2": int(len(lp.q2_values)),
        "q2_values": lp.q2_values,
    }


@dataclass
class TwoStepResult:
    theta: np.ndarray  # (P,) NaN where not identified (the robot's layout)
    cov: np.ndarray  # (P,P) NaN rows/cols where not identified
    identifiable: np.ndarray  # (P,) bool
    reasons: dict[str, str]
    step1_names: list[str]
    step1_k: np.ndarray  # step-1 estimate, NaN where not identified
    step1_cov: np.ndarray
    q2_values: np.ndarray
    residual: np.ndarray  # (M,3) dp - B k, m
    residual_w: np.ndarray  # (M,3) whitened
    chi2: float
    dof: int
    step2: dict = field(default_factory=dict)
    ident: Identifiability | None = None


def step1_columns(lp: LinearPlan) -> list[tuple[int, int | None]]:
    """Step 1's unknowns in order: (motor i, q2 group or None), the compensator joint's k split
    per group."""
    n_act = lp.cols.shape[2]
    return [(i, g) for i in range(n_act) for g in (range(len(lp.q2_values)) if i == lp.joint else (None,))]


def step1(lp: LinearPlan, dp: np.ndarray, white: Whitener):
    """Weighted LS of eqs. (19)-(20). Returns k, cov, names, whitened B, identifiability."""
    unknowns = step1_columns(lp)
    nk = len(unknowns)
    names = [
        f"k{i + 1}" if g is None else f"k{i + 1}@{np.degrees(lp.q2_values[g]):.6g}deg" for i, g in unknowns
    ]
    M = lp.cols.shape[0]
    b = np.zeros((M, 3, nk))
    g_row = lp.q2_group[lp.rows_pose]
    for col, (i, g) in enumerate(unknowns):
        if g is None:
            b[:, :, col] = lp.cols[:, :, i]
        else:
            rows = g_row == g
            b[rows, :, col] = lp.cols[rows, :, i]
    bw = white.mat(b)
    yw = white.vec(dp)
    ident = analyze(bw, tuple(names))
    keep = ident.identifiable
    k = np.full(nk, np.nan)
    cov = np.full((nk, nk), np.nan)
    if keep.any():
        sol, *_ = np.linalg.lstsq(bw[:, keep], yw, rcond=None)
        k[keep] = sol
        cov[np.ix_(keep, keep)] = np.linalg.inv(bw[:, keep].T @ bw[:, keep])
    return k, cov, names, b, bw, yw, ident


def step2_rows(geom, q2_values: np.ndarray) -> np.ndarray:
    """C_i of eq. (22) with sin^2 (PHYSICS.md), psi = q2 + offset (m, 3)."""
    psi = np.array([geom.angle(v) for v in q2_values])
    s = np.array([geom.length(v) for v in q2_values])
    ll = geom.l_c * geom.l_2
    return np.column_stack(
        [np.ones_like(psi), ll * np.cos(psi), ll * (ll * np.sin(psi) ** 2 / s**3 - np.cos(psi) / s)]
    )


def two_step(
    robot: Robot,
    obs: Observations,
    weighted: bool = False,
    lp: LinearPlan | None = None,
    white: Whitener | None = None,
) -> TwoStepResult:
    """Paper §4 on the observations. ``weighted``: GLS step 2 (else the paper's eq. 21).
    TwoStepError when the robot is outside the method (module docstring)."""
    two_step_applies(robot)
    lp = lp or linear_plan(robot, obs)
    lay = robot.layout
    npar = lay.n
    dp = obs.dp
    white = Whitener.from_observations(obs) if white is None else white
    k, kcov, names, b, bw, yw, ident = step1(lp, dp, white)
    m = len(lp.q2_values)
    M = dp.shape[0]
    kk = np.where(np.isfinite(k), k, 0.0)
    resid = dp - np.einsum("mij,j->mi", b, kk)
    resid_w = white.vec(resid).reshape(-1, 3)
    dof = 3 * M - int(ident.identifiable.sum())
    chi2 = float((resid_w**2).sum())

    theta = np.full(npar, np.nan)
    # map step-1 entries to theta: k_i -> i for every motor but the compensator's joint
    unknowns = step1_columns(lp)
    idx = {col: i for col, (i, g) in enumerate(unknowns) if g is None}
    split = [col for col, (_, g) in enumerate(unknowns) if g is not None]  # the k2_i columns
    hmat = np.zeros((npar, len(k)))  # d theta / d k (delta method), filled where defined
    ok = np.zeros(npar, bool)
    for src, dst in idx.items():
        if ident.identifiable[src]:
            theta[dst] = k[src]
            hmat[dst, src] = 1.0
            ok[dst] = True
    step2_info: dict = {"n_distinct_q2": m, "weighted": weighted}
    k2i = k[split]
    j2 = lp.joint
    if j2 is not None and m >= 3 and np.all(np.isfinite(k2i)) and np.all(k2i > 0):
        geom = robot.compensator_geometry(0)
        i_kc, i_s0 = int(lay.stiffness_index[0]), int(lay.preload_index[0])
        c = step2_rows(geom, lp.q2_values)
        big_k = 1.0 / k2i
        dk = np.diag(-1.0 / k2i**2)  # d K_2i / d k2_i
        cov_big = dk @ kcov[np.ix_(split, split)] @ dk.T
        if weighted:
            wmat = np.linalg.inv(cov_big)
            gmat = np.linalg.solve(c.T @ wmat @ c, c.T @ wmat)
        else:
            gmat = np.linalg.solve(c.T @ c, c.T)  # eq. (21)
        x = gmat @ big_k
        k_theta2, k_c, s0kc = x
        if k_theta2 > 0 and k_c != 0:
            theta[j2] = 1.0 / k_theta2
            theta[i_kc] = k_c
            theta[i_s0] = s0kc / k_c
            # d(k2, K_C, s0)/dx, then dx/dk2_i = G dK/dk
            dtx = np.array([[-1.0 / k_theta2**2, 0, 0], [0, 1.0, 0], [0, -s0kc / k_c**2, 1.0 / k_c]])
            hmat[np.ix_([j2, i_kc, i_s0], split)] = dtx @ gmat @ dk
            ok[[j2, i_kc, i_s0]] = True
        step2_info.update(
            {
                "rows_C": c.tolist(),
                "K2_aggregated": big_k.tolist(),
                "K_theta2": float(k_theta2),
                "K_C": float(k_c),
                "s0_K_C": float(s0kc),
                "l_c": geom.l_c,
                "l_2": geom.l_2,
                "psi_offset_rad": geom.offset,
                "residual_K2": (big_k - c @ x).tolist(),
            }
        )
    kc0 = np.where(np.isfinite(kcov), kcov, 0.0)
    cov = hmat @ kc0 @ hmat.T
    cov[~ok, :] = np.nan
    cov[:, ~ok] = np.nan

    # reasons: step 1's rank analysis mapped to theta names, plus step 2's requirement
    facts = plan_facts(robot, obs, lp)
    pnames = lay.names
    theta_ident = Identifiability(
        pnames, ident.singular_values, ident.rank, ok.copy(), np.zeros((npar, 0)), np.ones(npar)
    )
    reasons: dict[str, str] = {}
    for src, dst in idx.items():
        if not ident.identifiable[src]:
            sub = explain(ident, lay, facts)
            reasons[pnames[dst]] = sub.get(names[src], "not identified by step 1")
    if j2 is not None and not ok[j2]:
        q, jn = f"q{j2 + 1}", f"J{j2 + 1}"
        if m < 3:
            why = (
                f"only {m} distinct {q} in the plan: step 2 (eqs. 21-22) needs the aggregated "
                f"{jn} stiffness at three or more {q} to separate K_theta{j2 + 1}, K_C and s0"
            )
        else:
            why = (
                f"step 1 did not identify every aggregated {jn} stiffness k{j2 + 1}_i, or step 2 "
                f"gave K_theta{j2 + 1} <= 0"
            )
        for n in (pnames[j2], pnames[lay.stiffness_index[0]], pnames[lay.preload_index[0]]):
            reasons[n] = why
    theta_ident.reasons = reasons
    return TwoStepResult(
        theta, cov, ok, reasons, names, k, kcov, lp.q2_values, resid, resid_w, chi2, dof, step2_info, ident
    )


# --------------------------------------------------------------------------- the family's face


def two_step_result(r: TwoStepResult, method: str, robot: Robot) -> MethodResult:
    """The family's result of a two-step solve (plain, weighted or iterated); its details are
    step 1's per-q2 stiffnesses (names, estimates, stds) and step 2's record."""
    details = {
        "step1": {
            "names": r.step1_names,
            "estimate": [None if not np.isfinite(x) else float(x) for x in r.step1_k],
            "std": [None if not np.isfinite(x) else float(math.sqrt(x)) for x in np.diag(r.step1_cov)],
        },
        "step2": r.step2,
    }
    lay = robot.layout
    return MethodResult(
        method,
        lay.names,
        lay.units,
        r.theta,
        r.cov,
        r.identifiable,
        dict(r.reasons),
        r.residual,
        r.residual_w,
        float(r.chi2),
        int(r.dof),
        details=details,
    )


def _two_step_method(name: str, weighted: bool, **kw) -> Method:
    """The paper's two-step (``weighted``: GLS step 2) as a method of the family. Its Monte
    Carlo reuses the exact readings' linear plan (it depends on the commands and loads only)."""

    def estimate(robot: Robot, obs: Observations, options: IdentifyOptions) -> MethodResult:
        return two_step_result(two_step(robot, obs, weighted), name, robot)

    def repeat(robot: Robot, obs0: Observations, white0: Whitener) -> Repeats:
        lp = linear_plan(robot, obs0)

        def run(obs: Observations, white: Whitener) -> MethodResult:
            return two_step_result(two_step(robot, obs, weighted, lp=lp, white=white), name, robot)

        return Repeats(run(obs0, white0), run)

    return Method(
        name,
        estimate,
        applies=two_step_applies,
        requirement=REQUIREMENT,
        repeat=repeat,
        seconds_per_run=0.002,  # in-process, per Monte Carlo run on the paper campaign (measured)
        noise_free_always=True,
        **kw,
    )


TWO_STEP = _two_step_method(
    "two-step",
    False,
    summary="the paper's §4, for robots with at most one compensator across one actuated hinge",
)
# step 2 weighted by step 1's covariance: a Monte Carlo comparison, not offered by `identify`
TWO_STEP_WEIGHTED = _two_step_method(
    "two-step-weighted",
    True,
    summary="the same, step 2 weighted by step 1's covariance",
    group="two-step",
    offered=False,
)


__all__ = [
    "group_q2",
    "LinearPlan",
    "linear_plan",
    "PoseRows",
    "pose_rows",
    "plan_from_rows",
    "plan_facts",
    "TwoStepResult",
    "TwoStepError",
    "two_step_applies",
    "step1",
    "step1_columns",
    "step2_rows",
    "two_step",
    "two_step_result",
    "Q2_GROUP_TOL",
    "REQUIREMENT",
    "TWO_STEP",
    "TWO_STEP_WEIGHTED",
]
