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

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from calbench.identify.core import GEOMETRY_RANK_TOL as RANK_TOL  # identify/core/tolerances.py
from calbench.identify.core import fit_rigid

from .chain import Chain
from .model import GeometricModel, kind

# the models a validation compares, by the effects each one fits
MODELS = {
    "nominal": ("base_frame", "tool_frame"),
    "geometry": ("base_frame", "tool_frame", "joint_offset", "link_geometry"),
    "geometry+compliance": ("base_frame", "tool_frame", "joint_offset", "link_geometry", "joint_compliance"),
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

    @property
    def names(self) -> list[str]:
        return [self.model.names[i] for i in self.free]

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.diag(self.cov))

    def predict(self, q: np.ndarray) -> np.ndarray:
        return self.model.predict(q, self.theta)

    def calibrated(self) -> tuple[Chain, np.ndarray, np.ndarray, np.ndarray]:
        """The fit folded into a plain chain: (chain, probe point in the flange frame, tracker from
        robot base (4x4), joint compliances (0 where not fitted)). Each link frame becomes
        P_k E_k Rz(o_k), so that the calibrated chain at q is the fitted model at q without the
        compliance term (which a calbench MJCF carries as joint stiffness 1/c)."""
        return self.model.calibrated(self.theta)


def initial_model(chain: Chain, q: np.ndarray, y: np.ndarray, tool: np.ndarray) -> GeometricModel:
    """The nominal model registered on the readings (closed-form rigid fit, Horn/Kabsch) as start.

    ``tool``: the probe in the flange frame (e.g. :func:`tool_from_transform` of the dataset's
    probe-to-flange transform)."""
    p = chain.flange_point(q, tool)
    reg = fit_rigid(y, p, np.broadcast_to(np.eye(3) * 1e-8, (len(y), 3, 3)))
    base0 = np.eye(4)
    base0[:3, :3] = reg.rotation.T  # tracker from robot: y = R^T (p - t)
    base0[:3, 3] = -reg.rotation.T @ reg.position
    return GeometricModel(chain, base0, np.asarray(tool, float))


def tool_from_transform(probe_to_flange: np.ndarray) -> np.ndarray:
    """The probe's origin in the flange frame from a 4x4 transform of flange coordinates into probe
    coordinates (the dataset's ``Trafo_TM_F``, which puts the flange 109 mm behind the probe)."""
    r, t = probe_to_flange[:3, :3], probe_to_flange[:3, 3]
    return -r.T @ t


def base_set(jac: np.ndarray, names: Sequence[str], effects: Sequence[str]) -> tuple[int, ...]:
    """Indices of an identifiable base set among the parameters of the given effects (see above)."""
    order = ("base_frame", "tool_frame", "joint_offset", "joint_compliance", "link_geometry")
    a = jac.reshape(-1, jac.shape[-1])
    scale = np.linalg.norm(a, axis=0)
    chosen: list[int] = []
    rank = 0
    for eff in order:
        if eff not in effects:
            continue
        for i, name in enumerate(names):
            # a column of rounding noise only (a rotation about an axis through the probe) is
            # no parameter: it would enter with any scaling
            if kind(name) != eff or scale[i] <= RANK_TOL * np.median(scale):
                continue
            cols = a[:, [*chosen, i]] / scale[[*chosen, i]]
            s = np.linalg.svd(cols, compute_uv=False)
            r = int(np.sum(s > RANK_TOL * s[0]))
            if r > rank:
                chosen.append(i)
                rank = r
    return tuple(sorted(chosen))


def calibrate(
    model: GeometricModel,
    q: np.ndarray,
    y: np.ndarray,
    effects: Sequence[str],
    sigma: float | None = None,
    tau: np.ndarray | None = None,
) -> GeometryFit:
    """Fit the base set of ``effects`` to readings y (n, 3) at q; ``sigma`` (m, per axis) when known;
    ``tau`` the gravity torques (default: the model's nominal ones at q)."""
    tau = model.torques(q) if tau is None else tau
    theta = np.zeros(model.size)
    _, jac0 = model.jacobian(q, theta, tau)
    free = base_set(jac0, model.names, effects)
    idx = np.asarray(free)
    scale = np.linalg.norm(jac0.reshape(-1, model.size)[:, idx], axis=0)

    def full(x):
        th = np.zeros(model.size)
        th[idx] = x / scale
        return th

    def resid(x):
        return (model.predict(q, full(x), tau) - y).ravel()

    def jac(x):
        return model.jacobian(q, full(x), tau)[1].reshape(-1, model.size)[:, idx] / scale

    sol = least_squares(resid, np.zeros(len(idx)), jac=jac, method="lm", xtol=1e-12, ftol=1e-12)
    theta = full(sol.x)
    r = sol.fun.reshape(-1, 3)
    dof = max(r.size - len(idx), 1)
    s2 = sigma**2 if sigma is not None else float(r.ravel() @ r.ravel()) / dof
    js = sol.jac * scale  # d/d theta = d/dx * scale (x = theta * scale)
    cov = s2 * np.linalg.pinv(js.T @ js)  # pinv: a start far off may end where the rank drops
    return GeometryFit(model, theta, free, cov, float(np.sqrt(np.mean(np.sum(r**2, 1)))), len(y))


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
