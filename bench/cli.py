"""The bench's command-line verbs: `simulate`, `view`, `export`, `check-robot`, `from-urdf`
and `recover`.

The console script itself lives in identify/cli.py, which sits on top of both packages and
registers these; bench never imports identify. This module and identify/cli.py are the only
ones that parse arguments or print: every library function they call returns its result.
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
from pathlib import Path

from calbench.bench.campaign import CampaignInterrupted, simulate_to_log
from calbench.bench.core import atomic_path, check_outputs, terminal_progress, write_text
from calbench.bench.log import read_log, recover_log
from calbench.bench.robots import DEFAULT_MASS, check_robot
from calbench.bench.scenario import MAX_LOG_BYTES, MAX_SECONDS, duration, load_scenario, size
from calbench.bench.view import (
    DEFAULT_MAGNIFY,
    Summary,
    ViewerUnavailable,
    default_rrd_path,
    has_display,
    open_hint,
    spawn_recording,
    write_recording,
)

# --------------------------------------------------------------------------- simulate


def add_simulate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "simulate",
        help="run a calibration campaign and write one MCAP log",
        description="Run a calibration campaign and write one MCAP log. Ctrl-C "
        "(or SIGTERM) finishes the log with the poses done so far.",
    )
    p.add_argument("scenario", type=Path, help="scenario TOML file")
    p.add_argument("--out", type=Path, required=True, help="output MCAP log (required)")
    p.add_argument("--seed", type=int, default=None, help="noise seed (default: the scenario's `seed`)")
    p.add_argument(
        "--force",
        action="store_true",
        help=f"run a campaign estimated to take more than {duration(MAX_SECONDS)} or "
        f"{size(MAX_LOG_BYTES)} of log (default: refuse it)",
    )
    p.set_defaults(func=cmd_simulate)


@contextlib.contextmanager
def _sigterm_as_interrupt():
    """SIGTERM (``kill PID``) ends the campaign like Ctrl-C: the log is finished properly.
    (SIGKILL cannot be caught: `calbench recover` mends what it leaves.)"""

    def handler(signum, frame):
        raise KeyboardInterrupt

    try:
        old = signal.signal(signal.SIGTERM, handler)
    except ValueError:  # not the main thread (a notebook worker): leave it alone
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def cmd_simulate(args: argparse.Namespace) -> int:
    scn = load_scenario(args.scenario, seed=args.seed)
    check_outputs({"--out": args.out}, {"SCENARIO": args.scenario, "robot": scn.robot})
    bar = terminal_progress("calbench simulate", "equilibria")
    try:
        with _sigterm_as_interrupt():
            campaign = simulate_to_log(scn, args.out, progress=bar, force=args.force)
    except CampaignInterrupted as stop:
        bar.close()
        if not stop.written:
            print(
                f"calbench simulate: interrupted before the log was started; {args.out} untouched",
                file=sys.stderr,
            )
            return 130
        print(
            f"calbench simulate: interrupted: {args.out} is a finished MCAP log with "
            f"{stop.complete} of {stop.planned} poses",
            file=sys.stderr,
        )
        return 130
    bar.close()
    n_meas = sum(p.visible.sum() for p in campaign.plans)
    print(
        f"wrote {args.out}: {len(campaign.plans)} poses, unloaded and loaded, {n_meas} reflector sightings "
        f"(tracker sigma {scn.tracker.sigma * 1e6:.0f} um, seed {scn.seed})"
    )
    return 0


# --------------------------------------------------------------------------- view


def add_view(sub: argparse._SubParsersAction) -> None:
    from .view import recording as view

    p = sub.add_parser(
        "view",
        help="Rerun recording of a campaign (and its identification)",
        description=view.__doc__.split("\n\n")[0],
    )
    p.add_argument("log", type=Path, help="campaign MCAP log")
    p.add_argument(
        "--rrd",
        type=Path,
        default=None,
        help="write the recording to this .rrd file instead of spawning the viewer "
        "(default without a display: LOG.rrd beside the log)",
    )
    p.add_argument(
        "--identified",
        type=Path,
        default=None,
        help="JSON report of `calbench identify --json` (the parameters by name, the "
        "model's deformation; predicted deflections and residuals when it "
        "carries them; default: none)",
    )
    p.add_argument(
        "--magnify",
        type=float,
        default=DEFAULT_MAGNIFY,
        help="magnification of the deformation and the deflection arrows (default: "
        "%(default)g; residuals 10 times more; stated in the 3D view's title)",
    )
    p.set_defaults(func=cmd_view)


def _view_summary(s: Summary, magnify: float) -> str:
    return (
        f"{s.poses} poses, {s.arrows} deflection arrows (x{magnify:g})"
        + (f", {s.predicted} predicted" if s.predicted else "")
        + f"; deformation ghost from {s.ghost}"
    )


def cmd_view(args: argparse.Namespace) -> int:
    from calbench.bench.view import check_magnify

    magnify = check_magnify(args.magnify)
    inputs = {"LOG": args.log, "--identified": args.identified}
    if args.rrd is not None:
        check_outputs({"--rrd": args.rrd}, inputs)
    why = " (no display, so no viewer was spawned)"
    if args.rrd is None and has_display():
        try:
            s = spawn_recording(args.log, args.identified, magnify)
        except ViewerUnavailable as e:  # no viewer binary, cannot start: fall back to a file
            print(f"calbench view: could not spawn the viewer ({e}); writing a file instead", file=sys.stderr)
            why = " (the viewer could not be spawned)"
        else:
            print(f"sent to the Rerun viewer: {_view_summary(s, magnify)}")
            if s.completeness:
                print(f"  campaign: {s.completeness}")
            return 0
    out = args.rrd if args.rrd is not None else default_rrd_path(args.log)
    check_outputs({"--rrd": out}, inputs)
    s = write_recording(args.log, out, args.identified, magnify)
    for w in s.warnings:
        print(f"calbench view: warning: {w}", file=sys.stderr)
    print(f"wrote {out}{'' if args.rrd is not None else why}: {_view_summary(s, magnify)}")
    if s.completeness:
        print(f"  campaign: {s.completeness}")
    for line in open_hint(out, has_display()):
        print(line)
    return 0


# --------------------------------------------------------------------------- check-robot


def add_check_robot(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "check-robot",
        help="validate a robot's MJCF and its calbench description",
        description="Checks that ROBOT.xml names the elements calbench needs "
        "(docs/contract.md, Robot description), that its loops close, its "
        "reflectors are seen and its statics converge over a grid of poses.",
    )
    p.add_argument("robot", type=Path, help="robot MJCF")
    p.add_argument(
        "--tracker",
        type=float,
        nargs=3,
        default=None,
        metavar=("X", "Y", "Z"),
        help="tracker position (m, world) for the line-of-sight check (default: 5 m from "
        "axis 1, 3 m up, 45 deg beside the payload)",
    )
    p.add_argument(
        "--mass",
        type=float,
        help=f"payload (kg) of the loaded grid (default: {DEFAULT_MASS:g}, or a third of the robot's "
        "moving mass if less)",
    )
    p.add_argument(
        "--grid", type=int, default=3, help="values per joint of the grid of poses (default: %(default)s)"
    )
    p.set_defaults(func=cmd_check_robot)


def cmd_check_robot(args: argparse.Namespace, more=None) -> int:
    """``more(args, result)``: further lines after the checks (identify/cli.py adds design's
    feasibility rules; bench knows nothing of design)."""
    from calbench.bench.core import InputError

    if args.grid < 1:
        raise InputError("--grid", "grid", "an integer >= 1", args.grid)
    if args.mass is not None and not args.mass > 0:
        raise InputError("--mass", "mass", "a mass > 0 (kg)", args.mass)
    res = check_robot(args.robot, args.tracker, args.mass, args.grid)
    print("\n".join(res.lines()), flush=True)
    for line in more(args, res) if more is not None else ():
        print(line, flush=True)
    return 0


# --------------------------------------------------------------------------- export


def add_export(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "export", help="the tracker readings of a log as CSV (the form `calbench import` reads)"
    )
    p.add_argument("log", type=Path, help="campaign MCAP log (simulated or imported)")
    p.add_argument(
        "--csv",
        type=Path,
        required=True,
        help="output CSV: pose,state,point,x,y,z,time[,sigma] (mm; required)",
    )
    p.set_defaults(func=cmd_export)


def cmd_export(args: argparse.Namespace) -> int:
    from calbench.bench.shopfloor import export_readings

    check_outputs({"--csv": args.csv}, {"LOG": args.log})
    log = read_log(args.log)
    n = export_readings(log, args.csv)  # a reading at a time: a log of any size
    print(f"wrote {args.csv}: {n} readings (mm, tracker frame)")
    if log.completeness():
        print(f"  campaign: {log.completeness()}")
    return 0


# --------------------------------------------------------------------------- from-urdf


def add_from_urdf(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "from-urdf",
        help="a calbench MJCF from a URDF and an overlay (TOML)",
        description="Build the calbench MJCF of a robot from its URDF (links, joints, "
        "inertials, geometry) and an overlay naming what a URDF cannot say: "
        "the actuated joints, reflectors, payload, compensators and loops "
        "(docs/contract.md, 'From a URDF').",
    )
    p.add_argument("urdf", type=Path, help="the robot's URDF, or its .xacro (expanded by the xacro package)")
    p.add_argument("--overlay", type=Path, required=True, help="overlay TOML (required)")
    p.add_argument("--out", type=Path, required=True, help="output MJCF (required)")
    p.set_defaults(func=cmd_from_urdf)


def cmd_from_urdf(args: argparse.Namespace) -> int:
    from calbench.bench.robots import PLACEHOLDER_STIFFNESS, import_robot, load_overlay

    check_outputs({"--out": args.out}, {"URDF": args.urdf, "--overlay": args.overlay})
    conv = import_robot(args.urdf, load_overlay(args.overlay))  # the importer that accepts the file
    write_text(args.out, conv.xml)
    for w in conv.warnings:
        print(f"calbench from-urdf: warning: {w}", file=sys.stderr)
    for n in conv.notes:
        print(f"calbench from-urdf: note: {n}", file=sys.stderr)
    print(
        f"wrote {args.out}: {len(conv.actuated)} actuated joints ({' '.join(conv.actuated)})"
        + (f", passive {' '.join(conv.passive)}" if conv.passive else "")
        + f"; moving mass {conv.moving_mass:.1f} kg "
        + (
            f"(ASSUMED for {' '.join(conv.assumed)}: the overlay's [inertials] or assumed_density)"
            if conv.assumed
            else "from the URDF's inertials"
        )
        + f"; {conv.geoms} geoms"
        + (f" ({conv.meshes} meshes inline)" if conv.meshes else "")
        + f"; joint stiffness placeholders {PLACEHOLDER_STIFFNESS:g} N*m/rad (a scenario's [truth] "
        "replaces them)"
    )
    print(f"check it with: calbench check-robot {args.out}")
    return 0


# --------------------------------------------------------------------------- recover


def add_recover(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "recover",
        help="rewrite a cut-short or damaged log as a valid MCAP file",
        description="Rewrite a campaign log that was cut short (a campaign killed "
        "with SIGKILL, a crash) or damaged as a valid MCAP file with its summary "
        "and footer, which every MCAP reader opens. Complete, intact poses are "
        "kept; the others are named, and the new log reports them as lost.",
    )
    p.add_argument("log", type=Path, help="the broken campaign MCAP log (read only)")
    p.add_argument("--out", type=Path, required=True, help="the recovered MCAP log (required)")
    p.set_defaults(func=cmd_recover)


def cmd_recover(args: argparse.Namespace) -> int:
    check_outputs({"--out": args.out}, {"LOG": args.log})
    with atomic_path(args.out) as tmp:
        rec = recover_log(args.log, tmp)
    print(f"wrote {args.out}: {rec.summary()}")
    for note in rec.notes:
        print(f"  note: {note}")
    return 0


__all__ = [
    "add_simulate",
    "cmd_simulate",
    "add_view",
    "cmd_view",
    "add_export",
    "cmd_export",
    "add_check_robot",
    "cmd_check_robot",
    "add_from_urdf",
    "cmd_from_urdf",
    "add_recover",
    "cmd_recover",
]
