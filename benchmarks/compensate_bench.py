"""Compensation on the bench (issue 26). Prints JSON.

For each robot (the FANUC M-900iB/700 on the paper plan, scenarios/paper_table5.toml; the
KR 270 on its paper plan, scenarios/kr270_paper.toml) and each campaign seed: simulate the
campaign (20 um tracker), identify (one-step), compensate the robot's milling job
(scenarios/jobs/*_milling.toml, 24 points, 1.5-4.5 kN, default target `unloaded`) and apply
the commands to the true robot. Reported: the true RMS tool position error before and after,
over all seeds and points together and per seed, the fraction removed per seed, the largest
error after, the predicted error (RMS of predicted_error_std_m) and z = |true after| /
predicted std (its RMS over seeds and points; the seeds are the independent samples, the
points of one seed move together, so its sampling error is about 1/sqrt(2 x seeds)).

Then the rigid target on the FANUC (seed 1): predicted and true error, the same without the
compensator spring (both targets: the sag then rests on determined parameters), a hidden
forearm compliance compensated with the user's model and with discover's augmented one, and the
speed on a long
job (a path sweeping the FANUC's front): the batched compensation (identify/compensate/batch.py)
on --points points, the scalar loop on 2000 of them, seconds per point side by side (each with
the load average at its start: other work on the 2 cores slows wall time).

    .venv/bin/python benchmarks/compensate_bench.py [--seeds 10] [--points 10000] [--quick]

(--quick: 3 seeds, 500 points batched, 200 scalar.)
"""

from __future__ import annotations

import argparse
import json
import math
import os
import tempfile
import time
from pathlib import Path

import numpy as np
from steps import say

from calbench.bench.campaign import run_campaign
from calbench.bench.model import Robot
from calbench.bench.model.effects import without_compensator
from calbench.bench.scenario import load_scenario, scenario_variant
from calbench.identify import run_discover
from calbench.identify.compensate import (
    CompensationRequest,
    Compensator,
    JobPoint,
    check_job,
    compensate_batch,
    load_job,
    read_identified,
    run_compensate,
    with_tool,
)
from calbench.identify.report import run_identify

ROOT = Path(__file__).resolve().parent.parent
CASES = {
    "fanuc_m900ib700": (
        ROOT / "scenarios" / "paper_table5.toml",
        ROOT / "scenarios" / "jobs" / "fanuc_milling.toml",
    ),
    "kr270": (ROOT / "scenarios" / "kr270_paper.toml", ROOT / "scenarios" / "jobs" / "kr270_milling.toml"),
}


def rms(x) -> float:
    x = np.asarray(x, dtype=float)
    return float(np.sqrt(np.mean(x * x)))


def identified(scenario: Path, seed: int, work: Path) -> Path:
    log, js = work / f"{scenario.stem}_{seed}.mcap", work / f"{scenario.stem}_{seed}.json"
    run_campaign(load_scenario(scenario, seed=seed), log)
    js.write_text(run_identify(log).to_json())
    return js


def case(name: str, seeds: list[int], work: Path) -> dict:
    scenario, job = CASES[name]
    per_seed, before, after, z, pred = [], [], [], [], []
    for s in seeds:
        say("compensate", f"{name} seed {s}")
        res = run_compensate(CompensationRequest(job, identified(scenario, s, work), truth=scenario))
        b = [t.error_before_m for t in res.truth]
        a = [t.error_after_m for t in res.truth]
        before += b
        after += a
        z += [t.z for t in res.truth]
        pred += [p.predicted_error_std_m for p in res.points]
        per_seed.append(
            {
                "seed": s,
                "before_rms_um": rms(b) * 1e6,
                "after_rms_um": rms(a) * 1e6,
                "after_max_um": max(a) * 1e6,
                "removed": 1.0 - rms(a) / rms(b),
                "predicted_rms_um": rms([p.predicted_error_std_m for p in res.points]) * 1e6,
                "z_rms": rms([t.z for t in res.truth]),
                "unreached": len(res.unreached),
            }
        )
    return {
        "scenario": str(scenario.relative_to(ROOT)),
        "job": str(job.relative_to(ROOT)),
        "points": len(load_job(job).points),
        "seeds": seeds,
        "before_rms_mm": rms(before) * 1e3,
        "after_rms_um": rms(after) * 1e6,
        "after_max_um": max(after) * 1e6,
        "removed_min": min(p["removed"] for p in per_seed),
        "predicted_rms_um": rms(pred) * 1e6,
        "z_rms": rms(z),
        "z_rms_sampling_error": 1.0 / math.sqrt(2 * len(seeds)),
        "per_seed": per_seed,
    }


def rigid(work: Path) -> dict:
    scenario, job = CASES["fanuc_m900ib700"]
    res = run_compensate(
        CompensationRequest(job, work / f"{scenario.stem}_1.json", target="rigid", truth=scenario)
    )
    s = res.summary()
    return {
        "seed": 1,
        "predicted_rms_mm": s["predicted_error_rms_m"] * 1e3,
        "true_after_rms_mm": s["true_error_after_rms_m"] * 1e3,
        "true_before_rms_mm": s["true_error_before_rms_m"] * 1e3,
        "z_rms": s["z_rms"],
    }


def figures(s: dict) -> dict:
    """A compensation's summary on the bench in micrometres."""
    return {
        "true_before_rms_um": s["true_error_before_rms_m"] * 1e6,
        "true_after_rms_um": s["true_error_after_rms_m"] * 1e6,
        "true_after_max_um": s["true_error_after_max_m"] * 1e6,
        "predicted_rms_um": s["predicted_error_rms_m"] * 1e6,
        "z_rms": s["z_rms"],
        "prediction_exceeded": s["prediction_exceeded"],
    }


def rigid_without_spring(work: Path) -> dict:
    """The rigid target on the FANUC without its compensator (bench.model.without_compensator):
    the sag then rests on k1..k6 alone, which the paper plan determines (seed 1)."""
    scenario, job = CASES["fanuc_m900ib700"]
    xml = work / "nocomp.xml"
    xml.write_text(without_compensator(ROOT / "mjcf" / "m900ib700.xml"))
    scn = scenario_variant(scenario, work / "nocomp.toml", robot=xml, drop=("truth.compensator",))
    jb = work / "nocomp_job.toml"
    jb.write_text(job.read_text().replace('robot = "../../mjcf/m900ib700.xml"', f'robot = "{xml}"'))
    js = identified(scn, 1, work)
    out = {}
    for target in ("unloaded", "rigid"):
        out[target] = figures(run_compensate(CompensationRequest(jb, js, target=target, truth=scn)).summary())
    return out


def discovery_value(work: Path) -> dict:
    """A hidden forearm compliance (discover's test case): the error after compensation with the
    user's model against the model that discover augments with the effect it names, both
    identified from the same log (seed 1) and applied to the same true robot."""
    scenario, job = CASES["fanuc_m900ib700"]
    mjcf = ROOT / "mjcf" / "m900ib700.xml"
    text = scenario.read_text().replace(
        "[tracker]",
        '[truth.effects.link_compliance]\nlink = "forearm"\ncompliance = [1.8e-7, 0.0, 1.8e-7]\n\n[tracker]',
        1,
    )
    scn = work / "hidden.toml"
    scn.write_text(text.replace('robot = "../mjcf/m900ib700.xml"', f'robot = "{mjcf}"'))
    log = work / "hidden.mcap"
    run_campaign(load_scenario(scn), log)
    aug = work / "augmented.xml"
    say("compensate", "discover on the hidden-effect log")
    rep = run_discover(log, mjcf, out_model=aug)
    out = {"named_effects": rep["named_effects"]}
    for name, model in (("user_model", None), ("augmented_model", aug if aug.exists() else None)):
        if name == "augmented_model" and model is None:
            out[name] = None
            continue
        js = work / f"hidden_{name}.json"
        js.write_text(run_identify(log, model).to_json())
        out[name] = figures(run_compensate(CompensationRequest(job, js, model=model, truth=scn)).summary())
    return out


def speed(n: int, scalar: int, work: Path) -> dict:
    scenario, job_path = CASES["fanuc_m900ib700"]
    job = load_job(job_path)
    robot = Robot.from_file(job.robot)
    check_job(job, robot)
    ident = read_identified(work / f"{scenario.stem}_1.json", robot)
    s = np.linspace(0.0, 1.0, n)
    q = np.radians(
        np.column_stack(
            [
                -40 + 80 * s,
                55 + 10 * np.sin(3 * np.pi * s),
                -5 + 8 * s,
                0 * s,
                -60 + 6 * np.sin(8 * np.pi * s),
                0 * s,
            ]
        )
    )
    w = np.array([-1800.0, 600.0, 2400.0, 150.0, -200.0, -200.0])
    points = tuple(JobPoint(row, wrench=w) for row in q)
    comp = Compensator(with_tool(robot, job.tool), ident.params(robot), ident.covariance)
    out = {}
    for name, run, m in (
        ("scalar", comp.path, min(n, scalar)),
        ("batched", lambda pts: compensate_batch(comp, pts), n),
    ):
        say("compensate", f"speed: {m} points, {name}")
        load = round(os.getloadavg()[0], 2)
        t0, c0 = time.perf_counter(), time.process_time()
        res = run(points[:m])
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        out[name] = {
            "points": m,
            "converged": sum(r.converged for r in res),
            "wall_s": wall,
            "cpu_s": cpu,
            "ms_per_point": 1e3 * wall / m,
            "newton_steps_mean": float(np.mean([r.iterations for r in res])),
            "load_average": load,
        }
    out["batched_over_scalar_per_point"] = out["batched"]["ms_per_point"] / out["scalar"]["ms_per_point"]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--points", type=int, default=10000, help="the long job's points (batched)")
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    seeds = list(range(1, (3 if args.quick else args.seeds) + 1))
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        out = {name: case(name, seeds, work) for name in CASES}
        out["fanuc_rigid_target"] = rigid(work)
        say("compensate", "the rigid target without the compensator spring")
        out["fanuc_without_spring"] = rigid_without_spring(work)
        out["fanuc_hidden_effect"] = discovery_value(work)
        out["speed"] = speed(500 if args.quick else args.points, 200 if args.quick else 2000, work)
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
