"""One-step identification: all parameters at once on the exact statics (the default).

Weighted least squares on the exact forward model of identify/core/forward.py:

    theta_hat = argmin sum_jr (dp_jr - f_jr(theta))^T Cov_jr^-1 (dp_jr - f_jr(theta))

by Gauss-Newton with Levenberg-Marquardt damping when a step does not lower the cost. This is
the maximum-likelihood estimate for Gaussian tracker noise, and with the exact statics it has
none of the linear model's approximations (no H00 left out, eq. 18; the compensator through
its real geometry rather than eqs. 21-22; Jacobians at the deflected equilibria). Where the
paper solves eq. (20) once, we iterate because the model is nonlinear in theta.

* Parameters are normalised, u = theta / scale with scale = |start| (a generic size where the
  start is zero), so the normal matrix is well conditioned; the identifiability analysis
  further normalises columns (identify/core/identifiability.py).
* Start: the two-step estimate (paper §4) where it applies, its invalid entries (not
  identified, a non-positive compliance or compensator stiffness) replaced by generic values
  (bench/model/params.py): compliance 1e-7 rad/(N*m), K_C 1e6 N/m, s0 each spring's mean length over
  the plan's angles of the joint it spans, from the geometry. Never values from the MJCF.
  A two-step start can be valid and still far off (a plan whose step 2 is ill-posed: on a
  designed KR 270 plan with exact data it gave K_C 20x and s0 0.2x the truth; the fit from there
  did not converge in 40 iterations while the forward model's Jacobian went stale on the way,
  and converges since identify/core/forward.py's KKT_QTOL); when the fit from it does not converge,
  it is repeated from the generic start and the fit with the lower chi2 is kept (:func:`fit_from`).
* Stopping rule on the Gauss-Newton step in standard deviations, s_k = max_i |du_i| / sd_i:
  stop when s_k < ``step_tol`` or, with the observed contraction rho = s_k / s_(k-1) < 0.5,
  when the remaining error after applying the step, rho s_k / (1 - rho), is below ``step_tol``;
  the last step is applied. The estimate is then within ~step_tol sigma of the fixed point.
  Default 1e-6 for a single identification (solver precision, a few extra evaluations); the
  Monte Carlo uses 1e-2 (adds < 1e-4 to a variance ratio), which on the paper plan usually
  stops after one evaluation (rho ~ 0.03 there).
* Unidentifiable parameters (rank analysis at each iterate) are held at their start and
  reported as null; so are parameters the rank keeps but the noise buries (relative standard
  deviation above 1 at the estimate: identify/core/identifiability.py's :func:`resolve`), which are
  estimated with the others -- the others' covariances stay marginal over them -- and then
  reported as null with the reason.
* Covariance: inverse Fisher information (J^T Sigma^-1 J)^-1 at the estimate (at the last
  linearisation point when ``final_eval`` is False, within a step of it).
* Whether chi2 is quadratic over that std is checked, not assumed (:func:`profile`,
  identify/core/profile.py's check, the one discovery uses): each determined parameter is held at
  +-2 Fisher std and the others refitted. A parameter that fails keeps its Fisher std and is
  FLAGGED (the report's ``profile``), not made "not determined" and not given a profile std:
  where it fails, on the 7-pose KR 270 plan of tests/kr270_weak7.toml with a 100 um tracker
  (balancer_stiffness on 32 %, balancer_preload on 68 % of 100 campaigns), the Fisher std
  is the most honest of the three: empirical over reported std 0.85 and 0.89 over all runs;
  0.68 and 0.61 over the runs that pass (what "not determined" would leave); 0.85 and 0.51
  with the larger half-width of the profile's quadratic through the rise at 2 sd where it fails.
  With a 20 um tracker every profile passes there (100 of 100), as on both paper plans.
"""

from __future__ import annotations

import copy

import numpy as np

from calbench.bench.model import ParamLayout, Robot
from calbench.bench.statics import BatchStatics, StaticsSolver
from calbench.identify.core import (
    RANK_TOL,
    Fit,
    ForwardModel,
    Observations,
    Profile,
    Whitener,
    analyze,
    covariance,
    design_from_observations,
    explain,
    levenberg_marquardt,
    profile_check,
    resolve,
)

from .base import IdentifyOptions, Method, MethodResult, Repeats
from .twostep import TwoStepError, TwoStepResult, group_q2, plan_facts, two_step

MC_STEP_TOL = 1e-2  # sigma: the Monte Carlo's stopping rule (module docstring)


def generic_start(robot: Robot, obs: Observations) -> np.ndarray:
    """Generic starting values (no MJCF stiffness): see the module docstring. A spring whose
    geometry is not a triangle about one actuated hinge starts at the generic 1 m."""
    preloads = []
    for c in range(len(robot.tendons)):
        try:
            geom = robot.compensator_geometry(c)
        except ValueError:
            preloads.append(1.0)
            continue
        _, values = group_q2(np.array([p.q[geom.joint] for p in obs.poses]))
        preloads.append(float(np.mean([geom.length(v) for v in values])))
    return robot.layout.generic_start(preloads)


def sanitize_start(
    theta: np.ndarray, generic: np.ndarray, layout: ParamLayout
) -> tuple[np.ndarray, list[str]]:
    """Replace NaN or physically invalid entries (every parameter must be > 0) by generic
    values; names the replaced ones. A compensator's pair is replaced together."""
    out = np.array(theta, dtype=float)
    bad = ~np.isfinite(out) | (out <= 0)
    # a compensator pair is only meaningful together
    for kc, s0 in zip(layout.stiffness_index, layout.preload_index):
        if bad[kc] or bad[s0]:
            bad[kc] = bad[s0] = True
    out[bad] = generic[bad]
    return out, [layout.names[i] for i in np.flatnonzero(bad)]


class OneStep:
    """A reusable one-step estimator for one design (the Monte Carlo reuses it across runs)."""

    def __init__(self, robot: Robot, obs: Observations, model: ForwardModel | None = None):
        self.robot = robot
        self.obs = obs
        self.model = model or ForwardModel(robot, design_from_observations(robot, obs))
        self.facts = plan_facts(robot, obs)

    def fit(
        self,
        dp: np.ndarray,
        white: Whitener,
        start: np.ndarray,
        *,
        scale=None,
        start_eval: tuple[np.ndarray, np.ndarray] | None = None,
        step_tol: float = 1e-6,
        max_iter: int = 40,
        final_eval: bool = True,
        start_method: str = "given",
    ) -> Fit:
        """Fit to observations dp (M,3) whitened by ``white`` (identify/core/whitening.py).

        Iterates in phi = theta with every compensator's s0 replaced by P = K_C s0 (the spring's
        force K_C (L - s0) is linear in K_C and P, as in eq. 21's unknowns), scaled by ``scale``
        (|phi(start)| by default); reports theta (s0 = P / K_C). The maximum-likelihood point does
        not depend on the parametrisation; the iterations do (fewer here). The iterations are
        identify/core/leastsq.py's core; unidentifiable parameters (rank analysis at every iterate)
        are held at their start.
        start_eval: (f, J) already evaluated at ``start`` (saves one evaluation).
        """
        model = self.model
        lay = self.robot.layout
        names = lay.names
        phi0 = to_phi(np.array(start, dtype=float), lay)
        scale = np.where(np.abs(phi0) > 0, np.abs(phi0), 1.0) if scale is None else np.asarray(scale)
        yw = white.vec(dp)
        n_eval0 = model.stats["evaluations"]

        def whiten(ph, f, j):
            return white.vec(f), white.mat(j) @ dtheta_dphi(ph, lay)

        def evaluate(ph):
            return whiten(ph, *model.evaluate(to_theta(ph, lay)))

        # Positivity as bounds (an active set), not only as a validity test: when the data prefer
        # a spring that is not there (K_C -> 0, a realistic balancer), the fit then converges ON
        # the bound instead of damping its way through max_iter.
        lower = to_phi(lay.lower, lay)
        sol = levenberg_marquardt(
            evaluate,
            yw,
            np.maximum(phi0, lower),
            scale,
            valid=valid_phi,
            lower=lower,
            free_fn=lambda jw: analyze(jw, names).identifiable,
            step_tol=step_tol,
            rank_tol=RANK_TOL,
            max_iter=max_iter,
            max_damping=30,
            accept_within_sigma=True,
            final_eval=final_eval,
            start_eval=None if start_eval is None else whiten(phi0, *start_eval),
        )
        phi = sol.x
        ident = analyze(sol.j_w * scale, names)
        free = ident.identifiable
        cov_phi, _ = covariance(sol.j_w * scale, free, scale, RANK_TOL)
        cov_phi[np.isnan(cov_phi)] = 0.0
        dt = dtheta_dphi(phi, lay)
        cov = dt @ cov_phi @ dt.T
        theta = to_theta(phi, lay)
        resolve(ident, theta, cov)  # the noise, not just the rank
        bad = ~ident.identifiable.copy()
        for kc, s0 in zip(lay.stiffness_index, lay.preload_index):
            bad[s0] = bad[kc] or bad[s0]  # s0 = P / K_C needs both
        cov[bad, :] = np.nan
        cov[:, bad] = np.nan
        explain(ident, lay, self.facts)
        reasons = dict(ident.reasons)
        for s0 in lay.preload_index:
            if bad[s0] and names[s0] not in reasons:
                reasons[names[s0]] = "s0 = (K_C s0) / K_C and K_C is not identified"
        resid_w = sol.r_w.reshape(-1, 3)
        resid = white.unwhiten(resid_w)
        return Fit(
            theta,
            cov,
            ~bad,
            resid,
            resid_w,
            sol.cost,
            sol.r_w.size,
            int(free.sum()),
            sol.iterations,
            model.stats["evaluations"] - n_eval0,
            sol.converged,
            sol.seconds,
            names=names,
            units=lay.units,
            reasons=reasons,
            start=np.array(start, float),
            start_method=start_method,
            ident=ident,
            model=model,
            robot=self.robot,
        )


PROFILE_COST_TOL = 0.01  # chi2: a profile refit stops when a step gains less (as discovery's)
PROFILE_MAX_ITER = 12


def profile(est: OneStep, f: Fit, dp: np.ndarray, white: Whitener) -> Profile:
    """identify/core/profile.py's check of every determined parameter of the one-step fit ``f``: each
    held at its estimate +- 2 Fisher stds, the others refitted in theta (identify/core/leastsq.py's
    core; the parameters ``f`` did not determine stay held)."""
    lay = est.robot.layout
    model = est.model
    yw = white.vec(dp)

    def evaluate(th):
        fm, j = model.evaluate(th)
        return white.vec(fm), white.mat(j)

    def refit(v: np.ndarray, i: int) -> float:
        hold = ~np.asarray(f.identifiable, bool)
        hold[i] = True
        sol = levenberg_marquardt(
            evaluate,
            yw,
            v,
            np.where(v != 0, np.abs(v), 1.0),
            lower=lay.lower,
            upper=lay.upper,
            hold=hold,
            valid=valid_phi,
            rank_tol=RANK_TOL,
            cost_tol=PROFILE_COST_TOL,
            max_iter=PROFILE_MAX_ITER,
        )
        return sol.cost

    sd = np.sqrt(np.where(np.isfinite(np.diag(f.cov)), np.diag(f.cov), np.nan))
    out = profile_check(
        refit,
        f.values,
        f.chi2,
        sd,
        lay.lower,
        lay.upper,
        np.flatnonzero(f.identifiable),
        far=lay.spring_index,
    )
    model.evaluate(f.values, jacobian=False)  # the model back at the estimate
    return out


def to_phi(theta: np.ndarray, layout: ParamLayout) -> np.ndarray:
    """Every compensator's [K_C, s0] -> [K_C, P = K_C s0]."""
    phi = np.array(theta, dtype=float)
    kc, s0 = layout.stiffness_index, layout.preload_index
    phi[s0] = theta[kc] * theta[s0]
    return phi


def to_theta(phi: np.ndarray, layout: ParamLayout) -> np.ndarray:
    theta = np.array(phi, dtype=float)
    kc, s0 = layout.stiffness_index, layout.preload_index
    theta[s0] = phi[s0] / phi[kc]
    return theta


def dtheta_dphi(phi: np.ndarray, layout: ParamLayout) -> np.ndarray:
    d = np.eye(layout.n)
    kc, s0 = layout.stiffness_index, layout.preload_index
    d[s0, kc] = -phi[s0] / phi[kc] ** 2
    d[s0, s0] = 1.0 / phi[kc]
    return d


def valid_phi(phi: np.ndarray) -> bool:
    """Every compliance, K_C and K_C s0 finite and > 0."""
    return bool(np.all(np.isfinite(phi)) and np.all(phi > 0))


def two_step_start(
    robot: Robot, obs: Observations, generic: np.ndarray, two: TwoStepResult | None = None
) -> tuple[np.ndarray, str, list[str]]:
    """The one-step's start (module docstring): the two-step estimate (``two`` if given), its
    invalid entries replaced by ``generic``; ``generic`` itself where the two-step does not
    apply or fails. Returns the start, how it was made, and the replaced parameters' names."""
    try:
        two = two or two_step(robot, obs)
    except (np.linalg.LinAlgError, ValueError, TwoStepError):
        return generic, "generic", []
    start, replaced = sanitize_start(two.theta, generic, robot.layout)
    method = "two-step" if not replaced else "two-step (generic: " + ", ".join(replaced) + ")"
    return start, method, replaced


def one_step(
    robot: Robot,
    obs: Observations,
    start: np.ndarray | None = None,
    two: TwoStepResult | None = None,
    check_profile: bool = False,
    **kw,
) -> Fit:
    """Identify all parameters at once from the observations (see the module docstring);
    ``check_profile``: run :func:`profile` too (its outcome in ``extra["profile"]``)."""
    est = OneStep(robot, obs)
    white = Whitener.from_observations(obs)
    generic = generic_start(robot, obs)
    method = "given"
    replaced: list[str] = []
    if start is None:
        start, method, replaced = two_step_start(robot, obs, generic, two)
    res = fit_from(est, obs.dp, white, start, generic, method, **kw)
    res.extra["start_replaced"] = replaced
    if check_profile:
        res.extra["profile"] = profile(est, res, obs.dp, white)
    return res


def fit_from(
    est: OneStep, dp: np.ndarray, white: Whitener, start: np.ndarray, generic: np.ndarray, method: str, **kw
) -> Fit:
    """``est.fit`` from ``start`` (named ``method``); when that fit does not converge and the
    start is not ``generic``, again from ``generic``, keeping the converged fit, else the lower
    chi2 (see the module docstring: a valid two-step start can lie in another basin)."""
    res = est.fit(dp, white, start, start_method=method, **kw)
    if res.converged or np.array_equal(np.asarray(start, float), generic):
        return res
    alt = est.fit(
        dp, white, generic, start_method=f"generic (from the {method} start the fit did not converge)", **kw
    )
    return alt if (alt.converged, -alt.chi2) > (res.converged, -res.chi2) else res


# --------------------------------------------------------------------------- the family's face


def _num(x) -> float | None:
    return None if x is None or not np.isfinite(x) else float(x)


def profile_report(pr: Profile, names) -> dict:
    """The profile check per checked parameter (identify/core/profile.py), as the report's JSON
    carries it: chi2's rise at +-2 Fisher std (None: past a bound, or no fit there) and whether
    it is the quadratic's (4, within a factor 2); a parameter that fails keeps its Fisher std
    (module docstring)."""
    out = {
        names[i]: {"rise_plus": _num(r[0]), "rise_minus": _num(r[1]), "quadratic": not bool(pr.bad[i])}
        for i, r in sorted(pr.rises.items())
    }
    for i, r in pr.rises_far.items():  # a spring's, at +-FAR_SIGMAS (identify/core/profile.py, FAR)
        out[names[i]].update(rise_plus_far=_num(r[0]), rise_minus_far=_num(r[1]))
    return out


def one_step_result(fit: Fit, details: dict | None = None) -> MethodResult:
    """The family's result of a one-step fit; ``details`` default: how it started, its
    iterations, evaluations and convergence (and the profile check when it ran)."""
    if details is None:
        details = {
            "start": fit.start_method,
            "iterations": fit.iterations,
            "evaluations": fit.evaluations,
            "converged": bool(fit.converged),
        }
        if "profile" in fit.extra:
            details["profile"] = profile_report(fit.extra["profile"], fit.names)
    return MethodResult(
        "one-step",
        fit.names,
        fit.units,
        fit.theta,
        fit.cov,
        fit.identifiable,
        dict(fit.reasons),
        fit.residual,
        fit.residual_w,
        float(fit.chi2),
        int(fit.dof),
        bool(fit.converged),
        fit.iterations,
        fit.evaluations,
        details,
    )


def estimate_one_step(robot: Robot, obs: Observations, options: IdentifyOptions) -> MethodResult:
    """`calbench identify --method one-step`: :func:`one_step` (with its profile check when
    ``options`` asks)."""
    return one_step_result(one_step(robot, obs, check_profile=options.check_profile))


def fresh_copy(est: OneStep) -> OneStep:
    """A copy of the estimator in the state it was left in (its forward model warm-starts from
    its last solution, so a run's last bits would depend on the runs before it). Its workspaces
    are shared, not copied: the robot and the statics solvers (bench/statics/equilibrium.py,
    bench/statics/batched.py), whose MuJoCo model parameters, state and buffers every evaluation
    rewrites, and the observations (read-only); what is copied is the warm-start cache."""
    shared = [est.robot, est.obs] + [
        v for v in vars(est.model).values() if isinstance(v, (StaticsSolver, BatchStatics))
    ]
    return copy.deepcopy(est, {id(o): o for o in shared})


def repeat_one_step(robot: Robot, obs0: Observations, white0: Whitener) -> Repeats:
    """The Monte Carlo's one-step (identify/study/montecarlo.py). The noise-free estimate is the
    one-step's on the exact readings, from their two-step start (:func:`two_step_start`: no
    truth involved). Every run starts there, from a copy of the estimator in the same state
    (:func:`fresh_copy`), with the model value and Jacobian at the start evaluated once and
    reused, the noise-free scale, no final evaluation and the stopping rule at MC_STEP_TOL sigma:
    a run usually costs one evaluation of the exact model and its IFT Jacobian."""
    est = OneStep(robot, obs0)
    generic = generic_start(robot, obs0)
    start, method, _ = two_step_start(robot, obs0, generic)
    nf = fit_from(est, obs0.dp, white0, start, generic, method)
    theta0 = np.where(np.isfinite(nf.theta), nf.theta, start)
    scale = np.abs(to_phi(theta0, robot.layout))
    f0, j0 = est.model.evaluate(theta0)

    def run(obs: Observations, white: Whitener) -> MethodResult:
        res = fresh_copy(est).fit(
            obs.dp,
            white,
            theta0,
            scale=scale,
            start_eval=(f0, j0),
            final_eval=False,
            step_tol=MC_STEP_TOL,
            start_method="noise-free estimate",
        )
        return one_step_result(res, {})

    return Repeats(one_step_result(nf), run)


ONE_STEP = Method(
    "one-step",
    estimate_one_step,
    summary="all parameters at once on the exact statics",
    repeat=repeat_one_step,
    seconds_per_run=0.007,  # in-process, per Monte Carlo run on the paper campaign (measured)
    noise_free_always=True,
)


__all__ = [
    "Fit",
    "OneStep",
    "one_step",
    "fit_from",
    "generic_start",
    "sanitize_start",
    "profile",
    "two_step_start",
    "profile_report",
    "one_step_result",
    "estimate_one_step",
    "fresh_copy",
    "repeat_one_step",
    "ONE_STEP",
    "MC_STEP_TOL",
]
