"""`calbench`: the one console script.

Subcommands from both packages: bench/cli.py owns `simulate`, `view`, `export` and
`from-urdf`; this module owns the estimation verbs (identify, montecarlo, design, discover) and
`demo`. These two modules are the only ones that parse arguments or print; every workflow they
call is a library function that returns its result, so it can be called from a notebook as well.

Exit status: 0 success, 1 a check failed, 2 bad input (any CalbenchError: one line naming the
file, the key and what was expected).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import sys
import warnings
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import mujoco

from calbench.bench.cli import (
    add_check_robot,
    add_export,
    add_from_urdf,
    add_recover,
    add_simulate,
    add_view,
    cmd_check_robot,
)
from calbench.bench.core import (
    CalbenchError,
    InputError,
    check_outputs,
    duration,
    holding_outputs,
    refused_write,
    terminal_progress,
    write_text,
)
from calbench.bench.scenario import PlausibilityWarning
from calbench.identify.core import OUTLIER_SIGMA

from . import demo


def _version() -> str:
    try:
        return version("calbench")
    except PackageNotFoundError:  # pragma: no cover - always installed (editable or not)
        return "unknown"


# --------------------------------------------------------------------------- identify


def add_identify(sub) -> None:
    from calbench.identify.methods import identify_help, method_names
    from calbench.identify.report import Z_CHECK

    p = sub.add_parser("identify", help="estimate the elastostatic parameters from a campaign log")
    p.add_argument("log", type=Path, help="campaign MCAP log")
    p.add_argument("--model", type=Path, default=None, help="robot MJCF (default: the one in the log)")
    p.add_argument(
        "--method",
        choices=method_names(offered_only=True),
        default="one-step",
        help=identify_help() + " (default: %(default)s)",
    )
    p.add_argument(
        "--json", type=Path, default=None, help="write the report as JSON (default: none, the table only)"
    )
    p.add_argument(
        "--check",
        action="store_true",
        help=f"exit 1 when the fit did not converge, when a parameter is reported as "
        f"a number the plan does not determine, or when the log has ground truth "
        f"and any |z| > {Z_CHECK:g} (default: no check)",
    )
    p.add_argument(
        "--drop-outliers",
        action="store_true",
        help=f"refit without tracker readings off by more than {OUTLIER_SIGMA:g} sigma "
        "(default: list them, keep them)",
    )
    p.add_argument(
        "--self-check",
        action="store_true",
        help="re-simulate the readings from the estimate with the tracker's noise (30 replicas), "
        "refit each and flag a parameter whose std or bias the replicas contradict; --check then "
        "fails on it (default: no self-check)",
    )
    p.add_argument(
        "--exposure",
        action="store_true",
        help="for each parameter, the largest bias an effect of discovery's library that this plan "
        "would not name could cause (one-step; default: not computed)",
    )
    p.add_argument(
        "--geometry",
        action="store_true",
        help="the complete model from absolute (unloaded) readings of one flange point: joint offsets, "
        "link frames, base and probe frames and joint compliance under self-weight, serial arms "
        "(docs/geometry.md; default: the elastostatic model from deflections)",
    )
    p.add_argument(
        "--validate",
        type=Path,
        default=None,
        metavar="HELDOUT.mcap",
        help="with --geometry: predict this log's readings (same robot and tracker station); default: none",
    )
    p.add_argument(
        "--out-model",
        type=Path,
        default=None,
        metavar="CALIBRATED.xml",
        help="with --geometry: write the calibrated robot as a calbench MJCF (default: none)",
    )
    p.set_defaults(func=cmd_identify)


def cmd_identify(args) -> int:
    from calbench.identify.report import Z_CHECK, check_failed, format_table, run_identify

    if args.geometry:
        return cmd_identify_geometry(args)
    for flag, value in (("--validate", args.validate), ("--out-model", args.out_model)):
        if value is not None:
            raise InputError(
                flag, flag, "--geometry beside it (it belongs to the complete model)", str(value)
            )
    check_outputs({"--json": args.json}, {"LOG": args.log, "--model": args.model})
    rep = run_identify(
        args.log,
        args.model,
        args.method,
        args.drop_outliers,
        self_check=args.self_check,
        exposure=args.exposure,
    )
    print(format_table(rep))
    if args.json:
        write_text(args.json, rep.to_json())
    if args.check:
        bad = check_failed(rep)
        if bad:
            print("check FAILED: " + "; ".join(bad))
            return 1
        if not rep.has_truth():
            print(
                "check passed: the fit converged and every reported parameter is determined; "
                "the log carries no ground truth to compare with"
            )
            return 0
        print(
            f"check passed: the fit converged, and every identified parameter is within "
            f"{Z_CHECK:g} standard deviations of the truth"
        )
    return 0


def cmd_identify_geometry(args) -> int:
    """`identify --geometry`: identify/geometry/run.py; --check and --method belong to the other."""
    from calbench.identify.geometry import format_geometry, geometry_json, run_geometry

    if args.method != "one-step" or args.drop_outliers or args.check:
        raise InputError(
            "--geometry", "--geometry", "no --method, --check or --drop-outliers beside it", None
        )
    check_outputs(
        {"--json": args.json, "--out-model": args.out_model},
        {"LOG": args.log, "--model": args.model, "--validate": args.validate},
    )
    rep = run_geometry(args.log, args.model, args.validate, args.out_model)
    print(format_geometry(rep))
    if args.json:
        write_text(args.json, geometry_json(rep))
    return 0


# --------------------------------------------------------------------------- executors


def add_scheduler(p) -> None:
    """--scheduler and --workers: where montecarlo, design and study run their pieces."""
    p.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDR",
        help="run the pieces on the Dask cluster at tcp://HOST:PORT or tls://HOST:PORT (tls: "
        "Dask's security configuration); default: DASK_SCHEDULER_ADDRESS, else a local cluster "
        "on 127.0.0.1 when the job is large enough, else this process; 'local' and "
        "'in-process' force those",
    )
    p.add_argument(
        "--workers",
        type=int,
        default=None,
        help="worker processes of a local cluster (default: the CPU count; 1: this process)",
    )


def open_pieces(args, work_seconds: float, tasks: int, setup_seconds: float = 0.0, basis: str = ""):
    """The executor for this command (identify/runtime/executor.py), announced on stderr with
    the wall-clock time it is expected to take (``basis``: what the estimate was measured on)."""
    from calbench.identify.runtime import choose, open_executor

    ex = open_executor(choose(args.scheduler, work_seconds, tasks, args.workers))
    expect = duration(ex.choice.expected_seconds(work_seconds, tasks, setup_seconds))
    print(
        f"calbench {args.command}: {ex.choice.describe()}; expected to take about {expect}"
        + (f" ({basis})" if basis else ""),
        file=sys.stderr,
    )
    return ex


# --------------------------------------------------------------------------- montecarlo


def add_montecarlo(sub) -> None:
    from calbench.identify.methods import BOTH, montecarlo_choices

    p = sub.add_parser("montecarlo", help="re-measure a campaign with N noise seeds: bias, spread, CRB")
    p.add_argument("scenario", type=Path, help="scenario TOML file")
    p.add_argument("--runs", type=int, required=True, help="number of noise seeds (required)")
    p.add_argument(
        "--method",
        choices=tuple(montecarlo_choices()),
        default=BOTH,
        help="estimators to run; two-step runs both step-2 variants, two-step-iterated the paper's "
        "method at its self-consistent sagged pose (~5x the one-step's time per run), both for "
        "robots with at most one compensator across one actuated hinge; both: one-step and "
        "two-step (one-step alone on other robots); all: every method that applies "
        "(default: %(default)s)",
    )
    p.add_argument("--seed", type=int, default=None, help="base noise seed (default: the scenario's)")
    p.add_argument(
        "--json", type=Path, default=None, help="write the summary as JSON (default: none, the table only)"
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="run even when the campaign's readings times the runs are estimated to take "
        "too long (default: refuse, saying the estimate)",
    )
    add_scheduler(p)
    p.set_defaults(func=cmd_montecarlo)


def cmd_montecarlo(args) -> int:
    from calbench.bench.scenario import load_scenario
    from calbench.identify.runtime import Interrupted
    from calbench.identify.study import format_summary, prepare_montecarlo, run_montecarlo

    scn = load_scenario(args.scenario, seed=args.seed)
    check_outputs({"--json": args.json}, {"SCENARIO": args.scenario, "robot": scn.robot})
    job = prepare_montecarlo(scn, args.runs, args.method, args.seed, args.force)
    interrupted = None
    cost = job.cost
    basis = f"{1e3 * cost.seconds_per_piece:.0f} ms per run, measured on {cost.probed} runs"
    with open_pieces(args, job.seconds(), job.tasks, cost.setup_seconds, basis) as ex:
        bar = terminal_progress("calbench montecarlo", "runs")
        try:
            mc = run_montecarlo(scn, job.runs, job.methods, progress=bar, executor=ex)
        except Interrupted as exc:
            mc, interrupted = exc.partial, exc
        bar.close()
    if interrupted is not None:
        print(
            f"calbench montecarlo: interrupted; {interrupted.done} of {interrupted.total} runs finished",
            file=sys.stderr,
        )
        if interrupted.done < 2:
            return 130
    s = mc.summary()
    s["interrupted"] = interrupted is not None
    print(format_summary(s))
    if args.json:
        write_text(args.json, json.dumps(s, indent=2))
    return 130 if interrupted is not None else 0


# --------------------------------------------------------------------------- design


def add_design(sub) -> None:
    from calbench.identify.design.optimal import CRITERIA

    p = sub.add_parser("design", help="optimal measurement configurations (design of experiments)")
    p.add_argument(
        "scenario",
        type=Path,
        nargs="?",
        default=None,
        help="scenario TOML (robot, truth = prior guess, tracker, load, optional [work] and [design]); "
        "optional with --from-candidates, where it serves --out and --criterion pose",
    )
    p.add_argument(
        "--configs",
        type=int,
        default=12,
        help="number of measurement configurations M (default: %(default)s)",
    )
    p.add_argument(
        "--criterion",
        choices=CRITERIA,
        default="A",
        help="A: trace of the covariance; D: its determinant; AD: their mean (the paper's O3); "
        "pose: the deflection variance at the scenario's [work] pose (default: %(default)s)",
    )
    p.add_argument(
        "--job",
        type=Path,
        default=None,
        help="with --criterion pose: the mean squared compensation error over this job's points "
        "(calbench compensate's JOB.toml; I-optimal) instead of the [work] pose (default: none)",
    )
    p.add_argument(
        "--out", type=Path, default=None, help="write the plan as a runnable scenario (default: none)"
    )
    p.add_argument(
        "--json", type=Path, default=None, help="write the criteria, stds and poses as JSON (default: none)"
    )
    p.add_argument(
        "--export-candidates", type=Path, default=None, help="write the candidate set (NPZ; default: none)"
    )
    p.add_argument(
        "--normalise",
        action="store_true",
        help="with --export-candidates: divide each block column by its RMS (unit mean information "
        "diagonal, for tools that divide by it; the D-optimal plan is unchanged; default: off)",
    )
    p.add_argument(
        "--from-candidates",
        type=Path,
        default=None,
        metavar="CANDS.npz",
        help="optimise these candidates (the --export-candidates form: q N x 6 degrees, blocks N x m x p) "
        "instead of generating them; prints and records the chosen rows (default: generate)",
    )
    p.add_argument(
        "--distinct",
        action="store_true",
        help="no candidate twice (no repeats); reports the cost against the plan with repeats "
        "(default: repeats allowed)",
    )
    p.add_argument(
        "--candidates",
        type=int,
        default=None,
        help="number of candidates (default: the scenario's [design] candidates, else 10000)",
    )
    p.add_argument(
        "--starts", type=int, default=8, help="random starts besides the greedy one (default: %(default)s)"
    )
    p.add_argument(
        "--no-refine", action="store_true", help="skip the continuous refinement (default: refine)"
    )
    p.add_argument(
        "--processes",
        type=int,
        default=None,
        help="CPU threads for the candidates in each process (default: all the CPUs of this "
        "process; one on a Dask worker)",
    )
    add_scheduler(p)
    p.add_argument(
        "--study", action="store_true", help="reproduce the paper's §5 study (plots; default: off)"
    )
    p.add_argument(
        "--out-dir",
        type=Path,
        default=Path("logs/design_study"),
        help="--study output folder (default: %(default)s)",
    )
    p.set_defaults(func=cmd_design)


class _BarAndNotes:
    """A progress bar on stderr (on a terminal only) and the lines printed between its phases:
    a line first ends the bar's."""

    def __init__(self):
        self.bar = terminal_progress("calbench design", "pieces")
        self.drawn = False

    def start(self, total: int, label: str = "") -> None:
        self.drawn = True
        self.bar.start(total, label)

    def update(self, label: str = "", step: int = 1) -> None:
        self.drawn = True
        self.bar.update(label, step)

    def close(self) -> None:
        if self.drawn:
            self.bar.close()
            self.drawn = False

    def note(self, line: str) -> None:
        self.close()
        print(line, file=sys.stderr)


def cmd_design(args) -> int:
    from calbench.identify.design import DesignRequest, run_design

    request = DesignRequest(
        scenario=args.scenario,
        configs=args.configs,
        criterion=args.criterion,
        out=args.out,
        json=args.json,
        export_candidates=args.export_candidates,
        normalise=args.normalise,
        from_candidates=args.from_candidates,
        distinct=args.distinct,
        candidates=args.candidates,
        starts=args.starts,
        refine=not args.no_refine,
        processes=args.processes,
        study=args.study,
        out_dir=args.out_dir,
        job=args.job,
    )
    shown = _BarAndNotes()
    try:
        outcome = run_design(
            request,
            pieces=lambda seconds, tasks, setup, basis: open_pieces(args, seconds, tasks, setup, basis),
            progress=shown,
            notes=shown.note,
        )
    finally:
        shown.close()
    if outcome.summary is not None:
        print(outcome.summary)
    if outcome.plan_text is not None:
        write_text(args.out, outcome.plan_text)
        print(f"wrote {args.out}", file=sys.stderr)
    if outcome.json_text is not None:
        write_text(args.json, outcome.json_text)
    return 0


# --------------------------------------------------------------------------- discover


def add_discover(sub) -> None:
    p = sub.add_parser(
        "discover", help="find where the model and the measurements disagree and name the missing effect"
    )
    p.add_argument("log", type=Path, help="campaign MCAP log")
    p.add_argument(
        "--model", type=Path, default=None, help="the user's robot MJCF (default: the one in the log)"
    )
    p.add_argument(
        "--json", type=Path, default=None, help="write the report as JSON (default: none, the story only)"
    )
    p.add_argument(
        "--out-model",
        type=Path,
        default=None,
        help="augmented MJCF (default: LOG.augmented.xml next to the log, when an effect is named)",
    )
    p.add_argument(
        "--plot",
        type=Path,
        default=None,
        help="per-pose residuals before/after, PNG (default: next to --json, or LOG.discover.png)",
    )
    p.add_argument(
        "--view-json",
        type=Path,
        default=None,
        help="identify-style JSON with predicted deflections for `calbench view --identified` "
        "(default: next to --json)",
    )
    p.add_argument(
        "--rrd",
        type=Path,
        default=None,
        help="Rerun recording of where the model disagreed, residuals before and after on the robot "
        "(default: next to --json, or LOG.discover.rrd)",
    )
    p.add_argument(
        "--geometry",
        action="store_true",
        help="name geometric effects (joint offsets, link frames, the probe) from absolute unloaded "
        "readings, the tracker registration fitted (docs/geometry.md; default: elastostatic effects "
        "from deflections)",
    )
    p.add_argument(
        "--validate",
        type=Path,
        default=None,
        metavar="HELDOUT.mcap",
        help="with --geometry: predict this log's readings after each naming (default: none)",
    )
    p.set_defaults(func=cmd_discover)


def cmd_discover(args) -> int:
    from calbench.identify.discover import clean, discover, story

    if not args.log.is_file():
        raise InputError(args.log, "LOG.mcap", "an existing campaign log", "no such file")
    if args.geometry:
        return cmd_discover_geometry(args)
    if args.validate is not None:
        raise InputError("--validate", "--validate", "--geometry beside it", str(args.validate))
    plot = args.plot or (
        args.json.with_suffix(".png") if args.json else args.log.with_name(args.log.stem + ".discover.png")
    )
    view = args.view_json or (args.json.with_name(args.json.stem + ".view.json") if args.json else None)
    rrd = args.rrd or (
        args.json.with_suffix(".rrd") if args.json else args.log.with_name(args.log.stem + ".discover.rrd")
    )
    out_model = args.out_model or args.log.with_name(args.log.stem + ".augmented.xml")
    check_outputs(
        {"--json": args.json, "--out-model": out_model, "--plot": plot, "--view-json": view, "--rrd": rrd},
        {"LOG": args.log, "--model": args.model},
    )
    bar = terminal_progress("calbench discover", "candidates")
    try:
        rep = discover(
            args.log,
            args.model,
            out_model=args.out_model,
            plot=plot,
            view_json=view,
            view_rrd=rrd,
            progress=bar,
        )
    finally:
        bar.close()
    print(story(rep))
    if args.json:
        write_text(args.json, json.dumps(clean(rep), indent=2, allow_nan=False))
    return 0


def cmd_discover_geometry(args) -> int:
    """`discover --geometry`: identify/discover/geometric_run.py (no plot or view yet)."""
    from calbench.identify.discover import (
        discover_geometry_json,
        format_discover_geometry,
        run_discover_geometry,
    )

    for flag, value in (("--plot", args.plot), ("--view-json", args.view_json), ("--rrd", args.rrd)):
        if value is not None:
            raise InputError(flag, flag, "no plot or view beside --geometry (not made yet)", str(value))
    out_model = args.out_model or args.log.with_name(args.log.stem + ".augmented.xml")
    check_outputs(
        {"--json": args.json, "--out-model": out_model},
        {"LOG": args.log, "--model": args.model, "--validate": args.validate},
    )
    bar = terminal_progress("calbench discover --geometry", "candidates")
    try:
        rep = run_discover_geometry(args.log, args.model, args.validate, args.out_model, progress=bar)
    finally:
        bar.close()
    print(format_discover_geometry(rep))
    if args.json:
        write_text(args.json, discover_geometry_json(rep))
    return 0


# --------------------------------------------------------------------------- report


def add_report(sub) -> None:
    p = sub.add_parser("report", help="the calibration report: one self-contained HTML file")
    p.add_argument("log", type=Path, help="campaign MCAP log")
    p.add_argument(
        "--identified",
        type=Path,
        default=None,
        help="JSON of `calbench identify --json` (parameters, correlation, residuals; default: none)",
    )
    p.add_argument(
        "--discover",
        type=Path,
        default=None,
        help="JSON of `calbench discover --json` (verdict, before/after, aliasing; default: none)",
    )
    p.add_argument(
        "--design",
        type=Path,
        default=None,
        help="JSON of `calbench design --json` (the plan and its certificate; default: none)",
    )
    p.add_argument("--out", type=Path, required=True, help="the report, HTML (required)")
    p.set_defaults(func=cmd_report)


def cmd_report(args) -> int:
    from calbench.identify.report import write_report

    out = write_report(args.log, args.out, args.identified, args.discover, args.design)
    given = [k for k in ("identified", "discover", "design") if getattr(args, k) is not None]
    print(
        f"wrote {out} ({out.stat().st_size / 1024:.0f} KiB; from the log"
        + "".join(f", --{k}" for k in given)
        + ")"
    )
    return 0


# --------------------------------------------------------------------------- import


def add_import(sub) -> None:
    p = sub.add_parser(
        "import",
        help="a campaign log from real tracker readings (CSV) taken along a plan",
        description="READINGS.csv: pose,state,point,x,y,z[,time][,sigma] (docs/contract.md); "
        "PLAN.toml: a scenario without [truth]. Without a tracker position in the "
        "plan the tracker is registered from the unloaded readings.",
    )
    p.add_argument("readings", type=Path, help="READINGS.csv")
    p.add_argument(
        "--plan", type=Path, required=True, help="the plan the readings were taken along (TOML; required)"
    )
    p.add_argument("--out", type=Path, required=True, help="output MCAP log (required)")
    p.add_argument(
        "--units",
        choices=("mm", "m"),
        default="mm",
        help="unit of x, y, z and sigma in the CSV (default: %(default)s)",
    )
    p.add_argument("--model", type=Path, default=None, help="robot MJCF (default: the plan's `robot`)")
    p.set_defaults(func=cmd_import)


def cmd_import(args) -> int:
    from calbench.identify.shopfloor import import_readings

    check_outputs(
        {"--out": args.out}, {"READINGS": args.readings, "--plan": args.plan, "--model": args.model}
    )
    bars = (
        terminal_progress("calbench import", "MB read"),
        terminal_progress("calbench import", "poses written"),
    )
    try:
        res = import_readings(args.readings, args.plan, args.out, args.units, args.model, *bars)
    finally:
        for bar in bars:
            bar.close()
    s = res.summary
    for w in res.warnings:
        print(f"calbench import: warning: {w}", file=sys.stderr)
    print(
        f"wrote {res.out}: {len(s.poses)} of {len(res.plan.poses)} planned poses, {s.rows} readings "
        f"in {s.readings} tracker messages ({args.units})"
        + (f"; no readings for poses {s.lost}" if s.lost else "")
        + (f"; one state only (no deflection) for poses {s.one_state}" if s.one_state else "")
    )
    if res.registration is None:
        print("tracker pose: the plan's")
    else:
        f = res.registration.fit
        print(
            f"tracker registered at ({', '.join(f'{v:.4f}' for v in f.position)}) m "
            f"± {max(f.position_std) * 1e6:.1f} um, turned {math.degrees(f.angle):.3f} deg "
            f"± {max(f.rotation_std) * 1e6:.1f} urad; residual {f.rms * 1e6:.1f} um RMS per axis "
            f"(the tracker alone: {f.expected_rms * 1e6:.1f} um)"
        )
    return 0


# --------------------------------------------------------------------------- compensate


def add_compensate(sub) -> None:
    p = sub.add_parser(
        "compensate",
        help="compliance-error compensation: joint commands at which the identified model's loaded tool "
        "lands on target",
        description="JOB.toml: a path of nominal commands with their process loads (docs/contract.md, "
        "'Job file'); ID.json: `calbench identify --json`. Exit 1 when a point cannot be reached "
        "(named; its row keeps the nominal command).",
    )
    p.add_argument("job", type=Path, metavar="JOB.toml", help="the job: a path of nominal commands and loads")
    p.add_argument(
        "--identified",
        type=Path,
        required=True,
        metavar="ID.json",
        help="the identification (identify --json; required)",
    )
    p.add_argument(
        "--out",
        type=Path,
        required=True,
        metavar="COMMANDS.csv",
        help="COMMANDS.csv: point,q1,...,qN in degrees (required)",
    )
    p.add_argument(
        "--json",
        type=Path,
        default=None,
        metavar="OUT.json",
        help="per-point predictions (and truth) as JSON (default: none)",
    )
    p.add_argument(
        "--model",
        type=Path,
        default=None,
        metavar="ROBOT.xml",
        help="robot MJCF (default: the job's `robot`)",
    )
    p.add_argument(
        "--target",
        choices=("unloaded", "rigid"),
        default="unloaded",
        help="unloaded: where the same robot puts the tool without the job's load (removes the "
        "process deflection); rigid: the rigid nominal pose (removes the self-weight sag too, "
        "which a deflection campaign hardly determines) (default: %(default)s)",
    )
    p.add_argument(
        "--truth",
        type=Path,
        default=None,
        metavar="SCENARIO.toml",
        help="on the bench: apply the commands to the true robot of SCENARIO.toml and report the "
        "true error before and after (default: none)",
    )
    p.add_argument(
        "--rrd",
        type=Path,
        default=None,
        metavar="PATH.rrd",
        help="write a Rerun recording of the path: targets, the loaded tool uncompensated and compensated "
        "(the truth's with --truth), errors magnified (default: none)",
    )
    p.add_argument(
        "--magnify",
        type=float,
        default=200.0,
        metavar="K",
        help="error magnification in the recording (default: %(default)s)",
    )
    p.set_defaults(func=cmd_compensate)


def _um(x) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x * 1e6:.1f}"


def cmd_compensate(args) -> int:
    from calbench.identify.compensate import Z_EXCEEDED, CompensationRequest, run_compensate

    inputs = {"JOB": args.job, "--identified": args.identified, "--model": args.model, "--truth": args.truth}
    check_outputs({"--out": args.out, "--json": args.json, "--rrd": args.rrd}, inputs)
    if args.rrd is not None and not (math.isfinite(args.magnify) and args.magnify > 0):
        raise InputError("--magnify", "value", "a positive finite number", args.magnify)
    res = run_compensate(CompensationRequest(args.job, args.identified, args.target, args.model, args.truth))
    truth = {t.index: t for t in res.truth or ()}
    head = f"{'point':>5} {'dev um':>9} {'std um':>7}" + (
        f" {'true before um':>14} {'true after um':>13} {'z':>5}" if truth else ""
    )
    print(f"calbench compensate: {args.job} ({len(res.points)} points, target {res.target})")
    print(head)
    for p in res.points:
        line = f"{p.index:>5} {_um(p.predicted_deviation_m):>9} {_um(p.predicted_error_std_m):>7}"
        if p.index in truth:
            t = truth[p.index]
            z = "-" if not math.isfinite(t.z) else f"{t.z:.2f}"
            line += f" {_um(t.error_before_m):>14} {_um(t.error_after_m):>13} {z:>5}"
        print(line + ("" if p.converged else f"  NOT REACHED: {p.reason}"))
    s = res.summary()
    print(
        f"predicted: {_um(s['predicted_deviation_rms_m'])} um RMS uncompensated, "
        f"{_um(s['predicted_error_rms_m'])} um RMS (1 sigma) left after compensation"
    )
    if truth:
        print(
            f"true: {_um(s['true_error_before_rms_m'])} um RMS before, {_um(s['true_error_after_rms_m'])} um "
            f"RMS after (max {_um(s['true_error_after_max_m'])} um); z RMS {s['z_rms']:.2f}"
            + (
                f"\n  the true error is more than {Z_EXCEEDED:g} x the predicted one: the identified model "
                "lacks an effect of the true robot (calbench discover names it)"
                if s["prediction_exceeded"]
                else ""
            )
        )
    write_text(args.out, res.commands_csv())
    if args.json:
        write_text(args.json, json.dumps(res.to_dict(), indent=2, allow_nan=False))
    if args.rrd:
        from calbench.identify.compensate import write_path_recording

        write_path_recording(res, args.rrd, args.magnify)
        print(f"wrote {args.rrd} (Rerun; errors x{args.magnify:g}): rerun {args.rrd}")
    if res.unreached:
        print(f"{len(res.unreached)} point(s) cannot be reached: {[p.index for p in res.unreached]}")
        return 1
    return 0


# --------------------------------------------------------------------------- study


def add_study(sub) -> None:
    p = sub.add_parser(
        "study", help="a grid of whole campaigns (scenario keys x seeds) into Parquet; resumable"
    )
    p.add_argument("study", type=Path, help="study TOML (base scenario, axes, seeds; see docs/studies.md)")
    p.add_argument(
        "--out",
        type=Path,
        required=True,
        help="required: the results, one row per campaign (Parquet); re-running the same command resumes",
    )
    p.add_argument(
        "--plots",
        type=Path,
        default=None,
        help="folder for the accuracy and power plots (default: OUT's name + _plots beside it)",
    )
    p.add_argument(
        "--json",
        type=Path,
        default=None,
        help="write the per-cell summary as JSON (default: none, the table only)",
    )
    add_scheduler(p)
    p.set_defaults(func=cmd_study)


def cmd_study(args) -> int:
    from calbench.identify.runtime import Interrupted
    from calbench.identify.study import load_study, prepare, report_study, run_study

    study = load_study(args.study)  # every cell validated: nothing sent yet
    plots = args.plots or args.out.with_name(args.out.stem + "_plots")
    check_outputs(
        {"--out": args.out, "--json": args.json},
        {"STUDY": args.study, "scenario": study.base.path, "robot": study.base.robot},
    )
    if plots.exists() and not plots.is_dir():
        raise InputError(plots, "--plots", "a folder", "a file")
    pending = prepare(study, args.out)
    interrupted = None
    if pending.campaigns == 0:
        print(f"calbench study: all {pending.before} campaigns already in {args.out}", file=sys.stderr)
    else:
        print(
            f"calbench study: {pending.campaigns} campaigns to run ({pending.before} already in {args.out})",
            file=sys.stderr,
        )
        scale, each = pending.measure()
        basis = f"{each:.2g} s per campaign, measured on one" if each else "the constants' figures"
        with open_pieces(args, pending.estimated_seconds(scale), pending.tasks(), 0.0, basis) as ex:
            bar = terminal_progress("calbench study", "campaigns")
            try:
                outcome = run_study(pending, ex, progress=bar)
            except Interrupted as exc:
                outcome, interrupted = exc.partial, exc
            bar.close()
        print(
            f"calbench study: {outcome.ran} campaigns run in {outcome.seconds:.1f} s"
            + (f", {outcome.designs} plans designed" if outcome.designs else "")
            + f"; {outcome.rows} in {args.out}"
            + (f" ({outcome.failed} failed)" if outcome.failed else ""),
            file=sys.stderr,
        )
    rep = report_study(study, args.out, plots)
    print(rep.text)
    if rep.rows:
        print(f"plots: {', '.join(str(p) for p in rep.plots)}", file=sys.stderr)
    if args.json:
        write_text(args.json, rep.to_json())
    if interrupted is not None:
        print(
            f"calbench study: interrupted; {interrupted.done} of {interrupted.total} campaigns kept in "
            f"{args.out}; run the same command again to resume",
            file=sys.stderr,
        )
        return 130
    return 0


# --------------------------------------------------------------------------- check-robot


def add_check_robot_design(sub) -> None:
    """bench's check-robot, followed by design's feasibility rules on a sample of commands."""
    add_check_robot(sub)
    p = sub.choices["check-robot"]
    p.add_argument(
        "--sample",
        type=int,
        default=256,
        help="commands sampled as `design` samples them, for the share that passes each of its "
        "feasibility rules (0: skip; default: %(default)s)",
    )
    p.set_defaults(func=lambda args: cmd_check_robot(args, _design_lines))


def _design_lines(args, res) -> list[str]:
    from calbench.identify.design import robot_tally

    if args.sample < 0:
        raise InputError("--sample", "sample", "an integer >= 0", args.sample)
    if args.sample == 0:
        return []
    t = robot_tally(args.robot, res.tracker, res.mass, args.sample)
    share = t.passed_command / t.sampled * (t.feasible / t.solved if t.solved else 0.0)
    return [
        f"  design's feasibility rules on {t.sampled} sampled commands (default [design] settings: "
        f"{t.wrist_rules}; {res.mass:g} kg; equilibria checked on {t.solved} that pass the command rules): "
        f"{100 * share:.1f} % feasible",
        *t.lines(),
    ]


# --------------------------------------------------------------------------- demo


def add_demo(sub) -> None:
    p = sub.add_parser("demo", help="the paper campaign end to end: simulate, view, identify, discover")
    p.add_argument(
        "--logs",
        type=Path,
        default=Path("logs"),
        help="output folder, relative to where you run it (default: %(default)s)",
    )
    p.set_defaults(func=cmd_demo)


def cmd_demo(args) -> int:
    check_outputs(
        {f"--logs ({what})": path for what, path in demo.demo_files(args.logs).items()},
        {"demo scenario": demo.PAPER},
    )
    for line in demo.run_demo(args.logs):
        print(line, flush=True)
    return 0


# --------------------------------------------------------------------------- the script


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="calbench", description=__doc__.split("\n\n")[0])
    parser.add_argument("--version", action="version", version=f"calbench {_version()}")
    parser.add_argument(
        "-v",
        "--verbose",
        action="count",
        default=0,
        help="log the solvers' iterations to stderr (-v: info, -vv: debug; default: quiet)",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    add_simulate(sub)
    add_demo(sub)
    add_identify(sub)
    add_montecarlo(sub)
    add_design(sub)
    add_view(sub)
    add_discover(sub)
    add_report(sub)
    add_check_robot_design(sub)
    add_import(sub)
    add_export(sub)
    add_from_urdf(sub)
    add_recover(sub)
    add_study(sub)
    add_compensate(sub)
    return parser


def _one_line_warning(command: str):
    """Warnings as one line on stderr: ``calbench VERB: warning: FILE: KEY: what``; a
    PlausibilityWarning's origin in the code means nothing to its reader."""
    original = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, PlausibilityWarning):
            print(f"calbench {command}: warning: {message}", file=sys.stderr, flush=True)
        else:
            original(message, category, filename, lineno, file, line)

    return show


def _mujoco_warning(message: str) -> None:
    logging.getLogger("calbench.mujoco").warning("MuJoCo: %s", message)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.verbose:
        logging.basicConfig(
            level=logging.DEBUG if args.verbose > 1 else logging.INFO,
            format="%(name)s: %(message)s",
            stream=sys.stderr,
        )
    if mujoco.get_mju_user_warning() is None:
        # MuJoCo's own handler writes MUJOCO_LOG.TXT into the user's folder: say it on stderr
        mujoco.set_mju_user_warning(_mujoco_warning)
    from calbench.bench.log import showing_progress

    try:
        with (
            holding_outputs(),  # a second run on one output is refused
            showing_progress(lambda name: terminal_progress(name, "MB")),  # a big log's check
            warnings.catch_warnings(),
        ):
            warnings.simplefilter("default", PlausibilityWarning)
            warnings.showwarning = _one_line_warning(args.command)
            return int(args.func(args) or 0)
    except CalbenchError as exc:
        print(f"calbench {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("calbench: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `calbench ... | head`: the reader left, nothing to say
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except OSError as exc:  # a write the machine refused outside the atomic writers: one line
        cause = refused_write(exc)
        if cause is None:
            raise
        where = f"cannot write {exc.filename}" if exc.filename else "cannot write its output"
        print(f"calbench {args.command}: error: {where}: {cause}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
