"""Held-out accuracy of a real UR10 after geometric calibration (docs/geometry.md).

Reads the public laser-tracker dataset (christianlandgraf/ipa-robot-accuracy; in
../shared/data/ipa-robot-accuracy here, or --data DIR), calibrates on a random 70 % of a series
(seed 0) and predicts the other 30 %: the 3-D position error (mean, RMS, max, mm) and the fit
time for each model, side by side with a peer on the same split and the same points:
* nominal: the UR10's DH table, only the base (tracker registration) and the probe point fitted;
* geometry: + joint offsets and link frames (the SVD base set);
* geometry+compliance: + joint compliance under self-weight (gravity torques from the UR10's
  published masses);
* discover: `discover --geometry` from the nominal model (registration and compliances) on the same
  fitted rows, each step's model on the held-out rows, and a thermal check of its final model;
* pybotics (if installed): its MDH model of the same DH table, every MDH parameter, the probe
  position and the world frame fitted with scipy's least_squares as its OptimizationHandler does,
  from the same registered start.
* FIGAROH (with --figaroh PYTHON, a Python where `pip install figaroh` was run):
  benchmarks/ur10_figaroh_peer.py in that Python, its joint_offset and full_params models and its
  joint elasticity, on a URDF of the same nominal UR10, the same split and the same points.
Positions only (the probe's orientation is not used). Prints JSON.

--out-model PATH writes the calibrated arm (geometry + compliance as joint stiffness) as a calbench
MJCF, with the tracker-from-base transform in the JSON; keep it out of the project (it is made
from the data).

The peers are no dependency of calbench: `pip install figaroh` into a virtual environment of its own
(pass its python as --figaroh), `pip install --no-deps pybotics` into calbench's (it pins numpy < 2
but runs on numpy 2).

Usage: python benchmarks/ur10_real_bench.py [--series C] [--data DIR] [--quick] [--no-peer]
       [--out-model PATH] [--figaroh PYTHON]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from calbench.bench.model import Robot
from calbench.bench.shopfloor import read_probe_series, read_transform, series_files
from calbench.identify.discover import discover_geometry, geometric_problem
from calbench.identify.geometry import (
    MODELS,
    UR10_DH,
    calibrate,
    initial_model,
    load_arm,
    split,
    tool_from_transform,
    ur10,
    validate,
    write_chain_mjcf,
)

ROOT = Path(__file__).resolve().parent.parent
# The reference (another public dataset of a six-axis arm, ~500 poses, 30 % held out)
REFERENCE_MM = {"nominal": 2.32, "geometry": 1.59, "geometry+compliance": 0.66}


def find_data() -> Path:
    for up in (ROOT.parent, ROOT.parent.parent):
        if (up / "shared/data/ipa-robot-accuracy").is_dir():
            return up / "shared/data/ipa-robot-accuracy"
    raise SystemExit(
        "the dataset is not here: clone github.com/christianlandgraf/ipa-robot-accuracy, pass --data"
    )


def stats(err: np.ndarray) -> dict[str, float]:
    d = np.linalg.norm(err, axis=1) * 1e3
    return {"mean_mm": d.mean(), "rms_mm": float(np.sqrt(np.mean(d**2))), "max_mm": d.max()}


def pybotics_peer(q_fit, y_fit, q_val, y_val, base0, tool) -> dict:
    """pybotics as its users calibrate: MDH chain, probe position and world frame by least_squares."""
    from pybotics.optimization import OptimizationHandler, compute_absolute_errors, optimize_accuracy
    from pybotics.robot import Robot
    from pybotics.tool import Tool
    from scipy.optimize import least_squares

    # standard DH (theta, d, a, alpha) -> MDH rows (alpha_(i-1), a_(i-1), theta_i, d_i), in mm
    mdh, prev = [], (0.0, 0.0)
    for theta, d, a, alpha in UR10_DH:
        mdh.append([prev[0], prev[1] * 1e3, theta, d * 1e3])
        prev = (alpha, a)
    robot = Robot.from_parameters(np.array(mdh))
    robot.world_frame = np.array(base0) * np.array([1, 1, 1, 1e3])[None, :]  # translation in mm
    robot.world_frame[3] = [0, 0, 0, 1]
    tool_m = Tool()
    tool_m.position = np.asarray(tool) * 1e3
    robot.tool = tool_m
    handler = OptimizationHandler(
        robot, kinematic_chain_mask=True, tool_mask=[True, True, True, False, False, False], world_mask=True
    )
    x0 = handler.generate_optimization_vector()
    t0 = time.perf_counter()
    sol = least_squares(optimize_accuracy, x0, args=(handler, q_fit, y_fit * 1e3), method="lm")
    seconds = time.perf_counter() - t0
    handler.apply_optimization_vector(sol.x)
    d = compute_absolute_errors(q_val, y_val * 1e3, handler.robot)
    return {
        "mean_mm": float(d.mean()),
        "rms_mm": float(np.sqrt(np.mean(d**2))),
        "max_mm": float(d.max()),
        "parameters": int(len(x0)),
        "seconds": seconds,
    }


def figaroh_peer(python: str, chain, tool, q_fit, y_fit, q_val, y_val) -> dict:
    """benchmarks/ur10_figaroh_peer.py in FIGAROH's own Python, on the same split and points."""
    with tempfile.TemporaryDirectory() as work:
        split_file = Path(work) / "split.npz"
        np.savez(
            split_file, frames=chain.frames, joints=np.array(chain.joints), mass=chain.mass, com=chain.com,
            tool=tool, q_fit=q_fit, y_fit=y_fit, q_val=q_val, y_val=y_val,
        )  # fmt: skip
        run = subprocess.run(
            [python, str(ROOT / "benchmarks" / "ur10_figaroh_peer.py"), str(split_file)],
            capture_output=True, text=True, cwd=work, timeout=1800,
        )  # fmt: skip
    if run.returncode:
        return {"figaroh": {"failed": run.stderr.strip().splitlines()[-1:]}}
    return json.loads(run.stdout.strip().splitlines()[-1])


def discover_rows(chain, tool, s, q, y, fit_rows, val_rows, quick: bool) -> dict:
    """`discover --geometry` from the nominal model on the fitted rows (identify/discover/geometric.py,
    sigma the rows' RMS std; series A has none: 20 um), each step's model predicting the
    held-out rows; then a thermal check of the final model: its linearised fit with a term linear in
    the ambient temperature added (a drift of the readings, 3 numbers; a scale about the robot's
    base, 1 number), held out the same way."""
    with tempfile.TemporaryDirectory() as work:
        path = write_chain_mjcf(Path(work) / "ur10.xml", chain, tool, name="ur10")
        arm, robot = load_arm(path), Robot.from_file(path)
    # one sigma, the rows' RMS std: the readings' own std (1-10 um) would weigh rows by the
    # tracker's repeatability, while the misfit (0.3 mm) is the model's, the same for every row
    sigma = float(np.sqrt(np.mean(s.position_std**2))) if s.position_std is not None else 20e-6
    t0 = time.perf_counter()
    start, data, cands = geometric_problem(arm, robot, "probe", q[fit_rows], y[fit_rows], sigma)
    rep, fits = discover_geometry(start, data, cands)
    seconds = time.perf_counter() - t0
    out = {}
    for label, f in fits:
        v = validate(f.fit, q[val_rows], y[val_rows])
        out[f"discover: {label}"] = {
            "mean_mm": v.mean * 1e3, "rms_mm": v.rms * 1e3, "max_mm": v.max * 1e3,
            "fit_rms_mm": f.fit.rms * 1e3, "parameters": len(f.fit.free),
        }  # fmt: skip
    out[f"discover: {fits[-1][0]}"]["seconds"] = seconds
    out["discover: named"] = {"named": [label for label, _ in fits[1:]], "verdict": rep["named_effects"][-1:],
                              "dropped": rep["dropped"]}  # fmt: skip
    final = fits[-1][1].fit
    temp = s.temperature[::4] if quick else s.temperature
    out["discover + temperature (linearised)"] = thermal_check(final, q, y, temp, fit_rows, val_rows)
    return out


def thermal_check(fit, q, y, temp, fit_rows, val_rows) -> dict:
    """Held-out RMS (mm) of the fit's Gauss-Newton step with temperature terms added (docstring of
    :func:`discover_rows`)."""
    _, jac = fit.model.jacobian(q, fit.theta, fit.model.torques_at(q, fit.theta) if fit.own_torques else None)
    jac = jac[:, :, list(fit.free)]
    r = y - fit.predict(q)
    dt = temp - temp[fit_rows].mean()
    drift = np.zeros((len(q), 3, 3))
    for a in range(3):
        drift[:, a, a] = dt
    scale = (dt[:, None] * (y - fit.model.base0[:3, 3]))[:, :, None]
    res = {}
    for name, extra in (("drift", drift), ("scale", scale)):
        a = np.concatenate([jac, extra], axis=2)
        step = np.linalg.lstsq(a[fit_rows].reshape(-1, a.shape[2]), r[fit_rows].ravel(), rcond=None)[0]
        d = np.linalg.norm(r[val_rows] - (a[val_rows].reshape(-1, a.shape[2]) @ step).reshape(-1, 3), axis=1)
        res[f"{name}_rms_mm"] = float(np.sqrt(np.mean(d**2)) * 1e3)
    res["temperature_range_K"] = float(np.ptp(temp))
    return res


def run(
    series: str, data: Path, quick: bool, peer: bool, out_model: Path | None = None, figaroh=None
) -> dict:
    chain = ur10()
    csv, transform = series_files(data / f"Series_{series}")
    s = read_probe_series(csv, chain.joints)
    q, y = s.q, s.position
    if quick:  # every 4th row: the same robot and station, a quarter of the work
        q, y = q[::4], y[::4]
    fit_rows, val_rows = split(len(q), 0.7, seed=0)
    tool = tool_from_transform(read_transform(transform))
    start = initial_model(chain, q[fit_rows], y[fit_rows], tool)
    out: dict = {"series": series, "file": csv.name, "fit": len(fit_rows), "held_out": len(val_rows)}
    models = {}
    for name, effects in MODELS.items():
        t0 = time.perf_counter()
        fit = calibrate(start, q[fit_rows], y[fit_rows], effects)
        seconds = time.perf_counter() - t0
        v = validate(fit, q[val_rows], y[val_rows])
        models[name] = {
            "mean_mm": v.mean * 1e3,
            "rms_mm": v.rms * 1e3,
            "max_mm": v.max * 1e3,
            "fit_rms_mm": fit.rms * 1e3,
            "parameters": len(fit.free),
            "seconds": seconds,
        }
        if name == "geometry+compliance" and out_model is not None:
            chain_c, tool_c, base_c, comp = fit.calibrated()
            write_chain_mjcf(out_model, chain_c, tool_c, name="ur10_calibrated", compliance=comp)
            out["out_model"] = str(out_model)
            out["tracker_from_base"] = base_c.tolist()
        if name == "geometry+compliance":
            models[name]["compliance_urad_per_Nm"] = {
                n.split(".")[0]: [fit.theta[i] * 1e6, sd * 1e6]
                for n, i, sd in zip(fit.names, fit.free, fit.std, strict=True)
                if n.endswith(".compliance")
            }
    models.update(discover_rows(chain, tool, s, q, y, fit_rows, val_rows, quick))
    if peer:
        try:
            models["pybotics"] = pybotics_peer(
                q[fit_rows], y[fit_rows], q[val_rows], y[val_rows], start.base0, tool
            )
        except ImportError as e:
            models["pybotics"] = {"skipped": f"not installed ({e.name}): pip install pybotics"}
    if figaroh:
        models.update(figaroh_peer(figaroh, chain, tool, q[fit_rows], y[fit_rows], q[val_rows], y[val_rows]))
    out["models"] = models
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--series", default="C", help="A, B, C or D (default C, 2773 random poses)")
    ap.add_argument("--data", type=Path, default=None)
    ap.add_argument("--quick", action="store_true", help="every 4th row")
    ap.add_argument("--no-peer", action="store_true")
    ap.add_argument(
        "--out-model",
        type=Path,
        default=None,
        help="write the calibrated UR10 (geometry+compliance) as an MJCF",
    )
    ap.add_argument(
        "--figaroh",
        default=None,
        metavar="PYTHON",
        help="a Python with FIGAROH installed: run benchmarks/ur10_figaroh_peer.py in it on the same split",
    )
    a = ap.parse_args()
    data = a.data or find_data()
    if data is None:  # a clone: the data are not shipped (make bench runs on)
        print(
            json.dumps(
                {"skipped": "no dataset: clone github.com/christianlandgraf/ipa-robot-accuracy, pass --data"}
            )
        )
        return
    report = run(a.series, data, a.quick, not a.no_peer, a.out_model, a.figaroh)
    report["reference_rms_mm"] = {
        "values": REFERENCE_MM,
        "source": "issue 25: an independent calibration of another public six-axis dataset (not this one)",
    }
    if not a.figaroh:
        report["figaroh"] = (
            "not run: pass --figaroh PYTHON, a Python with `pip install figaroh` (docs/geometry.md)"
        )
    print(json.dumps(report, indent=1, default=float))


if __name__ == "__main__":
    main()
