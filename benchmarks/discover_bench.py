"""Detection power of `calbench discover` on the paper plan (20 um tracker): the study
studies/discovery_power.toml, run on Dask (issue 15 replaced this benchmark's own loop by it).

For each hidden effect and each magnitude (a fraction of the tested one), N campaigns (default
20 seeds) are simulated and discovered: how often the right effect (and option) is named first,
how often something else or `unexplained` or nothing, the median RMS before/after against noise,
the flange displacement the effect adds under 700 kg, and the smallest magnitude at which the
right effect is still named in >= 90 % of the seeds. Also: the false-alarm rate on campaigns with
no hidden effect, the discovery time per campaign, and the whole study's time and executor.
Prints JSON.

    python benchmarks/discover_bench.py [--seeds 20] [--effects forearm,base,...] [--quick]
                                        [--scheduler ADDR] [--out RESULTS.parquet]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
import tomllib
from collections import Counter
from pathlib import Path

import mujoco
import numpy as np

ROOT = Path(__file__).resolve().parent.parent

from steps import LineProgress, say

from calbench.bench.campaign import plan_campaign, truth_robot
from calbench.bench.scenario import scenario_to_toml
from calbench.identify.runtime import choose, open_executor
from calbench.identify.study import load_study, prepare, read_results, run_study

STUDY = ROOT / "studies" / "discovery_power.toml"


def study_file(tmp: Path, seeds: int, effects: list[str] | None, quick: bool) -> Path:
    """The shipped study with its seeds, effects (plus "none") and magnitudes chosen here."""
    doc = tomllib.loads(STUDY.read_text())
    doc["scenario"] = str((STUDY.parent / doc["scenario"]).resolve())
    doc["seeds"] = seeds
    for ax in doc["axis"]:
        if "cases" in ax and effects:
            ax["cases"] = [c for c in ax["cases"] if c["label"] == "none" or c["label"] in effects]
        if "scales" in ax and quick:
            ax["values"] = [1.0]
    out = tmp / "discovery_power.toml"
    out.write_text(scenario_to_toml(doc))
    return out


def largest_float(x) -> float:
    if isinstance(x, float):
        return abs(x)
    if isinstance(x, dict):
        x = list(x.values())
    if isinstance(x, list):
        return max((largest_float(v) for v in x), default=0.0)
    return 0.0


def flange_extra(study, with_cell, without_cell, site: str = "flange") -> float:
    """Median extra displacement (mm) of a site under the plan's loads that the effect adds."""
    moves = []
    for cell in (with_cell, without_cell):
        scn = study.portable(cell).scenario()
        robot = truth_robot(scn)
        f = robot.model.site(site).id
        m = []
        for p in plan_campaign(scn, robot):
            pos = []
            for e in p.equilibria:
                robot.data.qpos[:] = e.qpos
                mujoco.mj_kinematics(robot.model, robot.data)
                pos.append(robot.data.site_xpos[f].copy())
            m.append(pos[1] - pos[0])
        moves.append(np.array(m))
    return float(np.median(np.linalg.norm(moves[0] - moves[1], axis=1)) * 1e3)


def rows_of(table, cells) -> dict:
    want = {c.index for c in cells}
    cols = {
        n: table.column(n).to_pylist()
        for n in (
            "cell",
            "named_first",
            "detected",
            "rms_before",
            "noise_rms_before",
            "rms_after",
            "noise_rms_after",
            "discover_s",
            "error",
        )
    }
    idx = [i for i, c in enumerate(cols["cell"]) if c in want]
    return {k: [v[i] for i in idx] for k, v in cols.items()}


def case_row(r: dict, magnitude: float) -> dict:
    n = len(r["cell"])
    return {
        "magnitude": magnitude,
        "right": sum(bool(d) for d in r["detected"]) / n,
        "named": dict(Counter(r["named_first"])),
        "rms_before_over_noise_median": statistics.median(
            a / b for a, b in zip(r["rms_before"], r["noise_rms_before"])
        ),
        "rms_after_over_noise_median": statistics.median(
            a / b for a, b in zip(r["rms_after"], r["noise_rms_after"])
        ),
        "rms_after_over_noise_max": max(a / b for a, b in zip(r["rms_after"], r["noise_rms_after"])),
        "seconds_median": statistics.median(r["discover_s"]),
        "seconds_max": max(r["discover_s"]),
        "failed": sum(1 for e in r["error"] if e),
    }


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=None, help="seeds per cell (default: 20, --quick 4)")
    ap.add_argument("--effects", default=None, help="comma-separated case labels (default: all)")
    ap.add_argument("--quick", action="store_true", help="tested magnitude only, 4 seeds")
    ap.add_argument("--scheduler", default=None, help="as calbench study --scheduler")
    ap.add_argument(
        "--out", type=Path, default=None, help="keep the study's Parquet here (default: temporary)"
    )
    args = ap.parse_args()
    if args.seeds is None:
        args.seeds = 4 if args.quick else 20
    with tempfile.TemporaryDirectory() as tmp_:
        tmp = Path(tmp_)
        study = load_study(
            study_file(tmp, args.seeds, args.effects.split(",") if args.effects else None, args.quick)
        )
        out = args.out or tmp / "discovery_power.parquet"
        pending = prepare(study, out)
        t0 = time.perf_counter()
        with open_executor(choose(args.scheduler, pending.estimated_seconds(), pending.tasks())) as ex:
            where = ex.choice.describe()
            say("discover_bench", f"{pending.campaigns} campaigns of studies/discovery_power.toml, {where}")
            outcome = run_study(pending, ex, progress=LineProgress("discover_bench", "campaigns"))
        total = time.perf_counter() - t0
        table, _ = read_results(out)
        res: dict = {
            "plan": "scenarios/paper_table5.toml",
            "tracker_sigma_um": 20,
            "seeds": args.seeds,
            "study": "studies/discovery_power.toml",
            "executor": where,
            "total_seconds": total,
            "campaigns": outcome.total,
            "campaigns_run": outcome.ran,
            "failed": outcome.failed,
            "criterion": "right effect (and option) named first",
            "effects": {},
        }
        effect_axis = next(a for a in study.axes if a.scales is None)
        scale_axis = next(a for a in study.axes if a.scales is not None)
        by = {(c.values[effect_axis.name], c.values[scale_axis.name]): c for c in study.cells}
        top = max(scale_axis.column)
        none = by[("none", top)]
        r = rows_of(table, [none])
        res["no_effect"] = case_row(r, 0.0)
        res["no_effect"]["false_alarm_rate"] = 1.0 - res["no_effect"]["named"].get("nothing", 0) / len(
            r["cell"]
        )
        for label, settings in zip(effect_axis.column, effect_axis.settings):
            if label == "none":
                continue
            v0 = largest_float(list(settings.values()))
            rows = [
                case_row(rows_of(table, [by[(label, f)]]), v0 * f)
                for f in sorted(scale_axis.column, reverse=True)
            ]
            good = [row["magnitude"] for row in rows if row["right"] >= 0.9]
            cell = by[(label, top)]
            hidden = "compensator" not in (cell.expected or "")
            res["effects"][label] = {
                "expected": cell.expected,
                "tested_magnitude": v0,
                "flange_extra_mm_median": flange_extra(study, cell, none) if hidden else None,
                "payload_point_extra_mm_median": flange_extra(study, cell, none, "payload")
                if hidden
                else None,
                "smallest_magnitude_named_in_90pct": min(good) if good else None,
                "rows": rows,
            }
            print(json.dumps({label: res["effects"][label]}), file=sys.stderr)
    print(json.dumps(res, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
