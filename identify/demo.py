"""`calbench demo`: the main job end to end on the shipped paper scenario."""
from __future__ import annotations

import argparse
from pathlib import Path

from bench.campaign import run_campaign
from bench.scenario import load_scenario
from bench.view import write_recording

ROOT = Path(__file__).resolve().parent.parent
PAPER = ROOT / "scenarios" / "paper_table5.toml"


def add_demo(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="the paper campaign end to end")
    p.add_argument("--logs", type=Path, default=ROOT / "logs", help="output folder")
    p.set_defaults(func=cmd_demo)


def cmd_demo(args: argparse.Namespace) -> int:
    scn = load_scenario(PAPER)
    log = args.logs / f"{scn.name}.mcap"
    plans = run_campaign(scn, log)
    print(f"1. simulated {len(plans)} poses of {PAPER.name} -> {log}")
    rrd = log.with_suffix(".rrd")
    write_recording(log, rrd)
    print(f"2. Rerun recording of the deflections -> {rrd}   (open it with: rerun {rrd})")
    from .report import format_table, run_identify
    rep = run_identify(log)
    print(f"3. identified (one-step, {rep['seconds']:.2f} s), against the truth in the log:")
    print(format_table(rep))
    return 0
