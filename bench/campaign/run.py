"""A calibration campaign's log: the campaign simulated, then written pose by pose.

All statics are solved and every pose is checked (limits, reach, visibility) BEFORE the log is
opened, so bad input leaves no output file; the readings come from bench/campaign/simulation.py
(the one code path that draws the noise: one generator seeded by the scenario, or --seed,
consumed in plan order, so the same scenario and seed give the same log, byte for byte) and are
written pose by pose, each pose made durable on disk before the next begins (a crash loses at
most the pose in progress).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calbench.bench.core import STATES, ProgressSink, sink
from calbench.bench.log import FoxgloveWriter, LogWriter, read_log
from calbench.bench.model import Robot
from calbench.bench.scenario import Scenario

from .plan import check_campaign_size, truth_params, truth_robot
from .simulation import Campaign, simulate


def truth_record(scn: Scenario, robot: Robot) -> dict:
    d = truth_params(scn, robot).as_dict()
    d["effects"] = {
        name: {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in e.items()}
        for name, e in scn.effects.items()
    }
    return d


def run_campaign(
    scn: Scenario, out: str | Path, progress: ProgressSink | None = None, force: bool = False
) -> Campaign:
    """Simulate the whole campaign (:func:`simulate` with the generator seeded by the scenario's
    seed) into one MCAP log at `out`; returns the campaign. ``progress``
    (bench/core/progress.py) hears of every solved and every measured pose. A campaign beyond
    bench/scenario/timeline.py's size limits is refused (InputError) unless ``force``."""
    out = Path(out)
    robot = truth_robot(scn)
    if not force:
        check_campaign_size(scn, robot)
    n = len(scn.poses)
    progress = sink(progress)
    progress.start(2 * n)
    # raises before any file exists
    campaign = simulate(scn, np.random.default_rng(scn.seed), robot=robot, progress=progress, force=True)
    out.parent.mkdir(parents=True, exist_ok=True)
    plans = campaign.plans
    names = robot.reflector_names
    with LogWriter(out, campaign.header) as log:
        log.truth_parameters(truth_record(scn, robot))
        fox = FoxgloveWriter(log, Robot.from_file(scn.robot), robot, scn.tracker, names)
        fox.start(n, plans[0].q if plans else np.zeros(robot.n_act))
        for plan in plans:
            readings: tuple[list, list] = ([], [])
            for s, state in enumerate(STATES):  # in causal order, stamped by the log's clock
                if state == "loaded":
                    log.wrench(plan.index, plan.load.force, plan.load.moment, robot.payload_name, plan.mass)
                log.pose(plan.index, state, plan.q)
                for rep, m in enumerate(campaign.pose_readings(plan.index, state)):
                    log.measurement(plan.index, state, rep, names, m.position, m.covariance, m.visible)
                    readings[s].append(m)
                e = plan.equilibria[s]
                log.truth_reflectors(plan.index, state, names, plan.reflectors_world[s])
                log.truth_joints(plan.index, state, e.qpos, e.deflection)
            e0, e1 = plan.equilibria
            fox.pose(
                plan.index,
                plan.q,
                readings,
                (e0.qpos, e1.qpos),
                plan.reflectors_world,
                (e0.deflection, e1.deflection),
            )  # Foxglove's view; the truth on /truth/ only
            log.pose_done(plan.index)
            progress.update(f"measured pose {plan.index + 1}/{n}")
    return campaign


class CampaignInterrupted(KeyboardInterrupt):
    """Ctrl-C (or a SIGTERM made one) during :func:`simulate_to_log`: ``written`` False when no log
    was started (OUT is untouched), else OUT is a finished MCAP log with ``complete`` of
    ``planned`` poses."""

    def __init__(self, written: bool, complete: int = 0, planned: int = 0):
        super().__init__("campaign interrupted")
        self.written, self.complete, self.planned = written, complete, planned


def _stamp(path: Path) -> tuple | None:
    try:
        st = path.stat()
    except OSError:
        return None
    return (st.st_ino, st.st_mtime_ns, st.st_size)


def simulate_to_log(
    scn: Scenario, out: str | Path, progress: ProgressSink | None = None, force: bool = False
) -> Campaign:
    """`calbench simulate`: :func:`run_campaign`, and on Ctrl-C a :class:`CampaignInterrupted`
    saying what is on disk (the writer finishes the log with the poses done so far)."""
    out = Path(out)
    before = _stamp(out)
    try:
        return run_campaign(scn, out, progress=progress, force=force)
    except KeyboardInterrupt:
        if _stamp(out) == before:
            raise CampaignInterrupted(False) from None
        log = read_log(out)
        raise CampaignInterrupted(True, len(log.complete_poses), log.n_poses_planned) from None


__all__ = ["CampaignInterrupted", "run_campaign", "simulate_to_log", "truth_record"]
