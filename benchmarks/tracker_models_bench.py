"""Predicted parameter accuracy under the three tracker models (docs/performance.md, "Tracker models").

For the paper's 16-pose plan and a 12-pose A-optimal plan (``calbench design``, designed under the
default isotropic tracker), the Cramer-Rao standard deviation of every parameter
(identify/study/accuracy.py) with the tracker of the scenario replaced by
* isotropic: 20 um per axis (the bench's default),
* spec: 1-sigma (10 um + 0.3 um/m) along the beam, (15 um + 6 um/m) across it, independent
  readings (the MPE figures read as 1 sigma),
* iso10360: the same single-point error, mostly a smooth systematic field, plus independent noise
  and drift (bench/tracker/models/iso10360.py, its defaults),
and the deflection's own sigma per axis at one reflector of the first pose. Prints JSON.

Usage: python benchmarks/tracker_models_bench.py [--plan PLAN.toml] [--candidates N] [--quick]
(``--plan``: a designed plan instead of designing one; ``--quick``: 1000 candidates.)
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
import tomllib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent

from calbench.bench.campaign import simulate, truth_robot
from calbench.bench.scenario import load_scenario, scenario_to_toml
from calbench.identify.cli import main as calbench
from calbench.identify.core import from_campaign
from calbench.identify.runtime import blas_threads
from calbench.identify.study import predicted_std

PAPER = ROOT / "scenarios" / "paper_table5.toml"
MODELS = {"isotropic": {"sigma": 20e-6}, "spec": {"model": "spec"}, "iso10360": {"model": "iso10360"}}


def variant(src: Path, model: str, out: Path):
    """The scenario at ``src`` with its tracker's noise model replaced (same place, same yaw)."""
    doc = tomllib.loads(src.read_text())
    doc["robot"] = str((src.parent / doc["robot"]).resolve())
    doc["tracker"] = {k: v for k, v in doc["tracker"].items() if k in ("position", "yaw")} | MODELS[model]
    out.write_text(scenario_to_toml(doc))
    return load_scenario(out)


def deflection_sigma(scn) -> list[float]:
    """The sqrt of the diagonal of the first deflection's covariance (m, world x y z)."""
    truth = truth_robot(scn)
    obs = from_campaign(simulate(scn, None, robot=truth))
    return np.sqrt(np.diag(obs.poses[0].cov[0])).tolist()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--plan", type=Path, default=None)
    ap.add_argument("--candidates", type=int, default=None)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    t0 = time.perf_counter()
    out: dict = {"plans": {}}
    with tempfile.TemporaryDirectory() as tmp, blas_threads(1):
        tmp = Path(tmp)
        plan = args.plan
        if plan is None:
            plan = tmp / "designed.toml"
            n = args.candidates or (1000 if args.quick else None)
            assert (
                calbench(
                    ["design", str(PAPER), "--configs", "12", "--criterion", "A", "--out", str(plan)]
                    + (["--candidates", str(n)] if n else [])
                )
                == 0
            )
        for name, src in (
            ("paper (Table 5 + 4 pulls, 16 poses)", PAPER),
            ("designed (A-optimal, 12 poses)", plan),
        ):
            row = {}
            for model in MODELS:
                scn = variant(src, model, tmp / f"{model}.toml")
                row[model] = {"std": predicted_std(scn), "deflection_sigma_m": deflection_sigma(scn)}
            iso = row["isotropic"]["std"]
            for model in MODELS:
                row[model]["over_isotropic"] = {k: v / iso[k] for k, v in row[model]["std"].items()}
            out["plans"][name] = row
    out["seconds"] = time.perf_counter() - t0
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
