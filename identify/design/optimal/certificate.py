"""Approximate optimal designs and a certified bound for every exact plan (issue 16).

An exact plan of M poses from N candidates (repeats allowed) has information F = sum_i n_i A_i,
A_i = R_i^T R_i (R_i the candidate's whitened block, p = 8 columns), sum n_i = M. Written as
F = M M(xi) with the design measure xi = n / M, the best exact plan is bounded by the best
APPROXIMATE design, where the weights w (w >= 0, sum w = 1) are free reals:

    max over plans log det F  <=  p ln M + max_w log det M(w),                        (1)
    min over plans tr(W F^-1) >=  min_w tr(W M(w)^-1) / M.                            (2)

Kiefer-Wolfowitz equivalence theorem (Kiefer & Wolfowitz 1960; for blocks A_i of any rank,
Fedorov 1972 §2.6 / Pukelsheim 1993 §9): w is D-optimal iff max_i d_i(w) = p, where
d_i(w) = tr(M(w)^-1 A_i) and sum_i w_i d_i = p. For any w, optimal or not, with M(w) > 0:

    log det M(w') - log det M(w) = sum_k ln lambda_k(M(w)^-1 M(w'))
                                 <= p ln(tr(M(w)^-1 M(w')) / p)       (AM-GM on the eigenvalues)
                                  = p ln(sum_i w'_i d_i(w) / p) <= p ln(max_i d_i(w) / p),

so the D bound used here, valid whether or not the algorithm converged, is

    bound_logdet = p ln M + log det M(w) + p ln(max_i d_i(w) / p).                    (3)

A (and the work-pose measure: W = G^T G; A is W = I). With a_i(w) = tr(A_i M^-1 W M^-1) and
t(w) = tr(W M(w)^-1) = sum_i w_i a_i, the equivalence theorem reads max_i a_i = t (Kiefer 1974;
Fedorov 1972 §2.9). The dual bound: for every design w', Cauchy-Schwarz on
tr(W M^-1) = tr[(V^T M'^-1/2)(M'^1/2 M^-1 V)] (W = V V^T, M' = M(w')) gives
t(w)^2 <= tr(W M'^-1) tr(M' M^-1 W M^-1) = tr(W M'^-1) sum_i w'_i a_i(w), hence

    min_w' tr(W M(w')^-1) >= t(w)^2 / max_i a_i(w) = t(w) / (max_i a_i(w) / t(w)),    (4)

the weak duality of Pukelsheim's (1993, §7.21) dual problem for A-optimality, evaluated at the
dual point N = M^-1 W M^-1 / max_i a_i. Both gaps vanish at the optimum and have one form: with
g_i = d_i / p (D) or a_i / t (A), w is certified within a factor 1 / max_i g_i of the optimum
(in det^(1/p) for D, in the trace for A).

Distinct plans (no candidate twice) are the designs with w_i <= 1 / M. Over that capped simplex,
sum_i w'_i d_i(w) <= the mean of the M largest d_i(w), which replaces max_i d_i in (3) and (4):
a bound on the best DISTINCT plan, tighter than the one with repeats.

AD (0.5 trace + 0.5 det^(1/p) of C = F^-1): the sum of the two bounds (the minimum of a sum is at
least the sum of the minima), so it is valid but not tight.

Efficiency of a plan: D: exp((plan_logdet - bound_logdet) / p); A, pose, AD: bound / plan. A plan
with efficiency 0.99 is, provably, within 1 % of the best M-pose plan from these candidates.

Algorithms (chosen by benchmarks/certificate_bench.py on the paper scenario's candidates):

* ``multiplicative``: w_i <- w_i g_i (D; Titterington 1976, Silvey, Titterington & Torsney 1978)
  and w_i <- w_i g_i^(1/2) / sum (A; Yu 2010's monotone power 1/2). Monotone, full support,
  sublinear near the optimum.
* ``fw-away``: Frank-Wolfe / Fedorov-Wynn vertex steps with Wolfe's away steps (Wolfe 1970;
  Atwood 1973; Todd & Yildirim 2007), exact line search on the p eigenvalues of the step, sparse
  support, started from a given plan (the exchange's). With a cap (distinct), the away and toward
  steps become pairwise transfers between the support point of lowest g and the uncapped point
  of highest g (Bohning's 1986 vertex exchange).

Measured (benchmarks/certificate_bench.py, paper scenario, M = 12, N = 10^4): to a gap of 1e-4,
fw-away from the exchange's plan takes 0.10 s (D, 881 iterations) and 0.42 s (A, 3200), the
multiplicative 0.67 s (D, 4375) and 1.05 s (A, 6998). To a gap of 1e-3 the multiplicative is
sometimes ahead (D at 10^4: 0.066 s against 0.078 s; A at N = 2000), never by much. fw-away is
the default, and the default gap 1e-4 leaves the bound loose by at most
0.01 % (D, in det^(1/p)) and 0.01 % (A, in the trace).

Columns are scaled internally to unit mean information (as ``normalise_blocks``): log det shifts
by a constant, g_i are unchanged, so the designs and bounds are those of the blocks as given.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from calbench.identify.runtime import blas_threads as pinned_blas

from .criteria import AD_WEIGHTS, criterion_value, weight_matrix
from .exchange import compress

ALGORITHMS = ("fw-away", "multiplicative")


# A column (a parameter's RMS information over the candidates, blocks in prior-relative units) below
# this share of the largest is taken as zero: the plan would need readings 1e8 times more precise
# for it than for the best-seen parameter. Met: 6.7e-11 for k6 with the payload on the J6 axis of
# an M-710iC/50 (link_6's centre of mass on the axis too, to the mesh's rounding), where
# normalising blew that column up to unit noise and design wrote a plan of A = inf; 6.5e-7 for
# the tests' arm's k6 seen through link_6's own weight (tests/test_design_why.py), planned for.
MIN_COLUMN = 1e-8


class SingularCandidates(ValueError):
    """The candidates' total information is singular: no plan identifies every parameter."""


def column_scale(blocks: np.ndarray) -> np.ndarray:
    """s (p,): the RMS of each column over all candidates' rows, sqrt(diag(mean_i A_i))."""
    n = len(blocks)
    return np.sqrt(np.einsum("nij,nij->j", blocks, blocks) / n)


def normalise_blocks(blocks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(blocks / s, s): columns rescaled to unit mean information, diag(mean_i A_i) = 1.

    Every plan's log det F moves by the same -2 sum ln s_k, so the D-optimal plan (and every D
    efficiency) is unchanged; A and the pose measure re-weight parameter k by s_k^2 and do change.
    """
    s = column_scale(blocks)
    if not np.all(s > MIN_COLUMN * s.max()):
        raise SingularCandidates(
            f"column(s) {np.flatnonzero(~(s > MIN_COLUMN * s.max())).tolist()} zero in every block, "
            f"or below {MIN_COLUMN:g} of the largest: those parameters are not identifiable from any plan"
        )
    return blocks / s, s


def check_identifiable(blocks: np.ndarray) -> None:
    """Raise SingularCandidates unless the candidates' mean information is nonsingular (after
    column normalisation, its Cholesky pivots all above 1e-8 of the unit diagonal)."""
    b, _ = normalise_blocks(np.asarray(blocks, float))
    mean = np.einsum("nki,nkj->ij", b, b) / len(b)
    try:
        ok = np.diag(np.linalg.cholesky(mean)).min() > 1e-8
    except np.linalg.LinAlgError:
        ok = False
    if not ok:
        raise SingularCandidates(
            "the candidates' total information is singular: some parameter is not identifiable from any plan"
        )


@dataclass(frozen=True)
class ApproximateDesign:
    """An approximate design on the candidates and its equivalence-theorem sensitivity."""

    criterion: str  # "D" or "A" (A with weight matrix W: A, pose)
    p: int  # parameters
    weights: np.ndarray  # (N,) w >= 0, sum 1 (w <= cap when capped)
    cap: float | None  # 1/M for distinct plans, None for repeats
    sensitivity: np.ndarray  # (N,) g_i = d_i / p (D) or a_i / t (A); optimal iff the max is 1
    logdet: float  # log det M(w) (blocks as given)
    trace_w: float  # tr(W M(w)^-1) (A; nan for D)
    algorithm: str
    iterations: int
    seconds: float
    history: tuple = ()  # (iteration, seconds, g_max - 1) at each check

    @property
    def g_bound(self) -> float:
        """max of sum_i w'_i g_i over the feasible w' (the factor in (3) and (4))."""
        if self.cap is None:
            return float(self.sensitivity.max())
        k = int(round(1.0 / self.cap))
        return float(np.sort(self.sensitivity)[-k:].mean())

    def support(self, rel: float = 1e-2) -> np.ndarray:
        """Candidates carrying weight above rel x the largest, heaviest first."""
        idx = np.flatnonzero(self.weights > rel * self.weights.max())
        return idx[np.argsort(-self.weights[idx], kind="stable")]


# --------------------------------------------------------------------------- the algorithms


class _Problem:
    """Scaled candidate information A_i (flattened) and the criterion's sensitivities."""

    def __init__(self, blocks: np.ndarray, criterion: str, W: np.ndarray | None):
        if criterion not in ("D", "A"):
            raise ValueError(f"approximate designs for D and A only, not {criterion!r}")
        b, s = normalise_blocks(np.asarray(blocks, float))
        self.scale_logdet = 2.0 * float(np.log(s).sum())
        T = compress(b)
        self.p = b.shape[2]
        self.A = np.einsum("nki,nkj->nij", T, T).reshape(len(b), -1)  # (N, p*p)
        # tr(X A_i) for symmetric X from the upper triangle: off-diagonal terms counted twice
        self.tri = np.flatnonzero(np.triu(np.ones((self.p, self.p), bool)).ravel())
        twice = np.where(np.eye(self.p, dtype=bool).ravel()[self.tri], 1.0, 2.0)
        self.A_tri = np.ascontiguousarray(self.A[:, self.tri] * twice)  # (N, p(p+1)/2)
        self.criterion = criterion
        W = np.eye(self.p) if W is None else np.asarray(W, float)
        self.W = W / np.outer(s, s)
        self.n = len(b)

    def info(self, w: np.ndarray) -> np.ndarray:
        M = (w @ self.A).reshape(self.p, self.p)
        return 0.5 * (M + M.T)

    def state(self, M: np.ndarray):
        """(L, Minv, log det M, t, g): g_i = d_i/p (D) or a_i/t (A)."""
        L = np.linalg.cholesky(M)
        Li = np.linalg.inv(L)
        Minv = Li.T @ Li
        logdet = 2.0 * float(np.log(np.diag(L)).sum())
        if self.criterion == "D":
            return L, Minv, logdet, math.nan, (self.A_tri @ Minv.ravel()[self.tri]) / self.p
        K = Minv @ self.W @ Minv
        t = float(np.trace(self.W @ Minv))
        return L, Minv, logdet, t, (self.A_tri @ (0.5 * (K + K.T)).ravel()[self.tri]) / t

    def step(self, L: np.ndarray, B: np.ndarray, amax: float) -> float:
        """Exact line search of the criterion on M + a B, a in [0, amax].

        With mu, U the eigen-pairs of L^-1 B L^-T: log det(M + aB) = log det M + sum ln(1 + a mu)
        (concave in a), tr(W (M + aB)^-1) = sum c_k / (1 + a mu_k), c = diag(U^T L^-1 W L^-T U)
        (convex). Safeguarded Newton on the derivative."""
        Li = np.linalg.inv(L)
        mu, U = np.linalg.eigh(Li @ B @ Li.T)
        if self.criterion == "D":

            def d1(a):
                r = mu / (1 + a * mu)
                return r.sum(), -(r * r).sum()
        else:
            c = np.einsum("ki,kl,li->i", U, Li @ self.W @ Li.T, U)

            def d1(a):
                r = 1.0 / (1 + a * mu)
                return (c * mu * r * r).sum(), -2 * (c * mu * mu * r**3).sum()

        # the domain: 1 + a mu > 0
        neg = mu[mu < 0]
        hi = amax if neg.size == 0 else min(amax, (1 - 1e-12) / -neg.min())
        g0, h0 = d1(0.0)
        if g0 <= 0:
            return 0.0
        ghi, _ = d1(hi)
        if ghi >= 0:
            return hi
        lo = 0.0
        a = -g0 / h0 if h0 < 0 and -g0 / h0 < hi else 0.5 * hi  # the Newton step from 0
        for _ in range(60):
            g, h = d1(a)
            if g > 0:
                lo = a
            else:
                hi = a
            a_new = a - g / h if h < 0 else 0.5 * (lo + hi)
            if not lo < a_new < hi:
                a_new = 0.5 * (lo + hi)
            if abs(a_new - a) <= 1e-10 * a or hi - lo <= 1e-12 * hi:  # a step, not a root: 1e-10 is plenty
                return a_new
            a = a_new
        return a


def _finish(prob: _Problem, w, cap, algorithm, it, t0, history) -> ApproximateDesign:
    M = prob.info(w)
    _, _, logdet, t, g = prob.state(M)
    trace_w = t if prob.criterion == "A" else math.nan
    return ApproximateDesign(
        prob.criterion,
        prob.p,
        w,
        cap,
        g,
        logdet + prob.scale_logdet,
        trace_w,
        algorithm,
        it,
        time.perf_counter() - t0,
        tuple(history),
    )


def _multiplicative(prob: _Problem, tol, max_iter, max_seconds, check_every=10) -> ApproximateDesign:
    t0 = time.perf_counter()
    w = np.full(prob.n, 1.0 / prob.n)
    power = 1.0 if prob.criterion == "D" else 0.5
    history = []
    it = 0
    for it in range(1, max_iter + 1):
        _, _, _, _, g = prob.state(prob.info(w))
        gap = float(g.max()) - 1.0
        done = gap <= tol or time.perf_counter() - t0 > max_seconds
        if (it - 1) % check_every == 0 or done:
            history.append((it - 1, time.perf_counter() - t0, gap))
        if done:
            break
        w = w * (g if power == 1.0 else np.sqrt(g))
        w /= w.sum()
    return _finish(prob, w, None, "multiplicative", it, t0, history)


def _fw_away(
    prob: _Problem, start: np.ndarray, cap: float | None, tol, max_iter, max_seconds, check_every=10
) -> ApproximateDesign:
    """Frank-Wolfe with away steps (uncapped) or pairwise vertex exchange (capped)."""
    t0 = time.perf_counter()
    w = np.asarray(start, float).copy()
    w /= w.sum()
    history = []
    it = 0
    M = prob.info(w)
    for it in range(1, max_iter + 1):
        if it % 200 == 0:
            M = prob.info(w)  # no drift from the updates
        L, _, _, _, g = prob.state(M)
        sup = w > 0
        if cap is None:
            j = int(np.argmax(g))
            gap = float(g[j]) - 1.0
        else:
            free = w < cap * (1 - 1e-12)
            j = int(np.flatnonzero(free)[np.argmax(g[free])])
            k_cap = int(round(1.0 / cap))
            gap = float(np.sort(g)[-k_cap:].mean()) - 1.0
        done = gap <= tol or time.perf_counter() - t0 > max_seconds
        if (it - 1) % check_every == 0 or done:
            history.append((it - 1, time.perf_counter() - t0, gap))
        if done:
            break
        ks = np.flatnonzero(sup)
        k = int(ks[np.argmin(g[ks])])
        Aj = prob.A[j].reshape(prob.p, prob.p)
        Ak = prob.A[k].reshape(prob.p, prob.p)
        if cap is not None:  # pairwise: move weight from k to j
            if j == k:
                break
            amax = min(w[k], cap - w[j])
            a = prob.step(L, Aj - Ak, amax)
            w[j] += a
            w[k] = 0.0 if a >= amax * (1 - 1e-12) and amax == w[k] else w[k] - a
            M = M + a * (Aj - Ak)
        elif g[j] - 1.0 >= 1.0 - g[k] or w[k] >= 1.0:  # toward j
            a = prob.step(L, Aj - M, 1.0)
            w *= 1 - a
            w[j] += a
            M = (1 - a) * M + a * Aj
        else:  # away from k
            amax = w[k] / (1 - w[k])
            a = prob.step(L, M - Ak, amax)
            w *= 1 + a
            w[k] = 0.0 if a >= amax * (1 - 1e-12) else w[k] - a
            M = (1 + a) * M - a * Ak
        M = 0.5 * (M + M.T)
    w = np.clip(w, 0, None)
    return _finish(prob, w / w.sum(), cap, "fw-away", it, t0, history)


def approximate_design(
    blocks: np.ndarray,
    criterion: str = "D",
    W: np.ndarray | None = None,
    algorithm: str = "fw-away",
    start=None,
    cap: float | None = None,
    tol: float = 1e-4,
    max_iter: int = 20000,
    max_seconds: float = 10.0,
    blas_threads: int | None = 1,
) -> ApproximateDesign:
    """The approximate D- (or A-, weight W) optimal design on candidate blocks (N, m, p).

    Stops when max_i g_i - 1 <= tol (the design is then within a factor 1 + tol of the optimum),
    or after max_iter / max_seconds: the bounds (3), (4) hold at any w. ``start``: initial
    weights (fw-away; default: uniform, or the capped uniform when ``cap`` is set); a plan's
    counts n / M are a good one. Raises SingularCandidates when no design is nonsingular.
    ``blas_threads``: BLAS threads meanwhile (identify/runtime/threads.py; None: as is)."""
    with pinned_blas(blas_threads):
        return _approximate_design(blocks, criterion, W, algorithm, start, cap, tol, max_iter, max_seconds)


def _approximate_design(blocks, criterion, W, algorithm, start, cap, tol, max_iter, max_seconds):
    if algorithm not in ALGORITHMS:
        raise ValueError(f"algorithm must be one of {ALGORITHMS}, not {algorithm!r}")
    check_identifiable(blocks)
    prob = _Problem(blocks, criterion, W)
    if algorithm == "multiplicative":
        if cap is not None:
            raise ValueError("the capped (distinct) design uses fw-away")
        return _multiplicative(prob, tol, max_iter, max_seconds)
    if cap is not None and cap * prob.n < 1 - 1e-12:
        raise ValueError(
            f"a cap of {cap:g} per row needs at least {math.ceil(1 / cap)} candidates, not {prob.n}"
        )
    if start is None:
        start = np.full(prob.n, 1.0 / prob.n)
    start = np.asarray(start, float)
    if cap is not None:
        start = _cap_start(start / start.sum(), cap)
    try:
        prob.state(prob.info(start / start.sum()))
    except np.linalg.LinAlgError:  # a singular start: mix in the uniform design
        start = 0.5 * start / start.sum() + 0.5 / prob.n
    return _fw_away(prob, start, cap, tol, max_iter, max_seconds)


def _cap_start(w: np.ndarray, cap: float) -> np.ndarray:
    """Feasible weights under w <= cap near w: clip and spread the excess uniformly below the cap."""
    w = np.minimum(w, cap)
    for _ in range(100):
        excess = 1.0 - w.sum()
        if excess <= 1e-15:
            break
        room = cap - w
        w = w + excess * room / room.sum()
    return w / w.sum()


# --------------------------------------------------------------------------- certificates


@dataclass(frozen=True)
class Certificate:
    """A plan's criterion against the certified bound over all M-pose plans from the candidates."""

    criterion: str  # D, A, pose or AD
    configs: int  # M
    distinct: bool  # bound over distinct plans (no candidate twice) only
    plan: float  # D: log det F; A, pose, AD: the criterion (smaller is better)
    bound: float  # D: upper bound of log det F; others: lower bound of the criterion
    efficiency: float
    designs: tuple  # the ApproximateDesign(s) behind the bound

    @property
    def p(self) -> int:
        return self.designs[0].p

    def as_json(self) -> dict:
        out = {"criterion": self.criterion}
        if self.criterion == "D":
            out.update(plan_logdet=self.plan, bound_logdet=self.bound)
        else:
            out.update(plan_value=self.plan, bound_value=self.bound)
        out.update(efficiency=self.efficiency, configs=self.configs, distinct=self.distinct)
        return out


def design_json(d: ApproximateDesign, M: int, q: np.ndarray | None = None, load=None) -> dict:
    """The design's support: rows, weights and weights x M ("how many of the M poses"), with
    the rows' q (degrees, from q in rad) and load names when given."""
    support = []
    for i in d.support():
        e = {"row": int(i), "weight": float(d.weights[i]), "poses_of_M": float(M * d.weights[i])}
        if q is not None:
            e["q_deg"] = np.round(np.degrees(q[i]), 6).tolist()
        if load is not None:
            e["load"] = load[i]
        support.append(e)
    return {
        "criterion": d.criterion,
        "algorithm": d.algorithm,
        "iterations": d.iterations,
        "seconds": d.seconds,
        "optimality_gap": d.g_bound - 1.0,
        "capped": d.cap is not None,
        "support": support,
    }


def d_bound(design: ApproximateDesign, M: int) -> float:
    """(1) + (3): an upper bound of log det F over every M-pose plan (distinct plans when capped)."""
    if design.criterion != "D":
        raise ValueError("d_bound needs a D design")
    return design.p * math.log(M) + design.logdet + design.p * math.log(design.g_bound)


def a_bound(design: ApproximateDesign, M: int) -> float:
    """(2) + (4): a lower bound of tr(W F^-1) over every M-pose plan (distinct plans when capped)."""
    if design.criterion != "A":
        raise ValueError("a_bound needs an A design")
    return design.trace_w / design.g_bound / M


def plan_logdet(blocks: np.ndarray, rows) -> float:
    """log det of sum over rows of R_i^T R_i (-inf when singular)."""
    b = np.asarray(blocks)[np.asarray(rows, int)]
    sign, ld = np.linalg.slogdet(np.einsum("nki,nkj->ij", b, b))
    return float(ld) if sign > 0 else -math.inf


def certify(
    blocks: np.ndarray,
    rows,
    criterion: str,
    G: np.ndarray | None = None,
    distinct: bool = False,
    algorithm: str = "fw-away",
    tol: float = 1e-4,
    max_seconds: float = 10.0,
    blas_threads: int | None = 1,
) -> Certificate:
    """The certificate of plan ``rows`` (indices into blocks, repeats allowed unless distinct).

    criterion: D, A, AD or pose (pose needs G, W = G^T G). The approximate design(s) start from
    the plan's own weights (fw-away). See the module docstring for the bounds."""
    blocks = np.asarray(blocks, float)
    rows = np.asarray(rows, int)
    M = len(rows)
    p = blocks.shape[2]
    cap = 1.0 / M if distinct else None
    if distinct and len(np.unique(rows)) != M:
        raise ValueError("a distinct certificate for a plan with repeated rows")
    start = np.bincount(rows, minlength=len(blocks)).astype(float)
    kw = dict(
        algorithm=algorithm, start=start, cap=cap, tol=tol, max_seconds=max_seconds, blas_threads=blas_threads
    )
    F = np.einsum("nki,nkj->ij", blocks[rows], blocks[rows])
    designs = []
    if criterion in ("D", "AD"):
        dd = approximate_design(blocks, "D", **kw)
        designs.append(dd)
        ub = d_bound(dd, M)
    if criterion in ("A", "AD", "pose"):
        da = approximate_design(
            blocks, "A", weight_matrix("A" if criterion == "AD" else criterion, p, G), **kw
        )
        designs.append(da)
        lb = a_bound(da, M)
    if criterion == "D":
        plan = plan_logdet(blocks, rows)
        return Certificate("D", M, distinct, plan, ub, math.exp((plan - ub) / p), tuple(designs))
    if criterion == "AD":
        lb = AD_WEIGHTS[0] * lb + AD_WEIGHTS[1] * math.exp(-ub / p)
    plan = criterion_value(criterion, F, G)
    return Certificate(criterion, M, distinct, plan, lb, lb / plan, tuple(designs))


__all__ = [
    "ALGORITHMS",
    "ApproximateDesign",
    "Certificate",
    "SingularCandidates",
    "a_bound",
    "approximate_design",
    "certify",
    "check_identifiable",
    "d_bound",
    "column_scale",
    "design_json",
    "normalise_blocks",
    "plan_logdet",
]
