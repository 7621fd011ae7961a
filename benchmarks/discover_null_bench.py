"""False alarms of `calbench discover`: campaigns with no hidden effect (paper plan, 20 um).

Every candidate is tested on every run at the family-wise level ALPHA_EFFECT = 0.05 % and the
user's model's misfit at ALPHA_MISFIT = 0.05 % (identify/discover/decide.py), so on a campaign
with nothing to find discovery should name something (or say `unexplained`) in at most 0.1 %
of the seeds. N seeds (default 300) of the isotropic tracker and M
(default 100) of the spec (distance/transverse) noise model are discovered; reported:

* the false-alarm rate (anything named: an effect, `ambiguous` or `unexplained`) with its
  binomial standard error and its one-sided 95 % Clopper-Pearson upper bound. With 300 seeds
  and no alarm the bound is 1.0 %: a rate of 0.1 % itself needs ~3000 seeds to be resolved;
* the CALIBRATION that N seeds can resolve: the share of seeds whose smallest Bonferroni-
  adjusted p-value (n_candidates x the smallest p_LR of the first round) falls below a, for
  a = 1 %, 5 %, 10 %, 20 %, with its standard error; a valid family-wise test keeps it <= a
  (Bonferroni over correlated tests is conservative, parameters on a bound more so), and the
  tail at 0.1 % is the same chi2 law;
* the per-test calibration: the share of single tests (candidate x seed) with p_LR below
  1 %, 5 %, 10 %;
* the discovery time per seed (median, max; wall and CPU).

The campaign is solved once; each seed redraws the tracker noise (bench.campaign.remeasure, then
identify/core's from_campaign) and runs the whole discovery on the observations in memory
(identify/discover/workflow.py's discover_observations). Prints JSON; each seed's row goes to
stderr as it finishes (progress, and what a run cut short has measured).

    python benchmarks/discover_null_bench.py [--seeds 300] [--spec-seeds 100] [--processes 2]
                                             [--scheduler ADDR] [--scenario PATH] [--quick]
                                             [--first-seed N] [--rows ERR ...] [--first-order]

``--first-order`` runs, per seed, only what every verdict needs in the first round
(identify/discover/workflow.py's first_round_events: the first-order scores, a new spring's
LR, the misfit test), and whole discoveries only of the seeds where one of them fires: the
alarms exactly (a seed without an event names nothing), at 0.7 s of CPU a seed on the IRB 6640
against 12 s, so that thousands of seeds are within reach.
``--first-seed`` starts the seeds further on, so that a run adds seeds to an earlier one;
``--rows`` reads the rows earlier runs printed on stderr (the same plan, no other seed twice)
and summarises them together with this run's (``--seeds 0 --spec-seeds 0``: only them).

The seeds run as pieces on calbench's executors (identify/runtime/executor.py, issue 15: no pool of our
own): in this process, on a local Dask cluster of ``--processes`` workers, or on the cluster at
``--scheduler`` (its workers need this checkout: the pieces read scenarios/paper_table5.toml).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from scipy import stats

from calbench.identify.runtime import choose, open_executor

ROOT = Path(__file__).resolve().parent.parent
PAPER = ROOT / "scenarios" / "paper_table5.toml"
LEVELS = (0.01, 0.05, 0.10, 0.20)
SEEDS_PER_TASK = 5  # ~5-10 s of discovery per piece

_STATE: dict = {}


def _setup(model: str, scenario: str = str(PAPER)) -> None:
    """Per process: the solved campaign of ``scenario`` (default the paper's) with the tracker
    model."""
    import tempfile

    from calbench.bench.campaign import simulate
    from calbench.bench.scenario import load_scenario, scenario_variant

    tmp = Path(tempfile.mkdtemp())
    path = scenario_variant(scenario, tmp / "null.toml")
    if model == "spec":
        path.write_text(path.read_text().replace("[tracker]\n", '[tracker]\nmodel = "spec"\n', 1))
    scn = load_scenario(path)
    _STATE.update(scn=scn, campaign=simulate(scn, None), model=model, scenario=scenario)


def one_seed(args: tuple) -> dict:
    model, seed, *rest = args
    scenario = rest[0] if rest else str(PAPER)
    if _STATE.get("model") != model or _STATE.get("scenario") != scenario:
        _setup(model, scenario)
    from calbench.bench.campaign import remeasure
    from calbench.identify.core import from_campaign
    from calbench.identify.discover import discover_observations

    scn = _STATE["scn"]
    obs = from_campaign(remeasure(_STATE["campaign"], np.random.default_rng([20261, seed])))
    t, c = time.perf_counter(), time.process_time()
    rep, _ = discover_observations(obs, Path(scn.robot))
    cands = [x for x in rep["rounds"][0]["candidates"] if x.get("k")]
    n = len(rep["rounds"][0]["candidates"])
    p = [x["p_lr"] for x in cands]
    return {
        "seed": seed,
        "named": rep["named_effects"],
        "min_adjusted_p": min(1.0, n * min(p, default=1.0)),
        "p_lr": p,
        "n_candidates": n,
        "wall_s": time.perf_counter() - t,
        "cpu_s": time.process_time() - c,
        "p_before": rep["p_before"],
        "evaluations": rep["evaluations"],
    }


def first_order_seed(args: tuple) -> dict:
    """One seed's first-round events that any verdict of discovery needs (identify/discover/
    decide.py): a candidate whose first-order score passes its Bonferroni level, a candidate
    without a first-order test (a new spring) whose LR does, or the user's model's chi2 below
    ALPHA_MISFIT. A named effect needs both its LR and its score past the level and
    `unexplained` needs the misfit, so ``event`` False means discovery names nothing on this
    seed: the share of events bounds the false-alarm rate from above, for the user's model's fit
    and one candidate fit per spring instead of every candidate's."""
    model, seed, scenario = args
    if _STATE.get("model") != model or _STATE.get("scenario") != scenario:
        _setup(model, scenario)
    from calbench.bench.campaign import remeasure
    from calbench.identify.core import from_campaign
    from calbench.identify.discover import first_round_events

    scn = _STATE["scn"]
    obs = from_campaign(remeasure(_STATE["campaign"], np.random.default_rng([20261, seed])))
    t, c = time.perf_counter(), time.process_time()
    out = first_round_events(obs, Path(scn.robot))
    return {"seed": seed, **out, "wall_s": time.perf_counter() - t, "cpu_s": time.process_time() - c}


def first_order_block(model: str, seeds: list[int], scenario: str = str(PAPER)) -> list[dict]:
    """One piece of ``--first-order`` seeds (as :func:`seed_block`)."""
    return [first_order_seed((model, s, scenario)) for s in seeds]


def seed_block(model: str, seeds: list[int], scenario: str = str(PAPER)) -> list[dict]:
    """One piece: a block of seeds, so that a worker solves the campaign once per block (a
    script's function travels by value to Dask workers, its _STATE with it)."""
    return [one_seed((model, s, scenario)) for s in seeds]


def earlier_rows(paths: list[str]) -> dict[str, list[dict]]:
    """Rows an earlier run printed on stderr (one JSON object per seed, with its model), by
    model; summary lines and anything else are skipped."""
    out: dict[str, list[dict]] = {}
    for path in paths:
        for line in Path(path).read_text().splitlines():
            try:
                row = json.loads(line)
            except json.JSONDecodeError:
                continue
            if isinstance(row, dict) and "seed" in row and "model" in row:
                model = row.pop("model")
                out.setdefault(model, []).append(row)
    return out


def clopper_pearson_upper(k: int, n: int, conf: float = 0.95) -> float:
    return 1.0 if k >= n else float(stats.beta.ppf(conf, k + 1, n - k))


def summarise_bound(rows: list[dict]) -> dict:
    """``--first-order`` rows: the share of seeds with an event (an upper bound on the
    false-alarm rate, first_order_seed) with its 95 % bound, and the calibration of the scores and
    of the misfit test's p that the events come from."""
    n = len(rows)
    events = [r for r in rows if r["event"]]
    p = np.array([v for r in rows for v in r["p_score"].values()])
    before = np.array([r["p_before"] for r in rows])
    return {
        "seeds": n,
        "events": len(events),
        "false_alarm_bound": len(events) / n,
        "false_alarm_bound_upper_95": clopper_pearson_upper(len(events), n),
        "event_seeds": [r["seed"] for r in events],
        "score_calibration": {
            f"{a:g}": {"share": float(np.mean(p <= a)), "tests": int(p.size)}
            for a in (1e-4, 1e-3, 0.01, 0.05)
        },
        "misfit_calibration": {f"{a:g}": float(np.mean(before <= a)) for a in (5e-4, 0.01, 0.05)},
        "cpu_s_median": statistics.median(r["cpu_s"] for r in rows),
    }


def summarise(rows: list[dict]) -> dict:
    n = len(rows)
    alarms = [r for r in rows if r["named"]]
    rate = len(alarms) / n
    out = {
        "seeds": n,
        "false_alarms": len(alarms),
        "false_alarm_rate": rate,
        "false_alarm_rate_standard_error": float(np.sqrt(max(rate, 1.0 / n) * (1 - rate) / n)),
        "false_alarm_rate_upper_95": clopper_pearson_upper(len(alarms), n),
        "alarms": [{"seed": r["seed"], "named": r["named"]} for r in alarms],
        "familywise_calibration": {},
        "per_test_calibration": {},
    }
    adj = np.array([r["min_adjusted_p"] for r in rows])
    for a in LEVELS:
        share = float(np.mean(adj <= a))
        out["familywise_calibration"][f"{a:g}"] = {
            "share": share,
            "standard_error": float(np.sqrt(a * (1 - a) / n)),
            "valid_if_at_most": a,
        }
    p = np.concatenate([r["p_lr"] for r in rows]) if rows else np.zeros(0)
    for a in (0.01, 0.05, 0.10):
        out["per_test_calibration"][f"{a:g}"] = {
            "share": float(np.mean(p <= a)),
            "tests": int(p.size),
            "standard_error": float(np.sqrt(a * (1 - a) / max(p.size, 1))),
        }
    for key in ("wall_s", "cpu_s"):
        v = [r[key] for r in rows]
        out[f"{key}_median"] = statistics.median(v)
        out[f"{key}_max"] = max(v)
    out["evaluations_median"] = statistics.median(r["evaluations"] for r in rows)
    return out


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument(
        "--seeds", type=int, default=300, help="isotropic-noise null seeds (default: %(default)s)"
    )
    ap.add_argument(
        "--spec-seeds", type=int, default=100, help="spec-noise null seeds (default: %(default)s)"
    )
    ap.add_argument(
        "--processes",
        type=int,
        default=1,
        help="worker processes of a local Dask cluster (default: %(default)s: this process)",
    )
    ap.add_argument("--scheduler", default=None, help="a Dask scheduler's address (tcp:// or tls://)")
    ap.add_argument(
        "--scenario",
        default=str(PAPER),
        help="the plan and robot, its hidden effects kept (default: %(default)s; e.g. a third-party "
        "robot's scenario without [truth.effects])",
    )
    ap.add_argument(
        "--quick", action="store_true", help="10 isotropic and 5 spec seeds (to see that it works)"
    )
    ap.add_argument("--first-seed", type=int, default=0, help="the first seed (default: %(default)s)")
    ap.add_argument(
        "--first-order",
        action="store_true",
        help="every seed's first-round first-order events (an upper bound on the alarms), then "
        "whole discoveries of the seeds with one: the alarms exactly, ~15x cheaper on the IRB 6640",
    )
    ap.add_argument(
        "--rows",
        nargs="*",
        default=[],
        help="stderr files of earlier runs of this plan: their seeds' rows join this run's summary",
    )
    args = ap.parse_args()
    from calbench.bench.scenario import load_scenario

    if args.quick:
        args.seeds, args.spec_seeds = 10, 5
    t0 = time.perf_counter()
    res = {
        "plan": args.scenario,
        "tracker_sigma_um": load_scenario(args.scenario).tracker.sigma * 1e6,
        "alpha_familywise": 1e-3,
        "models": {},
    }
    earlier = earlier_rows(args.rows)
    for model, n in (("isotropic", args.seeds), ("spec", args.spec_seeds)):
        rows = earlier.get(model, [])
        if n > 0:
            first, last = args.first_seed, args.first_seed + n
            blocks = [
                (model, list(range(a, min(a + SEEDS_PER_TASK, last))), args.scenario)
                for a in range(first, last, SEEDS_PER_TASK)
            ]
            where = args.scheduler or ("local" if args.processes > 1 else "in-process")
            with open_executor(choose(where, 0.0, len(blocks), workers=args.processes)) as ex:
                done = {}
                for i, block_rows in ex.run(first_order_block if args.first_order else seed_block, blocks):
                    done[i] = block_rows
                    for r in block_rows:  # progress, and what a cut-short run has measured
                        print(json.dumps({"model": model, **r}), file=sys.stderr, flush=True)
            rows = rows + [r for i in range(len(blocks)) for r in done[i]]
        if not rows:
            continue
        seeds = [r["seed"] for r in rows]
        if len(set(seeds)) != len(seeds):
            sys.exit(f"--rows/--first-seed: a {model} seed is counted twice; seeds must not overlap")
        res["models"][model] = summarise_bound(rows) if args.first_order else summarise(rows)
        if args.first_order:  # the events' whole discoveries: the alarms themselves, exactly
            events = res["models"][model]["event_seeds"]
            confirmed = seed_block(model, events, args.scenario)
            alarms = [{"seed": r["seed"], "named": r["named"]} for r in confirmed if r["named"]]
            n = res["models"][model]["seeds"]
            res["models"][model].update(
                false_alarms=len(alarms),
                false_alarm_rate=len(alarms) / n,
                false_alarm_rate_upper_95=clopper_pearson_upper(len(alarms), n),
                alarms=alarms,
            )
        print(
            json.dumps({model: {k: v for k, v in res["models"][model].items() if k != "alarms"}}),
            file=sys.stderr,
        )
    all_rows = sum((m["seeds"] for m in res["models"].values()), 0)
    alarms = sum((m["false_alarms"] for m in res["models"].values()), 0)
    res["all"] = {
        "counted": "alarms: the first-order events' whole discoveries" if args.first_order else "alarms",
        "seeds": all_rows,
        "false_alarms": alarms,
        "false_alarm_rate": alarms / max(all_rows, 1),
        "false_alarm_rate_upper_95": clopper_pearson_upper(alarms, all_rows),
    }
    res["total_seconds"] = time.perf_counter() - t0
    print(json.dumps(res, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
