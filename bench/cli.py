"""The bench's command-line verbs (`simulate`). The console script itself lives in
identify/cli.py, which sits on top of both packages; bench never imports identify."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .campaign import run_campaign
from .scenario import load_scenario


def add_simulate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help="run a calibration campaign and write one MCAP log")
    p.add_argument("scenario", type=Path, help="scenario TOML file")
    p.add_argument("--out", type=Path, required=True, help="output MCAP log")
    p.add_argument("--seed", type=int, default=None, help="noise seed (overrides the scenario's)")
    p.set_defaults(func=cmd_simulate)


def cmd_simulate(args: argparse.Namespace) -> int:
    scn = load_scenario(args.scenario, seed=args.seed)
    plans = run_campaign(scn, args.out)
    n_meas = sum(p.visible.sum() for p in plans)
    print(f"wrote {args.out}: {len(plans)} poses, unloaded and loaded, {n_meas} reflector sightings "
          f"(tracker sigma {scn.tracker.sigma * 1e6:.0f} um, seed {scn.seed})", file=sys.stdout)
    return 0
