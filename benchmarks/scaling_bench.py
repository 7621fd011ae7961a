"""Scaling of studies on Dask (issue 15): efficiency, per-task overhead, what 10^5 campaigns cost.
Prints JSON.

* ``local_cluster``: in a fresh process, as a command pays it: importing distributed, starting a
  LocalCluster of 2 workers on 127.0.0.1 with its Client, a first task in each worker importing
  calbench, and closing it all (median of 3); then the scheduling cost per task: 1000 trivial
  tasks (operator.mul) on the 2 workers, W x wall / tasks. These are the constants
  identify/runtime/executor.py chooses its executor with.
* ``study``: the same study (identify-only campaigns of the paper plan: 8 cells x 20 seeds,
  16 tasks of ~2 s) in this process, on a local cluster of 1 worker and of 2 workers, side by
  side in this process, best of ``--repeats``. Times are of the run only (the cluster is started
  before). Efficiency on W workers = T(1 worker) / (W T(W)). Per-task overhead on one worker =
  (T - compute) / tasks, compute being the sum of the campaigns' own times measured inside the
  tasks: what a task costs beyond its work (transfer, journal, progress); worker utilisation =
  compute / (W T). On a machine shared with other work the campaigns themselves slow down when
  two workers compete for the cores, which lowers T(1)/(2 T(2)) but not the utilisation: both are
  reported, with the load average. The results must be identical in all three (checked).
* ``in_memory_vs_log``: the same identify-only study in this process with its campaigns in
  memory (identify/study/campaign.py, the default) and through a log written and read back (the
  path forced for every campaign), alternated, best of ``--repeats``; and the discover campaigns
  both ways. Ratios log / memory of the wall time and of the campaigns' own time; the rows must be
  identical (checked).
* ``campaign_100k``: the measured in-process cost of a campaign (identify only; and with
  discover, measured on a few campaigns with a hidden effect) times 10^5, on N workers of a core
  each at the 2-worker utilisation measured here; the Parquet bytes per row measured too.

The machine's load average is recorded: other work on the machine lowers the efficiency.

    .venv/bin/python benchmarks/scaling_bench.py [--seeds 20] [--quick] [--memory-only]
"""

from __future__ import annotations

import argparse
import json
import math
import operator
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pyarrow.parquet as pq

ROOT = Path(__file__).resolve().parent.parent

from steps import say

from calbench.identify.runtime import executor as X
from calbench.identify.study import TIMING_COLUMNS, load_study, prepare, run_study
from calbench.identify.study import campaign as campaign_mod

STUDY = """
name = "scaling"
scenario = "{paper}"
seeds = {seeds}
[campaign]
discover = {discover}
[[axis]]
key = "tracker.sigma"
values = {sigmas}
[[axis]]
key = "load.mass"
values = [500.0, 700.0]
"""


FRESH = """
import json, time
t0 = time.perf_counter()
from calbench.identify.runtime import executor as X
t1 = time.perf_counter()
ex = X.open_executor(X.ExecutorChoice(X.LOCAL, None, {workers}, "benchmark"))
t2 = time.perf_counter()
ex.client.run(lambda: __import__("calbench.identify.study.campaign"))   # what a first task imports
t3 = time.perf_counter()
ex.close()
t4 = time.perf_counter()
print(json.dumps({{"import_s": t1 - t0, "cluster_s": t2 - t1, "first_import_s": t3 - t2, "close_s": t4 - t3}}))
"""


def local_cluster(workers: int = 2, trivial: int = 1000, repeats: int = 3) -> dict:
    fresh = []
    for _ in range(repeats):
        r = subprocess.run(
            [sys.executable, "-c", FRESH.format(workers=workers)], capture_output=True, text=True, check=True
        )
        fresh.append(json.loads(r.stdout.strip().splitlines()[-1]))
    med = {k: statistics.median(f[k] for f in fresh) for k in fresh[0]}
    with X.open_executor(X.ExecutorChoice(X.LOCAL, None, workers, "benchmark")) as ex:
        ex.client.run(lambda: None)
        t1 = time.perf_counter()
        list(ex.run(operator.mul, [(i, i) for i in range(trivial)]))
        t2 = time.perf_counter()
    return {
        "workers": workers,
        "fresh_process_median_of": repeats,
        **med,
        "startup_s": med["import_s"] + med["cluster_s"] + med["first_import_s"],
        "shutdown_s": med["close_s"],
        "trivial_tasks": trivial,
        "wall_ms_per_trivial_task": 1e3 * (t2 - t1) / trivial,
        "scheduling_ms_per_task": 1e3 * workers * (t2 - t1) / trivial,
        "executor_constants": {
            "LOCAL_STARTUP_S": X.LOCAL_STARTUP_S,
            "LOCAL_SHUTDOWN_S": X.LOCAL_SHUTDOWN_S,
            "TASK_OVERHEAD_S": X.TASK_OVERHEAD_S,
            "break_even_s_2_workers": X.break_even_seconds(workers),
        },
    }


def run(study_path: Path, out: Path, choice: X.ExecutorChoice) -> dict:
    for p in (out, out.with_name(out.name + ".parts")):
        if p.is_dir():
            shutil.rmtree(p)
        elif p.exists():
            p.unlink()
    pending = prepare(load_study(study_path), out)
    tasks = pending.tasks()
    with X.open_executor(choice) as ex:
        t0 = time.perf_counter()
        outcome = run_study(pending, ex)
        wall = time.perf_counter() - t0
    t = pq.read_table(out)
    compute = float(sum(t.column("campaign_s").to_pylist()))
    w = choice.workers
    return {
        "executor": choice.describe(),
        "workers": w,
        "campaigns": outcome.ran,
        "tasks": tasks,
        "wall_s": wall,
        "compute_s": compute,
        "seconds_per_task": compute / tasks,
        "overhead_ms_per_task": 1e3 * (w * wall - compute) / tasks,
        "utilisation": compute / (w * wall),
        "failed": outcome.failed,
        "load_average": os.getloadavg(),
    }


def best(study_path: Path, out: Path, choice: X.ExecutorChoice, repeats: int) -> dict:
    say("scaling_bench", f"the study, {repeats} x {choice.kind} of {choice.workers}")
    runs = [run(study_path, out, choice) for _ in range(repeats)]
    return {**min(runs, key=lambda r: r["wall_s"]), "wall_s_all": [r["wall_s"] for r in runs]}


def same(a: Path, b: Path) -> bool:
    ta, tb = pq.read_table(a), pq.read_table(b)
    cols = [c for c in ta.column_names if c not in TIMING_COLUMNS]
    nan = lambda v: "nan" if isinstance(v, float) and math.isnan(v) else v  # noqa: E731
    return all(
        [nan(x) for x in ta.column(c).to_pylist()] == [nan(x) for x in tb.column(c).to_pylist()] for c in cols
    )


class through_logs:
    """Every campaign through its log (the path the in-memory one replaces), while in this block."""

    def __enter__(self):
        self.saved = campaign_mod.needs_log
        campaign_mod.needs_log = lambda scn: True

    def __exit__(self, *exc):
        campaign_mod.needs_log = self.saved


def memory_vs_log(study_path: Path, tmp: Path, repeats: int) -> dict:
    """The study in this process in memory and through logs, alternated; best wall time of each."""
    choice = X.ExecutorChoice(X.IN_PROCESS, None, 1, "bench")
    mem, log = [], []
    for _ in range(repeats):
        mem.append(run(study_path, tmp / "mem.parquet", choice))
        with through_logs():
            log.append(run(study_path, tmp / "log.parquet", choice))
    m, g = min(mem, key=lambda r: r["wall_s"]), min(log, key=lambda r: r["wall_s"])
    n = m["campaigns"]
    return {
        "campaigns": n,
        "memory_wall_s_all": [r["wall_s"] for r in mem],
        "log_wall_s_all": [r["wall_s"] for r in log],
        "memory_seconds_per_campaign": m["wall_s"] / n,
        "log_seconds_per_campaign": g["wall_s"] / n,
        "log_over_memory_wall": g["wall_s"] / m["wall_s"],
        "log_over_memory_campaign_time": g["compute_s"] / m["compute_s"],
        "identical_results": same(tmp / "mem.parquet", tmp / "log.parquet"),
        "load_average": os.getloadavg(),
    }


def discover_study(tmp: Path, seeds: int) -> Path:
    """A few campaigns with a hidden effect (the power study's forearm case), with discover."""
    dstudy = tmp / "discover.toml"
    dstudy.write_text(
        STUDY.format(
            paper=(ROOT / "scenarios" / "paper_table5.toml").as_posix(),
            seeds=seeds,
            discover="true",
            sigmas="[2e-5]",
        )
        + '[set]\n"truth.effects.link_compliance" = {link = "forearm", '
        "compliance = [1.8e-7, 0.0, 1.8e-7]}\n"
    )
    return dstudy


def identify_study(tmp: Path, seeds: int) -> Path:
    study = tmp / "scaling.toml"
    study.write_text(
        STUDY.format(
            paper=(ROOT / "scenarios" / "paper_table5.toml").as_posix(),
            seeds=seeds,
            discover="false",
            sigmas="[1e-5, 2e-5, 4e-5, 8e-5]",
        )
    )
    return study


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=2, help="runs of each executor, best kept")
    ap.add_argument("--quick", action="store_true", help="5 seeds, 1 repeat, 1 discover campaign")
    ap.add_argument(
        "--memory-only", action="store_true", help="only in_memory_vs_log (no cluster, no 10^5 extrapolation)"
    )
    args = ap.parse_args()
    seeds = 5 if args.quick else args.seeds
    reps = 1 if args.quick else args.repeats
    out: dict = {"machine_cpus": os.cpu_count(), "load_average_before": os.getloadavg()}
    with tempfile.TemporaryDirectory() as tmp_:
        tmp = Path(tmp_)
        say("scaling_bench", "identify-only campaigns in memory and through logs")
        out["in_memory_vs_log"] = {
            "identify": memory_vs_log(identify_study(tmp, seeds), tmp, reps),
            "discover": memory_vs_log(discover_study(tmp, 1 if args.quick else 3), tmp, 1),
        }
    if args.memory_only:
        out["load_average_after"] = os.getloadavg()
        print(json.dumps(out, indent=1))
        return 0
    say("scaling_bench", "local cluster start, stop and trivial tasks")
    out["local_cluster"] = local_cluster()
    with tempfile.TemporaryDirectory() as tmp_:
        tmp = Path(tmp_)
        study = identify_study(tmp, seeds)
        runs = {
            "in_process": best(
                study, tmp / "p.parquet", X.ExecutorChoice(X.IN_PROCESS, None, 1, "bench"), reps
            ),
            "local_1": best(study, tmp / "l1.parquet", X.ExecutorChoice(X.LOCAL, None, 1, "bench"), reps),
            "local_2": best(study, tmp / "l2.parquet", X.ExecutorChoice(X.LOCAL, None, 2, "bench"), reps),
        }
        t1, t2 = runs["local_1"]["wall_s"], runs["local_2"]["wall_s"]
        out["study"] = {
            "grid": "4 tracker sigmas x 2 payloads",
            "seeds": seeds,
            "runs": runs,
            "efficiency_2_workers": t1 / (2 * t2),
            "speedup_2_workers": t1 / t2,
            "utilisation_2_workers": runs["local_2"]["utilisation"],
            "overhead_ms_per_task_1_worker": runs["local_1"]["overhead_ms_per_task"],
            "cluster_of_1_over_in_process": t1 / runs["in_process"]["wall_s"],
            "identical_results": same(tmp / "p.parquet", tmp / "l1.parquet")
            and same(tmp / "p.parquet", tmp / "l2.parquet"),
            "parquet_bytes_per_row": (tmp / "l2.parquet").stat().st_size / runs["local_2"]["campaigns"],
        }
        dstudy = discover_study(tmp, 1 if args.quick else 3)  # in-process
        say("scaling_bench", "campaigns with discover")
        d = run(dstudy, tmp / "d.parquet", X.ExecutorChoice(X.IN_PROCESS, None, 1, "benchmark"))
    c_id = runs["in_process"]["compute_s"] / runs["in_process"]["campaigns"]
    c_disc = d["compute_s"] / d["campaigns"]
    util = out["study"]["utilisation_2_workers"]
    lc = out["local_cluster"]

    def cost(c: float, n: int) -> float:
        return 1e5 * c / (n * (1.0 if n == 1 else util)) + (
            lc["startup_s"] + lc["shutdown_s"] if n > 1 else 0
        )

    out["campaign_100k"] = {
        "seconds_per_campaign_identify": c_id,
        "seconds_per_campaign_with_discover": c_disc,
        "assumed_efficiency": util,
        "note": "the cost of a campaign measured here in this process; on N workers with a core each, at the "
        "worker utilisation measured on 2 (time inside tasks / (workers x wall): the share Dask and the "
        "bookkeeping leave to the work; on dedicated cores it is the efficiency). Tasks of ~2 s keep a "
        "scheduler (thousands of tasks per second) far from its limit up to hundreds of workers.",
        "hours_identify": {str(n): cost(c_id, n) / 3600 for n in (1, 2, 8, 32, 128)},
        "hours_with_discover": {str(n): cost(c_disc, n) / 3600 for n in (1, 2, 8, 32, 128)},
        "parquet_megabytes": 1e5 * out["study"]["parquet_bytes_per_row"] / 1e6,
    }
    out["load_average_after"] = os.getloadavg()
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
