"""The plan designed for a job against the paper's and the A- and D-optimal plans (issue 26,
"Design for the job"), in the unit a machining user cares about. Prints JSON.

Four 16-pose plans on the FANUC (scenarios/paper_table5.toml's robot, truth, tracker and load):
the paper's Table 5 plan itself, and `calbench design --configs 16` with --criterion A, D and
pose --job scenarios/jobs/fanuc_milling.toml (the I-optimal plan for the job: the mean
predicted compensation error over its 24 points). For each plan and each seed: simulate the
campaign, identify (one-step), compensate the job (default target) and apply the commands to
the true robot. Reported per plan: the true RMS error after compensation over all seeds and
points (sqrt of the mean of the per-seed mean squares, the seeds being the independent
samples), its sampling error (delta method on the per-seed mean squares), the design's own
predicted RMS, and the paired differences to the job's plan (same seeds: the noise of one seed
is not shared between plans, so the pairing only keeps the comparison honest about its spread).

    .venv/bin/python benchmarks/compensate_design_bench.py [--seeds 100] [--quick]

(--quick: 8 seeds.)
"""

from __future__ import annotations

import argparse
import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np
from steps import say

from calbench.bench.campaign import run_campaign
from calbench.bench.scenario import load_scenario
from calbench.identify import DesignRequest, run_design
from calbench.identify.compensate import CompensationRequest, run_compensate
from calbench.identify.report import run_identify

ROOT = Path(__file__).resolve().parent.parent
PAPER = ROOT / "scenarios" / "paper_table5.toml"
JOB = ROOT / "scenarios" / "jobs" / "fanuc_milling.toml"
CONFIGS = 16


def plans(work: Path) -> dict[str, Path]:
    out = {"paper_table5": PAPER}
    for name, crit, job in (("A_optimal", "A", None), ("D_optimal", "D", None), ("job_optimal", "pose", JOB)):
        say("compensate-design", f"design {name}")
        path = work / f"{name}.toml"
        res = run_design(DesignRequest(scenario=PAPER, configs=CONFIGS, criterion=crit, out=path, job=job))
        path.write_text(res.plan_text)
        out[name] = path
    return out


def mean_squares(plan: Path, seeds: list[int], work: Path) -> list[float]:
    """Per seed: the mean over the job's points of the true squared error after compensation."""
    out = []
    for s in seeds:
        log, js = work / f"{plan.stem}_{s}.mcap", work / f"{plan.stem}_{s}.json"
        run_campaign(load_scenario(plan, seed=s), log)
        js.write_text(run_identify(log).to_json())
        res = run_compensate(CompensationRequest(JOB, js, truth=PAPER))
        out.append(float(np.mean([t.error_after_m**2 for t in res.truth])))
        log.unlink()
    return out


def rms_and_error(ms: np.ndarray) -> tuple[float, float]:
    """sqrt(mean(ms)) and its standard error (delta method: se(mean) / (2 sqrt(mean)))."""
    m = float(np.mean(ms))
    se = float(np.std(ms, ddof=1) / math.sqrt(len(ms)))
    return math.sqrt(m), se / (2 * math.sqrt(m))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=100)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    seeds = list(range(1, (8 if args.quick else args.seeds) + 1))
    out: dict = {"job": str(JOB.relative_to(ROOT)), "configs": CONFIGS, "seeds": len(seeds), "plans": {}}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        ms = {}
        for name, path in plans(work).items():
            say("compensate-design", f"{name}: {len(seeds)} campaigns")
            ms[name] = np.array(mean_squares(path, seeds, work))
            rms, err = rms_and_error(ms[name])
            out["plans"][name] = {"true_after_rms_um": rms * 1e6, "sampling_error_um": err * 1e6}
    job = ms["job_optimal"]
    for name, v in ms.items():
        if name == "job_optimal":
            continue
        d = v - job  # paired by seed
        out["plans"][name]["mean_square_minus_job_plan_um2"] = float(np.mean(d) * 1e12)
        out["plans"][name]["its_sampling_error_um2"] = float(np.std(d, ddof=1) / math.sqrt(len(d)) * 1e12)
        out["plans"][name]["job_plan_better_in_seeds"] = float(np.mean(d > 0))
    out["load_average"] = round(os.getloadavg()[0], 2)
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
