"""The cost of fitting geometry on robots with a loop or a spring (docs/geometry.md, issue 25).

The FANUC M-900iB/700 (parallelogram, balancer) and the KR 270 (balancer), each a bench campaign
per seed: --poses random commands, the reflector's unloaded readings by a 20 um tracker, the truth
(bench/campaign: MjSpec edits, the bench's statics) with joint offsets on joints 2-5 (0.5-1.5 mrad,
1-3 mm at the reflector), one wrist body's frame off by 1-2 mm and 0.5-1 mrad, the paper's
compliances times 0.7-1.3 and the realistic balancer (scenarios/*balancer_realistic.toml) times
0.8-1.2. Each campaign is fitted twice on the same readings with identify/geometry/statics.py:
* complete: identify --geometry's model (registration, probe, offsets, link frames, compliances,
  the balancer's K_C and P = K_C s0);
* geometry known: the geometric parameters held at the truth, the registration, the compliances
  and the balancer fitted.
For each compliance and spring parameter: z = (estimate - truth) / reported std, its mean and std
over the seeds (unbiased: mean within ~2/sqrt(seeds); honest: std near 1), and the std price
(the complete fit's reported std over the geometry-known one's, mean over seeds). Prints JSON;
progress on stderr.

Usage: python benchmarks/geometry_statics_bench.py [--seeds N] [--poses N] [--robots m900ib700,kr270] [--quick]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from calbench.bench.campaign import plan_campaign, truth_robot
from calbench.bench.model import Robot
from calbench.bench.scenario import parse_scenario
from calbench.bench.tracker import to_tracker_frame
from calbench.identify.geometry import MODELS, base_set, calibrate, kind, rank_rule, statics_model

MJCF = Path(__file__).resolve().parent.parent / "mjcf"
SIGMA = 20e-6
ROBOTS = {  # reflector, compliances (rad/(N*m)), spring table, K_C, s0, command ranges (deg), wrist bodies
    "m900ib700": ("refl_a", [0.25e-6, 0.12e-6, 0.07e-6, 0.35e-6, 0.40e-6, 0.60e-6], "[truth.compensator]",
                  7.06e4, 0.6261, [-90, 5, -30, -150, -100, -150], [90, 100, 15, 150, 100, 150],
                  ("link4", "link5", "link6")),
    "kr270": ("smr_left", [0.25e-6, 0.16e-6, 0.35e-6, 1.6e-6, 1.4e-6, 2.0e-6], "[truth.compensators.balancer]",
              6.86e4, 0.1124, [-100, -120, -60, -150, -100, -150], [100, -20, 100, 150, 100, 150],
              ("wrist_a4", "wrist_a5", "wrist_a6")),
}  # fmt: skip


def campaign(name: str, n: int, rng):
    """(commands, true readings, truth: compliances, K_C, s0, offsets, link body and frame)."""
    refl, comp, table, kc, s0, lo, hi, wrists = ROBOTS[name]
    path = MJCF / f"{name}.xml"
    robot = Robot.from_file(path)
    poses = []
    while len(poses) < n:
        q = rng.uniform(lo, hi)
        if not robot.loops or np.all(robot.loop_conditioning(np.radians(q)) > 0.3):
            poses.append(q)
    truth = {
        "compliance": np.asarray(comp) * rng.uniform(0.7, 1.3, 6),
        "kc": kc * rng.uniform(0.8, 1.2),
        "s0": s0 * rng.uniform(0.95, 1.05),
        "offset": np.r_[0.0, rng.choice([-1, 1], 4) * rng.uniform(0.5e-3, 1.5e-3, 4), 0.0],
        "link": str(rng.choice(wrists)),
        "frame": rng.choice([-1, 1], 6) * np.r_[rng.uniform(1e-3, 2e-3, 3), rng.uniform(0.5e-3, 1e-3, 3)],
    }
    lines = [f'robot = "{path}"', "seed = 0", "[truth]", f"compliance = {truth['compliance'].tolist()}"]
    lines += [table, f"stiffness = {truth['kc']}", f"preload = {truth['s0']}"]
    lines += ["[truth.effects.joint_offset]", f"offset = {truth['offset'].tolist()}"]
    lines += [
        "[truth.effects.link_geometry]",
        f'link = "{truth["link"]}"',
        f"offset = {truth['frame'].tolist()}",
    ]
    lines += ["[tracker]", f"sigma = {SIGMA}", "position = [3.5, -3.5, 3.2]", "[load]", "mass = 100.0"]
    for q in poses:
        lines += ["[[pose]]", "q = [" + ", ".join(f"{v:.4f}" for v in q) + "]"]
    scn = parse_scenario("\n".join(lines) + "\n", MJCF / "geometry_statics_bench.toml")
    rb = truth_robot(scn)
    plans = plan_campaign(scn, rb)
    i = rb.reflector_names.index(refl)
    y = to_tracker_frame(scn.tracker, np.array([p.reflectors_world[0, i] for p in plans]))
    return np.array([p.q for p in plans]), y, truth


def truth_vector(model, truth: dict) -> np.ndarray:
    """The truth in the model's vector, the registration at zero."""
    theta = np.zeros(model.size)
    theta[model.lay.offset] = truth["offset"]
    theta[model.lay.compliance] = truth["compliance"] - model.compliance0
    theta[model.lay.spring] = [truth["kc"], truth["kc"] * truth["s0"]]
    k = model.bodies.index(truth["link"])
    theta[model.lay.link.start + 6 * k : model.lay.link.start + 6 * k + 6] = truth["frame"]
    return theta


def one(name: str, n: int, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    q, y0, truth = campaign(name, n, rng)
    y = y0 + rng.normal(0, SIGMA, y0.shape)
    model = statics_model(MJCF / f"{name}.xml", None, ROBOTS[name][0], q, y, name)
    t0 = time.perf_counter()
    complete = calibrate(model, q, y, MODELS["geometry+compliance"], sigma=SIGMA)
    seconds = time.perf_counter() - t0
    true = truth_vector(model, truth)
    # geometry known: the geometric parameters at the truth, the rest's base set fitted
    _, jac = model.jacobian(q, true)
    free = base_set(jac, model.names, ("base_frame", "joint_compliance", "compensator"), rank_rule(model))
    start = true.copy()
    start[list(free)] = 0.0  # from the generic start, as the complete fit
    known = calibrate(model, q, y, sigma=SIGMA, free=free, theta0=start)
    out: dict = {"seed": seed, "chi2_dof": complete.chi2 / (y.size - len(complete.free)), "seconds": seconds}
    for label, fit in (("complete", complete), ("known", known)):
        for nm, i, sd in zip(fit.names, fit.free, fit.std, strict=True):
            if kind(nm) in ("joint_compliance", "compensator"):
                out.setdefault(nm, {})[label] = {"z": float((fit.theta[i] - true[i]) / sd), "std": float(sd)}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--poses", type=int, default=40)
    ap.add_argument("--robots", default="m900ib700,kr270")
    ap.add_argument("--quick", action="store_true", help="2 seeds of 20 poses on the KR 270 only")
    a = ap.parse_args()
    if a.quick:
        a.seeds, a.poses, a.robots = 2, 20, "kr270"
    report: dict = {"poses": a.poses, "seeds": a.seeds, "sigma_m": SIGMA, "robots": {}}
    for name in a.robots.split(","):
        runs = []
        for seed in range(a.seeds):
            runs.append(one(name, a.poses, seed))
            print(f"{name} seed {seed}: chi2/dof {runs[-1]['chi2_dof']:.3f}, {runs[-1]['seconds']:.0f} s",
                  file=sys.stderr)  # fmt: skip
        params: dict = {}
        for nm in sorted({k for r in runs for k in r if isinstance(r[k], dict)}):
            both = [r[nm] for r in runs if nm in r and {"complete", "known"} <= set(r[nm])]
            if not both:
                continue
            zc = np.array([b["complete"]["z"] for b in both])
            zk = np.array([b["known"]["z"] for b in both])
            params[nm] = {
                "n": len(both),
                "complete_z_mean": float(zc.mean()), "complete_z_std": float(zc.std(ddof=1)) if len(zc) > 1 else None,
                "known_z_mean": float(zk.mean()), "known_z_std": float(zk.std(ddof=1)) if len(zk) > 1 else None,
                "std_price": float(np.mean([b["complete"]["std"] / b["known"]["std"] for b in both])),
                "std_complete": float(np.mean([b["complete"]["std"] for b in both])),
            }  # fmt: skip
        report["robots"][name] = {
            "chi2_dof": [r["chi2_dof"] for r in runs],
            "fit_seconds": float(np.mean([r["seconds"] for r in runs])),
            "parameters": params,
        }
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
