"""The certificate of a plan (issue 16): approximate optimal designs, the equivalence-theorem
bounds, distinct plans, and the normalised export.

The bounds are proofs, so the tests compare them with the truth they bound: the best exact plan,
found by exhaustive search over every multiset (or set, for distinct plans) of M = 3 of 12
candidates. Tolerance 1e-9 (absolute in log det, relative in the traces): the rounding of an 8 x 8
Cholesky factorisation in double precision, far below any gap the bounds leave.
"""
from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from calbench.identify.design.certificate import (ALGORITHMS, a_bound, approximate_design, certify,
                                                  column_scale, d_bound, normalise_blocks, plan_logdet)
from calbench.identify.design.criteria import criterion_value, information
from calbench.identify.design.exchange import Exchanger

ROUND = 1e-9


def _blocks(seed: int, n=12, m=3, p=4) -> np.ndarray:
    """Random blocks with column scales spanning 1e3 (like the exported ones: 1.9 to 71)."""
    rng = np.random.default_rng(seed)
    return rng.standard_normal((n, m, p)) * np.geomspace(0.1, 100, p)


def _exhaustive(blocks, M, value, distinct):
    combos = itertools.combinations if distinct else itertools.combinations_with_replacement
    return [value(c) for c in combos(range(len(blocks)), M)]


@pytest.mark.parametrize("seed, m, p", [(0, 3, 4), (1, 3, 4), (2, 2, 5), (3, 9, 8)])
@pytest.mark.parametrize("distinct", [False, True])
def test_d_bound_is_above_the_best_exact_plan_for_any_design(seed, m, p, distinct):
    """Exhaustive search over all plans of 3 of 12 candidates; the bound of converged AND
    unconverged designs (1, 3, 10 iterations) is never below the best plan's log det, and the
    converged one leaves a gap the certificate reports as the plan's efficiency."""
    b = _blocks(seed, m=m, p=p)
    M = 3
    best = max(_exhaustive(b, M, lambda c: plan_logdet(b, c), distinct))
    cap = 1 / M if distinct else None
    for alg in ALGORITHMS if not distinct else ("fw-away",):
        for it in (1, 3, 10, 100000):
            d = approximate_design(b, "D", algorithm=alg, cap=cap, tol=1e-10, max_iter=it)
            assert d_bound(d, M) >= best - ROUND, (alg, it)
    cert = certify(b, list(range(M)), "D", distinct=distinct, tol=1e-10)
    assert cert.bound >= best - ROUND
    assert cert.efficiency == pytest.approx(math.exp((plan_logdet(b, range(M)) - cert.bound) / p))
    assert 0 < cert.efficiency <= 1


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("crit", ["A", "pose", "AD"])
@pytest.mark.parametrize("distinct", [False, True])
def test_a_type_bounds_are_below_the_best_exact_plan(seed, crit, distinct):
    b = _blocks(seed)
    G = np.random.default_rng(10 + seed).standard_normal((2, 4))
    M = 3
    best = min(_exhaustive(b, M, lambda c: criterion_value(crit, information(b, c), G), distinct))
    cert = certify(b, [0, 1, 2], crit, G=G, distinct=distinct, tol=1e-10)
    assert cert.bound <= best * (1 + ROUND)
    # unconverged designs bound too (4): a few iterations from the plan's own weights
    W = G.T @ G if crit == "pose" else None
    if crit != "AD":
        for it in (1, 5):
            d = approximate_design(b, "A", W, start=np.bincount([0, 1, 2], minlength=12),
                                   cap=1 / M if distinct else None, max_iter=it)
            assert a_bound(d, M) <= best * (1 + ROUND)


def test_the_bound_is_attained_when_the_approximate_optimum_is_an_exact_plan():
    """p orthogonal candidates c e_k plus candidates on the diagonals (c (e_a + e_b) / 2, d = 2 <
    p): the D-optimal design is uniform on the p axes, the plan of those p candidates attains
    p ln M + log det M(xi*) exactly, and its efficiency is 1 (the bound is not loose)."""
    p, c = 4, 3.0
    axes = [np.vstack([c * np.eye(p)[k], np.zeros(p)]) for k in range(p)]
    diag = [np.vstack([c * (np.eye(p)[a] + np.eye(p)[b]) / 2, np.zeros(p)])
            for a, b in itertools.combinations(range(p), 2)]
    blocks = np.array(diag[:3] + axes + diag[3:])
    rows = [3, 4, 5, 6]
    assert plan_logdet(blocks, rows) == pytest.approx(p * math.log(c * c))
    for alg in ALGORITHMS:
        d = approximate_design(blocks, "D", algorithm=alg, tol=1e-10, max_iter=100000)
        assert d_bound(d, p) == pytest.approx(p * math.log(c * c), abs=1e-8)
        assert sorted(d.support().tolist()) == rows
        np.testing.assert_allclose(d.weights[rows], 0.25, atol=1e-6)
    cert = certify(blocks, rows, "D")
    assert cert.efficiency == pytest.approx(1.0, abs=1e-9)


def test_equivalence_theorem_holds_at_the_computed_optimum():
    """sum_i w_i g_i = 1 for every design (definition); at the optimum max g = 1 and g = 1 on the
    support (Kiefer-Wolfowitz); both algorithms find the same optimum within their gap."""
    b = _blocks(5, n=40, m=3, p=5)
    out = {}
    for alg in ALGORITHMS:
        for crit in ("D", "A"):
            d = approximate_design(b, crit, algorithm=alg, tol=1e-8, max_iter=200000, max_seconds=60)
            assert d.weights @ d.sensitivity == pytest.approx(1.0, abs=1e-12)
            assert d.g_bound - 1 <= 1e-8
            if alg == "fw-away":
                np.testing.assert_allclose(d.sensitivity[d.weights > 0], 1.0, atol=1e-6)
            out[alg, crit] = d
    p = b.shape[2]
    assert abs(out["fw-away", "D"].logdet - out["multiplicative", "D"].logdet) <= p * math.log(1 + 1e-8) + ROUND
    assert out["fw-away", "A"].trace_w == pytest.approx(out["multiplicative", "A"].trace_w, rel=2e-8)


def test_normalising_the_columns_shifts_every_log_det_by_one_constant():
    b = _blocks(7, n=200, m=9, p=8)
    nb, s = normalise_blocks(b)
    np.testing.assert_allclose(np.einsum("nij,nij->j", nb, nb) / len(b), 1.0, rtol=1e-12)
    np.testing.assert_allclose(s, column_scale(b))
    shift = -2 * np.log(s).sum()
    rng = np.random.default_rng(0)
    for _ in range(5):
        rows = rng.choice(len(b), 12)
        assert plan_logdet(nb, rows) == pytest.approx(plan_logdet(b, rows) + shift, abs=1e-9)
    r, rn = Exchanger(b, "D").optimise(12, n_random=2), Exchanger(nb, "D").optimise(12, n_random=2)
    assert r.idx.tolist() == rn.idx.tolist()


def test_distinct_exchange_never_repeats_and_its_scan_skips_the_excluded():
    b = _blocks(8, n=300, m=3, p=8)
    ex = Exchanger(b, "D")
    rep, dis = ex.optimise(30, n_random=2), ex.optimise(30, n_random=2, distinct=True)
    assert len(np.unique(rep.idx)) < 30          # at 30 of 300 the unconstrained plan repeats
    assert len(np.unique(dis.idx)) == 30
    assert plan_logdet(b, dis.idx) <= plan_logdet(b, rep.idx) + ROUND
    cert_d = certify(b, dis.idx, "D", distinct=True)
    cert_r = certify(b, rep.idx, "D")
    assert cert_d.bound <= cert_r.bound + ROUND   # distinct plans are a subset of plans
    P, ld, tr = ex.state(dis.idx[:10])
    exclude = np.zeros(len(b), bool)
    exclude[dis.idx[:10]] = True
    full = ex.scan(P, ld, tr, full=True, exclude=exclude)
    j, v = ex.scan(P, ld, tr, exclude=exclude)
    assert not exclude[j] and j == int(np.argmin(full)) and v == pytest.approx(full.min(), rel=1e-12)
    with pytest.raises(ValueError):
        ex.optimise(301, distinct=True)
