"""Candidates with exact information, batched against one at a time (issue 16). Prints JSON.

On the paper scenario (scenarios/paper_table5.toml, 700 kg, 3 reflectors):

* where the time goes, one candidate at a time (candidates.scalar_block, the path before issue
  16): cProfile's cumulative seconds of the command rules, the equilibria, the equilibrium rules
  (collision, clearance, visibility), the tangents and the site Jacobians, on --scalar candidates;
* the batched path (identify/design/batch_info.py) on --n candidates with 1 and 2 threads: wall
  and CPU seconds, its own phases, and the per-candidate ratio to the scalar path measured side
  by side in this process (the scalar on fewer candidates: per candidate it does not depend on n);
* end to end, the command ``calbench design SCENARIO --configs 12 --criterion D --candidates N
  --json`` (candidates, exchange, certificate, refinement), this checkout's and, with
  --baseline-cli, another calbench executable's (e.g. main's before issue 16), back to back,
  alternating, --repeats times: wall seconds, the child's CPU seconds and the JSON's timings.

Every figure carries the load average at its start (other work on the machine slows wall time;
CPU seconds much less). Usage:

    .venv/bin/python benchmarks/candidates_bench.py [--n 10000] [--scalar 1000] [--repeats 2]
        [--baseline-cli /path/to/old/.venv/bin/calbench] [--quick]

(--quick: 1000 candidates, 100 one at a time, one repeat, no command run.)
"""

from __future__ import annotations

import argparse
import cProfile
import json
import os
import pstats
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from steps import say

from calbench.identify.design import generate_candidates, load_design_scenario

ROOT = Path(__file__).resolve().parent.parent
PAPER = ROOT / "scenarios" / "paper_table5.toml"
# the scalar path's parts, by the function that does each (cumulative seconds under cProfile)
SCALAR_PARTS = {
    "command rules (rigid pose: limits, wrist, collision)": "check_command",
    "equilibria (StaticsSolver.solve)": "solve",
    "equilibrium rules (collision, clearance, visibility)": "check_equilibria",
    "tangents (exact matrix + IFT)": "tangent",
    "reflector Jacobians and tangents": "_site_jac",
    "covariance and whitening": "sigma_dp",
}


def load() -> float:
    return round(os.getloadavg()[0], 2)


def timed(fn) -> tuple[object, dict]:
    la, w, c = load(), time.perf_counter(), time.process_time()
    out = fn()
    return out, {"wall_s": time.perf_counter() - w, "cpu_s": time.process_time() - c, "load_average": la}


def scalar_profile(scn, st, n: int) -> dict:
    prof = cProfile.Profile()
    cands, t = timed(
        lambda: prof.runcall(generate_candidates, scn, st, n=n, processes=1, progress=False, batched=False)
    )
    stats = pstats.Stats(prof).stats
    parts = {}
    for label, fn in SCALAR_PARTS.items():
        parts[label] = sum(
            v[3] for k, v in stats.items() if k[2] == fn and ("/identify/" in k[0] or "/bench/" in k[0])
        )
    # check_command runs in screening and again inside pose(); _site_jac includes the tangents
    return {
        "candidates": len(cands),
        **t,
        "per_candidate_ms": t["wall_s"] / len(cands) * 1e3,
        "under_cprofile": True,
        "cumulative_s": parts,
        "note": "cProfile inflates Python-heavy parts; shares, not absolute times",
    }


def batched(scn, st, n: int, threads: int) -> dict:
    cands, t = timed(lambda: generate_candidates(scn, st, n=n, processes=threads, progress=False))
    return {
        "candidates": len(cands),
        "threads": threads,
        **t,
        "per_candidate_ms": t["wall_s"] / len(cands) * 1e3,
        "per_candidate_cpu_ms": t["cpu_s"] / len(cands) * 1e3,
        "raw_commands": cands.stats["raw_commands"],
        "phase_seconds": cands.stats["phase_seconds"],
    }


def scalar_plain(scn, st, n: int) -> dict:
    cands, t = timed(lambda: generate_candidates(scn, st, n=n, processes=1, progress=False, batched=False))
    return {
        "candidates": len(cands),
        **t,
        "per_candidate_ms": t["wall_s"] / len(cands) * 1e3,
        "per_candidate_cpu_ms": t["cpu_s"] / len(cands) * 1e3,
    }


def cli_run(exe: str, n: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        js = Path(tmp) / "d.json"
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        la, w = load(), time.perf_counter()
        proc = subprocess.run(
            [
                exe,
                "design",
                str(PAPER),
                "--configs",
                "12",
                "--criterion",
                "D",
                "--candidates",
                str(n),
                "--json",
                str(js),
            ],
            capture_output=True,
            text=True,
        )
        wall = time.perf_counter() - w
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        if proc.returncode != 0:
            return {"exe": exe, "error": proc.stderr[-2000:]}
        d = json.loads(js.read_text())
    cert = d.get("certificate", {})
    return {
        "exe": exe,
        "load_average": la,
        "wall_s": wall,
        "cpu_s": (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime),
        "timings": d.get("timings"),
        "plan_logdet": cert.get("plan_logdet"),
        "bound_logdet": cert.get("bound_logdet"),
        "efficiency": cert.get("efficiency"),
    }


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=10000)
    ap.add_argument("--scalar", type=int, default=1000, help="candidates of the one-at-a-time runs")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--baseline-cli", default=None, help="another calbench executable, run back to back")
    ap.add_argument("--no-cli", action="store_true", help="skip the end-to-end command (default: run it)")
    ap.add_argument(
        "--quick", action="store_true", help="1000 candidates, 100 one at a time, one repeat, no command run"
    )
    args = ap.parse_args()
    if args.quick:
        args.n, args.scalar, args.repeats, args.no_cli = 1000, 100, 1, True
    say("candidates_bench", f"profile of {args.scalar} candidates one at a time")
    scn, st = load_design_scenario(PAPER)
    generate_candidates(scn, st, n=100, processes=1, progress=False)  # imports, first-call costs
    out = {
        "machine_cpus": len(os.sched_getaffinity(0)),
        "scenario": str(PAPER.relative_to(ROOT)),
        "scalar_profile": scalar_profile(scn, st, args.scalar),
    }
    # side by side: scalar, batched 1 thread, batched 2 threads, alternating
    runs = {"scalar": [], "batched_1": [], "batched_2": []}
    for i in range(args.repeats):
        say("candidates_bench", f"scalar and batched, repeat {i + 1}/{args.repeats}")
        runs["scalar"].append(scalar_plain(scn, st, args.scalar))
        runs["batched_1"].append(batched(scn, st, args.n, 1))
        runs["batched_2"].append(batched(scn, st, args.n, 2))
    best = {k: min(v, key=lambda r: r["wall_s"]) for k, v in runs.items()}
    out["runs"] = runs
    out["per_candidate_ratio_scalar_over_batched"] = {
        f"{k}_wall": best["scalar"]["per_candidate_ms"] / best[k]["per_candidate_ms"]
        for k in ("batched_1", "batched_2")
    }
    out["per_candidate_ratio_scalar_over_batched"].update(
        {
            f"{k}_cpu": best["scalar"]["per_candidate_cpu_ms"] / best[k]["per_candidate_cpu_ms"]
            for k in ("batched_1", "batched_2")
        }
    )
    out["target"] = {
        "candidates": 10000,
        "seconds": 5.0,
        "cores": 2,
        "best_wall_s_2_threads": best["batched_2"]["wall_s"] * 10000 / best["batched_2"]["candidates"],
    }
    if not args.no_cli:
        exe = str(Path(sys.executable).parent / "calbench")
        cli = {"this": [], "baseline": []}
        for _ in range(args.repeats):
            cli["this"].append(cli_run(exe, args.n))
            if args.baseline_cli:
                cli["baseline"].append(cli_run(args.baseline_cli, args.n))
        out["cli_end_to_end"] = cli
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
