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

import numpy as np

from calbench.bench.robot import Robot

from .forward import NP, PARAM_NAMES, PARAM_UNITS, ForwardModel, design_from_observations
from .identifiability import RANK_TOL, analyze, explain, whiten_factors
from .leastsq import Fit, covariance, levenberg_marquardt
from .observations import Observations
from .twostep import TwoStepResult, group_q2, plan_facts, two_step

GENERIC_COMPLIANCE = 1e-7     # rad/(N*m)
GENERIC_KC = 1e6              # N/m


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
            max_iter: int = 40, final_eval: bool = True, start_method: str = "given") -> Fit:
        """Fit to observations dp (M,3) with whitening factors linv (M,3,3).

        Iterates in phi = [k1..k6, K_C, P = K_C s0] (the compensator's force K_C (L - s0) is
        linear in K_C and P, as in eq. 21's unknowns), scaled by ``scale`` (|phi(start)| by
        default); reports theta = [k1..k6, K_C, s0 = P / K_C]. The maximum-likelihood point does
        not depend on the parametrisation; the iterations do (fewer here). The iterations are
        identify/leastsq.py's core; unidentifiable parameters (rank analysis at every iterate)
        are held at their start.
        start_eval: (f, J) already evaluated at ``start`` (saves one evaluation).
        """
        model = self.model
        phi0 = to_phi(np.array(start, dtype=float))
        scale = np.where(np.abs(phi0) > 0, np.abs(phi0), 1.0) if scale is None else np.asarray(scale)
        yw = np.einsum("mij,mj->mi", linv, dp).reshape(-1)
        n_eval0 = model.stats["evaluations"]

        def whiten(ph, f, j):
            fw = np.einsum("mij,mj->mi", linv, f).reshape(-1)
            jw = np.einsum("mij,mjk->mik", linv, j).reshape(-1, NP) @ dtheta_dphi(ph)
            return fw, jw

        def evaluate(ph):
            return whiten(ph, *model.evaluate(to_theta(ph)))

        sol = levenberg_marquardt(
            evaluate, yw, phi0, scale, valid=valid_phi,
            free_fn=lambda jw: analyze(jw, PARAM_NAMES).identifiable,
            step_tol=step_tol, rank_tol=RANK_TOL, max_iter=max_iter, max_damping=30,
            accept_within_sigma=True, final_eval=final_eval,
            start_eval=None if start_eval is None else whiten(phi0, *start_eval))
        phi = sol.x
        ident = analyze(sol.j_w * scale, PARAM_NAMES)
        free = ident.identifiable
        cov_phi, _ = covariance(sol.j_w * scale, free, scale, RANK_TOL)
        cov_phi[np.isnan(cov_phi)] = 0.0
        dt = dtheta_dphi(phi)
        cov = dt @ cov_phi @ dt.T
        theta = to_theta(phi)
        bad = ~free.copy()
        bad[7] = bad[6] or bad[7]           # s0 = P / K_C needs both
        cov[bad, :] = np.nan
        cov[:, bad] = np.nan
        explain(ident, motor_torque_seen=self.facts["motor_torque_seen"],
                loads_vertical=self.facts["loads_vertical"],
                n_distinct_q2=self.facts["n_distinct_q2"],
                compensator_in_model=self.robot.tendon >= 0)
        reasons = dict(ident.reasons)
        if bad[7] and "compensator_preload" not in reasons:
            reasons["compensator_preload"] = "s0 = (K_C s0) / K_C and K_C is not identified"
        resid_w = sol.r_w.reshape(-1, 3)
        resid = np.einsum("mij,mj->mi", np.linalg.inv(linv), resid_w)
        return Fit(theta, cov, ~bad, resid, resid_w, sol.cost, sol.r_w.size, int(free.sum()), sol.iterations, model.stats["evaluations"] - n_eval0, sol.converged,
                   sol.seconds, names=PARAM_NAMES, units=PARAM_UNITS, reasons=reasons,
                   start=np.array(start, float), start_method=start_method, ident=ident, model=model,
                   robot=self.robot)


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
             two: TwoStepResult | None = None, **kw) -> Fit:
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


__all__ = ["Fit", "OneStep", "one_step", "generic_start", "sanitize_start"]
