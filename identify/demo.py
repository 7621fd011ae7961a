"""`calbench demo`: the main job end to end on the shipped paper scenario.

:func:`run_demo` yields the lines of the story as each step finishes (the command line prints
them), so the demo shows progress and stays callable from a notebook.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

from calbench.bench.campaign import run_campaign
from calbench.bench.core import PAPER_SCENARIO, scenario_path, write_text
from calbench.bench.model import Robot
from calbench.bench.scenario import load_scenario, scenario_variant
from calbench.bench.view import write_recording

PAPER = scenario_path(PAPER_SCENARIO)  # package data: works outside a checkout
HIDDEN = "paper_table5_hidden"  # the discovery step's campaign
HIDDEN_COMPLIANCE = "[1.8e-7, 0.0, 1.8e-7]"  # rad/(N*m): lateral bending + torsion at the link root


def hidden_link(scenario: Path = PAPER) -> str:
    """The link the demo hides a compliance in: the last of the robot's calbench:links (the
    FANUC's forearm)."""
    links = Robot.from_file(load_scenario(scenario).robot).description.links
    if not links:
        raise ValueError(f"{scenario}: the robot names no calbench:links for the discovery demo")
    return links[-1]


def hidden_demo(link: str) -> str:
    """The hidden effect's [truth.effects] table."""
    return (
        f"[truth.effects.link_compliance]      # hidden: lateral bending + torsion at the {link} root\n"
        f'link = "{link}"\ncompliance = {HIDDEN_COMPLIANCE}'
    )


def demo_files(logs: Path) -> dict[str, Path]:
    """Every file the demo writes under ``logs``, by what it is. The command line checks them all
    before the demo starts (bench/core/outputs.py: one behaviour for every verb), and the steps below
    write exactly these, so the check cannot miss one."""
    logs = Path(logs)
    log = logs / f"{load_scenario(PAPER).name}.mcap"
    h = f"{HIDDEN}."
    return {
        "campaign log": log,
        "recording": log.with_suffix(".rrd"),
        "hidden scenario": logs / f"{h}toml",
        "hidden log": logs / f"{h}mcap",
        "augmented model": logs / f"{h}augmented.xml",
        "discovery report": logs / f"{h}discover.json",
        "discovery plot": logs / f"{h}discover.png",
        "discovery view": logs / f"{h}discover.view.json",
        "discovery recording": logs / f"{h}discover.rrd",
    }


def run_demo(logs: Path) -> Iterator[str]:
    """Simulate the paper campaign, record its Rerun view, identify it against the truth, then
    run the discovery story; yields what to tell the user after each step."""
    from calbench.identify.report import format_table, run_identify

    files = demo_files(logs)
    log, rrd = files["campaign log"], files["recording"]
    campaign = run_campaign(load_scenario(PAPER), log)
    yield f"1. simulated {len(campaign.plans)} poses of {PAPER.name} -> {log}"
    write_recording(log, rrd)
    yield f"2. Rerun recording of the deflections -> {rrd}   (open it with: rerun {rrd})"
    rep = run_identify(log)
    yield f"3. identified (one-step, {rep.seconds:.2f} s), against the truth in the log:"
    yield format_table(rep)
    yield from discover_step(logs)


def discover_step(logs: Path) -> Iterator[str]:
    """Last demo step: a campaign whose robot has a link compliance (the FANUC's forearm) the
    model lacks; `calbench discover` finds where they disagree, names it, adds it, shows the gap
    shrink."""
    from calbench.identify.discover import clean, discover, story

    files = demo_files(logs)
    files["hidden log"].parent.mkdir(parents=True, exist_ok=True)
    link = hidden_link()
    scn_path = scenario_variant(PAPER, files["hidden scenario"], name=HIDDEN, extra=hidden_demo(link))
    log = files["hidden log"]
    run_campaign(load_scenario(scn_path), log)
    yield f"4. discover: a campaign on a robot with a hidden effect the model lacks -> {log}"
    js = files["discovery report"]
    rep = discover(
        log,
        out_model=files["augmented model"],
        plot=files["discovery plot"],
        view_json=files["discovery view"],
        view_rrd=files["discovery recording"],
    )
    write_text(js, json.dumps(clean(rep), indent=2, allow_nan=False))
    yield "\n".join("   " + line for line in story(rep).splitlines())
    yield (
        f"   (the hidden truth, read only now: link_compliance {link}, compliance [1.8e-7, 0, 1.8e-7] "
        "rad/(N*m))"
    )
    yield f"   report -> {js}"


__all__ = [
    "run_demo",
    "demo_files",
    "discover_step",
    "PAPER",
    "HIDDEN",
    "hidden_demo",
    "hidden_link",
    "HIDDEN_COMPLIANCE",
]
