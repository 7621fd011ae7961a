"""A calibration campaign: pose the robot unloaded and loaded, measure, log.

All statics are solved and every pose is checked (limits, reach, visibility) BEFORE the log is
opened, so bad input leaves no output file; then the measurements are drawn and written pose
by pose, each pose made durable on disk before the next begins (a crash loses at most the pose
in progress). The noise comes from one generator seeded by the scenario (or --seed), consumed
in plan order, so the same scenario and seed give the same log, byte for byte.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import mujoco
import numpy as np

from calbench.bench.core import STATES, InputError, ProgressSink, sink
from calbench.bench.log import FoxgloveWriter, LogHeader, LogWriter, read_log
from calbench.bench.model import LOOP_MARGIN, LOOP_MARGIN_ANGLE, Params, Robot
from calbench.bench.model.effects import Readings, apply_effects, effect_from_truth
from calbench.bench.scenario import (
    Scenario,
    check_joint_limits,
    check_scenario,
    check_size,
    estimate,
    reading_times,
    repeats_key,
)
from calbench.bench.scenario import scenario_params as _scenario_params
from calbench.bench.statics import Equilibrium, Load, StaticsError, StaticsSolver
from calbench.bench.tracker import (
    Measurement,
    measure_campaign,
    to_tracker_frame,
    tracker_rotation,
    visible_sites,
)


@dataclass(frozen=True)
class PosePlan:
    """One pose's solved physics, before any noise: what the campaign will measure."""

    index: int
    q: np.ndarray
    load: Load
    mass: float | None
    equilibria: tuple[Equilibrium, Equilibrium]  # unloaded, loaded
    reflectors_world: np.ndarray  # (2, n, 3) true positions
    visible: np.ndarray  # (2, n) bool


def scenario_params(scn: Scenario, robot: Robot) -> Params:
    """The scenario's truth for this robot (InputError naming a key that does not fit it)."""
    return _scenario_params(scn, robot.n_act, robot.description.compensators)


def truth_robot(scn: Scenario) -> Robot:
    """The simulated (true) robot: the scenario's MJCF with the scenario's truth written in,
    including the hidden `[truth.effects.*]` (bench/model/effects/ edits of the MJCF)."""
    try:
        robot = Robot.from_file(scn.robot)  # the user's model itself must load
    except ValueError as exc:  # MuJoCo compile errors
        raise InputError(scn.path, "robot", "a loadable MJCF robot", f"{scn.robot}: {exc}") from exc
    if scn.effects:
        effects = [effect_from_truth(name, table) for name, table in scn.effects.items()]
        try:
            robot = apply_effects(Path(scn.robot), effects)
        except (ValueError, NotImplementedError) as exc:
            raise InputError(
                scn.path, "truth.effects", "effects that apply to the robot's MJCF", f"{scn.robot}: {exc}"
            ) from exc
    robot.set_params(scenario_params(scn, robot))
    return robot


def reading_drift(scn: Scenario, index: int, reflectors: list[str]) -> np.ndarray | None:
    """(n, 3) m, tracker frame: what the truth's measurement-side effects (bench/model/effects/,
    e.g. `tracker_drift`) add to pose ``index``'s loaded readings of ``reflectors``; None when
    the truth has none. The robot and the noise are untouched."""
    rot = tracker_rotation(scn.tracker)
    total = None
    for name, table in scn.effects.items():
        effect, params = effect_from_truth(name, table)
        if effect.measurement_side:
            term = effect.deflection_term(params, Readings(tuple((index, r) for r in reflectors), rot))
            total = term if total is None else total + term
    return None if total is None else total @ rot  # world -> tracker frame: R^T x


def drifted(m: Measurement, shift: np.ndarray | None) -> Measurement:
    """A reading with the measurement-side shift added (invisible rows stay NaN)."""
    return m if shift is None else replace(m, position=m.position + shift)


def pose_load(robot: Robot, scn: Scenario, pose) -> tuple[Load, float | None]:
    if pose.wrench is not None:
        return Load.wrench(robot, pose.wrench), None
    return Load.mass(robot, scn.load_mass), scn.load_mass


def plan_campaign(
    scn: Scenario, robot: Robot | None = None, progress: ProgressSink | None = None
) -> list[PosePlan]:
    """Solve and check every pose; raise InputError naming the first bad one."""
    robot = robot or truth_robot(scn)
    check_joint_limits(scn, robot.limits())
    check_scenario(scn, robot)  # a slipped unit: InputError, or a PlausibilityWarning
    solver = StaticsSolver(robot)
    plans = []
    for i, pose in enumerate(scn.poses):
        key = f"pose[{i}].q"
        cond = robot.loop_conditioning(pose.q)
        if np.any(cond < LOOP_MARGIN):
            worst = robot.description.loops[int(np.argmin(cond))]
            raise InputError(
                scn.path,
                key,
                f"a command where loop {worst!r} is well conditioned: inverse condition number of its "
                f"passive-joint Jacobian >= {LOOP_MARGIN:.3f} (for a planar two-hinge loop, its links "
                f"{np.degrees(LOOP_MARGIN_ANGLE):.0f} deg or more from parallel), got {cond.min():.3f}",
                [round(float(np.degrees(x)), 3) for x in pose.q],
            )
        load, mass = pose_load(robot, scn, pose)
        try:
            e0 = solver.solve(pose.q)
            e1 = solver.solve(pose.q, load, warm=e0)
        except StaticsError as exc:
            raise InputError(scn.path, key, "a pose with a static equilibrium", str(exc)) from None
        for state, e in zip(STATES, (e0, e1)):
            if not e.acceptable:
                raise InputError(
                    scn.path,
                    key,
                    f"a pose with a static equilibrium ({state} did not converge)",
                    [round(float(np.degrees(x)), 3) for x in pose.q],
                )
        refl = np.empty((2, len(robot.reflector_sites), 3))
        vis = np.empty((2, len(robot.reflector_sites)), dtype=bool)
        for s, e in enumerate((e0, e1)):
            robot.data.qpos[:] = e.qpos
            mujoco.mj_kinematics(robot.model, robot.data)
            refl[s] = robot.data.site_xpos[robot.reflector_sites]
            vis[s] = visible_sites(robot.model, robot.data, scn.tracker, robot.reflector_sites)
        if not (vis[0] & vis[1]).any():
            raise InputError(
                scn.path,
                key,
                "a pose where the tracker sees at least one reflector both unloaded and loaded",
                "every reflector hidden by the robot",
            )
        plans.append(PosePlan(i, pose.q, load, mass, (e0, e1), refl, vis))
        if progress:
            progress.update(f"solving pose {i + 1}/{len(scn.poses)}")
    return plans


def truth_record(scn: Scenario, robot: Robot) -> dict:
    d = scenario_params(scn, robot).as_dict()
    d["effects"] = {
        name: {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in e.items()}
        for name, e in scn.effects.items()
    }
    return d


def run_campaign(
    scn: Scenario, out: str | Path, progress: ProgressSink | None = None, force: bool = False
) -> list[PosePlan]:
    """Simulate the whole campaign into one MCAP log at `out`. Returns the solved plan.
    ``progress`` (bench/core/progress.py) hears of every solved and every measured pose. A campaign
    beyond bench/scenario/timeline.py's size limits is refused (InputError) unless ``force``."""
    out = Path(out)
    robot = truth_robot(scn)
    if not force:
        repeats = [p.repeats for p in scn.poses]
        check_size(estimate(repeats, len(robot.reflector_names)), scn.path, repeats_key(repeats))
    n = len(scn.poses)
    progress = sink(progress)
    progress.start(2 * n)
    plans = plan_campaign(scn, robot, progress)  # raises before any file exists
    out.parent.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(scn.seed)
    repeats = [p.repeats for p in scn.poses]
    measured = measure_campaign(
        scn.tracker,
        [p.reflectors_world for p in plans],
        [p.visible for p in plans],
        repeats,
        rng,
        reading_times(repeats, len(robot.reflector_names)),
    )
    header = LogHeader(
        scenario_name=scn.name,
        scenario_text=scn.text,
        scenario_filename=scn.path.name,
        robot_filename=Path(scn.robot).name,
        mjcf_text=Path(scn.robot).read_text(),
        reflectors=list(robot.reflector_names),
        payload_site=robot.payload_name,
        n_joints=robot.n_act,
        tracker=scn.tracker.to_dict(),
        seed=int(scn.seed),
        start_time=scn.start_time,
    )
    with LogWriter(out, header) as log:
        log.truth_parameters(truth_record(scn, robot))
        fox = FoxgloveWriter(log, Robot.from_file(scn.robot), robot, scn.tracker, robot.reflector_names)
        fox.start(n, plans[0].q if plans else np.zeros(robot.n_act))
        for plan, pose in zip(plans, scn.poses):
            readings: tuple[list, list] = ([], [])
            for s, state in enumerate(STATES):  # in causal order, stamped by the log's clock
                if state == "loaded":
                    log.wrench(plan.index, plan.load.force, plan.load.moment, robot.payload_name, plan.mass)
                log.pose(plan.index, state, plan.q)
                shift = reading_drift(scn, plan.index, robot.reflector_names) if s == 1 else None
                for rep in range(pose.repeats):
                    m = drifted(measured[(plan.index, state, rep)], shift)
                    log.measurement(
                        plan.index, state, rep, robot.reflector_names, m.position, m.covariance, m.visible
                    )
                    readings[s].append(m)
                e = plan.equilibria[s]
                log.truth_reflectors(plan.index, state, robot.reflector_names, plan.reflectors_world[s])
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
    return plans


class CampaignInterrupted(KeyboardInterrupt):
    """Ctrl-C (or a SIGTERM made one) during :func:`simulate`: ``written`` False when no log
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


def simulate(
    scn: Scenario, out: str | Path, progress: ProgressSink | None = None, force: bool = False
) -> list[PosePlan]:
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


__all__ = [
    "CampaignInterrupted",
    "simulate",
    "PosePlan",
    "plan_campaign",
    "reading_drift",
    "drifted",
    "run_campaign",
    "truth_robot",
    "scenario_params",
    "to_tracker_frame",
]
