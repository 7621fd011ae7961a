"""Inputs of any size in bounded memory (issue 24): the peak memory (RSS, from the child
process's own resource usage: os.wait4) and time of calbench commands on inputs of growing size,
against the budget each states.

* ``import``: readings CSVs of 10^4..10^6 rows along the paper plan (tests/big_inputs.py),
  `calbench import` with the tracker where the plan puts it. Budget (the design): the first
  run's RSS + TABLE_BYTES_PER_ROW (100 B) a row + READING_BYTES (5 kB) per reading of the
  largest pose (the only pose whose readings exist at once).
* ``log``: campaign logs of 20 MB .. 2 GB (the paper campaign's poses repeated, 5000 readings
  per state each: a pose's readings are ~1 MB), `calbench identify LOG --json`. Budget: the
  first run's RSS + POSE_BYTES (40 kB: identify's own state per pose) per extra pose; the
  readings are read a pose at a time (bench/log/read.py LogReadings), so their number does not
  count.
* ``design``: `calbench design` on the paper scenario with 10^4 and 10^5 candidates (one
  process). Budget: the 10^4 run's RSS + DESIGN_BYTES (7 kB: the batched statics' peak per
  candidate, identify/design/run.py CANDIDATE_BYTES) per extra candidate.
* ``compensate``: a job of 24 and 10^4 points (the FANUC milling pass, interpolated), with the
  paper campaign's identification. Budget: the small run's RSS + JOB_BYTES (16 kB,
  identify/compensate/run.py POINT_BYTES) per extra point.

Prints JSON rows {what, size, seconds, peak_mb, budget_mb, within}. Usage:
python benchmarks/sizes_bench.py [--quick] [--only import,log,design,compensate] [--log-gb 2]
(--quick: 10^5 rows, 200 MB of log, 2*10^4 candidates, 2000 points). Run it with nice.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from steps import say

from calbench.bench.shopfloor import TABLE_BYTES_PER_ROW

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))  # the input makers the memory tests use (tests/big_inputs.py)
from big_inputs import readings_file, replicated_log  # noqa: E402

PAPER = ROOT / "scenarios" / "paper_table5.toml"
JOB = ROOT / "scenarios" / "jobs" / "fanuc_milling.toml"
READING_BYTES = 5000  # per reading of the largest pose (tests/test_sizes.py)
POSE_BYTES = 40_000  # per pose of a log: identify's own per-pose state (~34 kB measured; the reader's ~6 kB)
REPEATS = 5000  # readings per state of each pose of the big logs
DESIGN_BYTES = 7000  # per candidate: identify/design/run.py CANDIDATE_BYTES (its batched statics' peak)
JOB_BYTES = 16_000  # per job point: identify/compensate/run.py POINT_BYTES


def run(cmd: list[str]) -> tuple[float, float, str]:
    """Run ``calbench`` ``cmd`` in a child: (seconds, peak RSS in MB, its stderr's last line)."""
    t = time.perf_counter()
    proc = subprocess.Popen(
        [sys.executable, "-m", "calbench.identify.cli", *cmd],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "CALBENCH_PROGRESS_S": "60"},
    )
    err = proc.stderr.read() if proc.stderr else ""
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    seconds = time.perf_counter() - t
    if proc.returncode not in (0, 1):
        raise SystemExit(f"calbench {' '.join(cmd)} failed ({proc.returncode}): {err.strip()[-500:]}")
    return seconds, usage.ru_maxrss / 1024, (err.strip().splitlines() or [""])[-1]


def row(what: str, size: int, unit: str, seconds: float, peak: float, budget: float, **extra) -> dict:
    out = {
        "what": what,
        "size": size,
        "unit": unit,
        "seconds": round(seconds, 1),
        "peak_mb": round(peak, 1),
        "budget_mb": round(budget, 1),
        "within": peak <= budget,
        **extra,
    }
    say("sizes_bench", json.dumps(out))
    return out


def plan_file(d: Path) -> Path:
    s = PAPER.read_text().replace(
        'robot = "../mjcf/m900ib700.xml"', f'robot = "{(ROOT / "mjcf").as_posix()}/m900ib700.xml"'
    )
    s = s[: s.index("[truth]")] + s[s.index("[tracker]") :]
    (d / "plan.toml").write_text(s)
    return d / "plan.toml"


def bench_import(d: Path, sizes: list[int]) -> list[dict]:
    plan = plan_file(d)
    out, first = [], None
    for rows in sizes:
        csv_path = readings_file(d / f"r{rows}.csv", plan, rows)
        seconds, peak, _ = run(
            ["import", str(csv_path), "--plan", str(plan), "--out", str(d / f"r{rows}.mcap")]
        )
        n_rows = sum(1 for _ in open(csv_path)) - 1
        largest = 2 * (n_rows // (16 * 2 * 3))  # readings of the largest pose, both states
        if first is None:
            first = (peak, n_rows, largest)
        budget = (
            first[0]
            + (TABLE_BYTES_PER_ROW * (n_rows - first[1]) + READING_BYTES * (largest - first[2])) / 2**20
        )
        out.append(
            row(
                "import",
                n_rows,
                "rows",
                seconds,
                peak,
                budget,
                csv_mb=round(csv_path.stat().st_size / 1e6, 1),
            )
        )
        csv_path.unlink()
    return out


def bench_log(d: Path, sizes_gb: list[float]) -> list[dict]:
    src = d / "paper.mcap"
    subprocess.run(
        [sys.executable, "-m", "calbench.identify.cli", "simulate", str(PAPER), "--out", str(src)],
        check=True,
        capture_output=True,
    )
    per_pose = None
    out, first = [], None
    for gb in sizes_gb:
        if per_pose is None:  # bytes a pose of REPEATS readings per state takes in the log
            probe = replicated_log(src, d / "probe.mcap", 16, REPEATS, fast=True)
            per_pose = probe.stat().st_size / 16
            probe.unlink()
        poses = max(int(gb * 1e9 / per_pose), 16)
        say("sizes_bench", f"writing a log of {poses} poses (~{poses * per_pose / 1e9:.2f} GB)")
        log = replicated_log(src, d / "big.mcap", poses, REPEATS, fast=True)
        seconds, peak, _ = run(["identify", str(log), "--json", str(d / "id.json")])
        if first is None:
            first = (peak, poses)
        budget = first[0] + POSE_BYTES * (poses - first[1]) / 2**20
        out.append(
            row(
                "identify LOG",
                poses,
                "poses",
                seconds,
                peak,
                budget,
                log_gb=round(log.stat().st_size / 1e9, 3),
                readings=2 * REPEATS * poses,
            )
        )
        log.unlink()
    return out


def growing(what: str, unit: str, sizes: list[int], per_bytes: int, argv_of) -> list[dict]:
    """``calbench argv_of(n)`` for each size n: its peak against the first run's plus per_bytes
    per extra unit."""
    out, first = [], None
    for n in sizes:
        seconds, peak, _ = run(argv_of(n))
        if first is None:
            first = (peak, n)
        out.append(row(what, n, unit, seconds, peak, first[0] + per_bytes * (n - first[1]) / 2**20))
    return out


def bench_design(d: Path, sizes: list[int]) -> list[dict]:
    json_out = str(d / "design.json")
    return growing(
        "design",
        "candidates",
        sizes,
        DESIGN_BYTES,
        lambda n: ["design", str(PAPER), "--candidates", str(n), "--processes", "1", "--json", json_out],
    )


def job_of(points: int, d: Path) -> Path:
    """The FANUC milling pass with ``points`` points interpolated along its 24."""
    import tomllib

    job = tomllib.loads(JOB.read_text())
    q = np.array([p["q"] for p in job["point"]])
    w = np.array([p["wrench"] for p in job["point"]])
    s = np.linspace(0, len(q) - 1, points)
    qi = np.array([np.interp(s, np.arange(len(q)), q[:, j]) for j in range(q.shape[1])]).T
    wi = np.array([np.interp(s, np.arange(len(w)), w[:, j]) for j in range(w.shape[1])]).T
    head = (
        JOB.read_text()
        .split("[[point]]")[0]
        .replace('robot = "../../mjcf/', f'robot = "{(ROOT / "mjcf").as_posix()}/')
    )
    body = "".join(
        f"[[point]]\nq = [{', '.join(f'{v:.4f}' for v in a)}]\nwrench = [{', '.join(f'{v:.2f}' for v in b)}]\n\n"
        for a, b in zip(qi, wi)
    )
    path = d / f"job{points}.toml"
    path.write_text(head + body)
    return path


def bench_compensate(d: Path, sizes: list[int]) -> list[dict]:
    log = d / "paper.mcap"
    if not log.exists():
        subprocess.run(
            [sys.executable, "-m", "calbench.identify.cli", "simulate", str(PAPER), "--out", str(log)],
            check=True,
            capture_output=True,
        )
    subprocess.run(
        [sys.executable, "-m", "calbench.identify.cli", "identify", str(log), "--json", str(d / "id.json")],
        check=True,
        capture_output=True,
    )
    ident, csv_out, json_out = str(d / "id.json"), str(d / "c.csv"), str(d / "c.json")
    return growing(
        "compensate",
        "points",
        sizes,
        JOB_BYTES,
        lambda n: [
            "compensate",
            str(JOB if n == 24 else job_of(n, d)),
            "--identified",
            ident,
            "--out",
            csv_out,
            "--json",
            json_out,
        ],
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--only", default="import,design,compensate,log")
    ap.add_argument("--log-gb", type=float, default=2.0, help="the largest log (default 2 GB)")
    args = ap.parse_args()
    only = set(args.only.split(","))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        if "import" in only:
            rows += bench_import(d, [10_000, 100_000] if args.quick else [10_000, 100_000, 1_000_000])
        if "design" in only:
            rows += bench_design(d, [10_000, 20_000] if args.quick else [10_000, 100_000])
        if "compensate" in only:
            rows += bench_compensate(d, [24, 2_000] if args.quick else [24, 10_000])
        if "log" in only:
            top = 0.2 if args.quick else args.log_gb
            rows += bench_log(d, [0.02, 0.2] if args.quick else [0.02, 0.2, top])
    print(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
