"""The cost of fitting geometry with the compliances, from absolute readings (docs/geometry.md).

A UR10 whose truth hides a geometric error (every base-set parameter of the link frames, joint
offsets, probe and base drawn at 1-3 mm or mrad) and joint compliances (3-30 urad/(N*m), the
size series C measures for the shoulder) is "measured" at N random poses with a tracker of
--sigma per axis. For each seed, three fits of the same readings:
* complete: geometry and compliance together (identify --geometry);
* geometry known: the true geometry given, only base, probe and compliances fitted (the
  reference: what the compliances would cost if the geometry were known);
* geometry ignored: the nominal geometry, base, probe and compliances fitted (what a
  compliance-only calibration from absolute readings gets).
Per joint it prints, over the seeds, the mean and std of z = (estimate - truth) / reported std
(unbiased and honest: mean ~0, std ~1), and the std price: the complete fit's reported std over
the geometry-known one's. Prints JSON.

Usage: python benchmarks/geometry_cost_bench.py [--seeds N] [--poses N] [--sigma M] [--quick]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from calbench.identify.geometry import (
    MODELS,
    GeometricModel,
    base_set,
    calibrate,
    kind,
    rot,
    translation,
    ur10,
)

BASE0 = translation([0.4, -3.2, 0.2]) @ rot(2, 1.2)
TOOL = np.array([0.0, 0.0, 0.109])
WITH_COMPLIANCE_ONLY = ("base_frame", "tool_frame", "joint_compliance")


def one_seed(seed: int, n: int, sigma: float) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    chain = ur10()
    model = GeometricModel(chain, BASE0, TOOL)
    q = rng.uniform(-np.pi, np.pi, (n, 6))
    _, jac = model.jacobian(q, np.zeros(model.size))
    truth = np.zeros(model.size)
    for i in base_set(jac, model.names, MODELS["geometry+compliance"]):
        comp = kind(model.names[i]) == "joint_compliance"
        truth[i] = rng.uniform(3e-6, 3e-5) if comp else rng.choice([-1, 1]) * rng.uniform(1e-3, 3e-3)
    tau = model.torques(q)
    y = model.predict(q, truth, tau) + rng.normal(0, sigma, (n, 3))
    comp_idx = [i for i, nm in enumerate(model.names) if kind(nm) == "joint_compliance"]
    geometry_only = truth.copy()
    geometry_only[comp_idx] = 0.0
    true_chain, true_tool, true_base, _ = model.calibrated(geometry_only)
    known = GeometricModel(true_chain, true_base, true_tool)
    out = {}
    for label, start, effects in (
        ("complete", model, MODELS["geometry+compliance"]),
        ("geometry_known", known, WITH_COMPLIANCE_ONLY),
        ("geometry_ignored", model, WITH_COMPLIANCE_ONLY),
    ):
        fit = calibrate(start, q, y, effects, sigma=sigma, tau=tau)  # the torques the readings had
        z, sd = np.full(6, np.nan), np.full(6, np.nan)
        for k, i in enumerate(fit.free):
            if kind(start.names[i]) == "joint_compliance":
                j = start.names[i].rsplit(".", 1)[0]
                col = chain.joints.index(j)
                sd[col] = fit.std[k]
                z[col] = (fit.theta[i] - truth[i]) / fit.std[k]
        out[label], out[label + "_std"] = z, sd
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=50)
    ap.add_argument("--poses", type=int, default=300)
    ap.add_argument("--sigma", type=float, default=20e-6, help="m per axis (default: %(default)s)")
    ap.add_argument("--quick", action="store_true", help="10 seeds")
    a = ap.parse_args()
    seeds = 10 if a.quick else a.seeds
    t0 = time.perf_counter()
    runs = [one_seed(s, a.poses, a.sigma) for s in range(seeds)]
    joints = list(ur10().joints)
    report: dict = {"seeds": seeds, "poses": a.poses, "sigma_m": a.sigma, "joints": {}}
    for col, j in enumerate(joints):
        if all(np.isnan(r["complete"][col]) for r in runs):
            report["joints"][j] = "not identified (no gravity torque)"
            continue
        row = {}
        for label in ("complete", "geometry_known", "geometry_ignored"):
            z = np.array([r[label][col] for r in runs])
            row[label] = {"z_mean": float(np.mean(z)), "z_std": float(np.std(z, ddof=1))}
        price = np.array([r["complete_std"][col] / r["geometry_known_std"][col] for r in runs])
        row["std_price"] = float(np.median(price))
        row["std_urad_per_Nm"] = float(np.median([r["complete_std"][col] for r in runs]) * 1e6)
        report["joints"][j] = row
    report["seconds"] = time.perf_counter() - t0
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
