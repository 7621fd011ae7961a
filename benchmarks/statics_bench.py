"""Statics benchmark: our Newton-KKT equilibrium against relaxing with mj_step, same model.

Prints JSON: median time per equilibrium, a whole 16-pose loaded/unloaded campaign (physics
plus noise plus MCAP writing), and, side by side in this process, the time mj_step relaxation
needs to reach the same tolerance on the same poses, their ratio, and the loop-closure
violation of both (ours is hard, MuJoCo's soft). Usage: python benchmarks/statics_bench.py
"""
from __future__ import annotations

import json
import statistics
import tempfile
import time
from pathlib import Path

import mujoco
import numpy as np

ROOT = Path(__file__).resolve().parent.parent

from calbench.bench.campaign import run_campaign, truth_robot
from calbench.bench.loop import loop_gap
from calbench.bench.scenario import load_scenario
from calbench.bench.statics import StaticsSolver

PAPER = ROOT / "scenarios" / "paper_table5.toml"


def newton_times(scn, robot, repeats=5):
    solver = StaticsSolver(robot)
    times, loops, sols = [], [], []
    for _ in range(repeats):
        for pose in scn.poses:
            load = truth_load(robot, scn, pose)
            t = time.perf_counter()
            e0 = solver.solve(pose.q)
            t1 = time.perf_counter()
            e1 = solver.solve(pose.q, load, warm=e0)
            t2 = time.perf_counter()
            times += [t1 - t, t2 - t1]
            loops += [e0.loop_violation, e1.loop_violation]
            if len(sols) < len(scn.poses):
                sols.append((pose, load, e1))
    return times, loops, sols


def truth_load(robot, scn, pose):
    from calbench.bench.campaign import pose_load

    return pose_load(robot, scn, pose)[0]


def flange(robot, qpos):
    robot.data.qpos[:] = qpos
    mujoco.mj_kinematics(robot.model, robot.data)
    return robot.data.site_xpos[robot.flange_site].copy()


def relax(robot, q, load, target, tol=1e-6, max_steps=20000):
    """mj_step with heavy damping and the soft loop until the flange is within tol of target
    (the Newton solution) and at rest. Returns (seconds, steps, loop gap, flange error)."""
    m, d = robot.model, robot.data
    m.dof_damping[:] = 4.0e5
    # joint ranges are controller limits, not stops: the statics ignore them, so must this
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_LIMIT)
    robot.set_command(q)
    d.qpos[:] = robot.rigid_qpos(q)
    d.qvel[:] = 0.0
    mujoco.mj_forward(m, d)
    t = time.perf_counter()
    steps = 0
    for steps in range(1, max_steps + 1):
        d.qfrc_applied[:] = 0.0
        mujoco.mj_applyFT(m, d, load.force, load.moment, d.site_xpos[load.site], m.site_bodyid[load.site], d.qfrc_applied)
        mujoco.mj_step(m, d)
        if steps % 10 == 0:
            err = np.linalg.norm(d.site_xpos[robot.flange_site] - target)
            if err < tol and np.abs(d.qvel).max() < 1e-6:
                break
    elapsed = time.perf_counter() - t
    gap = float(np.linalg.norm(loop_gap(robot, d)[0]))
    err = float(np.linalg.norm(d.site_xpos[robot.flange_site] - target))
    m.dof_damping[:] = 0.0
    m.opt.disableflags &= ~int(mujoco.mjtDisableBit.mjDSBL_LIMIT)
    return elapsed, steps, gap, err


def main() -> None:
    scn = load_scenario(PAPER)
    robot = truth_robot(scn)
    times, loops, sols = newton_times(scn, robot)
    relax_times, relax_gaps, relax_errs, relax_steps = [], [], [], []
    newton_same = []
    for pose, load, e1 in sols[:6]:
        target = flange(robot, e1.qpos)
        t, steps, gap, err = relax(robot, pose.q, load, target)
        relax_times.append(t)
        relax_gaps.append(gap)
        relax_errs.append(err)
        relax_steps.append(steps)
        solver = StaticsSolver(robot)
        t0 = time.perf_counter()
        e0 = solver.solve(pose.q)
        solver.solve(pose.q, load, warm=e0)
        newton_same.append(time.perf_counter() - t0)
    with tempfile.TemporaryDirectory() as tmp:
        campaign = []
        for _ in range(3):
            t = time.perf_counter()
            run_campaign(scn, Path(tmp) / "bench.mcap")
            campaign.append(time.perf_counter() - t)
    med_newton = statistics.median(times)
    med_relax = statistics.median(relax_times)
    out = {
        "equilibrium_median_ms": med_newton * 1e3,
        "equilibrium_p90_ms": float(np.percentile(times, 90)) * 1e3,
        "campaign_16_poses_s": statistics.median(campaign),
        "loop_violation_max_m": max(loops),
        "baseline_mj_step_relaxation": {
            "median_ms": med_relax * 1e3,
            "median_steps": statistics.median(relax_steps),
            "tolerance_m": 1e-6,
            "flange_error_max_m": max(relax_errs),
            "soft_loop_gap_max_m": max(relax_gaps),
            "converged": bool(max(relax_errs) < 1e-6),
        },
        "speedup_vs_relaxation": med_relax / (statistics.median(newton_same) / 2),
        "targets": {"equilibrium_ms": 1.0, "speedup": 50.0},
    }
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
