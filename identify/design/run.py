"""`calbench design` as one library call: the settings, the candidates (generated or read), the
selection and its certificate, and the texts of the plan and the JSON.

:func:`run_design` takes a :class:`DesignRequest` (the verb's flags) and returns a
:class:`DesignOutcome`: what the command line prints (``summary``) and writes (``plan_text`` to
``request.out``, ``json_text`` to ``request.json``), with the typed results behind them. It
checks the request before any work, in the order the command line always has (every error an
InputError naming the flag or the file); the candidate set of ``--export-candidates`` is the
one output it writes itself, as soon as the candidates exist (before the exchange, so that an
export survives a plan that cannot be made). Three forms:

* generate: the feasible candidates with their exact
  information blocks on ``pieces`` (identify/runtime/executor.py), then the multi-start exchange,
  its certificate and the refinement (identify/design/plan.py);
* ``from_candidates``: the exchange and its certificate on the blocks of an NPZ
  (identify/design/selection.py), with the scenario optional;
* ``study``: the paper's §5 study (identify/design/study.py).

Long work shows progress on ``progress`` (the candidates, then the exchange); ``notes`` receives
the lines a person reads while it runs (how many candidates, which file was written).
"""

from __future__ import annotations

import contextlib
import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from calbench.bench.core import InputError, ProgressSink, atomic_path, check_memory, check_outputs, sink
from calbench.identify.compensate import job_design_jacobian
from calbench.identify.runtime import Executor, InProcess

from .candidates import (
    CandidateFile,
    CandidateSet,
    generate_candidates,
    read_candidates,
)
from .engine import InfoEngine
from .feasibility import LOAD_KINDS
from .optimal import Selection, SingularCandidates, select_rows, selection_text
from .plan import (
    DesignResult,
    design_plan,
    input_plan_measures,
    merge_repeats,
    plan_comment,
    plan_scenario_text,
    poses_of_rows,
    result_json,
    summary_text,
)
from .settings import load_design_scenario
from .study import run_paper_study

CANDIDATES_PER_TASK = 300  # candidates per piece of work, for the executor's choice

Pieces = Callable[[float, int, float, str], contextlib.AbstractContextManager[Executor]]


@dataclass(frozen=True)
class DesignRequest:
    """What `calbench design` is asked: its flags (paths as given)."""

    scenario: Path | None = None
    configs: int = 12
    criterion: str = "A"
    out: Path | None = None
    json: Path | None = None
    export_candidates: Path | None = None
    normalise: bool = False
    from_candidates: Path | None = None
    distinct: bool = False
    candidates: int | None = None
    starts: int = 8
    refine: bool = True
    processes: int | None = None
    study: bool = False
    out_dir: Path = Path("logs/design_study")
    job: Path | None = None  # --criterion pose over a compensation job's points (I-optimal)


@dataclass
class DesignOutcome:
    """What a design gave: ``summary`` for a person (None: nothing to say, an export alone),
    ``plan_text`` (the runnable PLAN.toml, when ``out`` was asked) and ``json_text`` (when
    ``json`` was), and the typed results they were made from."""

    summary: str | None = None
    plan_text: str | None = None
    json_text: str | None = None
    result: DesignResult | None = None  # the generated form's plan
    selection: Selection | None = None  # the from-candidates form's rows and certificate
    candidates: CandidateSet | CandidateFile | None = None
    study: dict | None = None
    timings: dict = field(default_factory=dict)


PROBE_CANDIDATES = 200  # candidates generated first, timed, to announce the rest
WARM_CANDIDATES = 20  # and fewer before them: the fixed start of a call, timed apart
# memory per candidate at the peak of their batched statics (budget; 6.1 kB of RSS measured)
CANDIDATE_BYTES = 7000


def _in_process(
    work_seconds: float, tasks: int, setup_seconds: float = 0.0, basis: str = ""
) -> contextlib.AbstractContextManager[Executor]:
    return contextlib.nullcontext(InProcess())


def run_design(
    request: DesignRequest,
    pieces: Pieces | None = None,
    progress: ProgressSink | None = None,
    notes: Callable[[str], Any] | None = None,
) -> DesignOutcome:
    """Everything `calbench design` does but printing and writing the plan and the JSON (module
    docstring). ``pieces(work_seconds, tasks, setup_seconds, basis)`` opens the executor the
    candidates run on (when they are generated; default: this process), ``basis`` saying what
    the work's estimate was measured on."""
    req = request
    if req.normalise and req.export_candidates is None:
        raise InputError("(command line)", "--normalise", "--export-candidates CANDS.npz with it", None)
    if req.job is not None and (req.from_candidates is not None or req.study):
        raise InputError(
            "(command line)",
            "--job",
            "a design generated from SCENARIO (not --from-candidates or --study)",
            None,
        )
    if req.from_candidates is not None:
        return _from_candidates(req)
    if req.scenario is None:
        raise InputError(
            "(command line)", "SCENARIO", "a scenario TOML (or --from-candidates CANDS.npz)", None
        )
    if req.study:
        res = run_paper_study(req.scenario, req.out_dir)
        text = json.dumps({k: res[k] for k in ("table1", "table2", "table3_parameters")}, indent=1)
        return DesignOutcome(summary=text, study=res)
    return _generate(req, pieces or _in_process, sink(progress), notes or (lambda line: None))


def _generate(
    req: DesignRequest, pieces: Pieces, bar: ProgressSink, note: Callable[[str], Any]
) -> DesignOutcome:
    if req.out is None and req.json is None and req.export_candidates is None:
        raise InputError(
            "(command line)",
            "--out",
            "--out PLAN.toml, --json OUT.json or --export-candidates CANDS.npz",
            None,
        )
    if req.configs < 1:
        raise InputError("--configs", "configs", "an integer >= 1", req.configs)
    if req.candidates is not None and req.candidates < 1:
        raise InputError("--candidates", "candidates", "an integer >= 1", req.candidates)
    if req.starts < 0:
        raise InputError("--starts", "starts", "an integer >= 0", req.starts)
    if req.processes is not None and req.processes < 1:
        raise InputError("--processes", "processes", "an integer >= 1", req.processes)
    scn, settings = load_design_scenario(req.scenario)
    check_outputs(
        {"--out": req.out, "--json": req.json, "--export-candidates": req.export_candidates},
        {"SCENARIO": req.scenario, "robot": scn.robot, "--job": req.job},
    )
    plan_wanted = req.out is not None or req.json is not None
    if req.job is not None and req.criterion != "pose":
        raise InputError(
            "--job", "criterion", "--criterion pose with --job (the job's compensation error)", req.criterion
        )
    if req.criterion == "pose" and scn.work is None and req.job is None and plan_wanted:
        raise InputError(
            scn.path, "work", "a [work] table (q in degrees, wrench in N and N*m) for --criterion pose", None
        )
    job_g = None
    if req.job is not None and plan_wanted:  # a job that does not fit: before minutes of candidates
        prior = InfoEngine(scn, settings)
        job_g = job_design_jacobian(req.job, prior.robot, prior.params0)
    n = settings.candidates if req.candidates is None else req.candidates
    if plan_wanted and req.configs > n:  # before minutes of candidates
        raise InputError(
            "--configs",
            "configs",
            f"at most the {n} candidates (more --candidates give more)",
            req.configs,
        )
    # memory: the batched statics of the candidates hold ~6 kB each at their peak (measured:
    # benchmarks/sizes_bench.py, 706 MB for 10^5; docs/reliability.md "Memory budgets")
    check_memory(
        n * CANDIDATE_BYTES, "--candidates", "candidates", f"{n:,} candidates at {CANDIDATE_BYTES} B each"
    )
    t0 = time.perf_counter()
    # the cost per feasible candidate, measured here on the first PROBE_CANDIDATES (the same
    # draws the full set starts with): the announced duration is this machine's, now. Each call
    # also pays a fixed start (the batched statics built): timed apart on the first
    # WARM_CANDIDATES, so that it is announced once a piece of work, not n / PROBE_CANDIDATES times
    probe = min(n, PROBE_CANDIDATES)
    if probe < n:
        generate_candidates(scn, settings, n=WARM_CANDIDATES, processes=req.processes)
        t_warm = time.perf_counter() - t0
    cands = generate_candidates(scn, settings, n=probe, processes=req.processes)
    if probe < n:
        t_probe = time.perf_counter() - t0 - t_warm
        per = max(t_probe - t_warm, 0.0) / (probe - WARM_CANDIDATES)
        start = max(t_warm - WARM_CANDIDATES * per, 0.0)
        basis = (
            f"generating the candidates, {1e3 * per:.2g} ms each and {start:.2g} s to start, "
            f"measured on the first {probe}"
        )
        tasks = -(-n // CANDIDATES_PER_TASK)  # each piece of work starts its own statics
        with pieces(n * per + tasks * start, tasks, 0.0, basis) as ex:
            cands = generate_candidates(
                scn, settings, n=n, processes=req.processes, progress=bar, executor=ex
            )
    t_c = time.perf_counter() - t0
    note(
        f"{len(cands)} feasible candidates ({int(cands.kind.sum())} lateral pulls) in {t_c:.1f} s "
        f"from {cands.stats['raw_commands']} sampled commands"
    )
    if req.export_candidates:
        with atomic_path(req.export_candidates, suffix=".npz") as tmp:  # savez adds .npz otherwise
            cands.save_npz(tmp, normalise=req.normalise)
        note(f"wrote {req.export_candidates}")
    out = DesignOutcome(candidates=cands, timings={"candidates_s": t_c})
    if not plan_wanted:
        return out
    if req.configs > len(cands):
        raise InputError(
            "--configs",
            "configs",
            f"at most the {len(cands)} feasible candidates "
            "(more --candidates, or looser [design] settings, give more)",
            req.configs,
        )
    bar.start(1 + 3 * req.configs, "exchange")
    engine = InfoEngine(scn, settings)
    engine.job_jacobian = job_g
    res = design_plan(
        scn,
        settings,
        cands,
        req.configs,
        req.criterion,
        n_random=req.starts,
        do_refine=req.refine,
        engine=engine,
        progress=bar,
        distinct=req.distinct,
    )
    res.timings["candidates_s"] = t_c
    input_plan = input_plan_measures(engine, scn, cands.theta0)
    out.result, out.timings = res, res.timings
    out.summary = summary_text(res, cands, input_plan)
    if req.out:
        out.plan_text = plan_scenario_text(scn, res.poses, req.out, plan_comment(req.scenario, res, req.job))
    if req.json:
        out.json_text = json.dumps(result_json(res, scn, cands, {"input_plan": input_plan}), indent=2)
    return out


def _from_candidates(req: DesignRequest) -> DesignOutcome:
    """`design --from-candidates CANDS.npz`: the exchange and its certificate on given blocks."""
    for flag, given in (("--study", req.study), ("--export-candidates", req.export_candidates)):
        if given:
            raise InputError("(command line)", flag, "no " + flag + " with --from-candidates", None)
    if req.configs < 1:
        raise InputError("--configs", "configs", "an integer >= 1", req.configs)
    check_outputs(
        {"--out": req.out, "--json": req.json},
        {"--from-candidates": req.from_candidates, "SCENARIO": req.scenario},
    )
    cf = read_candidates(req.from_candidates)
    if req.distinct and req.configs > len(cf):
        raise InputError(
            cf.path, "q", f"at least --configs {req.configs} candidates with --distinct", len(cf)
        )
    scn = G = None
    if req.scenario is not None:
        scn, settings = load_design_scenario(req.scenario)
        if cf.q.shape[1] != len(scn.compliance):
            raise InputError(
                cf.path,
                "q",
                f"N x {len(scn.compliance)} joint angles (one per actuated joint of {scn.robot.name})",
                f"N x {cf.q.shape[1]}",
            )
    if req.out is not None and (scn is None or cf.wrench is None or cf.kind is None):
        raise InputError(
            cf.path if scn is not None else "(command line)",
            "wrench" if scn is not None else "SCENARIO",
            "the scenario and the arrays wrench and load_kind in the candidate file for --out",
            None,
        )
    if req.criterion == "pose":
        if scn is None or scn.work is None:
            raise InputError(
                req.scenario or "(command line)",
                "work",
                "a scenario with a [work] table for --criterion pose (the work-pose Jacobian)",
                None,
            )
        engine = InfoEngine(scn, settings)
        if cf.blocks.shape[2] != len(engine.theta0) or (
            cf.theta0 is not None and not np.allclose(cf.theta0, engine.theta0, rtol=1e-9)
        ):
            raise InputError(
                cf.path,
                "theta0",
                f"the prior of {scn.path} ({len(engine.theta0)} parameters)",
                None if cf.theta0 is None else cf.theta0.tolist(),
            )
        G = engine.work_jacobian(scn.work.q, scn.work.wrench)
    try:
        sel = select_rows(
            cf.blocks, req.configs, req.criterion, G, distinct=req.distinct, n_random=req.starts
        )
    except SingularCandidates as exc:
        raise InputError(
            cf.path, "blocks", "candidates that together identify every parameter", str(exc)
        ) from None
    load = None if cf.kind is None else [LOAD_KINDS[k] for k in cf.kind]
    out = DesignOutcome(selection=sel, candidates=cf, timings=sel.seconds)
    out.summary = (
        f"design: {req.criterion}-optimal plan of {req.configs} rows from {len(cf)} candidates "
        f"({cf.path})\n" + selection_text(sel, len(cf), cf.q, load)
    )
    if req.out:
        poses = merge_repeats(poses_of_rows(cf.q, cf.wrench, cf.kind, cf.blocks, sel.rows))
        out.plan_text = plan_scenario_text(
            scn,
            poses,
            req.out,
            f"Measurement plan by `calbench design --from-candidates "
            f"{cf.path.name} --configs {req.configs} --criterion {req.criterion}`",
        )
    if req.json:
        r = sel.exchange
        doc = {
            "candidates_file": str(cf.path),
            "candidates": len(cf),
            "criterion": req.criterion,
            "configs": req.configs,
            **sel.as_json(cf.q, load),
            "exchange": {
                "value": r.value,
                "start_values": r.start_values,
                "start_results": r.start_results,
                "passes": r.passes,
                "swaps": r.swaps,
                **sel.exchanger_stats,
            },
            "timings": sel.seconds,
        }
        out.json_text = json.dumps(doc, indent=2)
    return out


__all__ = ["DesignRequest", "DesignOutcome", "run_design", "CANDIDATES_PER_TASK"]
