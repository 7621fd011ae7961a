"""Design of experiments benchmark (issue 4, §5-6). Prints JSON.

* time to build 10^4 feasible candidates with their EXACT information blocks (IFT Jacobians of
  the exact statics, batched: identify/design/batch_info.py) and, separately, the exchange for 12 of them;
* on the paper's robot and load (scenarios/paper_table5.toml, whose [work] table is a machining
  pose q = [30, 60, 0, 0, -60, 0] deg under a 2 kN process force [-1600, 800, 900] N), for each criterion A, D, AD, pose and M = 12 and 16: our plan, the
  paper's Table 5 plan (its 12 poses + the scenario's 4 lateral pulls, reflectors as seen) and the
  median of 100 random feasible plans of the same size, on every measure;
* Monte Carlo (identify/study/montecarlo.py, one-step estimator) of the paper plan and of our
  A-optimal plans: empirical trace of the normalised covariance against the predicted O1;
* the exchange alone on random 9 x 8 blocks, N = 10^4 (BENCHMARKS.md's FIGAROH row used 3 x 8).

    .venv/bin/python benchmarks/design_bench.py [--runs 200] [--quick]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent

from steps import say

from calbench.bench.scenario import load_scenario
from calbench.identify.design import (
    InfoEngine,
    design_plan,
    generate_candidates,
    load_design_scenario,
    plan_measures,
    plan_scenario_text,
    scenario_plan_information,
    work_jacobian,
)
from calbench.identify.design.optimal import Exchanger, information, measures
from calbench.identify.study import run_montecarlo


def work_scenario() -> Path:
    """The paper scenario; it carries the [work] pose the pose measure needs (a machining
    pose under a 2 kN process force)."""
    return ROOT / "scenarios" / "paper_table5.toml"


def short(m: dict) -> dict:
    return {k: m[k] for k in ("A", "D", "AD", "pose") if k in m}


def mc_check(path: Path, F: np.ndarray, runs: int) -> dict:
    C = np.linalg.inv(F)
    mc = run_montecarlo(load_scenario(path), runs, methods=("one-step",), progress=False)
    est = mc.estimates["one-step"] / mc.truth
    emp = np.cov(est.T, ddof=1)
    se = float(np.sqrt(2 * np.trace(C @ C) / (runs - 1)))
    return {
        "runs": runs,
        "predicted_A": float(np.trace(C)),
        "empirical_A": float(np.trace(emp)),
        "sampling_se_of_A": se,
        "z": float((np.trace(emp) - np.trace(C)) / se),
        "variance_ratio_per_parameter": {
            n: float(v)
            for n, v in zip(("k1", "k2", "k3", "k4", "k5", "k6", "K_C", "s0"), np.diag(emp) / np.diag(C))
        },
        "variance_ratio_se": float(np.sqrt(2 / (runs - 1))),
    }


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--quick", action="store_true", help="2000 candidates, no Monte Carlo")
    args = ap.parse_args()
    say("design_bench", f"{2000 if args.quick else 10000} candidates")
    path = work_scenario()
    scn, st = load_design_scenario(path)
    n = 2000 if args.quick else 10000
    t0 = time.perf_counter()
    cands = generate_candidates(scn, st, n=n, progress=False)
    t_c = time.perf_counter() - t0
    engine = InfoEngine(scn, st)
    G = work_jacobian(engine, scn)
    F_paper, viol = scenario_plan_information(engine, scn)
    out = {
        "machine_cpus": __import__("os").cpu_count(),
        "candidates": {
            "n": len(cands),
            "lateral": int(cands.kind.sum()),
            "seconds_exact_information": t_c,
            **{k: v for k, v in cands.stats.items() if k != "seconds"},
        },
        "work_pose": {"q_deg": [30, 60, 0, 0, -60, 0], "wrench": [-1600, 800, 900, 0, 0, 0]},
        "paper_plan": {
            "configs": 16,
            "measures": short(plan_measures(F_paper, cands.theta0, G, cands.param_names)),
            "relative_std": plan_measures(F_paper, cands.theta0, G, cands.param_names)["relative_std"],
            "violates_our_rules": viol,
        },
        "plans": {},
    }
    rng = np.random.default_rng(11)
    plans = {}
    for M in (12, 16):
        rand = [
            short(measures(information(cands.blocks, rng.choice(len(cands), M, replace=False)), G))
            for _ in range(100)
        ]
        med = {k: float(np.median([r[k] for r in rand])) for k in rand[0]}
        for crit in ("A", "D", "AD", "pose"):
            say("design_bench", f"{crit}-optimal plan of {M}")
            t = time.perf_counter()
            res = design_plan(scn, st, cands, M, crit, n_random=8, engine=engine)
            total = time.perf_counter() - t
            ours = short(res.measures)
            key = f"{crit}_M{M}"
            plans[key] = res
            out["plans"][key] = {
                "exchange_s": res.timings["exchange_s"],
                "refine_s": res.timings["refine_s"],
                "total_s": total,
                "ours": ours,
                "before_refinement": short(res.exchange_measures),
                "random_median": med,
                "ours_over_paper": {k: ours[k] / out["paper_plan"]["measures"][k] for k in ours},
                "ours_over_random_median": {k: ours[k] / med[k] for k in ours},
                "lateral_pulls": int(sum(p.repeats for p in res.poses if p.kind == 1)),
                "distinct_q2_deg": sorted({round(float(np.degrees(p.q[1])), 1) for p in res.poses}),
            }
    out["time_12_of_10k"] = {
        "candidates_s": t_c,
        "exchange_A_s": out["plans"]["A_M12"]["exchange_s"],
        "exchange_D_s": out["plans"]["D_M12"]["exchange_s"],
        "exchange_pose_s": out["plans"]["pose_M12"]["exchange_s"],
        "refine_A_s": out["plans"]["A_M12"]["refine_s"],
    }
    # exchange alone on random blocks (the FIGAROH row of BENCHMARKS.md, blocks 9 x 8 here)
    rb = np.random.default_rng(0).standard_normal((10000, 9, 8))
    t = time.perf_counter()
    r = Exchanger(rb, "D").optimise(12, n_random=8)
    out["random_blocks_D_12_of_10k"] = {
        "seconds": time.perf_counter() - t,
        "logdet_F": float(np.linalg.slogdet(information(rb, r.idx))[1]),
    }
    if not args.quick:
        say("design_bench", f"Monte Carlo checks, {args.runs} runs each")
        mc = {"paper_plan": mc_check(ROOT / "scenarios" / "paper_table5.toml", F_paper, args.runs)}
        for key in ("A_M16", "A_M12"):
            res = plans[key]
            p = ROOT / "logs" / f"design_{key}.toml"
            p.write_text(plan_scenario_text(scn, res.poses, p, f"design_bench {key}"))
            mc[key] = mc_check(p, res.information(), args.runs)
        out["monte_carlo"] = mc
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
