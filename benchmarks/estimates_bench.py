"""Announced against taken (issue 23): the durations `calbench montecarlo` and `calbench design`
announce, next to how long the work after the announcement took, on the paper and KR 270
scenarios. The target: every ratio taken / announced within 1/1.5 .. 1.5.

The announcements are the verbs' own (identify/cli.py's open_pieces): per-piece costs measured
at the start on a few pieces (identify/study/montecarlo.py's measure_montecarlo, the design's
first PROBE_CANDIDATES), the executor chosen as the verb chooses it, and its expected wall time
(identify/runtime/executor.py's ExecutorChoice.expected_seconds). Prints JSON. Usage:
python benchmarks/estimates_bench.py [--quick] (100 Monte Carlo runs, 1000 candidates; default
1000 and 10^4).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import tempfile
import time
from pathlib import Path

from steps import say

from calbench.bench.scenario import load_scenario
from calbench.identify.design import DesignRequest, run_design
from calbench.identify.runtime import choose, open_executor
from calbench.identify.study import RUNS_PER_TASK, measure_montecarlo, montecarlo_methods, run_montecarlo

ROOT = Path(__file__).resolve().parent.parent
SCENARIOS = ("paper_table5.toml", "kr270_paper.toml")
TARGET = 1.5


def row(verb: str, scenario: str, announced: float, taken: float, **extra) -> dict:
    ratio = taken / announced if announced > 0 else float("inf")
    return {
        "verb": verb,
        "scenario": scenario,
        "announced_s": round(announced, 2),
        "taken_s": round(taken, 2),
        "taken_over_announced": round(ratio, 3),
        "within_target": 1 / TARGET <= ratio <= TARGET,
        **extra,
    }


def montecarlo(name: str, runs: int) -> dict:
    scn = load_scenario(ROOT / "scenarios" / name)
    methods = montecarlo_methods("both", scn)
    cost = measure_montecarlo(scn, methods)
    tasks = -(-runs // RUNS_PER_TASK)
    choice = choose(None, cost.seconds(runs), tasks)
    announced = choice.expected_seconds(cost.seconds(runs), tasks, cost.setup_seconds)
    say("estimates_bench", f"montecarlo {name} --runs {runs}: announced {announced:.1f} s ({choice.kind})")
    t = time.perf_counter()
    with open_executor(choice) as ex:
        run_montecarlo(scn, runs, methods, executor=ex)
    return row("montecarlo", name, announced, time.perf_counter() - t, runs=runs, executor=choice.kind)


def design(name: str, candidates: int) -> dict:
    seen: dict = {}

    @contextlib.contextmanager
    def pieces(work, tasks, setup, basis):
        choice = choose(None, work, tasks)
        seen["announced"] = choice.expected_seconds(work, tasks, setup)
        seen["executor"] = choice.kind
        t = time.perf_counter()
        with open_executor(choice) as ex:
            yield ex
        seen["taken"] = time.perf_counter() - t

    # the candidates alone (the phase the verb announces), written to a scratch file
    with tempfile.TemporaryDirectory() as tmp:
        req = DesignRequest(
            scenario=ROOT / "scenarios" / name,
            configs=8,
            criterion="A",
            export_candidates=Path(tmp) / "c.npz",
            candidates=candidates,
        )
        say("estimates_bench", f"design {name} --candidates {candidates}")
        run_design(req, pieces=pieces)
    return row(
        "design (candidates)",
        name,
        seen["announced"],
        seen["taken"],
        candidates=candidates,
        executor=seen["executor"],
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="100 Monte Carlo runs, 1000 candidates")
    args = ap.parse_args()
    runs, cands = (100, 1000) if args.quick else (1000, 10_000)
    rows = [montecarlo(s, runs) for s in SCENARIOS] + [design(s, cands) for s in SCENARIOS]
    print(json.dumps({"target_ratio": TARGET, "rows": rows}, indent=2))


if __name__ == "__main__":
    main()
