"""The one least-squares core: Levenberg–Marquardt on a whitened residual, and its result type.

Both estimators use it: the one-step identification (identify/methods/onestep.py; the robot's parameters,
paper eq. 20 solved on the exact statics) and discovery's candidate fits
(identify/discover/fit.py; base parameters plus an effect's). It minimises

    chi2(x) = |y_w - f_w(x)|^2,     y_w = L^-1 y,  f_w = L^-1 f,  L L^T = Cov(y)

(the maximum-likelihood estimate for Gaussian tracker noise) in scaled coordinates
u = x / scale, by Gauss–Newton steps damped Levenberg–Marquardt style when a step does not
lower chi2.

Why a loop of our own, not ``scipy.optimize.least_squares`` or ``mujoco.minimize.least_squares``
(measured in benchmarks/identify_bench.py, "lm_core"): both are sound bounded LM/trust-region
solvers, but
* each model evaluation here solves 2 x 16 static equilibria and their implicit-function
  Jacobians at once; the library solvers ask for the residual and the Jacobian in separate
  calls and re-evaluate to confirm convergence. Our stopping rule is on the Gauss–Newton step
  in standard deviations of the estimate: when the next step is below ``step_tol`` sigma (or
  the observed contraction says the remaining error is), it is APPLIED without evaluating
  again. A Monte Carlo run started at the noise-free estimate therefore costs ONE evaluation.
  Measured on the paper campaign (python benchmarks/lm_bench.py): an identification takes 5-7
  evaluations here, 15-20 with scipy's trust-region-reflective and ~150 with
  mujoco.minimize (same optimum within 3e-4 sigma); a Monte Carlo run 1 here, 12-16 with
  scipy, ~150 with mujoco.minimize;
* parameters the plan cannot determine must be left where they are (held, or moved only in
  the directions the data see): steps are minimum-norm truncated-SVD steps on the columns that
  are free, which neither library offers;
* a model evaluation may fail (no equilibrium for a wild trial): such a trial is rejected
  like a cost increase.

Steps and damping. Columns are normalised to unit length (units and parameter sizes drop out);
the step is sum_i s_i / (s_i^2 + lam) (u_i . r) v_i over the singular values s_i above
``rank_tol`` s_1 (Marquardt damping in normalised coordinates: lam I = lam diag(J^T J)). lam
starts at 0 and goes x10 up (from 1e-3) on a rejected trial, /10 down on an accepted one.

Bounds: an active set (a parameter at its bound whose step points outward is fixed for that
step, the one pointing out furthest first, then the step is recomputed: correlated parameters
change each other's direction), then projection of the trial onto the box. ``valid(x)`` rejects trials outright (e.g.
the one-step's positivity of every compliance).

Stopping (any of):
* ``step_tol`` > 0: the undamped step is below step_tol standard deviations in every free
  parameter, or, with contraction rho = step_k / step_(k-1) < 0.5, the geometric remainder
  rho/(1 - rho) step_k is; the step is applied (see above) and the fit is converged. A step
  that would cross a bound is taken up to the bound only, on the same linearisation, and the
  fit goes on with that bound in its active set (clipped whole, along an undetermined split a
  step small in each parameter's own std moved the FANUC's determined k3 + forearm pitch by
  100 of its std in discovery's self-check);
* ``gain_tol`` > 0: the undamped step promises less than gain_tol of chi2: converged, step
  not applied;
* ``cost_tol`` > 0: an accepted step gained less than cost_tol of chi2: converged;
* no trial is accepted within 12 (30) damping increases: not converged.
Within one sigma of the optimum (undamped step < 1 sigma) the step is taken without a cost
test when ``accept_within_sigma``: there chi2 changes by ~step^2, below its own round-off at
the solver's precision.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

log = logging.getLogger(__name__)

Evaluate = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]  # x -> (f_w (n,), J_w (n, p))


# --------------------------------------------------------------------------- the result type


@dataclass
class Fit:
    """A maximum-likelihood fit of a model to whitened observations (SI units).

    ``values`` holds every parameter (held ones at their held values); ``theta`` the estimate
    reported to users: NaN where the data do not determine the parameter (``identifiable``
    False). ``cov`` is the inverse Fisher information on the determined parameters, NaN rows and
    columns elsewhere. ``dof`` = scalar residuals minus the rank the data determine.
    """

    values: np.ndarray  # (P,)
    cov: np.ndarray  # (P, P)
    identifiable: np.ndarray  # (P,) bool: determined by the data (not held, not at a bound)
    residual: np.ndarray  # (M, 3) measured - predicted, m
    residual_w: np.ndarray  # (M, 3) whitened
    chi2: float
    n_res: int  # scalar residuals (3 M)
    rank: int  # parameters the data determine
    iterations: int
    evaluations: int
    converged: bool
    seconds: float = 0.0
    names: tuple[str, ...] = ()
    units: tuple[str, ...] = ()
    predicted: np.ndarray | None = None  # (M, 3) model deflections, m
    at_bound: np.ndarray | None = None  # (P,) bool
    reasons: dict[str, str] = field(default_factory=dict)  # why a parameter is not determined
    start: np.ndarray | None = None
    start_method: str = "given"
    ident: Any = None  # identify.identifiability.Identifiability, when analysed
    effects: list = field(default_factory=list)  # discovery: the effects appended to the base
    model: Any = field(default=None, repr=False)  # the forward model that produced it
    robot: Any = field(default=None, repr=False)
    extra: dict = field(default_factory=dict)

    @property
    def theta(self) -> np.ndarray:
        out = np.array(self.values, dtype=float)
        out[~self.identifiable] = np.nan
        return out

    @property
    def free(self) -> np.ndarray:
        """Alias of ``identifiable`` (discovery's name: estimated, not held or at a bound)."""
        return self.identifiable

    @property
    def n_free(self) -> int:
        return int(self.rank)

    @property
    def dof(self) -> int:
        return int(self.n_res - self.rank)

    def effect_slices(self) -> list[tuple[Any, slice]]:
        """(effect, where its parameters sit in ``values``) for every appended effect, in order:
        the effects' parameters follow the base ones, each effect's in its own order."""
        out, off = [], self.values.size - sum(len(e.param_names) for e in self.effects)
        for e in self.effects:
            n = len(e.param_names)
            out.append((e, slice(off, off + n)))
            off += n
        return out

    def effect_params(self) -> list[tuple[Any, np.ndarray]]:
        """(effect, its parameter values) for every appended effect, in order."""
        return [(e, self.values[s].copy()) for e, s in self.effect_slices()]


# --------------------------------------------------------------------------- the core


@dataclass
class Solution:
    """What :func:`levenberg_marquardt` returns: the point, the model there, and how it got there."""

    x: np.ndarray
    f_w: np.ndarray  # whitened model at x (first-order prediction if the last step was not evaluated)
    j_w: np.ndarray  # whitened Jacobian, d f_w / d x, at the last evaluation
    r_w: np.ndarray  # y_w - f_w
    cost: float  # |r_w|^2
    free: np.ndarray  # (p,) bool: estimated in the last step (not held, not at a bound, free_fn)
    iterations: int
    evaluations: int
    converged: bool
    seconds: float
    last_step_evaluated: bool = True


def svd_step(j: np.ndarray, r: np.ndarray, lam: float, rank_tol: float) -> tuple[np.ndarray, np.ndarray, int]:
    """Minimum-norm damped step on column-normalised ``j`` (see the module docstring).

    Returns (du in j's columns, the standard deviation of each undamped du component, rank).
    Zero columns get du = 0 and an infinite standard deviation."""
    p = j.shape[1]
    du = np.zeros(p)
    sd = np.full(p, np.inf)
    norms = np.linalg.norm(j, axis=0)
    ok = norms > 0
    if not ok.any():
        return du, sd, 0
    jn = j[:, ok] / norms[ok]
    u, s, vt = np.linalg.svd(jn, full_matrices=False)
    keep = s > rank_tol * s[0]
    s_k, u_k, v_k = s[keep], u[:, keep], vt[keep].T
    du[ok] = (v_k @ (s_k / (s_k**2 + lam) * (u_k.T @ r))) / norms[ok]
    sd[ok] = np.sqrt((v_k**2 / s_k**2).sum(axis=1)) / norms[ok]
    return du, sd, int(keep.sum())


def covariance(j: np.ndarray, free: np.ndarray, scale: np.ndarray, rank_tol: float) -> tuple[np.ndarray, int]:
    """Pseudo-inverse Fisher information (J^T J)^+ on the free columns of the whitened Jacobian
    ``j`` (scaled coordinates), in x units; NaN rows and columns for the others. Returns (cov, rank)."""
    p = j.shape[1]
    cov = np.full((p, p), np.nan)
    idx = np.flatnonzero(free)
    if idx.size == 0:
        return cov, 0
    jf = j[:, idx]
    norms = np.linalg.norm(jf, axis=0)
    norms = np.where(norms > 0, norms, 1.0)
    _, s, vt = np.linalg.svd(jf / norms, full_matrices=False)
    keep = s > rank_tol * s[0] if s.size and s[0] > 0 else np.zeros(s.size, bool)
    pinv = (vt[keep].T / s[keep] ** 2) @ vt[keep]
    cov[np.ix_(idx, idx)] = pinv / np.outer(norms, norms) * np.outer(scale[idx], scale[idx])
    return cov, int(keep.sum())


def at_bounds(x: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(at the lower bound, at the upper bound), with a relative tolerance of 1e-9."""
    lo = np.isfinite(lower) & (x <= lower + 1e-9 * np.abs(np.where(np.isfinite(lower), lower, 0)))
    hi = np.isfinite(upper) & (x >= upper - 1e-9 * np.abs(np.where(np.isfinite(upper), upper, 0)))
    return lo, hi


def levenberg_marquardt(
    evaluate: Evaluate,
    y_w: np.ndarray,
    x0: np.ndarray,
    scale: np.ndarray,
    *,
    lower: np.ndarray | None = None,
    upper: np.ndarray | None = None,
    hold: np.ndarray | None = None,
    free_fn: Callable[[np.ndarray], np.ndarray] | None = None,
    valid: Callable[[np.ndarray], bool] | None = None,
    step_tol: float = 0.0,
    gain_tol: float = 0.0,
    cost_tol: float = 0.0,
    rank_tol: float = 1e-5,
    max_iter: int = 40,
    max_damping: int = 12,
    accept_within_sigma: bool = False,
    final_eval: bool = True,
    start_eval: tuple[np.ndarray, np.ndarray] | None = None,
) -> Solution:
    """Minimise |y_w - f_w(x)|^2 from x0 (see the module docstring for every option).

    evaluate(x) -> (f_w, J_w) with J_w = d f_w / d x (unscaled); it may raise RuntimeError or
    ValueError for a trial without a solution. free_fn(J_w scaled) -> bool mask of the columns
    the data determine (default: all), evaluated at every iterate. final_eval: evaluate the
    model at the returned point when the last step was applied without evaluation.
    """
    t0 = time.perf_counter()
    x = np.array(x0, dtype=float)
    p = x.size
    scale = np.asarray(scale, dtype=float)
    lower = np.full(p, -np.inf) if lower is None else np.asarray(lower, dtype=float)
    upper = np.full(p, np.inf) if upper is None else np.asarray(upper, dtype=float)
    hold = np.zeros(p, bool) if hold is None else np.asarray(hold, bool)
    n_eval = 0

    def lin(xx):
        nonlocal n_eval
        n_eval += 1
        f, j = evaluate(xx)
        return f, j * scale

    if start_eval is not None:
        f, j = start_eval[0], start_eval[1] * scale
    else:
        f, j = lin(x)
    r = y_w - f
    cost = float(r @ r)
    lam = 0.0
    converged = False
    evaluated = True
    prev_step = np.inf
    free = ~hold
    it = 0
    for it in range(1, max_iter + 1):
        free = ~hold
        if free_fn is not None:
            free = free & free_fn(j)
        lo, hi = at_bounds(x, lower, upper)
        du = np.zeros(p)
        sd = np.full(p, np.inf)
        for _ in range(p):  # fix bound parameters whose step points out,
            du[:] = 0.0  # the worst one at a time: fixing one changes the
            sd[:] = np.inf  # others' steps when they are correlated
            du[free], sd[free], _ = svd_step(j[:, free], r, 0.0, rank_tol)
            out = free & ((lo & (du < 0)) | (hi & (du > 0)))
            if not out.any():
                break
            worst = np.flatnonzero(out)[
                np.argmax(np.abs(du[out]) / np.where(np.isfinite(sd[out]), sd[out], 1.0))
            ]
            free[worst] = False
        seen = free & np.isfinite(sd) & (sd > 0)
        step = float(np.max(np.abs(du[seen]) / sd[seen])) if seen.any() else 0.0  # in sigmas
        gain = float(np.sum((j[:, free] @ du[free]) ** 2))  # promised chi2 drop
        rho = step / prev_step if np.isfinite(prev_step) and prev_step > 0 else np.inf
        prev_step = step
        log.debug(
            "it %d chi2 %.6g step %.3g sigma gain %.3g lam %.3g free %d",
            it,
            cost,
            step,
            gain,
            lam,
            int(free.sum()),
        )
        if step_tol > 0 and (step < step_tol or (rho < 0.5 and rho / (1 - rho) * step < step_tol)):
            target = x + scale * du
            out = (target < lower) | (target > upper)
            if not out.any():
                x = target
                f = f + j @ du
                r = y_w - f
                cost = float(r @ r)
                evaluated = False
                converged = True
                break
            # a bound clips it: the step is taken up to the first bound it meets, on the same
            # linear model (small in every std: the linearisation holds), and the fit goes on
            # with that bound in its active set. Clipping the whole step instead moved what the
            # data determine: along an undetermined split a step is small in each parameter's own
            # std, and its clipped part moved the FANUC's determined k3 + forearm pitch by 100
            # of its std in discovery's self-check.
            bound = np.where(target < lower, lower, upper)
            with np.errstate(divide="ignore", invalid="ignore"):
                t_i = np.where(out, (bound - x) / (scale * du), np.inf)
            t = float(np.clip(np.min(t_i), 0.0, 1.0))
            hit = out & (t_i <= t)
            x = x + t * scale * du
            x[hit] = bound[hit]
            f = f + t * (j @ du)
            r = y_w - f
            cost = float(r @ r)
            evaluated = False
            continue
        if gain_tol > 0 and gain < gain_tol:
            converged = True
            break
        accepted = False
        gained = 0.0
        for _ in range(max_damping):
            if lam > 0:
                du[:] = 0.0
                du[free], _, _ = svd_step(j[:, free], r, lam, rank_tol)
            trial = np.clip(x + scale * du, lower, upper)
            if valid is not None and not valid(trial):
                lam = max(10 * lam, 1e-3)
                continue
            try:
                f_t, j_t = lin(trial)
            except (RuntimeError, ValueError, np.linalg.LinAlgError):
                lam = max(10 * lam, 1e-3)
                continue
            r_t = y_w - f_t
            cost_t = float(r_t @ r_t)
            if (cost_t <= cost + 1e-9 * max(cost, 1.0)) or (
                accept_within_sigma and lam == 0.0 and step < 1.0
            ):
                gained = cost - cost_t
                x, f, j, r, cost = trial, f_t, j_t, r_t, cost_t
                lam = lam / 10 if lam > 1e-6 else 0.0
                accepted = True
                break
            lam = max(10 * lam, 1e-3)
        if not accepted:
            break
        if cost_tol > 0 and gained < cost_tol:
            converged = True
            break
    if not evaluated and final_eval:
        f, j = lin(x)
        r = y_w - f
        cost = float(r @ r)
        evaluated = True
    log.info(
        "least squares: chi2 %.6g after %d iterations, %d evaluations, %s",
        cost,
        it,
        n_eval,
        "converged" if converged else "NOT converged",
    )
    return Solution(
        x, f, j / scale, r, cost, free, it, n_eval, converged, time.perf_counter() - t0, evaluated
    )


__all__ = ["Fit", "Solution", "levenberg_marquardt", "svd_step", "covariance", "at_bounds"]
