"""Speed of `calbench discover` (multi-start included): no effect, one effect, two effects.

Targets (issue 12): <= 5 s for one effect, <= 15 s for two, on the 2-core machine. Each case is
a simulated paper campaign (20 um tracker, seed 1) discovered REPEATS times (default 3); the
median wall time and process CPU time are reported with the model evaluations, and the load
average of the machine while it ran (other jobs share the 2 cores: wall time is CPU time over
the share the process got).

``--baseline PYTHON`` runs the same cases, on the same logs, in a subprocess with another
checkout's interpreter (e.g. /work/main/.venv/bin/python: the discovery before this change) and
reports both side by side with their ratios; the two alternate case by case so that both see the
same load. Prints JSON.

    python benchmarks/discover_speed_bench.py [--repeats 3] [--baseline /work/main/.venv/bin/python] [--quick]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PAPER = ROOT / "scenarios" / "paper_table5.toml"
CASES = {
    "no effect": "",
    "one effect (forearm)": '[truth.effects.link_compliance]\nlink = "forearm"\ncompliance = [1.8e-7, 0.0, 1.8e-7]',
    "two effects (forearm + base)": (
        '[truth.effects.link_compliance]\nlink = "forearm"\ncompliance = [1.8e-7, 0.0, 1.8e-7]\n'
        "[truth.effects.base_compliance]\ncompliance = [4e-9, 4e-9]"
    ),
}


def time_case(log: Path, repeats: int) -> dict:
    """Discover ``log`` ``repeats`` times in this process (the code this interpreter imports)."""
    from calbench.identify.discover import discover

    wall, cpu, named, evals = [], [], None, None
    for _ in range(repeats):
        t, c = time.perf_counter(), time.process_time()
        rep = discover(log, out_model=log.with_suffix(".aug.xml"))
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
        named, evals = rep["named_effects"], rep.get("evaluations")
    return {
        "wall_s_median": statistics.median(wall),
        "cpu_s_median": statistics.median(cpu),
        "wall_s": wall,
        "cpu_s": cpu,
        "named": named,
        "evaluations": evals,
        "load_average_1min": os.getloadavg()[0],
    }


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=3, help="discoveries per case (default: %(default)s)")
    ap.add_argument(
        "--baseline",
        default=None,
        help="another checkout's python, timed side by side (default: none, this checkout only)",
    )
    ap.add_argument("--quick", action="store_true", help="one repeat per case (to see that it works)")
    ap.add_argument("--worker", type=Path, default=None, help=argparse.SUPPRESS)  # LOG: time one case
    args = ap.parse_args()
    if args.quick:
        args.repeats = 1
    if args.worker:
        print(json.dumps(time_case(args.worker, args.repeats)))
        return 0
    from calbench.bench.campaign import run_campaign
    from calbench.bench.scenario import load_scenario, scenario_variant

    out: dict = {
        "plan": "scenarios/paper_table5.toml",
        "repeats": args.repeats,
        "targets_s": {"one effect (forearm)": 5.0, "two effects (forearm + base)": 15.0},
        "cases": {},
    }
    with tempfile.TemporaryDirectory() as tmp_:
        tmp = Path(tmp_)
        for name, extra in CASES.items():
            log = tmp / f"{len(out['cases'])}.mcap"
            run_campaign(
                load_scenario(scenario_variant(PAPER, tmp / f"{len(out['cases'])}.toml", extra=extra)), log
            )
            row = {"this": time_case(log, args.repeats)}
            if args.baseline:
                res = subprocess.run(
                    [args.baseline, __file__, "--worker", str(log), "--repeats", str(args.repeats)],
                    capture_output=True,
                    text=True,
                    check=True,
                )
                row["baseline"] = json.loads(res.stdout.strip().splitlines()[-1])
                for k in ("wall_s_median", "cpu_s_median"):
                    row[f"{k}_ratio_this_over_baseline"] = row["this"][k] / row["baseline"][k]
            out["cases"][name] = row
            print(json.dumps({name: row}), file=sys.stderr)
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
