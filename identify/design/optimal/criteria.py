"""Performance measures of a measurement plan (issue 4, §1), from its Fisher information.

F = sum_i n_i R_i^T R_i with R_i the whitened regressor of pose i with respect to the
NORMALISED parameters u = theta / theta0 (identify/design_candidates.py), so C = F^-1 is the
covariance of the relative errors (the one-step estimator attains it: tests/test_montecarlo.py).

* ``A``  (paper O1): trace C, the sum of the parameters' relative variances.
* ``D``  (paper O2, reported as its p-th root): det(C)^(1/p), p = 8.
* ``AD`` (paper O3, "the weighted sum of the trace and the determinant"): 0.5 A + 0.5 D. The
  weights are read off the paper's Table 1, where O3 = (O1 + O2) / 2 in every row
  (8.19 = (14.27 + 2.11)/2, 5.77 ~ (9.85 + 1.68)/2, 4.59 ~ (7.86 + 1.33)/2).
* ``pose``: the variance of the predicted compliance error at the work pose, trace(G C G^T) (m^2),
  G (3 x 8) = d(deflection of the payload site under the work wrench)/du at the scenario's
  ``[work]`` pose (exact statics, identify/design_candidates.InfoEngine.work_jacobian). Its
  square root is the RMS error of the compensation the identified model would apply there.

All four are "smaller is better". A singular F gives +inf.
"""

from __future__ import annotations

import numpy as np

CRITERIA = ("A", "D", "AD", "pose")
AD_WEIGHTS = (0.5, 0.5)


def information(blocks: np.ndarray, idx=None, repeats=None) -> np.ndarray:
    """F = sum over the plan of n_i R_i^T R_i; blocks (N, m, p), idx into them (default all)."""
    b = blocks if idx is None else blocks[np.asarray(idx, int)]
    w = np.ones(len(b)) if repeats is None else np.asarray(repeats, float)
    return np.einsum("n,nmi,nmj->ij", w, b, b)


def inverse_information(F: np.ndarray) -> np.ndarray | None:
    """F^-1, or None when F is singular (rank-deficient to working precision)."""
    F = 0.5 * (F + F.T)
    try:
        c = np.linalg.cholesky(F)
    except np.linalg.LinAlgError:
        return None
    d = np.diag(c)
    if d.min() <= 1e-10 * d.max():
        return None
    ci = np.linalg.inv(c)
    return ci.T @ ci


def measures(F: np.ndarray, G: np.ndarray | None = None) -> dict:
    """All measures of information F (and the pose measure when G is given)."""
    p = F.shape[0]
    C = inverse_information(F)
    if C is None:
        out = {"A": np.inf, "D": np.inf, "AD": np.inf, "std": np.full(p, np.inf)}
        if G is not None:
            out["pose"] = np.inf
        return out
    sign, logdet = np.linalg.slogdet(F)
    a = float(np.trace(C))
    d = float(np.exp(-logdet / p))
    out = {"A": a, "D": d, "AD": AD_WEIGHTS[0] * a + AD_WEIGHTS[1] * d, "std": np.sqrt(np.diag(C))}
    if G is not None:
        out["pose"] = float(np.trace(G @ C @ G.T))
    return out


def criterion_value(name: str, F: np.ndarray, G: np.ndarray | None = None) -> float:
    if name == "pose" and G is None:
        raise ValueError("the pose criterion needs the work-pose Jacobian G")
    return float(measures(F, G)[name])


def weight_matrix(name: str, p: int, G: np.ndarray | None = None) -> np.ndarray:
    """W of the linear criteria trace(W C): identity for A / AD, G^T G for pose."""
    if name == "pose":
        if G is None:
            raise ValueError("the pose criterion needs the work-pose Jacobian G")
        return G.T @ G
    return np.eye(p)


def combine(name: str, trw, logdet, p: int):
    """Criterion from trace(W C) and log det F (arrays allowed)."""
    if name in ("A", "pose"):
        return trw
    d = np.exp(-np.asarray(logdet) / p)
    if name == "D":
        return d
    if name == "AD":
        return AD_WEIGHTS[0] * trw + AD_WEIGHTS[1] * d
    raise ValueError(f"unknown criterion {name!r}")


__all__ = [
    "CRITERIA",
    "AD_WEIGHTS",
    "information",
    "inverse_information",
    "measures",
    "criterion_value",
    "weight_matrix",
    "combine",
]
