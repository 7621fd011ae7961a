"""How much a real robot's geometric errors matter (docs/performance.md, "A real robot's geometry").

Deflections are differences of two readings of one reflector, so an error of the robot's
geometry cancels from them to first order; what is left, and what the registration of the
tracker (which fits absolute positions) absorbs, is measured here. For each of N random
geometries (every coordinate of the body offsets outside the parallelogram, of the shoulder's
two bodies together and of the reflector and payload sites perturbed by a normal error of sd
--mm, default 1 mm; the robot description requires the loop itself to close) the paper campaign is
simulated on the perturbed robot, then identified
* with the perturbed model itself and the tracker's true pose: the reference;
* with the nominal model and the tracker's true pose: the deflection model's share;
* imported with the tracker pose withheld (the readings turned by 40 deg, registered against the
  nominal model) and identified with the nominal model: everything a user meets;
and the differences from the reference are printed in units of the reference's standard
deviation, with the registration's residual and rotation error. Prints JSON.

Usage: python benchmarks/geometry_bench.py [--geometries N] [--mm SD] [--quick]
"""

from __future__ import annotations

import argparse
import json
import re
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent

from calbench.bench.campaign import run_campaign
from calbench.bench.log import read_log
from calbench.bench.scenario import load_scenario
from calbench.bench.shopfloor import export_rows, readings_csv
from calbench.identify.core import rotation_exp
from calbench.identify.report import run_identify
from calbench.identify.runtime import blas_threads
from calbench.identify.shopfloor import import_readings

PAPER = ROOT / "scenarios" / "paper_table5.toml"
MJCF = ROOT / "mjcf" / "m900ib700.xml"
# every body offset outside the parallelogram, the loop's two shoulder bodies moved together
# (the robot description requires the loop to close at the rigid command), and the sites
GROUPS = (
    ("body", ("turret",)),
    ("body", ("upper_arm", "crank")),
    ("body", ("link4",)),
    ("body", ("link5",)),
    ("body", ("link6",)),
    ("site", ("refl_a",)),
    ("site", ("refl_b",)),
    ("site", ("refl_c",)),
    ("site", ("payload",)),
)
TURN = rotation_exp(np.radians(40.0) * np.array([0.3, -0.5, 0.81]) / np.linalg.norm([0.3, -0.5, 0.81]))


def perturbed(sd: float, rng: np.random.Generator) -> str:
    """The MJCF with the GROUPS' offsets moved by N(0, sd) per axis (one draw per group)."""
    text = MJCF.read_text()
    for kind, names in GROUPS:
        shift = rng.normal(0.0, sd, 3)
        for name in names:
            pat = re.compile(rf'(<{kind} name="{name}" pos=")([^"]+)(")')
            m = pat.search(text)
            pos = np.array([float(v) for v in m.group(2).split()]) + shift
            text = (
                text[: m.start()]
                + m.group(1)
                + " ".join(f"{v:.6f}" for v in pos)
                + m.group(3)
                + text[m.end() :]
            )
    return text


def estimates(log: Path, model: Path) -> tuple[np.ndarray, np.ndarray]:
    rep = run_identify(log, model)
    return (
        np.array([p.estimate for p in rep.parameters], float),
        np.array([p.std for p in rep.parameters], float),
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--geometries", type=int, default=8)
    ap.add_argument("--mm", type=float, default=1.0)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    n = 2 if args.quick else args.geometries
    rng = np.random.default_rng(2026)
    t0 = time.perf_counter()
    rows = []
    names = None
    with tempfile.TemporaryDirectory() as tmp, blas_threads(1):
        tmp = Path(tmp)
        text = PAPER.read_text()
        plan_text = re.sub(r"(?ms)^\[truth\].*?(?=^\[tracker\])", "", text)
        plan_text = re.sub(r"position = \[3.5, -3.5, 3.2\].*\n", "", plan_text)
        plan = tmp / "plan.toml"
        plan.write_text(plan_text.replace('robot = "../mjcf/m900ib700.xml"', f'robot = "{MJCF.as_posix()}"'))
        for g in range(n):
            model = tmp / f"robot{g}.xml"
            model.write_text(perturbed(args.mm * 1e-3, rng))
            scn_path = tmp / f"scn{g}.toml"
            scn_path.write_text(
                text.replace('robot = "../mjcf/m900ib700.xml"', f'robot = "{model.as_posix()}"')
            )
            log = tmp / f"log{g}.mcap"
            run_campaign(load_scenario(scn_path), log)
            ref, sd = estimates(log, model)
            known, _ = estimates(log, MJCF)
            rows_csv = [replace(r, position=TURN.T @ r.position) for r in export_rows(read_log(log))]
            (tmp / "r.csv").write_text(readings_csv(rows_csv))
            imp = import_readings(tmp / "r.csv", plan, tmp / f"imp{g}.mcap")
            registered, _ = estimates(tmp / f"imp{g}.mcap", MJCF)
            fit = imp.registration.fit
            d = fit.rotation @ TURN.T
            angle = float(np.degrees(np.arccos(np.clip((np.trace(d) - 1) / 2, -1, 1))))
            rows.append(
                {
                    "deflection_model": ((known - ref) / sd).tolist(),
                    "with_registration": ((registered - ref) / sd).tolist(),
                    "registration_rms_mm": fit.rms * 1e3,
                    "registration_rotation_error_deg": angle,
                    "registration_warned": bool(imp.warnings),
                }
            )
        names = [p.name for p in run_identify(log, model).parameters]
    a = np.array([r["deflection_model"] for r in rows])
    b = np.array([r["with_registration"] for r in rows])
    print(
        json.dumps(
            {
                "geometric_error_sd_mm": args.mm,
                "geometries": n,
                "parameters": names,
                "max_abs_shift_over_sigma": {
                    "deflection_model": dict(zip(names, np.abs(a).max(0).tolist())),
                    "with_registration": dict(zip(names, np.abs(b).max(0).tolist())),
                },
                "rms_shift_over_sigma": {
                    "deflection_model": dict(zip(names, np.sqrt((a**2).mean(0)).tolist())),
                    "with_registration": dict(zip(names, np.sqrt((b**2).mean(0)).tolist())),
                },
                "registration_rms_mm": [r["registration_rms_mm"] for r in rows],
                "registration_rotation_error_deg": [r["registration_rotation_error_deg"] for r in rows],
                "warned": [r["registration_warned"] for r in rows],
                "seconds": time.perf_counter() - t0,
            },
            indent=1,
        )
    )


if __name__ == "__main__":
    main()
