"""What the Rerun view draws, computed from a campaign log: the robot at each command, the
measured reflectors, and the loaded robot with its joint deflections magnified (the ghost).

Pure computations (no rerun here; bench/view/recording.py logs the results).

Which robot is which
--------------------
* **The robot** is drawn at the commanded angles (the rigid closed loop,
  :meth:`bench.robot.Robot.rigid_qpos`): all a real campaign knows of its pose. Under its own
  weight and the compensator the arm sags from there by ~2-4 cm at the tool, so the measured
  reflectors sit that far from their posts; :attr:`PoseScene.sag` is that distance, measured.
* **The ghost** is the loaded robot with the payload's joint deflections magnified by the same
  factor F as the deflection arrows (the exaggerated-deformation view of structural FEM tools):
  motor angles ``q + d_u + F (d_l - d_u)``, where ``d_u``, ``d_l`` are the motor deflections from
  the command unloaded and loaded, so the ghost starts from the unloaded equilibrium and the
  tips of the arrows land on its reflectors (to first order in F times the deflection). The
  passive joints follow from the closed loop, which holds exactly at any motor angles. Two
  sources: the log's ``/truth/joints`` (a simulated campaign; drawn under ``truth/`` only), or
  the equilibria of the identified model (bench/statics/equilibrium.py with the report's estimates: the
  model's prediction, drawn under ``model/``). A real campaign without ``--identified`` has no
  joint deflections: no ghost. Effects beyond the motor springs (a compliant link, say) are
  not in the ghost: it shows the joint deflections only.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np

from calbench.bench.core import InputError
from calbench.bench.log import STATES, CampaignLog, IdentificationReport, PerState, WrenchRecord
from calbench.bench.model import Robot, tendon_sites
from calbench.bench.statics import Load, StaticsError, StaticsSolver
from calbench.bench.tracker import MeanReading, mean_reading

HALF_FOV_TAN = 0.46  # tangent of the half field of view the framing allows (a margin inside
# the viewer's own: the view is wider than tall, and labels need room)


@dataclass(frozen=True)
class RobotPose:
    """World poses of every body (``xpos`` (nbody, 3), ``xquat`` (nbody, 4) wxyz) and the
    tendon polylines (name -> (k, 3)), at one configuration."""

    qpos: np.ndarray
    xpos: np.ndarray
    xquat: np.ndarray
    tendons: dict[str, np.ndarray]


class RobotPoser:
    """One model posed by ``mj_kinematics`` in its own MjData."""

    def __init__(self, robot: Robot):
        self.robot = robot
        self.data = mujoco.MjData(robot.model)
        self.tendons = tendon_sites(robot.model)

    def at(self, qpos: np.ndarray) -> RobotPose:
        d = self.data
        d.qpos[:] = qpos
        mujoco.mj_kinematics(self.robot.model, d)
        return RobotPose(
            np.array(qpos, float),
            d.xpos.copy(),
            d.xquat.copy(),
            {name: d.site_xpos[s].copy() for name, s in self.tendons},
        )

    def site(self, site: int) -> np.ndarray:
        """World position of ``site`` in the last pose."""
        return self.data.site_xpos[site].copy()


def deformed_command(
    command: np.ndarray, unloaded: np.ndarray, loaded: np.ndarray, magnify: float
) -> np.ndarray:
    """Motor angles of the ghost: the unloaded equilibrium plus F times the payload's joint
    deflection, ``q + d_u + F (d_l - d_u)`` (rad; ``d`` = motor deflection from the command)."""
    return np.asarray(command, float) + unloaded + magnify * (np.asarray(loaded) - unloaded)


@dataclass
class PoseScene:
    """One pose: the robot at the command, the measured reflectors of both states (world frame,
    mean of the repeats, NaN where not seen), the load, and what truth or model adds."""

    index: int
    command: np.ndarray  # (N,) rad, one per actuated joint
    robot: RobotPose  # at the command
    reflector_sites: np.ndarray  # (n, 3) world, the sites at the command
    measured: dict[str, np.ndarray]  # state -> (n, 3)
    measured_cov: dict[str, np.ndarray]  # state -> (n, 3, 3), of the mean of repeats
    wrench: WrenchRecord | None
    payload: np.ndarray | None  # (3,) world, the payload site at the command
    truth: dict[str, np.ndarray] = field(default_factory=dict)  # state -> (n, 3) true
    ghosts: dict[str, RobotPose] = field(default_factory=dict)  # "truth" / "model" -> ghost

    def deflection(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Measured deflection (n, 3), its covariance (n, 3, 3), and which rows are valid."""
        d = self.measured["loaded"] - self.measured["unloaded"]
        cov = self.measured_cov["loaded"] + self.measured_cov["unloaded"]
        ok = np.all(np.isfinite(d), axis=1)
        return d, cov, ok

    @property
    def sag(self) -> np.ndarray:
        """(n,) distance from each reflector site of the robot at the command to where the
        tracker saw it unloaded, m (NaN where not seen): the arm's sag under its own weight."""
        return np.linalg.norm(self.measured["unloaded"] - self.reflector_sites, axis=1)


def mean_measurements(log: CampaignLog, names: list[str]) -> dict[tuple[int, str], MeanReading]:
    """(pose, state) -> the mean of its readings in the world frame
    (:func:`bench.tracker.mean_reading`), rows in ``names`` order (matched by reflector name)."""
    spec = log.tracker_spec()
    out = {}
    for p in log.complete_poses:  # a pose at a time: a log of any size
        for s in STATES:
            readings = [m.in_order(names) for m in log.readings(p, s)]
            if readings:
                out[(p, s)] = mean_reading(spec, readings)
    return out


def command_of(log: CampaignLog, pose: int, n_joints: int) -> np.ndarray:
    """The commanded angles of a complete pose (the unloaded one; both states share it), one
    per actuated joint of the robot."""
    per = log.poses.get(pose, PerState())
    q = per.unloaded if per.unloaded is not None else per.loaded
    if q is None or np.asarray(q).shape != (n_joints,):
        raise InputError(
            log.path,
            f"/campaign/pose (pose {pose})",
            f"the commanded joint angles q[{n_joints}] of every complete pose",
            None if q is None else np.asarray(q).tolist(),
        )
    return np.asarray(q, dtype=float)


def true_deflections(log: CampaignLog) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """pose -> (unloaded, loaded) true motor deflections from ``/truth/joints``: every complete
    pose, or none (a log without truth, or with a pose whose truth is missing)."""
    out = {}
    joints = log.truth.joints if log.truth else {}
    for p in log.complete_poses:
        per = joints.get(p)
        if per is None or per.unloaded is None or per.loaded is None:
            return {}
        out[p] = (np.asarray(per.unloaded.deflection, float), np.asarray(per.loaded.deflection, float))
    return out


def model_deflections(
    log: CampaignLog, robot_xml: str, ident: IdentificationReport
) -> tuple[dict[int, tuple[np.ndarray, np.ndarray]], str]:
    """pose -> (unloaded, loaded) motor deflections that the identified model predicts: the
    exact statics of the log's MJCF with the report's estimates, at each command and load.
    Returns ``({}, "none (why)")`` when the report cannot pose the model: it names parameters beyond
    the motor springs and the compensator (discover's effects), or lacks the compensator's
    estimates. A compliance the campaign could not identify is taken as rigid (it is the one
    no load of the plan excites), and ``why`` says so."""
    est = {p.name: p.estimate for p in ident.parameters}
    robot = Robot.from_xml(robot_xml)
    lay = robot.layout
    extra = [n for n in est if n not in lay.names]
    if extra:
        return {}, (
            f"none (the model has parameters beyond the motor springs and the "
            f"compensators: {', '.join(extra[:3])}{'...' if len(extra) > 3 else ''})"
        )
    missing = [n for n in lay.names[lay.n_joints :] if est.get(n) is None]
    if missing:
        return {}, f"none (no estimate of {', '.join(missing)})"
    rigid = [n for n in lay.names[: lay.n_joints] if est.get(n) is None]
    theta = np.array([est.get(n) or 0.0 for n in lay.names])
    # a compliance of 0 would be an infinite stiffness: a stiff spring stands for "rigid"
    theta[lay.compliance] = np.maximum(theta[lay.compliance], 1e-15)
    robot.set_params(lay.params(theta))
    solver = StaticsSolver(robot)
    out = {}
    for p in log.complete_poses:
        w = log.wrenches.get(p)
        q = command_of(log, p, robot.n_act)
        try:
            e0 = solver.solve(q)
            e1 = e0 if w is None else solver.solve(q, Load(w.force, w.moment, _site(robot, w.site)), warm=e0)
        except StaticsError as e:
            return {}, f"none (the identified model has no equilibrium at pose {p}: {e})"
        out[p] = (e0.deflection, e1.deflection)
    note = f"{', '.join(rigid)} not identified: taken as rigid" if rigid else ""
    return out, note


def _site(robot: Robot, name: str) -> int:
    s = mujoco.mj_name2id(robot.model, mujoco.mjtObj.mjOBJ_SITE, name)
    return int(s) if s >= 0 else robot.payload_site


def pose_scenes(
    log: CampaignLog,
    robot: Robot,
    names: list[str],
    magnify: float,
    ghosts: dict[str, dict[int, tuple[np.ndarray, np.ndarray]]],
) -> list[PoseScene]:
    """Every complete pose of the log as a :class:`PoseScene`. ``ghosts`` maps a source
    ("truth", "model") to its motor deflections per pose (:func:`true_deflections`,
    :func:`model_deflections`)."""
    poser = RobotPoser(robot)
    means = mean_measurements(log, names)
    truth_refl = log.truth.reflectors if log.truth else {}
    nan = np.full((len(names), 3), np.nan)
    nan_cov = np.full((len(names), 3, 3), np.nan)
    sites = [mujoco.mj_name2id(robot.model, mujoco.mjtObj.mjOBJ_SITE, n) for n in names]
    scenes = []
    for p in log.complete_poses:
        q = command_of(log, p, robot.n_act)
        at_command = poser.at(robot.rigid_qpos(q))
        refl_sites = np.array([poser.site(s) if s >= 0 else np.full(3, np.nan) for s in sites])
        w = log.wrenches.get(p)
        payload = poser.site(_site(robot, w.site)) if w is not None else None
        meas, cov, truth = {}, {}, {}
        for state in STATES:
            mean = means.get((p, state))
            meas[state], cov[state] = (nan, nan_cov) if mean is None else (mean.position, mean.covariance)
            tr = truth_refl.get(p, PerState()).get(state)
            if tr is not None:
                pos = np.full((len(names), 3), np.nan)
                for j, nm in enumerate(tr.reflectors):
                    if nm in names:
                        pos[names.index(nm)] = tr.position_world[j]
                truth[state] = pos
        ghost = {
            src: poser.at(robot.rigid_qpos(deformed_command(q, *d[p], magnify)))
            for src, d in ghosts.items()
            if p in d
        }
        scenes.append(PoseScene(p, q, at_command, refl_sites, meas, cov, w, payload, truth, ghost))
    return scenes


TRACKER_APART = 0.25  # the tracker's screen offset from the tool, across, in half-view widths
AZIMUTH_STEP, AZIMUTH_MAX = 5.0, 60.0  # degrees: how far the camera may turn off the profile


def framing(
    scenes: list[PoseScene], tracker: np.ndarray, magnify: float, half_fov_tan: float = HALF_FOV_TAN
) -> tuple[np.ndarray, np.ndarray]:
    """(eye, target) of a camera that frames the robot and its deflection arrows in every pose
    (stepping through the poses never takes the tool out of view) and the tracker's head.

    It looks at the first pose's arm in profile, across its vertical plane (where the payload
    bends it), from the side away from the tracker (which then stands beyond the robot, never
    in front), 20 degrees above the horizon, at the middle of all those points; it stands back
    just far enough that every one of them is inside a view whose half-width and half-height
    subtend ``half_fov_tan`` (a tangent) at the eye. When the tracker would then stand right
    behind the tool (its tripod across the arrows: less than TRACKER_APART half-widths apart
    across the screen), the camera turns off the profile by the least multiple of AZIMUTH_STEP
    (at most AZIMUTH_MAX) that sets them apart, the tracker still beyond the tool."""
    tracker = np.asarray(tracker, float)
    pts = [tracker[None]]
    for sc in scenes:
        d, _, ok = sc.deflection()
        pts += [sc.robot.xpos[1:], sc.measured["unloaded"][ok] + magnify * d[ok]]
    pts = np.vstack(pts)
    target = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    scene = scenes[0]
    base = scene.robot.xpos[1][:2]
    tool3 = np.nanmean(scene.reflector_sites, axis=0)
    tool = tool3[:2] - base
    side = np.array([-tool[1], tool[0]])  # normal of the arm's vertical plane
    side = side / np.linalg.norm(side) if np.linalg.norm(side) > 1e-9 else np.array([0.0, 1.0])
    if side @ (tracker[:2] - base) > 0:
        side = -side
    elev = np.radians(20.0)
    rel = pts - target

    def view(azimuth: float):
        c, s_ = np.cos(azimuth), np.sin(azimuth)
        h = np.array([c * side[0] - s_ * side[1], s_ * side[0] + c * side[1]])
        back = np.array([h[0] * np.cos(elev), h[1] * np.cos(elev), np.sin(elev)])  # eye - target
        right = np.cross(-back, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        up = np.cross(right, -back)
        # a point at depth (dist - rel.back) must have |rel.right|, |rel.up| <= tan * depth
        need = np.maximum(np.abs(rel @ right), np.abs(rel @ up)) / half_fov_tan + rel @ back
        eye = target + back * float(need.max())

        def across(p):  # screen x in half-widths, and depth
            r = p - eye
            depth = -(r @ back)
            return (r @ right) / depth / half_fov_tan, depth

        (xt, dt), (xk, dk) = across(tool3), across(tracker)
        return eye, abs(xk - xt), dk >= dt

    steps = np.arange(0.0, AZIMUTH_MAX + 1e-9, AZIMUTH_STEP)
    for deg in [0.0] + [x for a in steps[1:] for x in (a, -a)]:
        eye, apart, beyond = view(np.radians(deg))
        if apart >= TRACKER_APART and beyond:
            return eye, target
    return view(0.0)[0], target


__all__ = [
    "RobotPose",
    "RobotPoser",
    "PoseScene",
    "deformed_command",
    "mean_measurements",
    "command_of",
    "true_deflections",
    "model_deflections",
    "pose_scenes",
    "framing",
]
