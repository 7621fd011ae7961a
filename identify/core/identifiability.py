"""What a plan can and cannot identify, and which readings do not fit.

Rank. The observation matrix is whitened by the tracker covariances (rows) and its columns are
normalised to unit length (so units and parameter sizes drop out); its singular values
s_1 >= ... >= s_p give the rank as the number with s_i > RANK_TOL * s_1, RANK_TOL = 1e-6. With
unit columns a direction below it would need measurements 1e6 times more precise than the
best-determined direction to be seen (sub-picometre at 20 um). Measured on this robot: a
structurally lost direction (k1 under vertical loads, the compensator with one q2) comes out at
1e-16, while the identifiable directions of the paper plan sit at >= 0.17 of s_1 -- the
tolerance is not critical anywhere in between. A column below 1e-12 of the largest is a zero
column (the parameter has no effect at all). Parameters with a component larger than NULL_TOL
in the numerical null space are reported unidentifiable, with a reason:

* k_i's column is zero because no load puts a torque on motor i: for a vertical axis (the
  FANUC's k1) with loads that are all vertical, paper §5.1; generally "no pose loads motor i";
* k_i's column is zero although motor i is loaded: the reflectors seen do not move when motor i
  turns (e.g. every reflector on the J6 axis: the reflector set sees no rotation about it);
* a compensator's K_C, s0 and the compliance of the joint it spans (the FANUC's k2) mixed in the
  null space with fewer than three distinct angles of that joint (q2): paper §4, step 2 needs
  the aggregated J2 stiffness at three or more q2 to separate K_theta2, K_C and s0. (The
  exact model also sees the compensator's static torque, eq. 9, through the J2 sag it causes,
  one more equation per q2: on this robot the one-step estimator separates them from two q2,
  and fails with one.)
* anything else: "the plan does not separate these parameters" with the combination.

Resolution. The rank is a statement about numbers, not about noise: RANK_TOL asks whether a
direction is there at all, and the exact model makes directions that the linear model lacks
faintly there. With two distinct q2 the compensator is seen only through its static torque's
effect on the J2 sag (a second-order effect): its direction sits at ~0.05 of s_1, far above
1e-6, so the rank analysis calls K_C and s0 identifiable -- and the fit then reports, for a
2-pose plan with q2 in {0, 120} deg, K_C = 1196 +- 159207 kN/m, or runs off to K_C -> 0,
s0 -> infinity without converging. So after the fit, :func:`resolve` also asks the statistical
question on the estimate's covariance (inverse Fisher information, the tracker's noise in it):
a parameter whose standard deviation exceeds MAX_RELATIVE_STD (1) times its own size is not
determined by the plan -- the data do not tell its size, nor that it is not zero -- and is
reported unidentifiable like a structurally lost one, with the reason (fewer than three q2 for
the compensator, else the parameter it is confounded with). The threshold is not tuned: below
it the estimate is at least one standard deviation from zero; every parameter of the paper plan
is determined to better than 0.2 of its size (k4, the worst: 0.09), the compensator of a
2-pose plan to 0.3 ... 1e10 depending on the poses.

Outliers. After the fit each observation's whitened residual r_w = L^-1 (dp - f), L L^T = Cov,
gives the Mahalanobis distance d = |r_w|; d > OUTLIER_SIGMA (5) flags the (pose, reflector):
a tracker reading more than 5 sigma off. For a correct reading d^2 ~ chi^2(3) (slightly less:
the fit absorbs p of the M*3 degrees of freedom), so P(d > 5) = 1.5e-5 per observation.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calbench.bench.model import ParamLayout

from .tolerances import MAX_RELATIVE_STD, NULL_TOL, RANK_TOL, ZERO_COLUMN_TOL

OUTLIER_SIGMA = 5.0


@dataclass
class Identifiability:
    """Result of the rank analysis of a scaled observation matrix."""

    names: tuple[str, ...]
    singular_values: np.ndarray  # of the column-normalised matrix, descending
    rank: int
    identifiable: np.ndarray  # (p,) bool
    null_vectors: np.ndarray  # (p, p - rank) in column-normalised coordinates
    column_norms: np.ndarray  # (p,)
    reasons: dict[str, str] = field(default_factory=dict)
    relative_std: np.ndarray | None = None  # (p,) std / |estimate|, after :func:`resolve`
    unresolved: np.ndarray | None = None  # (p,) bool: rank says yes, the noise says no
    correlation: np.ndarray | None = None  # (p, p) of the estimate, after :func:`resolve`

    @property
    def condition(self) -> float:
        s = self.singular_values[: self.rank]
        return float(s[0] / s[-1]) if self.rank else float("inf")

    def as_dict(self) -> dict:
        return {
            "rank": int(self.rank),
            "n_parameters": len(self.names),
            "tolerance": RANK_TOL,
            "null_tolerance": NULL_TOL,
            "singular_values_scaled": [float(x) for x in self.singular_values],
            "condition_number": self.condition,
            "identifiable": {n: bool(b) for n, b in zip(self.names, self.identifiable)},
            "unidentifiable_reasons": dict(self.reasons),
            "max_relative_std": MAX_RELATIVE_STD,
            "relative_std": (
                None
                if self.relative_std is None
                else {
                    n: (float(x) if np.isfinite(x) else None) for n, x in zip(self.names, self.relative_std)
                }
            ),
        }


def analyze(jw: np.ndarray, names: tuple[str, ...]) -> Identifiability:
    """Rank, identifiable parameters and null space of a whitened matrix jw (rows, p)."""
    p = jw.shape[1]
    norms = np.linalg.norm(jw, axis=0)
    big = norms.max() if norms.size and norms.max() > 0 else 1.0
    zero = norms <= ZERO_COLUMN_TOL * big
    scale = np.where(zero, 1.0, norms)
    jn = jw / scale
    jn[:, zero] = 0.0
    _, s, vt = (
        np.linalg.svd(jn, full_matrices=jn.shape[0] < p) if jn.shape[0] else (None, np.zeros(p), np.eye(p))
    )
    s_full = np.zeros(p)
    s_full[: len(s)] = s
    rank = int(np.sum(s_full > RANK_TOL * (s_full[0] if s_full[0] > 0 else 1.0)))
    null = vt[rank:].T  # (p, p - rank)
    weight = np.sqrt((null**2).sum(axis=1)) if null.size else np.zeros(p)
    ident = (weight <= NULL_TOL) & ~zero
    return Identifiability(tuple(names), s_full, rank, ident, null, norms)


def resolve(ident: Identifiability, theta: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """The statistical half of identifiability (module docstring, "Resolution"): mark as not
    identifiable every parameter that the rank calls identifiable but whose standard deviation
    (from ``cov``, the covariance of the estimate ``theta``, same units) exceeds
    MAX_RELATIVE_STD times |theta|. Updates ``ident`` and returns the unresolved mask."""
    theta = np.asarray(theta, dtype=float)
    var = np.diag(np.asarray(cov, dtype=float))
    with np.errstate(invalid="ignore", divide="ignore"):
        sd = np.sqrt(np.where(var >= 0, var, np.nan))
        rel = sd / np.abs(theta)
        corr = np.asarray(cov, dtype=float) / np.outer(sd, sd)
    unresolved = ident.identifiable & ~(rel <= MAX_RELATIVE_STD)  # NaN is unresolved too
    ident.relative_std, ident.unresolved, ident.correlation = rel, unresolved, corr
    ident.identifiable = ident.identifiable & ~unresolved
    return unresolved


def explain(ident: Identifiability, layout: ParamLayout, facts: dict) -> dict[str, str]:
    """Name the reason for every unidentifiable parameter (fills ``ident.reasons``).

    ``facts`` (identify/methods/twostep.py's plan_facts): motor_torque_seen (N,) bool, whether some
    pose's load puts a torque on motor i; loads_vertical; vertical_axes (N,) bool, motor axes
    along gravity at every pose; compensator_joint, the compensator's joint (or None) and
    n_distinct_q2, the distinct angles of that joint in the plan.
    """
    names = ident.names
    reasons: dict[str, str] = {}
    seen, vertical_axes = facts["motor_torque_seen"], facts.get("vertical_axes")
    j2, n_q2 = facts.get("compensator_joint"), facts["n_distinct_q2"]
    comp = set()
    if j2 is not None and layout.compensators:
        comp = {f"k{j2 + 1}", layout.names[layout.stiffness_index[0]], layout.names[layout.preload_index[0]]}
    for i, name in enumerate(names):
        if ident.identifiable[i]:
            continue
        if ident.unresolved is not None and ident.unresolved[i]:
            reasons[name] = _unresolved_reason(ident, i, n_q2, j2 if name in comp else None)
            continue
        if name.startswith("k") and name[1:].isdigit():
            j = int(name[1:]) - 1
            zero_col = ident.column_norms[i] <= ZERO_COLUMN_TOL * max(ident.column_norms.max(), 1e-300)
            if zero_col and not seen[j]:
                if facts["loads_vertical"] and vertical_axes is not None and vertical_axes[j]:
                    reasons[name] = (
                        f"every load is vertical, so none turns the J{j + 1} axis (paper §5.1): "
                        f"k{j + 1} needs a non-vertical load with the arm outstretched"
                    )
                else:
                    reasons[name] = f"no pose's load puts a torque on motor {j + 1}"
                continue
            if zero_col:
                reasons[name] = (
                    f"no reflector seen moves when motor {j + 1} turns: the reflector "
                    "set sees no rotation about that axis"
                )
                continue
        if name in comp and n_q2 < 3:
            q, jn = f"q{j2 + 1}", f"J{j2 + 1}"
            reasons[name] = (
                f"only {n_q2} distinct {q} in the plan: too few to separate "
                f"K_theta{j2 + 1}, K_C and s0 (the paper's step 2, eqs. 21-22, needs the {jn} "
                f"stiffness at three {q}; the exact model adds the compensator's torque, "
                f"one more equation per {q})"
            )
            continue
        mix = [
            names[k]
            for k in range(len(names))
            if ident.null_vectors.size and np.sqrt((ident.null_vectors[k] ** 2).sum()) > NULL_TOL
        ]
        reasons[name] = (
            "the plan does not separate "
            + ", ".join(mix)
            + " (a combination of them leaves every measured deflection unchanged)"
        )
    ident.reasons = reasons
    return reasons


def _unresolved_reason(ident: Identifiability, i: int, n_q2: int, j2: int | None) -> str:
    """Why parameter i is unresolved; ``j2`` the compensator's joint when i is one of its
    parameters (or of that joint's spring), else None."""
    rel = ident.relative_std[i]
    head = (
        f"the plan determines it only to +-{100 * rel:,.0f} % of its value, so not even that it is not zero"
        if np.isfinite(rel) and rel < 1e4
        else "the plan does not determine it: its standard deviation dwarfs the estimate"
    )
    if j2 is not None and n_q2 < 3:
        q = f"q{j2 + 1}"
        return (
            head + f": only {n_q2} distinct {q} in the plan; K_theta{j2 + 1}, K_C and s0 "
            f"need the J{j2 + 1} stiffness at three or more {q} (the paper's step 2, eqs. 21-22)"
        )
    corr = ident.correlation[i] if ident.correlation is not None else None
    if corr is not None:
        others = [
            (abs(c), k)
            for k, c in enumerate(corr)
            if k != i and np.isfinite(c) and ident.unresolved is not None and not ident.unresolved[k]
        ]
        if others:
            c, k = max(others)
            if c > 0.5:
                return head + f": confounded with {ident.names[k]} (correlation {corr[k]:+.2f})"
    return head


def whiten_factors(cov: np.ndarray) -> np.ndarray:
    """(M,3,3) inverse Cholesky factors L^-1 with L L^T = cov (so L^-1 cov L^-T = I)."""
    chol = np.linalg.cholesky(cov)
    return np.linalg.inv(chol)


def outliers(
    residual_w: np.ndarray, labels: list[tuple[int, str]], threshold: float = OUTLIER_SIGMA
) -> list[dict]:
    """(pose, reflector) whose whitened residual (M,3) has Mahalanobis distance > threshold."""
    d = np.linalg.norm(residual_w, axis=1)
    return [
        {"pose": int(labels[i][0]), "reflector": labels[i][1], "sigma": float(d[i])}
        for i in np.flatnonzero(d > threshold)
    ]


__all__ = [
    "RANK_TOL",
    "NULL_TOL",
    "OUTLIER_SIGMA",
    "MAX_RELATIVE_STD",
    "Identifiability",
    "analyze",
    "resolve",
    "explain",
    "whiten_factors",
    "outliers",
]
