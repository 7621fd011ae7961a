"""`calbench check-robot ROBOT.xml`: is this MJCF a robot calbench can calibrate?

Checks, in order, each failure an InputError naming the element (exit status 2):

1. the MJCF compiles and its robot description (bench/model/description.py) names elements that
   exist and have the right types;
2. every actuated joint carries its VJM spring (stiffness > 0: any value, a scenario writes
   the real one), and every other joint is a loop's passive joint or a spring of its own (a
   free joint that is neither leaves the statics without an equilibrium);
3. the loops close: at the reference configuration (every command 0) and at every pose of the
   grid below, the rigid configuration closes each loop to bench.loop.LOOP_TOL;
4. the reflectors are not collinear (the second singular value of their centred positions at
   the reference configuration at least MIN_SPREAD = 1 cm: three points on one line cannot
   fix a rotation about it) and every one is seen at the reference configuration from a
   default tracker position (:func:`default_tracker`) or the one given;
5. the statics converge over a grid of poses: each actuated joint at 1/4, 1/2 and 3/4 of its
   range (clipped to +-180 deg; ``grid`` values per joint), unloaded and with a payload
   ``mass`` at the payload site, with the MJCF's own stiffness values. Poses within the loop
   margin of a degenerate loop (bench.robot.LOOP_MARGIN) are skipped, as a campaign rejects
   them; each other pose must reach an acceptable equilibrium (bench.statics).

And one warning, not a failure (a scenario's wrench can still carry a torque): an actuated joint
whose axis the payload site sits on (within MIN_SPREAD) at every grid pose, about which no hung
weight or pull has a lever arm (:func:`payload_levers`).

On success :func:`check_robot` returns a :class:`RobotCheck`, a short summary of what calbench
derived from the model.
"""

from __future__ import annotations

import itertools
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from calbench.bench.core import InputError, StaticsError, check_model_file
from calbench.bench.model import LOOP_MARGIN, LOOP_MARGIN_ANGLE, LOOP_TOL, DescriptionError, Robot, loop_gap
from calbench.bench.statics import Load, StaticsSolver
from calbench.bench.tracker import TrackerSpec, visible_sites

MIN_SPREAD = 0.01  # m, second singular value of the centred reflector positions
TRACKER_DISTANCE = 5.0  # m from axis 1, at least twice the payload's reach
TRACKER_HEIGHT = 3.0  # m above the world's z = 0
TRACKER_AZIMUTH = -45.0  # deg from the payload's direction at the reference pose
DEFAULT_MASS = 100.0  # kg hung at the payload site for the loaded grid (at most MASS_SHARE of the robot)
MASS_SHARE = 1 / 3  # of the robot's own mass: a cobot of 33 kg carries 10 kg, a KR 210 of 1.1 t 210 kg


@dataclass
class RobotCheck:
    """What check-robot found (all checks passed)."""

    path: Path
    actuated: tuple[str, ...]
    loops: dict[str, list[str]]  # loop -> its passive joints
    compensators: dict[str, str]  # tendon -> the actuated joint it spans ("" if none)
    reflectors: tuple[str, ...]
    payload: str
    flange: str | None
    parameters: tuple[str, ...]
    reference_conditioning: list[float]  # per loop, at the reference pose
    tracker: np.ndarray
    poses: int = 0  # grid poses solved (unloaded and loaded)
    skipped: int = 0  # grid poses within the loop margin
    max_gap: float = 0.0  # m, largest loop gap at an equilibrium
    mass: float = DEFAULT_MASS  # kg, the payload of the loaded grid
    optional: dict[str, tuple[str, ...]] = field(default_factory=dict)
    frames: list[LinkFrame] = field(default_factory=list)
    payload_on_axis: tuple[str, ...] = ()  # actuated joints whose axis the payload sits on

    def lines(self) -> list[str]:
        """The summary, for people."""
        out = [
            f"{self.path}: a calbench robot",
            f"  {len(self.actuated)} actuated joints: {' '.join(self.actuated)}",
            f"  parameters: {' '.join(self.parameters)}",
        ]
        if self.loops:
            for (name, passive), c in zip(self.loops.items(), self.reference_conditioning):
                out.append(
                    f"  loop {name}: passive joints {' '.join(passive)}; conditioning {c:.3f} at the "
                    f"reference pose, commands need >= {LOOP_MARGIN:.4f} (tan 5 deg: a planar "
                    f"two-hinge loop {math.degrees(LOOP_MARGIN_ANGLE):.0f} deg from flat)"
                )
        else:
            out.append("  no kinematic loop (a serial robot)")
        for t, j in self.compensators.items():
            out.append(
                f"  compensator {t}: across {j}"
                if j
                else f"  compensator {t}: not across one actuated hinge (the two-step method does not apply)"
            )
        if not self.compensators:
            out.append("  no compensator spring")
        out.append(
            f"  reflectors: {' '.join(self.reflectors)} (not collinear, all seen from a tracker at "
            f"[{', '.join(f'{x:.2f}' for x in self.tracker)}] m at the reference pose)"
        )
        out.append(f"  payload site: {self.payload}" + (f"; flange: {self.flange}" if self.flange else ""))
        for j in self.payload_on_axis:
            out.append(
                f"  WARNING: the payload site is on {j}'s axis at every grid pose (within "
                f"{MIN_SPREAD * 100:.0f} cm): a force there puts no torque on {j}, so no plan of "
                f"weights and pulls calibrates its compliance (design refuses). Move calbench:payload "
                f"(from-urdf: the overlay's [payload] pos) off that axis, by tens of cm."
            )
        for key, names in self.optional.items():
            if key == "assumed_masses":
                out.append(
                    f"  masses ASSUMED (a guess, not the maker's: calbench:assumed_masses) for {' '.join(names)}"
                )
            else:
                out.append(f"  {key}: {' '.join(names)}")
        if self.frames:
            out.append(
                "  links at the reference pose (q = 0), for placing reflectors and the payload: frame "
                "origin (world, m), the frame's x y z axes in the world, geometry's box in the link frame (m)"
            )
            out += ["    " + f.line() for f in self.frames]
        out.append(
            f"  statics converge at {self.poses} grid poses, unloaded and loaded"
            + (f" ({self.skipped} skipped: within the loop margin)" if self.skipped else "")
            + f"; largest loop gap {self.max_gap:.1e} m"
        )
        return out


@dataclass(frozen=True)
class LinkFrame:
    """A body at the reference pose: its frame (origin, axes in the world) and the box its geoms
    fill in its own frame (a mesh's vertices, a primitive's geom_aabb corners; None without
    geometry)."""

    name: str
    origin: np.ndarray  # (3,) world, m
    axes: np.ndarray  # (3, 3) rows: the frame's x, y, z in the world
    box: tuple[np.ndarray, np.ndarray] | None  # (lo, hi) in the body frame, m

    def line(self) -> str:
        def v(x) -> str:
            return "[" + ", ".join(f"{c:.3f}" for c in x) + "]"

        names = ("x", "y", "z")
        axes = " ".join(f"{n}{_axis(a)}" for n, a in zip(names, self.axes))
        box = f"box {v(self.box[0])} .. {v(self.box[1])}" if self.box is not None else "no geometry"
        return f"{self.name}: origin {v(self.origin)}, axes {axes}, {box}"


def _axis(a: np.ndarray) -> str:
    """A world direction as +X / -Z when it is one, else its components."""
    k = int(np.argmax(np.abs(a)))
    if abs(abs(a[k]) - 1.0) < 1e-6:
        return ("+" if a[k] > 0 else "-") + "XYZ"[k]
    return "(" + " ".join(f"{c:.2f}" for c in a) + ")"


def link_frames(robot: Robot) -> list[LinkFrame]:
    """Every body but the world at the reference pose (q = 0), as :class:`LinkFrame`."""
    m = robot.model
    d = mujoco.MjData(m)
    d.qpos[:] = robot.rigid_qpos(np.zeros(robot.n_act))
    mujoco.mj_kinematics(m, d)
    signs = np.array(list(itertools.product((-1.0, 1.0), repeat=3)))
    out = []
    for b in range(1, m.nbody):
        rot = d.xmat[b].reshape(3, 3)
        pts = []
        for g in np.flatnonzero(m.geom_bodyid == b):
            if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_PLANE:
                continue
            if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH:  # its vertices: an exact box
                k = m.geom_dataid[g]
                local = m.mesh_vert[m.mesh_vertadr[k] : m.mesh_vertadr[k] + m.mesh_vertnum[k]]
            else:  # a primitive's box in its own frame
                local = m.geom_aabb[g, :3] + signs * m.geom_aabb[g, 3:]
            world = d.geom_xpos[g] + local @ d.geom_xmat[g].reshape(3, 3).T
            pts.append((world - d.xpos[b]) @ rot)
        box = (np.min(np.vstack(pts), axis=0), np.max(np.vstack(pts), axis=0)) if pts else None
        out.append(LinkFrame(m.body(b).name, d.xpos[b].copy(), rot.T.copy(), box))
    return out


def default_tracker(robot: Robot) -> np.ndarray:
    """A tracker TRACKER_DISTANCE from axis 1 (at least twice the payload's distance from it),
    TRACKER_HEIGHT up, TRACKER_AZIMUTH from the payload's horizontal direction at the reference
    pose (the FANUC's: [3.54, -3.54, 3.0] m, beside its scenarios' [3.5, -3.5, 3.2])."""
    m, d = robot.model, mujoco.MjData(robot.model)
    d.qpos[:] = robot.rigid_qpos(np.zeros(robot.n_act))
    mujoco.mj_kinematics(m, d)
    foot = d.xanchor[robot.act_joint[0]].copy()
    v = d.site_xpos[robot.payload_site] - foot
    reach = math.hypot(v[0], v[1])
    az = math.atan2(v[1], v[0]) if reach > 1e-6 else 0.0
    az += math.radians(TRACKER_AZIMUTH)
    r = max(TRACKER_DISTANCE, 2.0 * reach)
    return np.array([foot[0] + r * math.cos(az), foot[1] + r * math.sin(az), TRACKER_HEIGHT])


def grid(robot: Robot, per_joint: int) -> np.ndarray:
    """The grid of commands (rad): each joint at (i + 1) / (per_joint + 1) of its range."""
    lim = np.clip(robot.limits(), -math.pi, math.pi)
    frac = (np.arange(per_joint) + 1.0) / (per_joint + 1.0)
    axes = [lo + (hi - lo) * frac for lo, hi in lim]
    return np.array(list(itertools.product(*axes)))


def _deg(q) -> list[float]:
    return [round(float(math.degrees(x)), 3) for x in q]


def _is_urdf(path: Path) -> bool:
    """A ``.urdf`` / ``.xacro`` file, or XML whose root element is ``<robot>``."""
    if path.name.endswith((".urdf", ".xacro")):
        return True
    try:
        for _, el in ET.iterparse(path, events=("start",)):
            return el.tag == "robot"
    except (ET.ParseError, OSError):
        return False
    return False


def check_robot(
    path: str | Path, tracker: np.ndarray | None = None, mass: float | None = None, per_joint: int = 3
) -> RobotCheck:
    """Run the checks of the module docstring on the MJCF at ``path``; InputError at the first
    failure, naming the element. ``mass`` (kg): the loaded grid's payload; None: DEFAULT_MASS, or
    MASS_SHARE of the robot's moving mass if less (a small robot is not loaded past its rating)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "ROBOT.xml", "an existing MJCF file", "no such file")
    if _is_urdf(path):
        raise InputError(
            path,
            "ROBOT.xml",
            "a calbench MJCF: convert a URDF first, calbench from-urdf ROBOT.urdf --overlay "
            "OVERLAY.toml --out ROBOT.xml (docs/your-robot.md)",
            "a URDF" + (" (xacro)" if path.name.endswith(".xacro") else ""),
        )
    try:
        model = mujoco.MjModel.from_xml_path(str(path))
    except ValueError as exc:
        raise InputError(path, "MJCF", "a model MuJoCo compiles", str(exc).splitlines()[0]) from None
    check_model_file(path)  # and safe XML whose files stay in its folder (bench/core/xmlsafe.py)
    try:
        robot = Robot(model, path)
    except DescriptionError as exc:
        key, _, what = str(exc).removeprefix(f"{path}: ").partition(": ")
        raise InputError(
            path, key, "a valid robot description (docs/contract.md, Robot description)", what
        ) from None
    except StaticsError as exc:
        raise InputError(path, "calbench:loops", "loops that close at the reference pose", str(exc)) from None
    m = robot.model
    desc = robot.description
    for name, j in zip(desc.actuated, robot.act_joint):
        if not m.jnt_stiffness[j] > 0:
            raise InputError(
                path,
                f"calbench:actuated: joint {name!r}",
                "a stiffness > 0 (the VJM spring; any value: a scenario writes the real one)",
                float(m.jnt_stiffness[j]),
            )

    free = [
        j
        for j in range(m.njnt)
        if j not in robot.act_joint and j not in robot.passive_joint and not m.jnt_stiffness[j] > 0
    ]
    if free:
        raise InputError(
            path,
            f"joint {m.joint(free[0]).name!r}",
            "an actuated joint (calbench:actuated), a "
            "loop's passive joint (calbench:loops) or a spring (stiffness > 0)",
            "a free joint: the statics have no equilibrium",
        )

    comps = {}
    for c, t in enumerate(desc.compensators):
        try:
            comps[t] = desc.actuated[robot.compensator_joint(c)]
        except ValueError:
            comps[t] = ""

    # reflectors at the reference pose: spread and line of sight
    d = mujoco.MjData(m)
    d.qpos[:] = robot.rigid_qpos(np.zeros(robot.n_act))
    mujoco.mj_kinematics(m, d)
    pts = d.site_xpos[robot.reflector_sites]
    spread = np.linalg.svd(pts - pts.mean(axis=0), compute_uv=False)
    if spread[1] < MIN_SPREAD:
        raise InputError(
            path,
            "calbench:reflectors",
            f"reflectors not on one line (spread >= {MIN_SPREAD * 100:.0f} cm across it)",
            f"{spread[1] * 100:.2g} cm for " + ", ".join(desc.reflectors),
        )
    spot = default_tracker(robot) if tracker is None else np.asarray(tracker, dtype=float)
    seen = visible_sites(m, d, TrackerSpec(position=spot), robot.reflector_sites)
    if not seen.all():
        hidden = [n for n, s in zip(desc.reflectors, seen) if not s]
        raise InputError(
            path,
            "calbench:reflectors",
            f"every reflector seen from a tracker at "
            f"{np.round(spot, 2).tolist()} m at the reference pose (q = 0)",
            "hidden: " + ", ".join(hidden),
        )
    reference = [float(x) for x in robot.loop_conditioning(np.zeros(robot.n_act))]

    # the grid: loops close, statics converge
    solver = StaticsSolver(robot)
    if mass is None:
        moving = float(m.body_mass[m.body_weldid != 0].sum())
        mass = DEFAULT_MASS if moving <= 0 else min(DEFAULT_MASS, float(f"{MASS_SHARE * moving:.2g}"))
    load = Load.mass(robot, mass)
    out = RobotCheck(
        path,
        desc.actuated,
        {e: [m.joint(j).name for j in js] for e, js in zip(desc.loops, robot.loop_passive)},
        comps,
        desc.reflectors,
        desc.payload,
        desc.flange,
        robot.layout.names,
        reference,
        spot,
        optional={
            k: v
            for k in ("mass_compensators", "links", "compensator_sites", "assumed_masses")
            if (v := getattr(desc, k))
        }
        | ({"wrist": (desc.wrist,)} if desc.wrist else {}),
        frames=link_frames(robot),
        mass=mass,
    )
    lever = np.zeros(robot.n_act)  # per actuated joint, the payload's largest distance from its axis
    for q in grid(robot, per_joint):
        try:
            qpos = robot.rigid_qpos(q)
        except StaticsError as exc:
            raise InputError(
                path, "calbench:loops", f"loops that close at every pose (command {_deg(q)} deg)", str(exc)
            ) from None
        lever = np.maximum(lever, payload_levers(robot, d, qpos))
        if robot.loops:
            d.qpos[:] = qpos
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            gap = np.abs(loop_gap(robot, d)[0]).reshape(-1, 3).max(axis=1)
            if gap.max() > LOOP_TOL:
                bad = desc.loops[int(np.argmax(gap))]
                raise InputError(
                    path,
                    f"calbench:loops: {bad}",
                    f"a loop that closes at command {_deg(q)} deg",
                    f"gap {gap.max():.1e} m",
                )
            if not robot.loop_ok(q, qpos):
                out.skipped += 1
                continue
        for state, ld in (("unloaded", None), ("loaded", load)):
            try:
                e = solver.solve(q, ld)
            except StaticsError as exc:
                raise InputError(
                    path, f"statics at command {_deg(q)} deg ({state})", "an equilibrium", str(exc)
                ) from None
            if not e.acceptable:
                raise InputError(
                    path,
                    f"statics at command {_deg(q)} deg ({state})",
                    "an equilibrium that converges (residual and loop gap)",
                    f"residual {e.residual:.1e} N*m, loop gap {e.loop_violation:.1e} m",
                )
            out.max_gap = max(out.max_gap, e.loop_violation)
        out.poses += 1
    if out.poses == 0:
        raise InputError(path, "calbench:loops", "a grid pose away from a degenerate loop", "none")
    out.payload_on_axis = tuple(n for n, r in zip(desc.actuated, lever) if r < MIN_SPREAD)
    return out


def payload_levers(robot: Robot, d: mujoco.MjData, qpos: np.ndarray) -> np.ndarray:
    """(n_act,) m: the payload site's distance from each actuated joint's axis at ``qpos``: the
    lever arm any force hung there has about that joint."""
    m = robot.model
    d.qpos[:] = qpos
    mujoco.mj_kinematics(m, d)
    p = d.site_xpos[robot.payload_site]
    r = p - d.xanchor[robot.act_joint]
    a = d.xaxis[robot.act_joint]
    return np.linalg.norm(r - (r * a).sum(axis=1, keepdims=True) * a, axis=1)


__all__ = [
    "RobotCheck",
    "LinkFrame",
    "link_frames",
    "check_robot",
    "default_tracker",
    "grid",
    "MIN_SPREAD",
    "DEFAULT_MASS",
]
