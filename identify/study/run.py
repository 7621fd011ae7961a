"""`calbench study STUDY.toml --out RESULTS.parquet`: the grid of campaigns, on any executor.

1. :func:`prepare`: the study (spec.load_study: every cell validated) and what RESULTS.parquet
   already holds (store.ResultStore); what is missing and about how long it will take. Any
   problem is an InputError here, before a task is sent.
2. :func:`run_study`: the designed plans the missing cells need (design:<criterion>:<M>,
   candidates on the executor, kept in the results' metadata), then the missing campaigns as
   tasks of CAMPAIGNS_PER_TASK-ish campaigns of one cell (campaign.run_campaigns), rows
   journaled as each task finishes; cells with identical inputs are computed once.
   Ctrl-C cancels what is running and raises executor.Interrupted with the outcome; what finished
   is in RESULTS.parquet.
3. :func:`report_study`: what RESULTS.parquet says, per cell (summary.py), and the accuracy and
   power plots (plots.py); the command line prints its text and writes its JSON.
"""

from __future__ import annotations

import copy
import json
import math
import time
import tomllib
from collections import defaultdict
from dataclasses import dataclass, field, replace
from pathlib import Path

import pyarrow as pa

from calbench.bench.tracker import DEFAULT_MODEL
from calbench.identify.runtime import ClusterLost, Executor, InProcess, Interrupted

from .campaign import (
    CampaignJob,
    discover_model_text,
    empty_record,
    result_columns,
    run_campaigns,
    tracker_needs_log,
)
from .spec import Cell, Study, digest
from .store import ResultStore, read_results
from .summary import cell_summaries, format_cells, pooled_by_axis

CONSOLIDATE_S = 30.0  # journal -> RESULTS.parquet at most this often (and at the end), and
# never more than 10 % of the time: a merge rewrites the whole file
TARGET_TASK_S = 2.0  # campaigns per task: about this long (scheduling ~5 ms per task)
# in-process seconds per campaign on the paper plan, for the executor choice and task sizes
# (measured, benchmarks/scaling_bench.py --memory-only: simulate + identify 0.083 s in memory,
# 0.20 s through the log, which iso10360 trackers need; discover 1.1 with nothing to find to
# ~3 with an effect)
SECONDS_PER_CAMPAIGN = {"identify": 0.09, "identify_log": 0.2, "discover": 2.0}
SECONDS_PER_DESIGN = 10.0  # 2000 candidates (batched), exchange and refinement


def campaign_seconds(cell: Cell) -> float:
    tracker = cell.doc.get("tracker") or {}
    through_log = tracker_needs_log(tracker.get("model", DEFAULT_MODEL))
    ident = SECONDS_PER_CAMPAIGN["identify_log" if through_log else "identify"]
    return ident + (SECONDS_PER_CAMPAIGN["discover"] if cell.campaign.discover else 0)


def _axis_type(values) -> pa.DataType:
    if all(isinstance(v, bool) for v in values):
        return pa.bool_()
    if all(isinstance(v, int) and not isinstance(v, bool) for v in values):
        return pa.int64()
    if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values):
        return pa.float64()
    return pa.string()


def schema(study: Study) -> pa.Schema:
    """The results' columns: cell and replicate first, then the axes, then the measurements."""
    fields = [pa.field("cell", pa.int64()), pa.field("replicate", pa.int64())]
    fields += [pa.field(a.name, _axis_type(a.column)) for a in study.axes]
    fields += [
        pa.field(k, t) for k, t in result_columns(study.param_names).items() if k not in ("cell", "replicate")
    ]
    return pa.schema(fields)


def _axis_value(study: Study, name: str, v):
    t = _axis_type(next(a.column for a in study.axes if a.name == name))
    if t == pa.float64():
        return float(v)
    if t == pa.string() and not isinstance(v, str):
        return str(v)
    return v


@dataclass
class StudyOutcome:
    """What a run of a study did (the command line prints it)."""

    out: Path
    total: int  # campaigns in the grid
    before: int  # finished before this run
    ran: int = 0  # finished in this run
    failed: int = 0  # of all rows, campaigns whose record holds an error
    designs: int = 0  # plans designed in this run
    seconds: float = 0.0
    interrupted: bool = False
    rows: int = 0  # in RESULTS.parquet now


@dataclass
class Pending:
    """A prepared study: its store, and the (cell, replicate) campaigns still missing."""

    study: Study
    store: ResultStore
    missing: dict[int, list[int]] = field(default_factory=dict)  # cell index -> replicates
    before: int = 0

    @property
    def campaigns(self) -> int:
        return sum(len(r) for r in self.missing.values())

    def _design_keys(self) -> set:
        return {
            design_key(c)
            for c in self.study.cells
            if self.missing.get(c.index)
            and c.plan.startswith("design:")
            and design_key(c) not in self.store.plans
        }

    def estimated_seconds(self, scale: float = 1.0) -> float:
        """About how long the missing work takes in this process (for the executor choice and
        the announcement): SECONDS_PER_CAMPAIGN's relative costs, times ``scale`` (this
        machine's, now: :meth:`measure`)."""
        unique = {self.study.cells[i].inputs: (self.study.cells[i], len(r)) for i, r in self.missing.items()}
        return scale * sum(campaign_seconds(c) * n for c, n in unique.values()) + SECONDS_PER_DESIGN * len(
            self._design_keys()
        )

    def measure(self, probe: int = 1) -> tuple[float, float]:
        """(scale, seconds): one campaign (``probe``) of the first missing cell that has a plan of
        its own, on seeds no replicate uses, timed in this process; scale is its time over the
        constants' figure for it (1, 0 when every missing cell waits for a designed plan)."""
        study = self.study
        for i in self.missing:
            cell = study.cells[i]
            if cell.plan.startswith("design:"):
                continue
            job = CampaignJob(
                replace(study.portable(cell), mjcf=""),
                cell.campaign.method,
                cell.campaign.discover,
                cell.campaign.discover_without,
                cell.expected,
                tuple((-1 - k, study.campaign_seed(2**31 + k)) for k in range(probe)),
            )
            without = cell.campaign.discover_without
            models = {without: discover_model_text(study.mjcf, without)} if cell.campaign.discover else {}
            t = time.perf_counter()
            run_campaigns(study.mjcf, models, job)
            each = (time.perf_counter() - t) / probe
            return each / campaign_seconds(cell), each
        return 1.0, 0.0

    def tasks(self) -> int:
        return sum(math.ceil(len(r) / per_task(self.study.cells[i])) for i, r in self.missing.items())


def per_task(cell: Cell) -> int:
    return max(1, round(TARGET_TASK_S / campaign_seconds(cell)))


def design_key(cell: Cell) -> str:
    """What a designed plan depends on: the cell's scenario without its poses and without its
    hidden effects (the design model never has them: design.candidates.nominal_robot), and the
    spec. Cells that differ only by a hidden effect share one design."""
    doc = {k: v for k, v in cell.doc.items() if k != "pose"}
    if "truth" in doc:
        doc["truth"] = {k: v for k, v in doc["truth"].items() if k != "effects"}
    return digest(doc, cell.plan)


def prepare(study: Study, out: str | Path) -> Pending:
    """Read what RESULTS.parquet (and its journal) hold; refuse results of another study."""
    from calbench.bench.core import InputError

    store = ResultStore(out, schema(study), study.text)
    have = store.load()
    known = {c.cell_id for c in study.cells}
    ids = have.column("cell_id").to_pylist()
    foreign = sum(1 for c in ids if c not in known)
    if foreign:
        raise InputError(
            out,
            "--out",
            "results of this study (the same base scenario, axes and settings) or a new file",
            f"{foreign} campaigns of cells this study does not have",
        )
    done = set(zip(ids, have.column("replicate").to_pylist()))
    beyond = sum(1 for _, r in done if r >= study.seeds)
    if beyond:
        raise InputError(
            out,
            "--out",
            f"at most seeds = {study.seeds} campaigns per cell (raise seeds, or use another --out)",
            f"{beyond} campaigns beyond them",
        )
    p = Pending(study, store, before=len(done))
    for cell in study.cells:
        miss = [r for r in range(study.seeds) if (cell.cell_id, r) not in done]
        if miss:
            p.missing[cell.index] = miss
    return p


def _design(study: Study, cell: Cell, executor: Executor, progress) -> list:
    """The [[pose]] entries of the plan design:<criterion>:<M> for the cell's scenario."""
    from calbench.identify.design import (
        design_plan,
        generate_candidates,
        plan_scenario_text,
        read_design_settings,
    )

    _, criterion, m = cell.plan.split(":")
    scn = study.portable(cell).scenario(seed=study.seed)
    settings = read_design_settings(scn.path, scn.text)
    cands = generate_candidates(scn, settings, progress=progress, executor=executor)
    res = design_plan(scn, settings, cands, int(m), criterion)
    text = plan_scenario_text(scn, res.poses, Path(scn.path))
    return tomllib.loads(text)["pose"]


def run_study(pending: Pending, executor: Executor | None = None, progress=None) -> StudyOutcome:
    """Run the missing campaigns (see the module docstring); returns the outcome."""
    from calbench.bench.core import sink

    t0 = time.perf_counter()
    study, store = pending.study, pending.store
    executor = executor or InProcess()
    bar = sink(progress)
    outcome = StudyOutcome(Path(store.out), len(study.cells) * study.seeds, pending.before)
    index = {c.cell_id: c.index for c in study.cells}
    results = None
    lost: ClusterLost | None = None
    try:
        # 1. designed plans
        docs: dict[int, dict] = {}
        for i in pending.missing:
            cell = study.cells[i]
            if cell.plan.startswith("design:"):
                key = design_key(cell)
                if key not in store.plans:
                    store.add_plan(key, _design(study, cell, executor, progress))
                    outcome.designs += 1
                doc = copy.deepcopy(cell.doc)
                doc["pose"] = store.plans[key]
                docs[i] = doc
        # 2. the campaigns: one group per distinct inputs, tasks of per_task(cell) replicates
        groups: dict[str, dict[int, list[Cell]]] = defaultdict(lambda: defaultdict(list))
        for i, reps in pending.missing.items():
            for r in reps:
                groups[study.cells[i].inputs][r].append(study.cells[i])
        models = {
            c.campaign.discover_without: discover_model_text(study.mjcf, c.campaign.discover_without)
            for c in study.cells
            if c.campaign.discover
        }
        jobs, fanout = [], []
        for by_rep in groups.values():
            cell = next(iter(by_rep.values()))[0]
            scn = replace(study.portable(replace(cell, doc=docs.get(cell.index, cell.doc))), mjcf="")
            reps = sorted(by_rep)
            k = per_task(cell)
            for a in range(0, len(reps), k):
                chunk = reps[a : a + k]
                jobs.append(
                    (
                        CampaignJob(
                            scn,
                            cell.campaign.method,
                            cell.campaign.discover,
                            cell.campaign.discover_without,
                            cell.expected,
                            tuple((r, study.campaign_seed(r)) for r in chunk),
                        ),
                    )
                )
                fanout.append({r: by_rep[r] for r in chunk})
        bar.start(pending.campaigns, "campaigns")
        last, merge_s = time.perf_counter(), 0.0
        blank = empty_record(result_columns(study.param_names))
        results = executor.run(run_campaigns, jobs, shared=(study.mjcf, models))
        for j, records in results:
            rows = []
            for rec in records:
                for cell in fanout[j][rec["replicate"]]:
                    row = {
                        **blank,
                        **rec,
                        "cell": cell.index,
                        "cell_id": cell.cell_id,
                        **{k: _axis_value(study, k, v) for k, v in cell.values.items()},
                    }
                    rows.append(row)
            store.add(rows)
            outcome.ran += len(rows)
            bar.update(
                executor.progress_label(f"cell {fanout[j][records[0]['replicate']][0].index}"), step=len(rows)
            )
            if time.perf_counter() - last > max(CONSOLIDATE_S, 10 * merge_s):
                t_merge = time.perf_counter()
                store.consolidate(index, complete=False)
                last = time.perf_counter()
                merge_s = last - t_merge
    except KeyboardInterrupt:
        outcome.interrupted = True
    except ClusterLost as exc:  # the scheduler went away: keep what finished, as for Ctrl-C
        outcome.interrupted, lost = True, exc
    finally:
        if results is not None:
            results.close()  # cancels whatever is still queued or running
        table = store.consolidate(
            index, complete=not outcome.interrupted and outcome.before + outcome.ran >= outcome.total
        )
        outcome.rows = table.num_rows
        outcome.failed = sum(1 for e in table.column("error").to_pylist() if e)
        outcome.seconds = time.perf_counter() - t0
    if lost is not None:
        raise ClusterLost(
            f"{lost}; {outcome.before + outcome.ran} of {outcome.total} campaigns kept in {store.out}; "
            "run the same command again to resume"
        )
    if outcome.interrupted:
        raise Interrupted(outcome, outcome.before + outcome.ran, outcome.total)
    return outcome


@dataclass
class StudyReport:
    """What a study's results say: the per-cell summaries, their table as text, the plots made
    and the rows they rest on."""

    study: Study
    results: Path
    cells: list
    text: str
    plots: list[Path]
    rows: int

    def to_json(self) -> str:
        """The summary `calbench study --json` writes."""
        doc = {
            "study": self.study.name,
            "file": str(self.study.path),
            "results": str(self.results),
            "seeds": self.study.seeds,
            "cells": self.cells,
        }
        return json.dumps(doc, indent=2)


def report_study(study: Study, out: str | Path, plots: Path) -> StudyReport:
    """Step 3 (module docstring): the cells' summaries of the results in ``out`` and, when it
    holds any row, the accuracy and power plots written into the folder ``plots``."""
    from .plots import accuracy_plots, power_plots  # matplotlib: only where a study is reported

    table, _ = read_results(out)
    cells = cell_summaries(study, table)
    made: list[Path] = []
    if table.num_rows:
        plots.mkdir(parents=True, exist_ok=True)
        made = accuracy_plots(study, pooled_by_axis(study, table), plots) + power_plots(study, cells, plots)
    return StudyReport(study, Path(out), cells, format_cells(study, cells), made, table.num_rows)


__all__ = [
    "prepare",
    "run_study",
    "report_study",
    "Pending",
    "StudyOutcome",
    "StudyReport",
    "schema",
    "campaign_seconds",
]
