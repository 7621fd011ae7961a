"""One-step identification: all eight parameters at once on the exact statics (the default).

Weighted least squares on the exact forward model of identify/forward.py:

    theta_hat = argmin sum_jr (dp_jr - f_jr(theta))^T Cov_jr^-1 (dp_jr - f_jr(theta))

by Gauss-Newton with Levenberg-Marquardt damping when a step does not lower the cost. This is
the maximum-likelihood estimate for Gaussian tracker noise, and with the exact statics it has
none of the linear model's approximations (no H00 left out, eq. 18; the compensator through
its real geometry rather than eqs. 21-22; Jacobians at the deflected equilibria). Where the
paper solves eq. (20) once, we iterate because the model is nonlinear in theta.

* Parameters are normalised, u = theta / scale with scale = |start| (a generic size where the
  start is zero), so the normal matrix is well conditioned; the identifiability analysis
  further normalises columns (identify/identifiability.py).
* Start: the two-step estimate (paper §4), its invalid entries (not identified, a non-positive
  compliance or compensator stiffness) replaced by generic values: compliance 1e-7 rad/(N*m),
  K_C 1e6 N/m, s0 the mean spring length over the plan's q2 from the geometry. Never values
  from the MJCF.
* Stopping rule on the Gauss-Newton step in standard deviations, s_k = max_i |du_i| / sd_i:
  stop when s_k < ``step_tol`` or, with the observed contraction rho = s_k / s_(k-1) < 0.5,
  when the remaining error after applying the step, rho s_k / (1 - rho), is below ``step_tol``;
  the last step is applied. The estimate is then within ~step_tol sigma of the fixed point.
  Default 1e-6 for a single identification (solver precision, a few extra evaluations); the
  Monte Carlo uses 1e-2 (adds < 1e-4 to a variance ratio), which on the paper plan usually
  stops after one evaluation (rho ~ 0.03 there).
* Unidentifiable parameters (rank analysis at each iterate) are held at their start and
  reported as null.
* Covariance: inverse Fisher information (J^T Sigma^-1 J)^-1 at the estimate (at the last
  linearisation point when ``final_eval`` is False, within a step of it).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calbench.bench.robot import Robot

from .forward import NP, PARAM_NAMES, ForwardModel, design_from_observations
from .identifiability import Identifiability, analyze, explain, whiten_factors
from .observations import Observations
from .twostep import TwoStepResult, group_q2, plan_facts, two_step

GENERIC_COMPLIANCE = 1e-7     # rad/(N*m)
GENERIC_KC = 1e6              # N/m


@dataclass
class FitResult:
    theta: np.ndarray               # (8,) NaN where not identifiable
    cov: np.ndarray                 # (8,8) NaN rows/cols where not identifiable
    identifiable: np.ndarray
    reasons: dict[str, str]
    residual: np.ndarray            # (M,3) dp - f(theta), m
    residual_w: np.ndarray          # (M,3) whitened
    chi2: float
    dof: int
    iterations: int
    evaluations: int
    converged: bool
    start: np.ndarray
    start_method: str
    ident: Identifiability | None = None
    extra: dict = field(default_factory=dict)


def generic_start(robot: Robot, obs: Observations) -> np.ndarray:
    """Generic starting values (no MJCF stiffness): see the module docstring."""
    theta = np.full(NP, GENERIC_COMPLIANCE)
    theta[6] = GENERIC_KC
    if robot.tendon >= 0:
        geom = robot.compensator_geometry()
        _, q2 = group_q2(np.array([p.q[1] for p in obs.poses]))
        theta[7] = float(np.mean([geom.length(v) for v in q2]))
    else:
        theta[7] = 1.0
    return theta


def sanitize_start(theta: np.ndarray, generic: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """Replace NaN or physically invalid entries by generic values; names the replaced ones."""
    out = np.array(theta, dtype=float)
    bad = ~np.isfinite(out)
    bad[:6] |= out[:6] <= 0
    bad[6] |= out[6] <= 0
    bad[7] |= out[7] <= 0
    # the compensator pair is only meaningful together
    if bad[6] or bad[7]:
        bad[6] = bad[7] = True
    out[bad] = generic[bad]
    return out, [PARAM_NAMES[i] for i in np.flatnonzero(bad)]


class OneStep:
    """A reusable one-step estimator for one design (the Monte Carlo reuses it across runs)."""

    def __init__(self, robot: Robot, obs: Observations, model: ForwardModel | None = None):
        self.robot = robot
        self.obs = obs
        self.model = model or ForwardModel(robot, design_from_observations(robot, obs))
        self.facts = plan_facts(robot, obs)

    def fit(self, dp: np.ndarray, linv: np.ndarray, start: np.ndarray, *, scale=None,
            start_eval: tuple[np.ndarray, np.ndarray] | None = None, step_tol: float = 1e-6,
            max_iter: int = 40, final_eval: bool = True, start_method: str = "given") -> FitResult:
        """Fit to observations dp (M,3) with whitening factors linv (M,3,3).

        Iterates in phi = [k1..k6, K_C, P = K_C s0] (the compensator's force K_C (L - s0) is
        linear in K_C and P, as in eq. 21's unknowns), scaled by ``scale`` (|phi(start)| by
        default); reports theta = [k1..k6, K_C, s0 = P / K_C]. The maximum-likelihood point does
        not depend on the parametrisation; the iterations do (fewer here).
        start_eval: (f, J) already evaluated at ``start`` (saves one evaluation).
        """
        model = self.model
        phi = to_phi(np.array(start, dtype=float))
        scale = np.where(np.abs(phi) > 0, np.abs(phi), 1.0) if scale is None else np.asarray(scale)
        yw = np.einsum("mij,mj->mi", linv, dp).reshape(-1)
        n_eval0 = model.stats["evaluations"]

        def lin(ph, fj=None):
            th = to_theta(ph)
            f, j = fj if fj is not None else model.evaluate(th)
            fw = np.einsum("mij,mj->mi", linv, f).reshape(-1)
            jw = np.einsum("mij,mjk->mik", linv, j).reshape(-1, NP) @ dtheta_dphi(ph) * scale
            return fw, jw

        fw, jw = lin(phi, start_eval)
        rw = yw - fw
        cost = float(rw @ rw)
        lam = 0.0
        converged = False
        it = 0
        prev_step = np.inf
        ident = analyze(jw, PARAM_NAMES)
        for it in range(1, max_iter + 1):
            ident = analyze(jw, PARAM_NAMES)
            free = ident.identifiable
            jf = jw[:, free]
            jtj = jf.T @ jf
            g = jf.T @ rw
            std_u = np.sqrt(np.diag(np.linalg.inv(jtj)))
            du = np.linalg.solve(jtj, g)
            step = float(np.max(np.abs(du) / std_u))    # Gauss-Newton step in sigmas
            prev, prev_step = prev_step, step
            rho = step / prev if np.isfinite(prev) else np.inf   # observed contraction of the steps
            if step < step_tol or (np.isfinite(prev) and rho < 0.5 and rho / (1 - rho) * step < step_tol):
                # the remaining error after this step (geometric series) is below step_tol sigma
                phi[free] += scale[free] * du
                rw = rw - jf @ du
                cost = float(rw @ rw)
                converged = True
                break
            accepted = False
            for _ in range(30):
                if lam > 0:
                    du = np.linalg.solve(jtj + lam * np.diag(np.diag(jtj)), g)
                trial = phi.copy()
                trial[free] += scale[free] * du
                if not valid_phi(trial):
                    lam = max(10 * lam, 1e-3)
                    continue
                try:
                    fw_t, jw_t = lin(trial)
                except (RuntimeError, ValueError):
                    lam = max(10 * lam, 1e-3)
                    continue
                rw_t = yw - fw_t
                cost_t = float(rw_t @ rw_t)
                # Within one sigma of the optimum the undamped Gauss-Newton step is taken without
                # a cost test: there the cost changes by ~step^2, which for tiny steps is below
                # the cost's round-off (solver precision ~1e-6 sigma per residual).
                if (lam == 0.0 and step < 1.0) or cost_t <= cost:
                    phi, fw, jw, rw, cost = trial, fw_t, jw_t, rw_t, cost_t
                    lam = lam / 10 if lam > 1e-6 else 0.0
                    accepted = True
                    break
                lam = max(10 * lam, 1e-3)
            if not accepted:
                break
        if final_eval:
            fw, jw = lin(phi)
            rw = yw - fw
            cost = float(rw @ rw)
            ident = analyze(jw, PARAM_NAMES)
        free = ident.identifiable
        jf = jw[:, free]
        cov_phi = np.zeros((NP, NP))
        cov_phi[np.ix_(free, free)] = np.linalg.inv(jf.T @ jf) * np.outer(scale[free], scale[free])
        dt = dtheta_dphi(phi)
        cov = dt @ cov_phi @ dt.T
        theta = to_theta(phi)
        bad = ~free.copy()
        bad[7] = bad[6] or bad[7]           # s0 = P / K_C needs both
        cov[bad, :] = np.nan
        cov[:, bad] = np.nan
        est = theta.copy()
        est[bad] = np.nan
        explain(ident, motor_torque_seen=self.facts["motor_torque_seen"],
                loads_vertical=self.facts["loads_vertical"],
                n_distinct_q2=self.facts["n_distinct_q2"],
                compensator_in_model=self.robot.tendon >= 0)
        reasons = dict(ident.reasons)
        if bad[7] and "compensator_preload" not in reasons:
            reasons["compensator_preload"] = "s0 = (K_C s0) / K_C and K_C is not identified"
        resid_w = rw.reshape(-1, 3)
        resid = np.einsum("mij,mj->mi", np.linalg.inv(linv), resid_w)
        return FitResult(est, cov, ~bad, reasons, resid, resid_w, cost,
                         int(rw.size - free.sum()), it, model.stats["evaluations"] - n_eval0,
                         converged, np.array(start, float), start_method, ident)


def to_phi(theta: np.ndarray) -> np.ndarray:
    """[k, K_C, s0] -> [k, K_C, P = K_C s0]."""
    phi = np.array(theta, dtype=float)
    phi[7] = theta[6] * theta[7]
    return phi


def to_theta(phi: np.ndarray) -> np.ndarray:
    theta = np.array(phi, dtype=float)
    theta[7] = phi[7] / phi[6]
    return theta


def dtheta_dphi(phi: np.ndarray) -> np.ndarray:
    d = np.eye(NP)
    d[7, 6] = -phi[7] / phi[6] ** 2
    d[7, 7] = 1.0 / phi[6]
    return d


def valid_phi(phi: np.ndarray) -> bool:
    return bool(np.all(np.isfinite(phi)) and np.all(phi[:6] > 0) and phi[6] > 0 and phi[7] > 0)


def one_step(robot: Robot, obs: Observations, start: np.ndarray | None = None,
             two: TwoStepResult | None = None, **kw) -> FitResult:
    """Identify all parameters at once from the observations (see the module docstring)."""
    est = OneStep(robot, obs)
    linv = whiten_factors(obs.cov)
    generic = generic_start(robot, obs)
    method = "given"
    replaced: list[str] = []
    if start is None:
        try:
            two = two or two_step(robot, obs)
            start, replaced = sanitize_start(two.theta, generic)
            method = "two-step" if not replaced else "two-step (generic: " + ", ".join(replaced) + ")"
        except (np.linalg.LinAlgError, ValueError):
            start, method = generic, "generic"
    res = est.fit(obs.dp, linv, start, start_method=method, **kw)
    res.extra["start_replaced"] = replaced
    return res


__all__ = ["FitResult", "OneStep", "one_step", "generic_start", "sanitize_start"]
