"""Statics benchmark: our Newton-KKT equilibrium against relaxing with mj_step, same model.

Prints JSON: median time per equilibrium, a whole 16-pose loaded/unloaded campaign (physics
plus noise plus MCAP writing), and, side by side in this process, the time mj_step relaxation
needs to reach the same tolerance on the same poses, their ratio, and the loop-closure
violation of both (ours is hard, MuJoCo's soft).

Batched (issue 16): the same equilibria for many configurations at once
(bench/statics/batched.py: the scenario's 16 poses repeated to --batch configurations, unloaded
cold and loaded warm from them), per equilibrium, on 1 and 2 threads; and relaxation batched the
same way (mujoco.batch steps 10 at a time, the load as xfrc_applied refreshed between them, each
configuration dropped once converged), so that the lead is shown both against today's
relaxation loop and against relaxation given the same batching. Times are CPU seconds of this
process where marked ``cpu`` (robust to other load on the machine) and wall seconds otherwise;
the load average is recorded. And the estimator's forward model, whose warm evaluations run
stacked the same way, in a Monte Carlo of the one-step estimator against its scalar loop.
Usage: python benchmarks/statics_bench.py [--batch 1024] [--mc-runs 200] [--quick]
(--quick: 2 relaxations, one campaign, a batch of 64, 20 Monte Carlo runs).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from pathlib import Path

import mujoco
import numpy as np

ROOT = Path(__file__).resolve().parent.parent

from steps import say

from calbench.bench.campaign import run_campaign, truth_robot
from calbench.bench.model import loop_gap
from calbench.bench.scenario import load_scenario
from calbench.bench.statics import BatchStatics, Load, StaticsSolver

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
    t, c = time.perf_counter(), time.process_time()
    steps = 0
    for steps in range(1, max_steps + 1):
        d.qfrc_applied[:] = 0.0
        mujoco.mj_applyFT(
            m, d, load.force, load.moment, d.site_xpos[load.site], m.site_bodyid[load.site], d.qfrc_applied
        )
        mujoco.mj_step(m, d)
        if steps % 10 == 0:
            err = np.linalg.norm(d.site_xpos[robot.flange_site] - target)
            if err < tol and np.abs(d.qvel).max() < 1e-6:
                break
    elapsed, cpu = time.perf_counter() - t, time.process_time() - c
    gap = float(np.linalg.norm(loop_gap(robot, d)[0]))
    err = float(np.linalg.norm(d.site_xpos[robot.flange_site] - target))
    m.dof_damping[:] = 0.0
    m.opt.disableflags &= ~int(mujoco.mjtDisableBit.mjDSBL_LIMIT)
    return elapsed, steps, gap, err, cpu


def batched_newton(robot, scn, n: int, nthread: int) -> dict:
    """Unloaded (cold) and loaded (warm, the exact matrix at the unloaded one) equilibria of the
    scenario's poses repeated to n configurations; best of 3."""
    poses = [scn.poses[i % len(scn.poses)] for i in range(n)]
    q = np.array([p.q for p in poses])
    loads = [truth_load(robot, scn, p) for p in poses]
    load = Load(
        np.array([ld.force for ld in loads]), np.array([ld.moment for ld in loads]), robot.payload_site
    )
    bs = BatchStatics(StaticsSolver(robot), nsim=n, nthread=nthread)
    best = None
    for _ in range(3):
        w, c = time.perf_counter(), time.process_time()
        e0 = bs.solve(q)
        e1 = bs.solve(q, load, warm=e0, warm_stiffness=bs.stiffness(e0, None))
        w, c = time.perf_counter() - w, time.process_time() - c
        if best is None or w < best[0]:
            best = (w, c)
    return {
        "configurations": n,
        "threads": nthread,
        "equilibria": 2 * n,
        "per_equilibrium_ms": best[0] / (2 * n) * 1e3,
        "per_equilibrium_cpu_ms": best[1] / (2 * n) * 1e3,
        "all_acceptable": bool(e0.acceptable.all() and e1.acceptable.all()),
        "loop_violation_max_m": float(max(e0.loop_violation.max(), e1.loop_violation.max())),
        "iterations_median": [float(np.median(e0.iterations)), float(np.median(e1.iterations))],
    }


def batched_relax(robot, scn, sols, n: int, nthread: int, tol=1e-6, max_steps=20000) -> dict:
    """relax() on a mujoco.batch: the loaded poses of ``sols`` repeated to n configurations,
    10 steps per call, the load as xfrc_applied (force at the site, moved to the body's centre
    of mass) refreshed between calls; a configuration stops once its flange is within tol of
    the Newton solution and at rest (the scalar loop's criterion)."""
    import mujoco.batch

    m = robot.model
    saved = m.dof_damping.copy(), m.opt.disableflags
    m.dof_damping[:] = 4.0e5
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_LIMIT)
    try:
        b = mujoco.batch.Batch(m, n, nthread)
    finally:
        m.dof_damping[:], m.opt.disableflags = saved
    spring = b.expand("qpos_spring")
    qpos, qvel, xfrc = b.bind("qpos"), b.bind("qvel"), b.bind("xfrc_applied")
    site_x, com = b.bind("site_xpos"), b.bind("xipos")
    picks = [sols[i % len(sols)] for i in range(n)]
    targets = np.array([flange(robot, e1.qpos) for _, _, e1 in picks])
    for i, (pose, _, _) in enumerate(picks):
        spring[i, robot.act_qpos] = pose.q
        qpos[i] = robot.rigid_qpos(pose.q)
    qvel[:] = 0.0
    body = int(m.site_bodyid[picks[0][1].site])
    force = np.array([ld.force for _, ld, _ in picks])
    moment = np.array([ld.moment for _, ld, _ in picks])
    b.forward(stage=mujoco.mjtStage.mjSTAGE_POS)
    ids = np.arange(n)
    steps = np.zeros(n, int)
    w, c = time.perf_counter(), time.process_time()
    while len(ids) and steps[ids[0]] < max_steps:
        lever = site_x[ids, picks[0][1].site] - com[ids, body]
        xfrc[ids, body, :3] = force[ids]
        xfrc[ids, body, 3:] = np.cross(lever, force[ids]) + moment[ids]
        b.step(ids, nstep=10, stage=mujoco.mjtStage.mjSTAGE_POS)
        steps[ids] += 10
        err = np.linalg.norm(site_x[ids, robot.flange_site] - targets[ids], axis=1)
        ids = ids[~((err < tol) & (np.abs(qvel[ids]).max(axis=1) < 1e-6))]
    w, c = time.perf_counter() - w, time.process_time() - c
    err = np.linalg.norm(site_x[:, robot.flange_site] - targets, axis=1)
    return {
        "configurations": n,
        "threads": nthread,
        "per_equilibrium_ms": w / n * 1e3,
        "per_equilibrium_cpu_ms": c / n * 1e3,
        "median_steps": float(np.median(steps)),
        "converged": bool(len(ids) == 0),
        "flange_error_max_m": float(err.max()),
    }


def monte_carlo(scn, runs: int, repeats: int = 2) -> dict:
    """The estimator's forward model (identify/core/forward.py: 16 poses, 32 warm equilibria and their
    tangents per evaluation) stacked against its scalar loop, side by side: a Monte Carlo of the
    one-step estimator (one or two evaluations per run), alternating, best of ``repeats``."""
    from calbench.identify.core import ForwardModel
    from calbench.identify.study import run_montecarlo

    best: dict = {}
    for _ in range(repeats):
        for stacked in (False, True):
            ForwardModel.BATCHED = stacked
            la, w, c = os.getloadavg()[0], time.perf_counter(), time.process_time()
            mc = run_montecarlo(scn, runs, methods=("one-step",), progress=False)
            r = {
                "wall_s": time.perf_counter() - w,
                "cpu_s": time.process_time() - c,
                "load_average": la,
                "one_step_s": mc.times["one-step"],
            }
            key = "stacked" if stacked else "scalar"
            if key not in best or r["wall_s"] < best[key]["wall_s"]:
                best[key] = r
    ForwardModel.BATCHED = True
    return {
        "runs": runs,
        **best,
        "ratio_cpu": best["scalar"]["cpu_s"] / best["stacked"]["cpu_s"],
        "ratio_one_step_s": best["scalar"]["one_step_s"] / best["stacked"]["one_step_s"],
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--batch", type=int, default=1024, help="configurations of the batched runs")
    ap.add_argument(
        "--mc-runs", type=int, default=200, help="Monte Carlo runs, stacked vs scalar forward model"
    )
    ap.add_argument(
        "--quick", action="store_true", help="2 relaxations, one campaign, a batch of 64, 20 Monte Carlo runs"
    )
    args = ap.parse_args()
    if args.quick:
        args.batch, args.mc_runs = min(args.batch, 64), min(args.mc_runs, 20)
    load_before = os.getloadavg()
    scn = load_scenario(PAPER)
    robot = truth_robot(scn)
    say("statics_bench", "Newton-KKT equilibria")
    times, loops, sols = newton_times(scn, robot)
    relax_times, relax_gaps, relax_errs, relax_steps, relax_cpu = [], [], [], [], []
    newton_same, newton_cpu = [], []
    n_relax = 2 if args.quick else 6
    for k, (pose, load, e1) in enumerate(sols[:n_relax]):
        say("statics_bench", f"mj_step relaxation {k + 1}/{n_relax}")
        target = flange(robot, e1.qpos)
        t, steps, gap, err, cpu = relax(robot, pose.q, load, target)
        relax_times.append(t)
        relax_cpu.append(cpu)
        relax_gaps.append(gap)
        relax_errs.append(err)
        relax_steps.append(steps)
        solver = StaticsSolver(robot)
        t0, c0 = time.perf_counter(), time.process_time()
        e0 = solver.solve(pose.q)
        solver.solve(pose.q, load, warm=e0)
        newton_same.append(time.perf_counter() - t0)
        newton_cpu.append(time.process_time() - c0)
    with tempfile.TemporaryDirectory() as tmp:
        campaign = []
        say("statics_bench", "whole campaigns")
        for _ in range(1 if args.quick else 3):
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
    say("statics_bench", f"batched equilibria, {args.batch} configurations")
    batched = {f"newton_{t}_threads": batched_newton(robot, scn, args.batch, t) for t in (1, 2)}
    batched.update(
        {f"relaxation_{t}_threads": batched_relax(robot, scn, sols, args.batch, t) for t in (1, 2)}
    )
    # the lead, per equilibrium, in wall and in CPU seconds (the CPU ratio is the one that does
    # not move with the machine's load, the runs being seconds apart)
    relax_ms = {"wall": med_relax * 1e3, "cpu": statistics.median(relax_cpu) * 1e3}
    scalar_ms = {
        "wall": statistics.median(newton_same) / 2 * 1e3,
        "cpu": statistics.median(newton_cpu) / 2 * 1e3,
    }
    lead = {}
    for clock, key in (("wall", "per_equilibrium_ms"), ("cpu", "per_equilibrium_cpu_ms")):
        lead[clock] = {"relaxation_loop_over_scalar_newton": relax_ms[clock] / scalar_ms[clock]}
        for t in (1, 2):
            nt = batched[f"newton_{t}_threads"][key]
            lead[clock][f"relaxation_loop_over_batched_newton_{t}_threads"] = relax_ms[clock] / nt
            lead[clock][f"batched_relaxation_over_batched_newton_{t}_threads"] = (
                batched[f"relaxation_{t}_threads"][key] / nt
            )
    out["batched"] = batched
    out["lead_over_relaxation"] = lead
    say("statics_bench", f"Monte Carlo forward model, {args.mc_runs} runs")
    out["monte_carlo_forward_model"] = monte_carlo(scn, args.mc_runs)
    out["load_average"] = {"before": list(load_before), "after": list(os.getloadavg())}
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
