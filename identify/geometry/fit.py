"""Geometric calibration from absolute readings: the base set, the least-squares fit, validation.

Which parameters a campaign can see: the classic redundancies (a link frame's z-rotation and the
joint offset after it; consecutive parallel axes; the base frame against the first joint; the
flange frame against the probe point; orientation parameters of the probe, which a point cannot
show) make the Jacobian rank-deficient. The base set is chosen from the SVD of the column-scaled
Jacobian at the start: parameters are taken in a fixed priority order (base frame, tool, joint
offsets, compliances, link frames) and one enters when it raises the numerical rank (singular
values above RANK_TOL of the largest; a column below RANK_TOL of the median column is none: a
rotation about an axis through the probe); the others stay at zero and are reported as not
identified. Then scipy's Levenberg-Marquardt on the base set (analytic Jacobian), a first-order
covariance sigma^2 (J^T J)^-1 with sigma^2 = chi2/dof when no reading std is given.

Units: SI (m, rad, N*m).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares

from calbench.identify.core import GEOMETRY_RANK_TOL as RANK_TOL  # identify/core/tolerances.py
from calbench.identify.core import fit_rigid

from .chain import Chain
from .model import GeometricModel, as_rows, kind

# the models a validation compares, by the effects each one fits
MODELS = {
    "nominal": ("base_frame", "tool_frame"),
    "geometry": ("base_frame", "tool_frame", "joint_offset", "link_geometry"),
    "geometry+compliance": (
        "base_frame",
        "tool_frame",
        "joint_offset",
        "link_geometry",
        "joint_compliance",
        "compensator",  # a spring's stiffness and preload (statics.py; none on a serial arm)
    ),
}


@dataclass(frozen=True)
class GeometryFit:
    """A calibrated model: the full parameter vector (zeros outside the base set) and its spread."""

    model: GeometricModel
    theta: np.ndarray  # (size,)
    free: tuple[int, ...]  # indices of the base set
    cov: np.ndarray  # (len(free), len(free))
    rms: float  # m, 3-D RMS of the fitted readings' residuals
    n: int  # readings used
    residual_w: np.ndarray | None = None  # (3 n,) the residuals over their sigma (None: no sigma given)
    own_torques: bool = False  # fitted with the torques at its own deflected pose (refresh_torques)

    @property
    def chi2(self) -> float:
        """|residual / sigma|^2 (NaN when no reading sigma was given)."""
        return float("nan") if self.residual_w is None else float(self.residual_w @ self.residual_w)

    @property
    def names(self) -> list[str]:
        return [self.model.names[i] for i in self.free]

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.diag(self.cov))

    def predict(self, q: np.ndarray) -> np.ndarray:
        tau = self.model.torques_at(q, self.theta) if self.own_torques else None
        return self.model.predict(q, self.theta, tau)

    def calibrated(self) -> tuple[Chain, np.ndarray, np.ndarray, np.ndarray]:
        """The fit folded into a plain chain: (chain, probe point in the flange frame, tracker from
        robot base (4x4), joint compliances (0 where not fitted)). Each link frame becomes
        P_k E_k Rz(o_k), so that the calibrated chain at q is the fitted model at q without the
        compliance term (which a calbench MJCF carries as joint stiffness 1/c)."""
        return self.model.calibrated(self.theta)


def initial_model(
    chain: Chain,
    q,
    y: np.ndarray,
    tool: np.ndarray,
    points: Sequence[str] = (),
    sites: Mapping[str, np.ndarray] | None = None,
) -> GeometricModel:
    """The nominal model registered on the readings (closed-form rigid fit, Horn/Kabsch) as start.

    ``tool``: the probe in the flange frame (e.g. :func:`tool_from_transform` of the dataset's
    probe-to-flange transform), or (m, 3) the points ``points`` (several reflectors), which ``q``
    (:class:`~.model.Rows`) indexes; ``sites``: where loads act (flange frame, by site name)."""
    rows = as_rows(q)
    tools = np.atleast_2d(np.asarray(tool, float))
    _, flange = chain.joint_frames(rows.q)
    p = np.einsum("nij,nj->ni", flange[:, :3, :3], tools[rows.point]) + flange[:, :3, 3]
    reg = fit_rigid(y, p, np.broadcast_to(np.eye(3) * 1e-8, (len(y), 3, 3)))
    base0 = np.eye(4)
    base0[:3, :3] = reg.rotation.T  # tracker from robot: y = R^T (p - t)
    base0[:3, 3] = -reg.rotation.T @ reg.position
    return GeometricModel(chain, base0, np.asarray(tool, float), tuple(points), dict(sites or {}))


def tool_from_transform(probe_to_flange: np.ndarray) -> np.ndarray:
    """The probe's origin in the flange frame from a 4x4 transform of flange coordinates into probe
    coordinates (the dataset's ``Trafo_TM_F``, which puts the flange 109 mm behind the probe)."""
    r, t = probe_to_flange[:3, :3], probe_to_flange[:3, 3]
    return -r.T @ t


PRIORITY = ("base_frame", "tool_frame", "joint_offset", "joint_compliance", "compensator", "link_geometry")


def in_priority(names: Sequence[str], indices: Sequence[int]) -> list[int]:
    """``indices`` in the base set's priority order (by effect: :data:`PRIORITY`, then by index)."""
    return sorted(indices, key=lambda i: (PRIORITY.index(kind(names[i])), i))


def rank_rule(model) -> dict:
    """The base set's rank tolerance and column floor of a model (extend_base's ``tol`` and
    ``column_floor``): the defaults for model.py's exact Jacobian; statics.py's differences pass theirs."""
    return {"tol": getattr(model, "rank_tol", None), "column_floor": getattr(model, "column_floor", None)}


def extend_base(
    jac: np.ndarray,
    chosen: Sequence[int],
    candidates: Sequence[int],
    tol: float | None = None,
    column_floor: float | None = None,
) -> tuple[int, ...]:
    """A base set ``chosen`` grown by each of ``candidates``, taken in the order given, that raises
    the rank of the column-scaled Jacobian (module docstring); the grown set, in its order.

    The singular values of the chosen columns with one more are those of the small triangular
    factor [[R, Q^T c], [0, |c - Q Q^T c|]] of their QR (Q^T c twice: re-orthogonalised), so each
    test is an SVD of a (k + 1)-square matrix, not of the tall Jacobian. ``tol``: the rank
    tolerance (default RANK_TOL; a model whose columns are differences passes its own);
    ``column_floor``: the column norm at or below which a column is none (default ``tol`` times the
    median column's, which compares columns of different units: a model that zeroes its own
    noise columns passes 0)."""
    tol = RANK_TOL if tol is None else tol
    a = jac.reshape(-1, jac.shape[-1])
    scale = np.linalg.norm(a, axis=0)
    out = list(chosen)
    if out:
        q, r = np.linalg.qr(a[:, out] / scale[out])
    else:
        q, r = np.zeros((a.shape[0], 0)), np.zeros((0, 0))
    rank = len(out)
    floor = tol * np.median(scale) if column_floor is None else column_floor
    for i in candidates:
        # a column of rounding noise only (a rotation about an axis through the probe) is
        # no parameter: it would enter with any scaling
        if i in out or scale[i] <= floor:
            continue
        c = a[:, i] / scale[i]
        h = q.T @ c
        res = c - q @ h
        h2 = q.T @ res  # the second pass of Gram-Schmidt
        res -= q @ h2
        h += h2
        rho = float(np.linalg.norm(res))
        k = r.shape[0]
        grown = np.zeros((k + 1, k + 1))
        grown[:k, :k], grown[:k, k], grown[k, k] = r, h, rho
        sv = np.linalg.svd(grown, compute_uv=False)
        if int(np.sum(sv > tol * sv[0])) > rank:
            out.append(i)
            rank += 1
            q = np.column_stack([q, res / rho])
            r = grown
    return tuple(out)


def base_set(
    jac: np.ndarray, names: Sequence[str], effects: Sequence[str], rule: dict | None = None
) -> tuple[int, ...]:
    """Indices of an identifiable base set among the parameters of the given effects (see above;
    ``rule``: :func:`rank_rule` of the model)."""
    order = in_priority(names, [i for i, n in enumerate(names) if kind(n) in effects])
    return tuple(sorted(extend_base(jac, (), order, **(rule or {}))))


def weights(sigma: float | np.ndarray | None, shape: tuple[int, ...]) -> np.ndarray:
    """1 / sigma per coordinate (shape (n, 3)) from one sigma, one per reading (n,) or one per
    coordinate (n, 3); ones where no sigma is given."""
    if sigma is None:
        return np.ones(shape)
    s = np.asarray(sigma, float)
    return np.broadcast_to(1.0 / (s[:, None] if s.ndim == 1 else s), shape)


def calibrate(
    model: GeometricModel,
    q: np.ndarray,
    y: np.ndarray,
    effects: Sequence[str] = (),
    sigma: float | np.ndarray | None = None,
    tau: np.ndarray | None = None,
    free: Sequence[int] | None = None,
    theta0: np.ndarray | None = None,
) -> GeometryFit:
    """Fit the base set of ``effects`` to readings y (n, 3) at q; ``sigma`` (m, per axis: one number,
    or one per reading (n,) or per coordinate (n, 3)) when known: the residuals are weighted by it;
    ``tau`` the gravity torques (default: the model's nominal ones at q). ``free``: the parameters
    to fit, already a base set, in place of the base set of ``effects``; ``theta0``: the start of
    the free ones and the values of the others (default: zero, the nominal model)."""
    tau = model.torques(q) if tau is None else tau
    theta = np.zeros(model.size) if theta0 is None else np.asarray(theta0, float)
    if free is None:
        _, jac0 = model.jacobian(q, np.zeros(model.size), tau)
        free = base_set(jac0, model.names, effects, rank_rule(model))
    else:
        _, jac0 = model.jacobian(q, theta, tau, columns=free)
    idx = np.asarray(free, dtype=int)
    wf = weights(sigma, np.shape(y)).ravel()
    scale = np.linalg.norm(jac0.reshape(-1, model.size)[:, idx], axis=0)

    held = theta.copy()  # the parameters not fitted keep theta0's values

    def full(x):
        th = held.copy()
        th[idx] = x / scale
        return th

    def resid(x):
        try:
            return (model.predict(q, full(x), tau) - y).ravel() * wf
        except ValueError:  # statics.py: no equilibrium there; a huge residual makes LM step back
            return np.full(wf.size, 1e8)

    def jac(x):
        j = model.jacobian(q, full(x), tau, columns=idx)[1]
        return j.reshape(-1, model.size)[:, idx] * wf[:, None] / scale

    bounds = getattr(model, "bounds", None)  # statics.py: compliances kept positive
    _method = "lm"
    if bounds is None or not np.any(np.isfinite(np.concatenate([bounds[0][idx], bounds[1][idx]]))):
        sol = least_squares(resid, theta[idx] * scale, jac=jac, method="lm", xtol=1e-12, ftol=1e-12)
    else:
        lo, hi = bounds[0][idx] * scale, bounds[1][idx] * scale
        x0 = gauss_newton_start(resid, jac, np.clip(theta[idx] * scale, lo, hi), lo, hi)
        # dogbox, not trf: near the solution trf held its trust region at a fixed size along the
        # weakly determined directions (a balancer's K_C against its preload, condition ~4e4) and
        # crept down the last 10 % of chi2 in ~100 Jacobians of fresh equilibria; dogbox takes 7
        # to the same minimum (the paper's FANUC campaign, docs/geometry.md)
        sol = least_squares(resid, x0, jac=jac, method="dogbox", bounds=(lo, hi), xtol=1e-12, ftol=1e-12)
        _method = "dogbox"
    theta = full(sol.x)
    rw = sol.fun
    r = (rw / wf).reshape(-1, 3)
    dof = max(r.size - len(idx), 1)
    s2 = 1.0 if sigma is not None else float(rw @ rw) / dof
    # in x = theta * scale, whose columns are of one size (theta's span 1e10 in units: a spring's
    # N/m against a compliance's rad/(N*m), beyond pinv's 1e-15), then back: cov_theta = cov_x /
    # (scale scale^T). With bounds, the Jacobian is taken again at the solution (the solver's last
    # one may be an earlier iterate's).
    jx = sol.jac if _method == "lm" else jac(sol.x)
    cov = s2 * np.linalg.pinv(jx.T @ jx) / np.outer(scale, scale)  # pinv: the rank may drop far off
    rms = float(np.sqrt(np.mean(np.sum(r**2, 1))))
    return GeometryFit(
        model, theta, tuple(int(i) for i in idx), cov, rms, len(y), rw if sigma is not None else None
    )


def gauss_newton_start(resid, jac, x0: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """A start for the bounded fit: one Gauss-Newton step from x0, kept inside the bounds (a tenth
    of the way from a bound it would cross), where it lowers the residual; else x0.

    Why: a spring starts at K_C = 0, on its bound, and a balancer's is 1e5-1e6 N/m; a bounded
    solver's trust region grows to it over many Jacobians of fresh equilibria (scipy's ``trf``
    scales each step by the variable's distance to its bound: a factor ~2 per iteration).
    Compliances and springs act nearly linearly on the readings, so one linear step lands near
    the solution: measured on the paper's FANUC campaign with loads, 7 Jacobians with it, 40
    without (dogbox), to the same minimum."""
    r0 = resid(x0)
    j0 = jac(x0)
    step = np.linalg.lstsq(j0, -r0, rcond=None)[0]
    x1 = x0 + step
    inside_lo = np.where(x1 < lo, x0 + 0.9 * (lo - x0), x1)
    x1 = np.where(x1 > hi, x0 + 0.9 * (hi - x0), inside_lo)
    r1 = resid(x1)
    return x1 if float(r1 @ r1) < float(r0 @ r0) else x0


def refresh_torques(
    fit: GeometryFit,
    q: np.ndarray,
    y: np.ndarray,
    sigma: float | np.ndarray | None = None,
    rounds: int = 3,
) -> tuple[GeometryFit, np.ndarray]:
    """The fit repeated with the gravity torques at its own model's deflected pose
    (:meth:`GeometricModel.torques_at`) until they settle (``rounds`` at most; a round changes them
    by ~1e-3 of the last change): (the fit, the torques it used). Only a fit with compliances
    needs it: without, the fit is returned with the nominal torques."""
    if getattr(fit.model, "self_consistent", False):  # statics.py: each reading its own equilibrium
        return replace(fit, own_torques=True), fit.model.torques(q)
    if not any(kind(fit.model.names[i]) == "joint_compliance" for i in fit.free):
        return fit, fit.model.torques(q)
    tau = fit.model.torques(q)
    for _ in range(rounds):
        new = fit.model.torques_at(q, fit.theta)
        step = float(np.max(np.abs(new - tau)))
        tau = new
        fit = calibrate(fit.model, q, y, sigma=sigma, tau=tau, free=fit.free, theta0=fit.theta)
        if step < 1e-9 * max(1.0, float(np.max(np.abs(tau)))):
            break
    return replace(fit, own_torques=True), tau


@dataclass(frozen=True)
class Validation:
    """Held-out position errors (3-D distance per reading), m."""

    mean: float
    rms: float
    max: float
    n: int

    def as_dict(self) -> dict[str, float | int]:
        return {"mean": self.mean, "position_rms": self.rms, "max": self.max, "n": self.n}


def validate(fit: GeometryFit, q: np.ndarray, y: np.ndarray) -> Validation:
    """Predict held-out readings with a calibrated model: the only figure that counts on real data."""
    d = np.linalg.norm(fit.predict(q) - y, axis=1)
    return Validation(float(d.mean()), float(np.sqrt(np.mean(d**2))), float(d.max()), len(d))


def split(n: int, fraction: float = 0.7, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A random ``fraction`` of n rows to fit and the rest held out (fixed seed: same split)."""
    perm = np.random.default_rng(seed).permutation(n)
    k = int(round(fraction * n))
    return np.sort(perm[:k]), np.sort(perm[k:])
