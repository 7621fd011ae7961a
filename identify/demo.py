"""`calbench demo`: the main job end to end on the shipped paper scenario."""
from __future__ import annotations

import argparse
from pathlib import Path

from calbench.bench.campaign import run_campaign
from calbench.bench.scenario import load_scenario, scenario_variant
from calbench.bench.resources import PAPER_SCENARIO, scenario_path
from calbench.bench.view import write_recording

PAPER = scenario_path(PAPER_SCENARIO)   # package data: works outside a checkout


def add_demo(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="the paper campaign end to end")
    p.add_argument("--logs", type=Path, default=Path("logs"),
                   help="output folder, relative to where you run it (default: %(default)s)")
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
    discover_step(args.logs)
    return 0


HIDDEN_DEMO = """[truth.effects.link_compliance]      # hidden: lateral bending + torsion at the forearm root
link = "forearm"
compliance = [1.8e-7, 0.0, 1.8e-7]"""


def discover_step(logs: Path) -> None:
    """Last demo step: a campaign whose robot has a forearm compliance the model lacks;
    `calbench discover` finds where they disagree, names it, adds it, shows the gap shrink."""
    from .discover.workflow import discover, story
    logs.mkdir(parents=True, exist_ok=True)
    scn_path = scenario_variant(PAPER, logs / "paper_table5_hidden.toml", name="paper_table5_hidden",
                                extra=HIDDEN_DEMO)
    log = logs / "paper_table5_hidden.mcap"
    run_campaign(load_scenario(scn_path), log, show_progress=False)
    print(f"4. discover: a campaign on a robot with a hidden effect the model lacks -> {log}")
    import json
    from .discover.workflow import clean
    js = logs / "paper_table5_hidden.discover.json"
    rep = discover(log, out_model=logs / "paper_table5_hidden.augmented.xml",
                   plot=js.with_suffix(".png"), view_json=logs / "paper_table5_hidden.discover.view.json")
    js.write_text(json.dumps(clean(rep), indent=2, allow_nan=False))
    print("\n".join("   " + line for line in story(rep).splitlines()))
    print("   (the hidden truth, read only now: link_compliance forearm, compliance [1.8e-7, 0, 1.8e-7] rad/(N*m))")
    print(f"   report -> {js}")
