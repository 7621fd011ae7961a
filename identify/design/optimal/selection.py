"""Choose M rows of a candidate block set, with the certificate of the choice (issue 16).

The discrete half of `calbench design`, on blocks alone, so it runs the same on calbench's own
candidates and on any other tool's (``design --from-candidates``): the multi-start exchange
(exchange.py) picks the rows, and certificate.py bounds every M-row plan from the same
candidates, which turns the plan's criterion into a proven efficiency.

``distinct``: no row twice (a row is a configuration with its load, as a [[pose]] entry: the same
q under the vertical load and under a lateral pull are two rows). Forbidding repeats costs
something; the plan with repeats is computed too, and the cost against the BEST plan with
repeats is bracketed: at least the loss against the repeats plan found (or 0), at most the loss
against the bound of every plan with repeats. Both ends are exact statements, not estimates.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from .certificate import Certificate, certify, check_identifiable, design_json
from .exchange import Exchanger, ExchangeResult


def relative_efficiency(criterion: str, plan: float, reference: float, p: int) -> float:
    """Efficiency of ``plan`` against ``reference`` (<= 1 when the reference is better):
    D (log dets): exp((plan - reference) / p); A, AD, pose (smaller is better): reference / plan."""
    if criterion == "D":
        return math.exp((plan - reference) / p)
    return reference / plan


@dataclass
class Selection:
    """M rows chosen from the candidates, and their certificate."""

    criterion: str
    rows: np.ndarray  # (M,) sorted, repeats possible unless distinct
    exchange: ExchangeResult
    exchanger_stats: dict
    certificate: Certificate
    seconds: dict  # exchange_s, certificate_s
    repeats: Selection | None = None  # when distinct: the plan with repeats

    @property
    def distinct(self) -> bool:
        return self.certificate.distinct

    def distinct_cost(self) -> dict | None:
        """The efficiency lost by forbidding repeats, bracketed (see the module docstring)."""
        if self.repeats is None:
            return None
        c, r = self.certificate, self.repeats.certificate
        p = c.p
        vs_found = relative_efficiency(c.criterion, c.plan, r.plan, p)
        vs_bound = relative_efficiency(c.criterion, c.plan, r.bound, p)
        return {
            "repeats_rows": self.repeats.rows.tolist(),
            "repeats_plan": r.plan,
            "repeats_bound": r.bound,
            "repeats_efficiency": r.efficiency,
            "efficiency_vs_repeats_plan": vs_found,
            "efficiency_vs_repeats_bound": vs_bound,
            "cost": {"at_least": max(0.0, 1.0 - vs_found), "at_most": 1.0 - vs_bound},
        }

    def as_json(self, q: np.ndarray | None = None, load=None) -> dict:
        """rows, certificate, continuous_design (per criterion behind the bound; q in rad and
        load names of the candidates, when known, label its support) and the distinct cost."""
        cert = self.certificate
        out = {
            "rows": self.rows.tolist(),
            "certificate": cert.as_json(),
            "continuous_design": {
                _design_name(d.criterion, cert.criterion): design_json(d, cert.configs, q, load)
                for d in cert.designs
            },
        }
        cost = self.distinct_cost()
        if cost is not None:
            out["distinct"] = cost
        return out


def _design_name(design_criterion: str, plan_criterion: str) -> str:
    """D, A, or pose (an A design with W = G^T G)."""
    return "pose" if design_criterion == "A" and plan_criterion == "pose" else design_criterion


def select_rows(
    blocks: np.ndarray,
    M: int,
    criterion: str,
    G: np.ndarray | None = None,
    distinct: bool = False,
    n_random: int = 8,
    seed: int = 0,
    blas_threads: int | None = 1,
) -> Selection:
    """The exchange's best plan of M rows and its certificate (and, when distinct, the plan
    with repeats for the cost). Raises ValueError for M > N distinct rows and
    certificate.SingularCandidates when no plan identifies every parameter."""
    blocks = np.asarray(blocks, float)
    check_identifiable(blocks)
    t0 = time.perf_counter()
    ex = Exchanger(blocks, criterion, G)
    r = ex.optimise(M, n_random=n_random, seed=seed, distinct=distinct, blas_threads=blas_threads)
    t1 = time.perf_counter()
    cert = certify(blocks, r.idx, criterion, G, distinct=distinct, blas_threads=blas_threads)
    t2 = time.perf_counter()
    sel = Selection(
        criterion, r.idx, r, dict(ex.stats), cert, {"exchange_s": t1 - t0, "certificate_s": t2 - t1}
    )
    if distinct:
        sel.repeats = select_rows(blocks, M, criterion, G, False, n_random, seed, blas_threads)
    return sel


def _rows_text(rows: np.ndarray) -> str:
    u, n = np.unique(rows, return_counts=True)
    return " ".join(f"{i}" + (f"x{c}" if c > 1 else "") for i, c in zip(u, n))


def selection_text(
    sel: Selection, n_candidates: int, q: np.ndarray | None = None, load=None, max_support: int = 20
) -> str:
    """Lines for people: the certificate as a proven statement, the rows, the distinct cost and
    the continuous design's support (q in rad and load names label it when known)."""
    c = sel.certificate
    M = c.configs
    which = "distinct plans" if c.distinct else "plans"
    if c.criterion == "D":
        head = f"log det F {c.plan:.3f} <= bound {c.bound:.3f}"
        unit = f"det^(1/{c.p})"
    else:
        head = f"{c.criterion} {c.plan:.5g} >= bound {c.bound:.5g}"
        unit = {"A": "the trace of the covariance", "pose": "the work-pose variance"}.get(
            c.criterion, "the criterion"
        )
    lines = [
        f"  certificate ({c.criterion}, every {M}-pose {which[:-1]} from these {n_candidates} candidates): {head}",
        f"    efficiency {100 * c.efficiency:.1f} %: provably within {100 * (1 - c.efficiency):.1f} % of the best "
        f"{M}-pose {which[:-1]} from these candidates (in {unit}; equivalence-theorem bound, a proof, "
        "not an estimate)",
        f"  rows: {_rows_text(sel.rows)}",
    ]
    cost = sel.distinct_cost()
    if cost is not None:
        lines.append(
            f"  no repeats: costs {100 * cost['cost']['at_least']:.2f} % to {100 * cost['cost']['at_most']:.2f} % "
            f"against the best plan with repeats (found: rows {_rows_text(sel.repeats.rows)}, "
            f"efficiency {100 * cost['repeats_efficiency']:.1f} %)"
        )
    in_plan = dict(zip(*np.unique(sel.rows, return_counts=True)))
    for d in c.designs:
        sup = d.support()
        lines.append(
            f"  continuous {_design_name(d.criterion, c.criterion)}-optimal design"
            f"{' (at most 1/M per row)' if d.cap is not None else ''} ({d.algorithm}, {d.iterations} "
            f"iterations, {d.seconds:.2f} s, gap {d.g_bound - 1:.1e}): {len(sup)} support points"
        )
        lines.append(
            f"    {'row':>6}  {'poses of ' + str(M):>11}  {'in plan':>7}"
            + (f"  {'load':<8}" if load is not None else "")
            + ("  q (deg)" if q is not None else "")
        )
        for i in sup[:max_support]:
            line = f"    {i:>6}  {M * d.weights[i]:>11.2f}  {in_plan.get(i, 0):>7}"
            if load is not None:
                line += f"  {load[i]:<8}"
            if q is not None:
                line += "  [" + ", ".join(f"{v:7.1f}" for v in np.degrees(q[i])) + "]"
            lines.append(line)
        if len(sup) > max_support:
            lines.append(f"    ... {len(sup) - max_support} more")
    return "\n".join(lines)


__all__ = ["Selection", "relative_efficiency", "select_rows", "selection_text"]
