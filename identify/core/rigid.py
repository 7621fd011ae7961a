"""The rigid transform from a tracker's frame to the robot's world: weighted fit and uncertainty.

Given points y_i measured in the tracker frame (covariance C_i there) and the same points p_i
predicted in the world frame, find R, t with

    p_i = R y_i + t + r_i,     minimising  sum_i r_i^T (R C_i R^T)^-1 r_i.

t is where the tracker stands (its frame's origin) and R its orientation (world from tracker).
Start: the closed-form least-squares solution with scalar weights (Horn 1987 / Kabsch: SVD of
the weighted cross-covariance, det fixed to +1), exact for an isotropic tracker; then
Gauss-Newton on the full covariances with R = exp([w]x) R_k (a left perturbation about world
axes), which needs one or two steps from there.

Uncertainty: the inverse Fisher information (J^T W J)^-1 of [w, t] at the solution (6 x 6,
rotation in rad about world x, y, z, position in m), what the tracker's noise alone leaves. The
residual tells whether the prediction itself is right: chi2 / dof (dof = 3n - 6) near 1 says the
points agree to the tracker's noise; far above, the model of the p_i (the robot's nominal
geometry) is off, and ``scale`` = sqrt(chi2 / dof) scales the uncertainty (the usual
Birge-ratio inflation: the misfit then dominates).

Units: SI (m, rad).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MAX_STEPS = 10
STEP_TOL = 1e-12  # rad and m: a Gauss-Newton step below this has converged (1e-6 of a um)


@dataclass(frozen=True)
class RigidFit:
    """A fitted tracker pose: world point = rotation @ tracker point + position."""

    rotation: np.ndarray  # (3, 3) world from tracker
    position: np.ndarray  # (3,) m, the tracker frame's origin in the world
    cov: np.ndarray  # (6, 6) of [rotation about world x, y, z (rad), position (m)]
    residual: np.ndarray  # (n, 3) m, world: predicted - registered measurement
    chi2: float
    n_points: int
    expected_rms: float  # m per axis: the RMS residual the measurement noise alone gives
    n_params: int = 6  # parameters fitted (more when fitted jointly with others)

    @property
    def dof(self) -> int:
        return 3 * self.n_points - self.n_params

    @property
    def chi2_per_dof(self) -> float:
        return self.chi2 / max(self.dof, 1)

    @property
    def scale(self) -> float:
        """sqrt(chi2 / dof) when above 1 (the misfit inflates the uncertainty), else 1."""
        return float(max(1.0, np.sqrt(self.chi2_per_dof)))

    @property
    def rms(self) -> float:
        """RMS residual per axis, m."""
        return float(np.sqrt(np.mean(self.residual**2))) if self.residual.size else 0.0

    @property
    def angle(self) -> float:
        """The rotation's angle about its own axis, rad (0 to pi)."""
        return float(np.arccos(np.clip((np.trace(self.rotation) - 1) / 2, -1, 1)))

    @property
    def rotation_std(self) -> np.ndarray:
        """(3,) rad about world x, y, z, scaled by the misfit."""
        return np.sqrt(np.diag(self.cov)[:3]) * self.scale

    @property
    def position_std(self) -> np.ndarray:
        """(3,) m, scaled by the misfit."""
        return np.sqrt(np.diag(self.cov)[3:]) * self.scale


def skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def rotation_exp(w: np.ndarray) -> np.ndarray:
    """Rodrigues: the rotation by |w| rad about w."""
    th = float(np.linalg.norm(w))
    if th < 1e-300:
        return np.eye(3)
    k = skew(np.asarray(w, dtype=float) / th)
    return np.eye(3) + np.sin(th) * k + (1 - np.cos(th)) * (k @ k)


def kabsch(y: np.ndarray, p: np.ndarray, weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) minimising sum_i w_i |R y_i + t - p_i|^2 (closed form, proper rotation)."""
    w = np.ones(len(y)) if weights is None else np.asarray(weights, dtype=float)
    w = w / w.sum()
    cy, cp = w @ y, w @ p
    h = ((y - cy) * w[:, None]).T @ (p - cp)
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    rot = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return rot, cp - rot @ cy


def non_collinear(y: np.ndarray, tol: float = 1e-3) -> bool:
    """At least three points not on one line (to tol m): a rigid transform is then determined."""
    if len(y) < 3:
        return False
    s = np.linalg.svd(y - y.mean(axis=0), compute_uv=False)
    return bool(s[1] > tol)


def fit_rigid(y: np.ndarray, p: np.ndarray, cov: np.ndarray) -> RigidFit:
    """Register tracker-frame points ``y`` (n, 3) with covariances ``cov`` (n, 3, 3) onto world
    points ``p`` (n, 3): see the module docstring. Needs three points not on one line."""
    y, p, cov = np.asarray(y, float), np.asarray(p, float), np.asarray(cov, float)
    if not non_collinear(y):
        raise ValueError("a rigid fit needs at least three points not on one line")
    cinv = np.linalg.inv(cov)
    rot, t = kabsch(y, p, 1.0 / np.trace(cov, axis1=1, axis2=2))
    for _ in range(MAX_STEPS):
        jtj, jtr, _, _ = _normal(y, p, cinv, rot, t)
        step = np.linalg.solve(jtj, jtr)
        rot = rotation_exp(step[:3]) @ rot
        t = t + step[3:]
        if np.abs(step).max() < STEP_TOL:
            break
    jtj, _, r, chi2 = _normal(y, p, cinv, rot, t)
    cov6 = np.linalg.inv(jtj)
    expected = float(np.sqrt(np.mean([np.trace(c) / 3 for c in cov])))
    return RigidFit(rot, t, cov6, r, chi2, len(y), expected)


def _normal(y, p, cinv, rot, t):
    """J^T W J, J^T W r, r and chi2 at (rot, t) with r = p - (R y + t) (world frame)."""
    ry = y @ rot.T
    r = p - (ry + t)
    w = rot @ cinv @ rot.T  # (n, 3, 3) world-frame weights
    jac = np.zeros((len(y), 3, 6))
    jac[:, :, :3] = -np.array([skew(v) for v in ry])  # d(R y)/dw = -[R y]x
    jac[:, :, 3:] = np.eye(3)
    jw = np.einsum("nki,nkl->nil", jac, w)  # J^T W per point (6, 3)
    jtj = np.einsum("nil,nlj->ij", jw, jac)
    jtr = np.einsum("nil,nl->i", jw, r)
    chi2 = float(np.einsum("ni,nij,nj->", r, w, r))
    return jtj, jtr, r, chi2


__all__ = ["RigidFit", "fit_rigid", "kabsch", "rotation_exp", "skew", "non_collinear"]
