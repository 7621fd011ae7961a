"""A campaign's physics, before any noise: every pose solved and checked.

:func:`plan_campaign` solves both equilibria of every pose of a scenario on its true robot
(:func:`truth_robot`: the MJCF with the scenario's truth and hidden effects written in) and
checks each pose (joint limits, a well-conditioned loop, a converged equilibrium, a reflector the
tracker sees), raising an InputError naming the first bad pose, before anything is measured or
written. bench/campaign/simulation.py measures the solved poses.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from calbench.bench.core import STATES, InputError, ProgressSink
from calbench.bench.model import LOOP_MARGIN, LOOP_MARGIN_ANGLE, Params, Robot, load_robot
from calbench.bench.model.effects import apply_effects, effect_from_truth
from calbench.bench.scenario import (
    Scenario,
    check_joint_limits,
    check_scenario,
    check_size,
    estimate,
    repeats_key,
    scenario_params,
)
from calbench.bench.statics import Equilibrium, Load, StaticsError, StaticsSolver
from calbench.bench.tracker import visible_sites


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


def truth_params(scn: Scenario, robot: Robot) -> Params:
    """The scenario's truth for this robot (InputError naming a key that does not fit it)."""
    return scenario_params(scn, robot.n_act, robot.description.compensators)


def truth_robot(scn: Scenario) -> Robot:
    """The simulated (true) robot: the scenario's MJCF with the scenario's truth written in,
    including the hidden `[truth.effects.*]` (bench/model/effects/ edits of the MJCF)."""
    robot = load_robot(scn.path, "robot", path=scn.robot)  # the user's model itself must load
    if scn.effects:
        effects = [effect_from_truth(name, table) for name, table in scn.effects.items()]
        try:
            robot = apply_effects(Path(scn.robot), effects)
        except (ValueError, NotImplementedError) as exc:
            raise InputError(
                scn.path, "truth.effects", "effects that apply to the robot's MJCF", f"{scn.robot}: {exc}"
            ) from exc
    robot.set_params(truth_params(scn, robot))
    return robot


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


def check_campaign_size(scn: Scenario, robot: Robot) -> None:
    """InputError when the scenario's campaign is estimated to be too large to simulate
    (bench/scenario/timeline.py's limits: time and log size), naming the key that makes it so."""
    repeats = [p.repeats for p in scn.poses]
    check_size(estimate(repeats, len(robot.reflector_names)), scn.path, repeats_key(repeats))


__all__ = ["PosePlan", "check_campaign_size", "plan_campaign", "pose_load", "truth_params", "truth_robot"]
