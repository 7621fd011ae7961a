"""The certificate of a design (issue 16). Prints JSON.

On the paper scenario's candidates (scenarios/paper_table5.toml, blocks 9 x 8), for N = 2000 and
10^4 and M = 12:

* the exchange's D plan: log det of sum R_i^T R_i over its rows, the certified bound on every
  12-pose plan from the candidates, the efficiency exp((plan - bound)/8) and the times; the same
  for A (trace, bound, efficiency), and for distinct rows (with the cost bracket);
* the approximate D and A designs by both algorithms (fw-away, multiplicative): iterations and
  seconds to reach an optimality gap (max_i g_i - 1) of 1e-2, 1e-3, 1e-4;
* BLAS threads: the exchange with BLAS pinned to 1 thread against the default pool, side by side
  in this process, on the machine as it is and with 1 and 2 busy-loop processes started here
  (load on the other core); medians of --repeats runs, alternating.

    .venv/bin/python benchmarks/certificate_bench.py [CANDS.npz ...] [--repeats 3]

Without NPZ files the candidates are generated (2000 and 10^4; ~2 s of CPU for 10^4).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from steps import say

from calbench.identify.design import generate_candidates, load_design_scenario, read_candidates
from calbench.identify.design.optimal import ALGORITHMS, Exchanger, approximate_design, select_rows

ROOT = Path(__file__).resolve().parent.parent
M = 12
GAPS = (1e-2, 1e-3, 1e-4)


def blocks_sets(files: list[str], sizes=(2000, 10000)) -> list[tuple[str, np.ndarray, float | None]]:
    if files:
        return [(f, read_candidates(f).blocks, None) for f in files]
    scn, st = load_design_scenario(ROOT / "scenarios" / "paper_table5.toml")
    out = []
    for n in sizes:
        say("certificate_bench", f"generating {n} candidates")
        t = time.perf_counter()
        c = generate_candidates(scn, st, n=n)
        out.append((f"generated {n}", c.blocks, time.perf_counter() - t))
    return out


def certified(blocks: np.ndarray, criterion: str, distinct: bool = False) -> dict:
    sel = select_rows(blocks, M, criterion, distinct=distinct)
    c = sel.certificate
    out = {
        "plan": c.plan,
        "bound": c.bound,
        "efficiency": c.efficiency,
        **sel.seconds,
        "approximate_design_iterations": [d.iterations for d in c.designs],
        "support_points": [int(len(d.support())) for d in c.designs],
    }
    if distinct:
        out["cost_vs_best_plan_with_repeats"] = sel.distinct_cost()["cost"]
    return out


def convergence(blocks: np.ndarray, criterion: str, start_rows) -> dict:
    """Iterations and seconds until max g - 1 <= each gap, both algorithms (fw-away starts from
    the exchange's plan, as the certificate does; the multiplicative from uniform weights)."""
    out = {}
    for alg in ALGORITHMS:
        start = np.bincount(start_rows, minlength=len(blocks)) if alg == "fw-away" else None
        d = approximate_design(
            blocks, criterion, algorithm=alg, start=start, tol=min(GAPS), max_iter=100000, max_seconds=60
        )
        reach = {}
        for gap in GAPS:
            hit = [h for h in d.history if h[2] <= gap]
            reach[f"{gap:g}"] = {"iterations": hit[0][0], "seconds": hit[0][1]} if hit else None
        out[alg] = {
            "reached": reach,
            "final_gap": d.g_bound - 1,
            "iterations": d.iterations,
            "seconds": d.seconds,
        }
    return out


def busy(n: int) -> list[subprocess.Popen]:
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]


def threads(blocks: np.ndarray, repeats: int) -> dict:
    out = {}
    for n_busy in (0, 1, 2):
        procs = busy(n_busy)
        try:
            time.sleep(0.5)
            runs = {"pinned_1": [], "default": []}
            for _ in range(repeats):
                for key, bt in (("pinned_1", 1), ("default", None)):
                    t = time.perf_counter()
                    Exchanger(blocks, "D").optimise(M, blas_threads=bt)
                    runs[key].append(time.perf_counter() - t)
        finally:
            for p in procs:
                p.kill()
                p.wait()
        med = {k: float(np.median(v)) for k, v in runs.items()}
        out[f"busy_loops_{n_busy}"] = {
            "median_s": med,
            "runs_s": runs,
            "default_over_pinned": med["default"] / med["pinned_1"],
            "loadavg_1min": os.getloadavg()[0],
        }
    return out


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("npz", nargs="*", help="candidate files (default: generate 2000 and 10^4)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--no-threads", action="store_true", help="skip the BLAS-threads comparison")
    ap.add_argument("--quick", action="store_true", help="2000 candidates only, no BLAS-threads comparison")
    args = ap.parse_args()
    if args.quick:
        args.no_threads = True
    from threadpoolctl import threadpool_info

    res = {
        "machine_cpus": os.cpu_count(),
        "loadavg_at_start": os.getloadavg(),
        "M": M,
        "blas": [
            {k: i.get(k) for k in ("internal_api", "num_threads", "version")} for i in threadpool_info()
        ],
        "sets": {},
    }
    for name, blocks, t_gen in blocks_sets(args.npz, (2000,) if args.quick else (2000, 10000)):
        say("certificate_bench", f"{name}: certificates and convergence")
        r = {"N": len(blocks), "block_shape": list(blocks.shape[1:]), "candidates_s": t_gen}
        r["D"] = certified(blocks, "D")
        r["A"] = certified(blocks, "A")
        r["D_distinct"] = certified(blocks, "D", distinct=True)
        rows = select_rows(blocks, M, "D").rows
        r["convergence_D"] = convergence(blocks, "D", rows)
        r["convergence_A"] = convergence(blocks, "A", select_rows(blocks, M, "A").rows)
        if not args.no_threads:
            r["exchange_blas_threads"] = threads(blocks, args.repeats)
        res["sets"][name] = r
    print(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
