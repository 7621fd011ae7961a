"""Time of discovery's self-check (issue 22) with the model's statics batched and pose by pose.

The self-check (identify/discover/uncertainty.py's ``self_check``) refits 30 bootstrap replicas
of the final model. A model with effects (identify/discover/fit.py's AugmentedForward) ran its
equilibria pose by pose until its warm evaluations ran stacked on bench/statics/batched.py as the
base model's do. For each case the campaign is simulated in memory (the scenario's seed),
discovered once, and the self-check of the final model is run twice on the same fit, in the
same process, alternating: pose by pose (``batched = False``, the baseline) and batched.
The same for `calbench identify --self-check` (identify/report/selfcheck.py: the one-step's refits
on the base model, which ran batched before): its wall and CPU seconds both ways.
Reported per case: wall and CPU seconds of each, their ratio, the model evaluations, and how
far apart the two runs' replicas came out (the largest |difference| over replicas and
parameters, in the parameter's reported std: the replicas stop on a step below 1e-2 std, so
that is the scale two runs whose statics agree to the solver's tolerance may differ by), and
whether the verdicts agree.

Cases: the FANUC paper plan (the user's model, nothing named), the same with a hidden forearm
bending (discover_speed_bench.py's one effect: a named model with effects) and, where
../shared/data holds it, the converted IRB 6640 with its hidden link_2 bending (the case of
issue 22), seeds 2-4. Prints JSON.

    python benchmarks/selfcheck_bench.py [--irb-seeds 2,3,4] [--repeats 1] [--no-fanuc] [--quick]
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
PAPER = ROOT / "scenarios" / "paper_table5.toml"
FOREARM = '[truth.effects.link_compliance]\nlink = "forearm"\ncompliance = [1.8e-7, 0.0, 1.8e-7]'


def shared_case() -> Path | None:
    """The IRB 6640 case in the shared data (CALBENCH_SHARED_DATA, else ../shared/data)."""
    root = Path(os.environ.get("CALBENCH_SHARED_DATA", ROOT.parent / "shared" / "data"))
    case = root / "cases" / "irb6640"
    return case if case.is_dir() else None


def irb_scenario(case: Path, seed: int, tmp: Path) -> Path:
    text = (case / "irb6640_hidden.toml").read_text().replace("seed = 2", f"seed = {seed}")
    text = text.replace('robot = "irb6640.xml"', f'robot = "{case / "irb6640.xml"}"')
    path = tmp / f"irb{seed}.toml"
    path.write_text(text)
    return path


def one_check(fit, obs, white, det, batched: bool) -> dict:
    from calbench.identify.discover import self_check

    fit.model.batched = batched
    fit.model.evaluate(fit.values, jacobian=False)  # both start from the estimate's equilibria
    est: list = []
    n0 = fit.model.stats["evaluations"]
    t, c = time.perf_counter(), time.process_time()
    rec = self_check(fit, obs, white, copy.deepcopy(det), estimates=est)
    return {
        "wall_s": time.perf_counter() - t,
        "cpu_s": time.process_time() - c,
        "evaluations": fit.model.stats["evaluations"] - n0,
        "failed": rec["failed"],
        "ratios": {k: v["std_ratio"] for k, v in rec["parameters"].items()},
        "estimates": np.array(est),
    }


def identify_check(robot, obs, batched: bool) -> dict:
    """`calbench identify --self-check`'s bootstrap (identify/report/selfcheck.py: the one-step's
    Monte Carlo refits on the base model, identify/core/forward.py) with the statics batched or
    pose by pose (ForwardModel.BATCHED: the refits build their own model)."""
    from calbench.identify.core import ForwardModel
    from calbench.identify.report import identify, self_check

    ForwardModel.BATCHED = batched
    try:
        res = identify(robot, obs)
        r = res.result
        t, c = time.perf_counter(), time.process_time()
        rec = self_check(robot, res.obs, "one-step", r.theta, r.std, res.obs.dp - r.residual)
        return {"wall_s": time.perf_counter() - t, "cpu_s": time.process_time() - c, "failed": rec["failed"]}
    finally:
        ForwardModel.BATCHED = True


def run_case(name: str, scn_path: Path, model, repeats: int) -> dict:
    from calbench.bench.model import Robot
    from calbench.bench.scenario import load_scenario
    from calbench.identify.core import Whitener
    from calbench.identify.discover import checked, discover_observations
    from calbench.identify.study import simulate_in_memory

    sim = simulate_in_memory(load_scenario(scn_path))
    src = model if model is not None else sim.mjcf
    t = time.perf_counter()
    rep, fit = discover_observations(sim.obs, src)
    discover_s = time.perf_counter() - t
    white = Whitener.from_observations(sim.obs)
    det = checked(fit, sim.obs, white)
    runs: dict[str, list[dict]] = {"pose_by_pose": [], "batched": []}
    for _ in range(repeats):  # alternating: both see the same load
        runs["pose_by_pose"].append(one_check(fit, sim.obs, white, det, False))
        runs["batched"].append(one_check(fit, sim.obs, white, det, True))
    fit.model.batched = type(fit.model).BATCHED
    a, b = runs["pose_by_pose"][0], runs["batched"][0]
    std = np.where(det.determined, det.std, np.nan)
    diff = np.abs(a["estimates"] - b["estimates"]) / std
    out = {
        "case": name,
        "named": rep["named_effects"],
        "parameters": len(fit.names),
        "discover_s": discover_s,
        "replica_difference_max_std": float(np.nanmax(diff)) if np.isfinite(diff).any() else None,
        "replica_difference_median_std": float(np.nanmedian(diff)) if np.isfinite(diff).any() else None,
        "same_verdict": a["failed"] == b["failed"],
        "failed": b["failed"],
        "std_ratio_difference_max": max(
            (abs(a["ratios"][k] - b["ratios"][k]) for k in a["ratios"] if a["ratios"][k] is not None),
            default=None,
        ),
    }
    for key, rows in runs.items():
        out[key] = {
            "wall_s": [r["wall_s"] for r in rows],
            "cpu_s": [r["cpu_s"] for r in rows],
            "evaluations": rows[0]["evaluations"],
        }
    out["speedup_wall"] = min(out["pose_by_pose"]["wall_s"]) / min(out["batched"]["wall_s"])
    out["speedup_cpu"] = min(out["pose_by_pose"]["cpu_s"]) / min(out["batched"]["cpu_s"])
    robot = Robot.from_file(model) if model is not None else Robot.from_xml(sim.mjcf)
    ident: dict[str, list[dict]] = {"pose_by_pose": [], "batched": []}
    for _ in range(repeats):
        ident["pose_by_pose"].append(identify_check(robot, sim.obs, False))
        ident["batched"].append(identify_check(robot, sim.obs, True))
    out["identify_self_check"] = {
        key: {
            "wall_s": [r["wall_s"] for r in rows],
            "cpu_s": [r["cpu_s"] for r in rows],
            "failed": rows[0]["failed"],
        }
        for key, rows in ident.items()
    }
    out["load_average_1min"] = os.getloadavg()[0]
    return out


def main() -> int:
    import tempfile

    ap = argparse.ArgumentParser()
    ap.add_argument("--irb-seeds", default="2,3,4", help="IRB 6640 case seeds (default: %(default)s)")
    ap.add_argument("--repeats", type=int, default=1, help="self-checks of each kind per case")
    ap.add_argument("--no-fanuc", action="store_true", help="leave out the FANUC paper plan")
    ap.add_argument("--quick", action="store_true", help="the FANUC cases only, no IRB 6640")
    args = ap.parse_args()
    if args.quick:
        args.irb_seeds = ""
    tmp = Path(tempfile.mkdtemp())
    from calbench.bench.scenario import scenario_variant

    cases: list[tuple[str, Path, object]] = []
    if not args.no_fanuc:
        cases += [
            ("fanuc paper plan", PAPER, None),
            ("fanuc forearm bending", scenario_variant(PAPER, tmp / "forearm.toml", extra=FOREARM), None),
        ]
    case = shared_case()
    seeds = [int(s) for s in args.irb_seeds.split(",") if s]
    if case is None and seeds:
        print("no IRB 6640 case in the shared data: FANUC only", file=sys.stderr)
    elif case is not None:
        cases += [(f"irb6640 seed {s}", irb_scenario(case, s, tmp), case / "irb6640.xml") for s in seeds]
    res = []
    for name, scn, model in cases:
        print(f"{name} ...", file=sys.stderr, flush=True)
        res.append(run_case(name, scn, model, args.repeats))
        print(json.dumps(res[-1]), file=sys.stderr, flush=True)
    print(json.dumps({"cases": res}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
