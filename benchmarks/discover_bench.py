"""Detection power of `calbench discover` on the paper plan (20 um tracker).

For each hidden effect and each magnitude (a fraction of the tested one), campaigns with N noise
seeds (default 20) are simulated and discovered: how often the right effect (and option) is named
first, how often something else or `unexplained` or nothing, the median RMS before/after against
noise, the flange displacement the effect adds under 700 kg, and the smallest magnitude at which
the right effect is still named in >= 90 % of the seeds. Also: the false-alarm rate on logs with
no hidden effect, and the workflow time. Prints JSON.

    python benchmarks/discover_bench.py [--seeds 20] [--effects forearm,base,...] [--quick]
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent

from calbench.bench.campaign import plan_campaign, run_campaign, truth_robot
from calbench.bench.effects import without_compensator
from calbench.bench.scenario import load_scenario, scenario_variant
from calbench.identify.discover.workflow import discover
from steps import say

PAPER = ROOT / "scenarios" / "paper_table5.toml"
MJCF = ROOT / "mjcf" / "m900ib700.xml"

# name: (TOML template with {v} the magnitude, tested magnitude, expected effect, detail, model)
CASES = {
    "forearm": ('[truth.effects.link_compliance]\nlink = "forearm"\ncompliance = [{v}, 0.0, {v}]', 1.8e-7,
                "link_compliance", "forearm"),
    "upper_arm": ('[truth.effects.link_compliance]\nlink = "upper_arm"\ncompliance = [{v}, {v}, {v}]', 1.5e-8,
                  "link_compliance", "upper_arm"),
    "base": ("[truth.effects.base_compliance]\ncompliance = [{v}, {v}]", 4e-9, "base_compliance", ""),
    "j3": ("[truth.effects.joint_nonlinearity]\njoint = 3\ncubic = {v}", 6e12, "joint_nonlinearity", "j3"),
    "compensator": ("COMPENSATOR {v}", 6e6, "compensator", ""),
    "tool (outside the library)": ("[truth.effects.tool_compliance]\ncompliance = [{v}, {v}]", 4e-7,
                                   "unexplained", ""),
}
FRACTIONS = (1.0, 0.75, 0.5, 0.35)


def scenario(tmp: Path, extra: str, seed: int) -> Path:
    """The paper scenario with a hidden effect ("COMPENSATOR K_C" sets the spring's stiffness)."""
    out = tmp / f"s{seed}.toml"
    if extra.startswith("COMPENSATOR"):
        return scenario_variant(PAPER, out, seed=seed, compensator=(float(extra.split()[1]), 0.83))
    return scenario_variant(PAPER, out, seed=seed, extra=extra)


def bare_model(tmp: Path) -> Path:
    path = tmp / "bare.xml"
    path.write_text(without_compensator(MJCF))
    return path


def flange_extra(extra: str, tmp: Path, site: str = "flange") -> float | None:
    """Median extra displacement (mm) of a site (the flange; the payload point for an effect on
    the tool, which does not move the flange) that the effect adds under the plan's loads."""
    if extra.startswith("COMPENSATOR") or not extra:
        return None
    with_e = load_scenario(scenario(tmp, extra, 1))
    without = load_scenario(scenario(tmp, "", 1))
    out = []
    for scn in (with_e, without):
        robot = truth_robot(scn)
        plans = plan_campaign(scn, robot)
        f = robot.model.site(site).id
        moves = []
        for p in plans:
            pos = []
            for e in p.equilibria:
                robot.data.qpos[:] = e.qpos
                import mujoco
                mujoco.mj_kinematics(robot.model, robot.data)
                pos.append(robot.data.site_xpos[f].copy())
            moves.append(pos[1] - pos[0])
        out.append(np.array(moves))
    return float(np.median(np.linalg.norm(out[0] - out[1], axis=1)) * 1e3)


def run_case(tmp: Path, tmpl: str, v: float, effect: str, detail: str, seeds: int, model) -> dict:
    extra = tmpl.format(v=v)
    named, ok, before, after, secs = [], 0, [], [], []
    for seed in range(1, seeds + 1):
        log = tmp / f"log{seed}.mcap"
        run_campaign(load_scenario(scenario(tmp, extra, seed)), log)
        rep = discover(log, model, out_model=tmp / "aug.xml")
        first = rep["steps"][0] if rep["steps"] else None
        tag = (first["effect"] + (f"[{first['detail']}]" if first["detail"] and first["effect"] != "unexplained"
                                  else "")) if first else "nothing"
        named.append(tag)
        ok += int(first is not None and first["effect"] == effect and (not detail or first["detail"] == detail)
                  and (effect == "unexplained" or rep["named_effects"][0] == effect))
        before.append(rep["rms_before"] / rep["noise_rms_before"])
        after.append(rep["rms_after"] / rep["noise_rms_after"])
        secs.append(rep["seconds"])
    counts: dict[str, int] = {}
    for t in named:
        counts[t] = counts.get(t, 0) + 1
    return {"magnitude": v, "right": ok / seeds, "named": counts,
            "rms_before_over_noise_median": statistics.median(before),
            "rms_after_over_noise_median": statistics.median(after),
            "rms_after_over_noise_max": max(after),
            "seconds_median": statistics.median(secs), "seconds_max": max(secs)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=None, help="seeds per case (default: 20, --quick 4)")
    ap.add_argument("--effects", default=",".join(CASES))
    ap.add_argument("--quick", action="store_true", help="tested magnitude only, 4 seeds")
    args = ap.parse_args()
    if args.seeds is None:
        args.seeds = 4 if args.quick else 20
    out: dict = {"plan": "scenarios/paper_table5.toml", "tracker_sigma_um": 20, "seeds": args.seeds,
                 "criterion": "right effect (and option) named first", "effects": {}}
    with tempfile.TemporaryDirectory() as tmp_:
        tmp = Path(tmp_)
        bare = bare_model(tmp)
        t0 = time.perf_counter()
        out["no_effect"] = run_case(tmp, "", 0.0, "nothing", "", args.seeds, None)
        out["no_effect"]["false_alarm_rate"] = 1.0 - out["no_effect"]["named"].get("nothing", 0) / args.seeds
        for name in args.effects.split(","):
            say("discover_bench", f"{name}: {args.seeds} seeds per magnitude")
            tmpl, v0, effect, detail = CASES[name]
            model = bare if effect == "compensator" else None
            rows = []
            for frac in ((1.0,) if args.quick else FRACTIONS):
                rows.append(run_case(tmp, tmpl, v0 * frac, effect, detail, args.seeds, model))
                if rows[-1]["right"] < 0.5:
                    break
            good = [r["magnitude"] for r in rows if r["right"] >= 0.9]
            out["effects"][name] = {"expected": effect + (f"[{detail}]" if detail else ""),
                                    "tested_magnitude": v0,
                                    "flange_extra_mm_median": flange_extra(tmpl.format(v=v0), tmp),
                                    "payload_point_extra_mm_median": flange_extra(tmpl.format(v=v0), tmp, "payload"),
                                    "smallest_magnitude_named_in_90pct": min(good) if good else None,
                                    "rows": rows}
            print(json.dumps({name: out["effects"][name]}), file=sys.stderr)
        out["total_seconds"] = time.perf_counter() - t0
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
