"""Exchange algorithm (Fedorov / DETMAX style) on a candidate set, with low-rank updates.

Blocks. Each candidate's whitened regressor R_j (m x p, m = 9 rows for 3 reflectors, p = 8) is
compressed once to its p x p triangular factor T_j (QR: R_j = Q_j T_j, so R_j^T R_j = T_j^T T_j
exactly). Adding or removing a candidate is then a rank-<=8 update of the plan's information F,
done on the inverse P = F^-1 and log det F by Woodbury and the matrix determinant lemma:

    S = I + T P T^T,   log det(F + T^T T) = log det F + log det S,
    (F + T^T T)^-1 = P - U^T S^-1 U,   U = T P,
    trace(W (F + T^T T)^-1) = trace(W P) - trace(S^-1 U W U^T),

evaluated for all N candidates at once as batched 8 x 8 products (removal: the same with
S = I - T P T^T and the signs flipped).

Algorithm (Cook & Nachtsheim's modified Fedorov exchange): for each design point in turn,
remove it, evaluate every candidate as its replacement, and make the best swap if it lowers the
criterion by more than ``rel_tol``; repeat passes until a pass makes no swap. Candidates may be
chosen more than once (a repeated measurement), unless ``distinct``: then every scan skips the
candidates already in the plan (the one being exchanged may come back). Multi-start: a greedy sequential start
(adding the best candidate one at a time) plus ``n_random`` random plans; the best result is
returned together with every start's value. A tiny ridge ``ridge`` x I (1e-9 of the mean
candidate information's diagonal) keeps F invertible while a start lacks some parameter (e.g.
k1 without a lateral pull); final values are recomputed from scratch without it.

Threads: the algebra is small (8 x 8 blocks, N x 64 products), where OpenBLAS threads only add
synchronisation and, on a loaded machine, fight over the cores; ``optimise`` pins BLAS to
``blas_threads`` (default 1) for its duration (identify/runtime/threads.py;
benchmarks/certificate_bench.py measures both).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calbench.identify.runtime import blas_threads as pinned_blas

from .criteria import combine, criterion_value, information, weight_matrix


def compress(blocks: np.ndarray) -> np.ndarray:
    """(N, m, p) -> (N, p, p) factors T with T^T T = R^T R (zero-padded when m < p)."""
    n, m, p = blocks.shape
    if m < p:
        blocks = np.concatenate([blocks, np.zeros((n, p - m, p))], axis=1)
    return np.linalg.qr(blocks, mode="r")[:, :p, :]


@dataclass
class ExchangeResult:
    idx: np.ndarray  # (M,) chosen candidate indices (repeats possible)
    value: float  # criterion, recomputed from scratch (no ridge)
    updated_value: float  # criterion as tracked by the low-rank updates (with ridge)
    start_values: list[float]  # each start's criterion (from scratch, ridge included)
    start_results: list[float]  # each start's final criterion
    passes: int
    swaps: int
    distinct: bool = False
    history: list[float] = field(default_factory=list)


class Exchanger:
    """Batched low-rank evaluation of one criterion over a candidate set."""

    def __init__(
        self, blocks: np.ndarray, criterion: str, G: np.ndarray | None = None, ridge: float | None = None
    ):
        self.blocks = blocks
        self.T = np.ascontiguousarray(compress(blocks))
        self.TT = np.ascontiguousarray(np.swapaxes(self.T, 1, 2))
        self.T2 = self.T.reshape(-1, blocks.shape[2])
        self.n, self.p = len(blocks), blocks.shape[2]
        self.criterion = criterion
        self.G = G
        self.W = weight_matrix(criterion, self.p, G)
        ev, evec = np.linalg.eigh(self.W)
        self.V = evec * np.sqrt(np.clip(ev, 0, None))  # W = V V^T
        self.identity_w = bool(np.allclose(self.W, np.eye(self.p)))
        self.chunk = 256
        self.stats = {"scans": 0, "exact_evaluations": 0}
        mean_diag = float(np.mean(np.einsum("nij,nij->j", self.T, self.T)) / self.n)
        self.ridge = 1e-9 * mean_diag if ridge is None else ridge
        self.need_logdet = criterion in ("D", "AD")
        self.need_trace = criterion in ("A", "AD", "pose")

    # -- state -------------------------------------------------------------------------------
    def state(self, idx) -> tuple[np.ndarray, float, float]:
        """(P, log det F, trace W P) of plan idx from scratch (ridge included)."""
        F = information(self.blocks, idx) + self.ridge * np.eye(self.p)
        P = np.linalg.inv(F)
        P = 0.5 * (P + P.T)
        return P, float(np.linalg.slogdet(F)[1]), float(np.trace(self.W @ P))

    def value(self, logdet, trw):
        return float(combine(self.criterion, trw, logdet, self.p))

    def exact_value(self, idx) -> float:
        """Criterion of plan idx from scratch, without the ridge."""
        return criterion_value(self.criterion, information(self.blocks, idx), self.G)

    # -- updates -----------------------------------------------------------------------------
    def _update(self, P, logdet, t, sign):
        """Add (sign +1) or remove (sign -1) factor t (p, p): new (P, logdet)."""
        u = t @ P
        s = np.eye(self.p) + sign * u @ t.T
        P2 = P - sign * u.T @ np.linalg.solve(s, u)
        return 0.5 * (P2 + P2.T), logdet + float(np.linalg.slogdet(s)[1])

    def _exact(self, U, idx, logdet, trw):
        """Exact criterion after adding candidates idx (U = T P for them)."""
        S = np.matmul(U, self.TT[idx])
        S += np.eye(self.p)
        ld = logdet
        if self.need_logdet:
            sg, lds = np.linalg.slogdet(S)
            ld = np.where(sg > 0, logdet + lds, -np.inf)
        tr = trw
        if self.need_trace:
            UV = U if self.identity_w else np.matmul(U, self.V)
            X = np.linalg.solve(S, UV)
            tr = trw - np.einsum("nij,nij->n", UV, X)
        val = combine(self.criterion, tr, ld, self.p)
        self.stats["exact_evaluations"] += len(idx)
        return np.where(np.isfinite(val), val, np.inf)

    def scan(self, P, logdet, trw, full: bool = False, exclude: np.ndarray | None = None):
        """Best candidate to add: (index, criterion after adding it).

        Branch and bound, exact: with S = I + T P T^T >= I, the gains obey
        log det S <= trace(T P T^T) and trace(S^-1 T P W P T^T) <= trace(T P W P T^T), which
        give a lower bound of every candidate's criterion from two cheap batched products.
        Candidates are evaluated exactly in the order of their bounds, in chunks, until the best
        exact value is below the next bound (``full``: evaluate all, for tests). ``exclude``: a
        boolean mask of candidates that may not be added (their values count as +inf)."""
        self.stats["scans"] += 1
        U = (self.T2 @ P).reshape(self.n, self.p, self.p)
        if full:
            v = self._exact(U, np.arange(self.n), logdet, trw)
            return v if exclude is None else np.where(exclude, np.inf, v)
        b_ld = np.einsum("nij,nij->n", U, self.T) if self.need_logdet else 0.0
        if self.need_trace:
            UV = U if self.identity_w else (U.reshape(-1, self.p) @ self.V).reshape(self.n, self.p, self.p)
            b_tr = np.einsum("nij,nij->n", UV, UV)
        else:
            b_tr = 0.0
        lb = combine(self.criterion, trw - b_tr, logdet + b_ld, self.p)
        lb = np.where(np.isfinite(lb), lb, -np.inf) if np.ndim(lb) else np.full(self.n, lb)
        if exclude is not None:
            lb = np.where(exclude, np.inf, lb)
        c = min(self.chunk, self.n - 1)
        head = np.argpartition(lb, c)[: c + 1]  # the chunk + 1 smallest bounds
        head = head[np.argsort(lb[head], kind="stable")]
        best_j, best_v = -1, np.inf
        v = self._masked(self._exact(U[head[:-1]], head[:-1], logdet, trw), head[:-1], exclude)
        i = int(np.argmin(v))
        best_j, best_v = int(head[i]), float(v[i])
        if best_v <= lb[head[-1]] or self.n <= c + 1:
            if self.n <= c + 1:  # tiny sets: the last one too
                vl = float(
                    self._masked(self._exact(U[head[-1:]], head[-1:], logdet, trw), head[-1:], exclude)[0]
                )
                if vl < best_v:
                    best_j, best_v = int(head[-1]), vl
            return best_j, best_v
        order = np.argsort(lb, kind="stable")
        for k in range(c, self.n, self.chunk):
            sel = order[k : k + self.chunk]
            v = self._masked(self._exact(U[sel], sel, logdet, trw), sel, exclude)
            i = int(np.argmin(v))
            if v[i] < best_v:
                best_j, best_v = int(sel[i]), float(v[i])
            if k + self.chunk >= self.n or best_v <= lb[order[k + self.chunk]]:
                break
        return best_j, best_v

    @staticmethod
    def _masked(v, sel, exclude):
        return v if exclude is None else np.where(exclude[sel], np.inf, v)

    # -- algorithms --------------------------------------------------------------------------
    def greedy(self, M: int, rng=None, distinct: bool = False) -> np.ndarray:
        """Sequential start: add the best candidate M times (from the ridge alone)."""
        idx: list[int] = []
        taken = np.zeros(self.n, bool) if distinct else None
        P = np.eye(self.p) / self.ridge
        logdet = self.p * np.log(self.ridge)
        trw = float(np.trace(self.W @ P))
        for _ in range(M):
            j, _ = self.scan(P, logdet, trw, exclude=taken)
            idx.append(j)
            if distinct:
                taken[j] = True
            P, logdet = self._update(P, logdet, self.T[j], +1)
            trw = float(np.trace(self.W @ P))
        return np.array(idx)

    def exchange(self, start, max_passes: int = 100, rel_tol: float = 1e-9, rng=None, distinct: bool = False):
        """Modified Fedorov exchange from plan ``start``; returns (idx, tracked value, passes,
        swaps, history)."""
        idx = np.array(start, int).copy()
        M = len(idx)
        taken = None
        if distinct:
            if len(np.unique(idx)) != M:
                raise ValueError("a distinct exchange needs a start without repeated candidates")
            taken = np.zeros(self.n, bool)
            taken[idx] = True
        P, logdet, trw = self.state(idx)
        cur = self.value(logdet, trw)
        history = [cur]
        swaps = 0
        passes = 0
        order = np.arange(M)
        for passes in range(1, max_passes + 1):  # noqa: B007 (read after the loop)
            changed = False
            if rng is not None:
                rng.shuffle(order)
            for pos in order:
                i = idx[pos]
                Pm, ldm = self._update(P, logdet, self.T[i], -1)
                trm = float(np.trace(self.W @ Pm))
                if distinct:
                    taken[i] = False
                j, vj = self.scan(Pm, ldm, trm, exclude=taken)
                if j != i and vj < cur * (1 - rel_tol):
                    idx[pos] = j
                    P, logdet = self._update(Pm, ldm, self.T[j], +1)
                    trw = float(np.trace(self.W @ P))
                    cur = self.value(logdet, trw)
                    swaps += 1
                    changed = True
                if distinct:
                    taken[idx[pos]] = True
            history.append(cur)
            # refresh from scratch once per pass (no drift from the updates)
            P, logdet, trw = self.state(idx)
            cur = self.value(logdet, trw)
            if not changed:
                break
        return idx, cur, passes, swaps, history

    def optimise(
        self,
        M: int,
        n_random: int = 8,
        seed: int = 0,
        starts=None,
        distinct: bool = False,
        blas_threads: int | None = 1,
    ) -> ExchangeResult:
        """Multi-start exchange: greedy + n_random random starts (+ given ``starts``).
        ``distinct``: no candidate twice. ``blas_threads``: BLAS threads meanwhile (None: as is)."""
        if distinct and M > self.n:
            raise ValueError(f"{M} distinct configurations from {self.n} candidates")
        with pinned_blas(blas_threads):
            return self._optimise(M, n_random, seed, starts, distinct)

    def _optimise(self, M, n_random, seed, starts, distinct) -> ExchangeResult:
        rng = np.random.default_rng(seed)
        plans = [self.greedy(M, distinct=distinct)] + [
            rng.choice(self.n, M, replace=False) for _ in range(n_random)
        ]
        if starts is not None:
            plans += [np.asarray(s, int) for s in starts]
        best = None
        start_values, start_results = [], []
        tot_passes = tot_swaps = 0
        for s in plans:
            P, ld, tr = self.state(s)
            start_values.append(self.value(ld, tr))
            idx, val, passes, swaps, hist = self.exchange(s, rng=rng, distinct=distinct)
            start_results.append(val)
            tot_passes += passes
            tot_swaps += swaps
            if best is None or val < best[1]:
                best = (idx, val, hist)
        idx, val, hist = best
        return ExchangeResult(
            np.sort(idx),
            self.exact_value(idx),
            val,
            start_values,
            start_results,
            tot_passes,
            tot_swaps,
            distinct,
            hist,
        )


__all__ = ["compress", "Exchanger", "ExchangeResult"]
