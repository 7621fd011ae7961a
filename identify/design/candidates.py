"""Feasible measurement configurations and their Fisher information blocks (issue 4, §2).

A candidate is a commanded configuration q (rad, controller convention) and a load: either the
scenario's ``[load]`` mass hanging at the payload site ("vertical") or a horizontal pull
("lateral", paper §5.1: vertical loads cannot turn J1, so k1 needs a non-vertical load)
of ``lateral_force`` newtons perpendicular to the arm's vertical plane, direction
(-sin q1, cos q1, 0) times a random sign. Like a ``[[pose]] wrench``, the pull REPLACES the
payload in the loaded state.

Parameters and prior guess. theta = the robot's layout (bench/model/params.py; the FANUC's
[k1..k6, K_C, s0]) normalised by a nominal value:
u_i = theta_i / theta0_i. A design needs a prior guess of theta (the information of the nonlinear
model depends on it); a design study uses the scenario's ``[truth]``, which is the natural
nominal (in a real cell: the manufacturer's values or a previous identification).

Information. For one candidate with reflectors r, the deflection dp_r = x_r(loaded) -
x_r(unloaded) is the exact-statics one of identify/core/forward.py; its Jacobian with respect to u
comes from the implicit function theorem at both equilibria (``StaticsSolver.tangent``, exact
KKT matrix, d g / d theta from ``Robot.dforce_dtheta``), J_r = (J_site dq/dtheta)|loaded -
(...)|unloaded, times theta0 column-wise. The deflections' covariance Sigma is
bench.iso10360.deflection_covariance's (the estimator's: Cov(reading unloaded) + Cov(reading
loaded) per reflector, 2 sigma^2 I for the isotropic tracker, one repeat; for the iso10360
tracker also the field and drift shared by the pose's readings, on the campaign clock). The
candidate's block is the whitened regressor R = L^-1 [J_r], L L^T = Sigma: rows = the 3
coordinates of each reflector (9 rows for 3 reflectors), columns = the p normalised parameters,
and the Fisher information of a plan is sum_i R_i^T R_i (with repeats n: n R_i^T R_i, exact
for independent readings; for the iso10360 tracker repeats do not average its correlated part
and this overstates what they add).

Feasibility rules (each named; :func:`Feasibility.check` returns the violated ones):

* ``joint_limits``: q inside the MJCF's controller ranges (q4, q6 sampled in [-180, 180]).
* ``degenerate_loop``: every kinematic loop at least ``bench.robot.LOOP_MARGIN`` from degenerate
  (``bench.robot.Robot.loop_ok``: the inverse condition number of its passive-joint Jacobian;
  on the FANUC q3 - q2 at least 10 deg away from the degenerate -120 / 60 deg).
* ``min_height`` / ``min_radius``: the WRIST CENTRE (the origin of the robot's calbench:wrist
  body, by default of the body of the last-but-one actuated joint: on a six-axis arm the J5
  axis, the point of the paper's Fig. 6; the FANUC's link5) at z >= min_height and at least
  min_radius from axis 1 (distance from the first actuated joint's axis line), at the commanded
  (rigid) pose. Paper: 0.5 m and 1 m.
* ``self_collision``: MuJoCo collision detection on a copy of the MJCF with every geom made
  collidable (contype = conaffinity = 1, margin = ``clearance``), at the rigid pose and at both
  equilibria. Not counted (:func:`excluded_pairs`, derived from the model, no table): parent-
  child pairs (MuJoCo's own filter, which includes bodies welded to their parent, e.g. the
  FANUC's counterweight on the crank); the bodies of a kinematic loop among themselves (the
  bodies on its path between its two sites and the bodies welded to them: they meet by design
  at the loop's hinges; the FANUC's upper arm, crank, rod, forearm and the masses on them);
  and the pairs that come within REFERENCE_GAP = 2 cm of each other in the model's reference
  configuration (they touch by design, a housing across a bearing: the FANUC's coupler rod
  foot beside the turret, the forearm's end around the wrist's pitch housing). Everything else
  counts, e.g. the wrist or the tool against the upper arm, the turret or a counterweight.
* ``compensator_discontinuity`` (paper §3.3): the vertical through a mass compensator's centre
  (the robot's calbench:mass_compensators; the FANUC's m1, m2; none: the rule is void) must not
  cross a passive joint of a loop (derived from the loops: the FANUC's elbow and rod): the
  horizontal distance from the compensator's centre to each passive hinge's axis line is at
  least ``compensator_margin`` (default 0.02 m) in both the unloaded and the loaded
  equilibrium. The discontinuity needs the external load to carry the vertical across the hinge;
  the load moves those points by < 1 mm (0.2 mm on Table 5 with 700 kg), so 2 cm is a wide
  margin. (Gravity's sag of J2, up to 1.8 deg, moves them by centimetres: that is why the rule is
  checked at the equilibria, not at the command.)
* ``visibility``: every reflector seen by the tracker (``bench.tracker.visible_sites``) in both
  the unloaded and the loaded equilibrium.
* ``statics``: both equilibria converge (residual, loop gap) as in bench.campaign.plan_campaign.
"""

from __future__ import annotations

import functools
import math
import os
import re
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from calbench.bench.campaign.run import scenario_params
from calbench.bench.core.errors import InputError
from calbench.bench.core.progress import ProgressSink, sink
from calbench.bench.model.robot import Robot, ancestors
from calbench.bench.scenario.parse import Scenario, parse_scenario
from calbench.bench.statics.equilibrium import Equilibrium, Load, StaticsSolver
from calbench.bench.tracker.instrument import (
    Measurement,
    noise_covariance,
    to_tracker_frame,
    tracker_rotation,
    visible_sites,
)
from calbench.bench.tracker.iso10360 import deflection_covariance
from calbench.bench.tracker.measuring import reading_times
from calbench.identify.runtime.executor import IN_PROCESS, Executor, InProcess
from calbench.identify.runtime.portable import PortableScenario

RULES = (
    "joint_limits",
    "degenerate_loop",
    "min_height",
    "min_radius",
    "self_collision",
    "compensator_discontinuity",
    "statics",
    "visibility",
)
COMMAND_RULES = ("joint_limits", "degenerate_loop", "min_height", "min_radius", "self_collision")
EQUILIBRIUM_RULES = ("statics", "self_collision", "compensator_discontinuity", "visibility")
REFERENCE_GAP = 0.02  # m: closer than this in the reference configuration = touching by design
LOAD_KINDS = ("vertical", "lateral")


# --------------------------------------------------------------------------- settings


@dataclass(frozen=True)
class DesignSettings:
    """The scenario's optional ``[design]`` table (read here from the TOML text)."""

    min_height: float = 0.5  # m, wrist centre z
    min_radius: float = 1.0  # m, wrist centre from axis 1
    candidates: int = 10000  # size of the candidate set
    seed: int | None = None  # candidate sampling; default: the scenario's seed
    clearance: float = 0.0  # m, collision margin
    compensator_margin: float = 0.02  # m, §3.3 rule
    lateral_force: float = 1200.0  # N, horizontal pull of the lateral candidates
    lateral_fraction: float = 0.5  # share of lateral candidates in the set

    def as_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


DESIGN_KEYS = tuple(DesignSettings.__dataclass_fields__)


def _design_number(path, key, v, lo=None, hi=None, integer=False):
    what = (
        ("an integer" if integer else "a finite number")
        + (f" >= {lo}" if lo is not None else "")
        + (f" and <= {hi}" if hi is not None else "")
    )
    ok = not isinstance(v, bool) and isinstance(v, int if integer else (int, float))
    if not ok or not math.isfinite(float(v)) or (lo is not None and v < lo) or (hi is not None and v > hi):
        raise InputError(path, f"design.{key}", what, v)
    return int(v) if integer else float(v)


def read_design_settings(path: str | Path, text: str | None = None) -> DesignSettings:
    """Parse the optional ``[design]`` table of a scenario file (InputError naming the key)."""
    path = Path(path)
    text = Path(path).read_text(encoding="utf-8") if text is None else text
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(path, "(syntax)", "valid TOML", str(exc)) from None
    tab = doc.get("design", {})
    if not isinstance(tab, dict):
        raise InputError(path, "design", "a table", type(tab).__name__)
    for k in tab:
        if k not in DESIGN_KEYS:
            raise InputError(path, f"design.{k}", "no such key; allowed keys here: " + ", ".join(DESIGN_KEYS))
    kw = {}
    limits = {
        "min_height": (None, None, False),
        "min_radius": (0, None, False),
        "candidates": (1, None, True),
        "seed": (0, None, True),
        "clearance": (0, None, False),
        "compensator_margin": (0, None, False),
        "lateral_force": (0, None, False),
        "lateral_fraction": (0, 1, False),
    }
    for k, v in tab.items():
        lo, hi, integer = limits[k]
        kw[k] = _design_number(path, k, v, lo, hi, integer)
    return DesignSettings(**kw)


_DESIGN_TABLE = re.compile(r"^\[design\][^\n]*\n(?:(?!\s*\[)[^\n]*\n?)*", re.MULTILINE)


def load_design_scenario(path: str | Path) -> tuple[Scenario, DesignSettings]:
    """The scenario (bench.scenario.parse_scenario) and its ``[design]`` settings.

    bench/scenario/parse.py does not (yet) accept a ``[design]`` table, so it is cut out of the text
    before parsing; the Scenario's ``text`` is the file without it.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, "(file)", "a readable UTF-8 scenario file", str(exc)) from None
    settings = read_design_settings(path, text)
    stripped = _DESIGN_TABLE.sub("", text)
    try:
        if "design" in tomllib.loads(stripped):
            raise InputError(path, "design", "a [design] table written as a table header")
    except tomllib.TOMLDecodeError:
        pass  # parse_scenario reports it
    return parse_scenario(stripped, path), settings


def nominal_theta(scn: Scenario, robot: Robot) -> np.ndarray:
    """The prior guess theta0 = the scenario's [truth] (see the module docstring)."""
    return robot.layout.theta(scenario_params(scn, robot))


def nominal_robot(scn: Scenario) -> Robot:
    """The design model: the scenario's MJCF with theta0 written in, WITHOUT the hidden
    ``[truth.effects]`` (a design knows the model, not what the model lacks)."""
    try:
        robot = Robot.from_file(scn.robot)
    except ValueError as exc:  # MuJoCo compile errors, the robot description
        raise InputError(scn.path, "robot", "a loadable MJCF robot", f"{scn.robot}: {exc}") from None
    robot.set_params(scenario_params(scn, robot))
    return robot


def wrist_body(robot: Robot) -> int:
    """The body whose origin is the wrist centre: calbench:wrist, else the body of the
    last-but-one actuated joint (a six-axis arm's J5; the joint itself with fewer than two)."""
    m = robot.model
    if robot.description.wrist:
        return mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, robot.description.wrist)
    return int(m.jnt_bodyid[robot.act_joint[max(robot.n_act - 2, 0)]])


def lateral_wrench(q1: float, sign: float, force: float) -> np.ndarray:
    return np.array([-math.sin(q1) * sign * force, math.cos(q1) * sign * force, 0.0, 0.0, 0.0, 0.0])


# --------------------------------------------------------------------------- feasibility


def _collidable(robot_path: Path, margin: float) -> mujoco.MjSpec:
    spec = mujoco.MjSpec.from_file(str(robot_path))
    for g in spec.geoms:
        g.contype = 1
        g.conaffinity = 1
        g.margin = margin
        g.gap = 0.0
    return spec


def _welded(model: mujoco.MjModel, body: int) -> list[int]:
    """The body and its descendants reached without crossing a joint."""
    out = [body]
    for b in range(model.nbody):
        if model.body_parentid[b] == body and b != body and model.body_jntnum[b] == 0:
            out += _welded(model, b)
    return out


def excluded_pairs(robot: Robot, robot_path: Path) -> tuple[tuple[str, str], ...]:
    """Body pairs the self-collision rule does not count (module docstring), derived from the
    model: the bodies of each loop among themselves, and the pairs within REFERENCE_GAP at the
    reference configuration (the rigid pose at q = 0). Sorted name pairs."""
    m = robot.model
    pairs: set[tuple[str, str]] = set()
    for a, b in robot.loops:
        up_a, up_b = ancestors(m, m.site_bodyid[a]), ancestors(m, m.site_bodyid[b])
        root = next(x for x in up_a if x in up_b)
        path = up_a[: up_a.index(root)] + up_b[: up_b.index(root)]
        bodies = sorted({w for x in path for w in _welded(m, x)})
        pairs |= {(m.body(x).name, m.body(y).name) for x in bodies for y in bodies if x != y}
    ref = _collidable(robot_path, REFERENCE_GAP).compile()
    d = mujoco.MjData(ref)
    d.qpos[:] = robot.rigid_qpos(np.zeros(robot.n_act))
    mujoco.mj_kinematics(ref, d)
    mujoco.mj_collision(ref, d)
    for c in d.contact[: d.ncon]:
        b1, b2 = int(ref.geom_bodyid[c.geom[0]]), int(ref.geom_bodyid[c.geom[1]])
        if ref.body_parentid[b1] != b2 and ref.body_parentid[b2] != b1:  # MuJoCo filters those
            pairs.add((ref.body(b1).name, ref.body(b2).name))
    return tuple(sorted({tuple(sorted(p)) for p in pairs}))


def collision_model(robot: Robot, robot_path: Path, clearance: float = 0.0) -> mujoco.MjModel:
    """A copy of the MJCF where every geom collides (margin = clearance), the
    :func:`excluded_pairs` off."""
    spec = _collidable(robot_path, clearance)
    for a, b in excluded_pairs(robot, robot_path):
        ex = spec.add_exclude()
        ex.bodyname1, ex.bodyname2 = a, b
    return spec.compile()


class Feasibility:
    """The feasibility rules of the module docstring for one robot, tracker and settings."""

    def __init__(self, robot: Robot, scn: Scenario, settings: DesignSettings):
        self.robot = robot
        self.scn = scn
        self.settings = settings
        self.limits = robot.limits()
        m = robot.model
        self.cmodel = collision_model(robot, Path(scn.robot), settings.clearance)
        self.cdata = mujoco.MjData(self.cmodel)
        self._kd = mujoco.MjData(m)
        self.wrist = wrist_body(robot)
        self.masses = [
            mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, n) for n in robot.description.mass_compensators
        ]
        self.hinges = list(robot.passive_joint)
        # axis 1: the first actuated joint's axis line, fixed in the world (its body hangs from
        # the world: it does not move with the command)
        self._kd.qpos[:] = robot.rigid_qpos(np.zeros(robot.n_act))
        mujoco.mj_kinematics(m, self._kd)
        self.axis1 = (self._kd.xanchor[robot.act_joint[0]].copy(), self._kd.xaxis[robot.act_joint[0]].copy())

    # -- individual rules ---------------------------------------------------------------------
    def loop(self, q) -> bool:
        return self.robot.loop_ok(q)

    def wrist_centre(self, qpos) -> np.ndarray:
        d = self._kd
        d.qpos[:] = qpos
        mujoco.mj_kinematics(self.robot.model, d)
        return d.xpos[self.wrist].copy()

    def collides(self, qpos) -> list[tuple[str, str]]:
        """Body pairs in contact (within the clearance) at qpos; empty when free."""
        m, d = self.cmodel, self.cdata
        d.qpos[:] = qpos
        mujoco.mj_kinematics(m, d)
        mujoco.mj_collision(m, d)
        out = []
        if d.ncon == 0:  # slicing d.contact costs ~120 us even when empty
            return out
        for c in d.contact[: d.ncon]:
            b1, b2 = m.geom_bodyid[c.geom[0]], m.geom_bodyid[c.geom[1]]
            out.append((m.body(b1).name, m.body(b2).name))
        return out

    def compensator_clearance(self, qpos) -> float:
        """Smallest horizontal distance from a mass compensator's centre to a passive hinge's
        axis line (m) at qpos (§3.3); infinite without mass compensators or passive hinges."""
        m, d = self.robot.model, self._kd
        d.qpos[:] = qpos
        mujoco.mj_kinematics(m, d)
        return float(
            horizontal_clearance(
                d.xipos[self.masses][None], d.xanchor[self.hinges][None], d.xaxis[self.hinges][None]
            )[0]
        )

    def radius(self, points: np.ndarray) -> np.ndarray:
        """(n,) distance of points (n, 3) from axis 1 (m)."""
        p, a = self.axis1
        v = np.asarray(points, float) - p
        return np.linalg.norm(v - np.outer(v @ a, a), axis=1)

    # -- the rules' decisions, stacked over configurations (also identify/design/batch_info.py) --
    def command_violations(self, q: np.ndarray, wrist: np.ndarray, collides, loop_ok=None) -> np.ndarray:
        """(n, len(COMMAND_RULES)) bool, True where a rule fails, for commands q (n, joints) whose
        rigid poses have wrist centres ``wrist`` (n, 3) and collision flags ``collides`` (n,);
        ``loop_ok`` (n,): Robot.loop_ok of each, if already known (else asked here)."""
        lo, hi = self.limits[:, 0], self.limits[:, 1]
        loop_ok = [self.loop(x) for x in q] if loop_ok is None else loop_ok
        return np.column_stack(
            [
                ~np.all((q >= lo - 1e-9) & (q <= hi + 1e-9), axis=1),
                ~np.asarray(loop_ok, bool),
                wrist[:, 2] < self.settings.min_height,
                self.radius(wrist) < self.settings.min_radius,
                np.asarray(collides, bool),
            ]
        )

    def equilibrium_violations(
        self, acceptable, collides, clearance, visible, require_all_visible: bool = True
    ) -> tuple[np.ndarray, np.ndarray]:
        """(n, len(EQUILIBRIUM_RULES)) bool violations and the (n, k) reflectors seen in both
        states, from per-state inputs with the states on axis 1: acceptable and collides (n, 2),
        clearance (n, 2) m, visible (n, 2, k)."""
        vis = np.asarray(visible, bool).all(axis=1)
        seen = vis.all(axis=1) if require_all_visible else vis.any(axis=1)
        return np.column_stack(
            [
                ~np.asarray(acceptable, bool).all(axis=1),
                np.asarray(collides, bool).any(axis=1),
                np.asarray(clearance).min(axis=1) < self.settings.compensator_margin,
                ~seen,
            ]
        ), vis

    # -- combined -----------------------------------------------------------------------------
    def check_command(self, q) -> list[str]:
        """Rules decided at the commanded (rigid) pose, cheapest first; all violations."""
        q = np.asarray(q, float)
        qpos = self.robot.rigid_qpos(q)
        bad = self.command_violations(q[None], self.wrist_centre(qpos)[None], [bool(self.collides(qpos))])[0]
        return [r for r, b in zip(COMMAND_RULES, bad) if b]

    def check_equilibria(self, e0: Equilibrium, e1: Equilibrium, require_all_visible=True):
        """Rules decided at the solved equilibria: (violations, visible mask (n,) both states)."""
        m, d = self.robot.model, self._kd
        vis = []
        for e in (e0, e1):
            d.qpos[:] = e.qpos
            mujoco.mj_kinematics(m, d)
            vis.append(visible_sites(m, d, self.scn.tracker, self.robot.reflector_sites))
        states = (e0, e1)
        bad, seen = self.equilibrium_violations(
            [[e.acceptable for e in states]],
            [[bool(self.collides(e.qpos)) for e in states]],
            [[self.compensator_clearance(e.qpos) for e in states]],
            [vis],
            require_all_visible,
        )
        return [r for r, b in zip(EQUILIBRIUM_RULES, bad[0]) if b], seen[0]


def horizontal_clearance(centres: np.ndarray, anchors: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """Smallest horizontal distance (n,) from k points (n, k, 3) to h axis lines through
    ``anchors`` along ``axes`` (n, h, 3), in the horizontal plane (the §3.3 rule: a vertical
    line through a mass compensator's centre must not cross a passive hinge's axis); a vertical
    axis counts by its foot point. No points or no axes: infinitely far (the rule is void)."""
    if centres.shape[1] == 0 or anchors.shape[1] == 0:
        return np.full(len(centres), np.inf)
    v = centres[:, :, None, :2] - anchors[:, None, :, :2]  # (n, k, h, 2)
    axh = axes[:, None, :, :2]
    n = np.sqrt(np.einsum("...i,...i->...", axh, axh))
    vertical = n < 1e-9
    u = axh / np.where(vertical, 1.0, n)[..., None]
    along = np.where(vertical, 0.0, np.einsum("...i,...i->...", v, u))
    w = v - u * along[..., None]
    return np.sqrt(np.einsum("...i,...i->...", w, w)).min(axis=(1, 2))


# --------------------------------------------------------------------------- information


@dataclass
class PoseInfo:
    q: np.ndarray
    wrench: np.ndarray  # (6,) world: payload weight or the pull
    kind: str
    block: np.ndarray  # (3 n_visible, p) whitened, normalised regressor
    visible: np.ndarray  # (n,) bool
    violations: list[str]
    dp: np.ndarray | None = None  # (n, 3) deflections (visible rows meaningful)


class InfoEngine:
    """Exact information of single poses on the design model (one per process)."""

    def __init__(self, scn: Scenario, settings: DesignSettings):
        self.scn = scn
        self.settings = settings
        self.robot = nominal_robot(scn)
        self.params0 = scenario_params(scn, self.robot)
        self.theta0 = self.robot.layout.theta(self.params0)
        self.n_params = self.robot.layout.n
        self.solver = StaticsSolver(self.robot, tol=1e-10)
        self.feas = Feasibility(self.robot, scn, settings)
        self.rot = tracker_rotation(scn.tracker)
        self._js = np.zeros((3, self.robot.model.nv))
        self._jr = np.zeros((3, self.robot.model.nv))

    def load_for(self, wrench) -> Load:
        return Load.wrench(self.robot, wrench)

    def _dforce(self, e: Equilibrium) -> np.ndarray:
        """dg/dtheta at fixed q (nv, p) at equilibrium e, for the prior guess theta0."""
        rb = self.robot
        rb.set_command(e.command)
        rb.data.qpos[:] = e.qpos
        mujoco.mj_fwdPosition(rb.model, rb.data)
        return rb.dforce_dtheta(self.params0)

    def _site_jac(self, e: Equilibrium, load: Load | None) -> tuple[np.ndarray, np.ndarray]:
        """Reflector positions (n,3) and d position / d theta (n,3,p) at equilibrium e."""
        rb = self.robot
        tan = self.solver.tangent(e, load, self._dforce(e))
        m, d = rb.model, rb.data
        d.qpos[:] = e.qpos
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        pos = d.site_xpos[rb.reflector_sites].copy()
        jac = np.empty((len(rb.reflector_sites), 3, self.n_params))
        for i, s in enumerate(rb.reflector_sites):
            mujoco.mj_jacSite(m, d, self._js, None, int(s))
            jac[i] = self._js @ tan
        return pos, jac

    def sigma_dp_blocks(self, p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
        """(n, 3k, 3k): :meth:`sigma_dp` of n candidates at once (p0, p1: (n, k, 3), one reading
        per state); block diagonal by reflector, vectorised, unless the tracker's error is
        correlated (iso10360: one candidate at a time)."""
        n, k = p0.shape[:2]
        if self.scn.tracker.model == "iso10360":
            return np.stack([self.sigma_dp(a, b) for a, b in zip(p0, p1)])
        spec = self.scn.tracker
        c = noise_covariance(spec, to_tracker_frame(spec, p0.reshape(-1, 3))) + noise_covariance(
            spec, to_tracker_frame(spec, p1.reshape(-1, 3))
        )
        c = (self.rot @ c @ self.rot.T).reshape(n, k, 3, 3)
        out = np.zeros((n, k, 3, k, 3))
        for i in range(k):
            out[:, i, :, i, :] = c[:, i]
        return out.reshape(n, 3 * k, 3 * k)

    def sigma_dp(self, p0: np.ndarray, p1: np.ndarray, repeats: int = 1) -> np.ndarray:
        """(3n, 3n) world covariance of the n deflections of one pose read ``repeats`` times per
        state on the campaign clock (bench.iso10360.deflection_covariance: block diagonal by
        reflector unless the tracker's error is correlated)."""
        spec = self.scn.tracker
        n = len(p0)
        reads, times = [], reading_times([repeats], n)
        for p in (p0, p1):
            y = to_tracker_frame(spec, p)
            reads.append([Measurement(y, noise_covariance(spec, y), np.ones(n, bool))] * repeats)
        when = tuple([times[(0, s, r)] for r in range(repeats)] for s in ("unloaded", "loaded"))
        c = deflection_covariance(spec, reads[0], reads[1], np.arange(n), when)
        return np.einsum("ia,ranb,jb->rinj", self.rot, c, self.rot).reshape(3 * n, 3 * n)

    def pose(
        self,
        q,
        wrench,
        kind="vertical",
        e0: Equilibrium | None = None,
        require_all_visible=True,
        check=True,
        repeats: int = 1,
    ) -> PoseInfo:
        """Feasibility and the information block of one pose (the unloaded e0 may be reused)."""
        q = np.asarray(q, float)
        wrench = np.asarray(wrench, float)
        bad = self.feas.check_command(q) if check else []
        if check and any(r in bad for r in ("joint_limits", "degenerate_loop")):
            return PoseInfo(q, wrench, kind, np.zeros((0, self.n_params)), np.zeros(0, bool), bad)
        load = self.load_for(wrench)
        if e0 is None:
            e0 = self.solver.solve(q)
        e1 = self.solver.solve(q, load, warm=e0)
        if check:
            bad2, vis = self.feas.check_equilibria(e0, e1, require_all_visible)
            bad += [b for b in bad2 if b not in bad]
        else:
            vis = np.ones(len(self.robot.reflector_sites), bool)
        p0, j0 = self._site_jac(e0, None)
        p1, j1 = self._site_jac(e1, load)
        jac = (j1 - j0)[vis] * self.theta0  # normalised columns
        linv = np.linalg.inv(np.linalg.cholesky(self.sigma_dp(p0[vis], p1[vis], repeats)))
        block = linv @ jac.reshape(-1, self.n_params)
        return PoseInfo(q, wrench, kind, block, vis, bad, p1 - p0)

    def work_jacobian(self, q, wrench) -> np.ndarray:
        """G (3, p): d(payload-site deflection under the work wrench)/d(theta normalised)."""
        rb = self.robot
        load = self.load_for(wrench)
        e0 = self.solver.solve(np.asarray(q, float))
        e1 = self.solver.solve(np.asarray(q, float), load, warm=e0)
        out = []
        for e, ld in ((e0, None), (e1, load)):
            tan = self.solver.tangent(e, ld, self._dforce(e))
            m, d = rb.model, rb.data
            d.qpos[:] = e.qpos
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            mujoco.mj_jacSite(m, d, self._js, None, rb.payload_site)
            out.append(self._js @ tan)
        return (out[1] - out[0]) * self.theta0


# --------------------------------------------------------------------------- candidate set


@dataclass
class CandidateSet:
    q: np.ndarray  # (N, n_joints) rad
    wrench: np.ndarray  # (N, 6)
    kind: np.ndarray  # (N,) 0 vertical, 1 lateral
    blocks: np.ndarray  # (N, m, p)
    theta0: np.ndarray
    settings: DesignSettings
    stats: dict = field(default_factory=dict)
    param_names: tuple[str, ...] = ()  # the p parameters (the robot's layout)

    def __len__(self) -> int:
        return len(self.q)

    def save_npz(self, path: str | Path, normalise: bool = False) -> None:
        """The NPZ of identify/design/candidate_file.py (``normalise``: unit column scales)."""
        from .candidate_file import write_candidates

        write_candidates(
            path, self.q, self.blocks, self.wrench, self.kind, self.theta0, self.param_names, normalise
        )


def sample_commands(rng: np.random.Generator, limits: np.ndarray, n: int) -> np.ndarray:
    """n commands uniform in the joint ranges, each clipped to [-180, 180] deg (a hinge's
    statics is periodic: the FANUC's q4, q6 range over +-360)."""
    lo, hi = np.maximum(limits[:, 0], -np.pi), np.minimum(limits[:, 1], np.pi)
    return lo + (hi - lo) * rng.random((n, len(limits)))


CANDIDATE_BLOCK = 512  # raw commands per chunk (a few tenths of a second of batched work)
BATCH = 4096  # commands drawn at a time (the order of the random stream)
SECONDS_PER_CANDIDATE = 2e-4  # in-process, batched (10^4 in ~1.7 s of CPU), for the executor choice


@dataclass(frozen=True)
class CandidateJob:
    """What a chunk of raw commands needs on any machine (identify/runtime/executor.py): the scenario's
    texts, the settings, the load probabilities, and how to compute (batched, threads)."""

    scenario: PortableScenario
    settings: DesignSettings
    p_vertical: float
    p_lateral: float
    batched: bool = True
    threads: int = 1


@functools.lru_cache(maxsize=2)
def _engine(scenario: PortableScenario, settings: DesignSettings) -> InfoEngine:
    return InfoEngine(scenario.scenario(), settings)


@functools.lru_cache(maxsize=2)
def _batch(job: CandidateJob):
    from .batch_info import BatchInfo

    return BatchInfo(_engine(job.scenario, job.settings), nthread=job.threads)


def candidate_block(job: CandidateJob, q, signs, u_lat, u_vert) -> dict:
    """The task: one chunk of raw commands (see :func:`scalar_block`), on this process's engine
    for the job (built once per process; a chunk's result does not depend on the chunks before)."""
    if job.batched:
        return _batch(job).block(q, signs, u_lat, u_vert, job.p_vertical, job.p_lateral)
    return scalar_block(
        _engine(job.scenario, job.settings), q, signs, u_lat, u_vert, job.p_vertical, job.p_lateral
    )


def scalar_block(eng: InfoEngine, q, signs, u_lat, u_vert, p_vertical: float, p_lateral: float) -> dict:
    """One chunk of raw commands, one candidate at a time (InfoEngine.pose): the reference that
    identify/design/batch_info.BatchInfo.block reproduces. Returns the feasible candidates as
    (q, wrench, kind, block) in command order, the rejections by first rule, and how many
    commands passed the command rules with a load."""
    st = eng.settings
    vertical = np.concatenate([eng.robot.weight(eng.scn.load_mass), np.zeros(3)])
    rejected = {r: 0 for r in RULES}
    out, passed = [], 0
    for qi, s, ul, uv in zip(np.asarray(q, float), signs, u_lat, u_vert):
        bad = eng.feas.check_command(qi)
        if bad:
            rejected[bad[0]] += 1
            continue
        loads = []
        if uv < p_vertical:
            loads.append((vertical, 0))
        if ul < p_lateral and st.lateral_force > 0:
            loads.append((lateral_wrench(qi[0], s, st.lateral_force), 1))
        if not loads:
            continue
        passed += 1
        try:
            e0 = eng.solver.solve(qi)
        except (np.linalg.LinAlgError, RuntimeError):
            e0 = None
        for w, kind in loads:
            info = None
            if e0 is not None:
                try:
                    info = eng.pose(qi, w, LOAD_KINDS[kind], e0=e0, check=True)
                except (np.linalg.LinAlgError, RuntimeError):
                    pass
            if info is not None and not info.violations:
                out.append((qi, w, kind, info.block))
            else:
                rejected["visibility"] += 1  # equilibrium rules, mostly visibility
    return {"candidates": out, "rejected": rejected, "passed": passed}


def generate_candidates(
    scn: Scenario,
    settings: DesignSettings,
    n: int | None = None,
    processes: int | None = None,
    progress: ProgressSink | None = None,
    batched: bool = True,
    executor: Executor | None = None,
) -> CandidateSet:
    """At least ``n`` (default settings.candidates) feasible candidates, exactly n returned.

    Raw commands are drawn uniformly in the joint ranges (seeded by settings.seed or the
    scenario's) in batches of BATCH and handled in chunks of CANDIDATE_BLOCK: the command rules,
    the equilibria, the remaining rules and the exact information, by
    identify/design/batch_info.BatchInfo.block (``batched=False``: :func:`scalar_block`, one
    candidate at a time, the reference). The chunks are tasks of ``executor``
    (identify/runtime/executor.py; default: this process, on ``processes`` threads, default the CPUs it
    may use; a Dask worker uses ``processes`` threads, default one: one worker per core). Each
    surviving command yields a vertical candidate and, with probability lateral_fraction /
    (1 - lateral_fraction) capped at 1, a lateral one. The first n feasible candidates in the
    order of the draws are kept, so the result is deterministic for a given seed and n, whatever
    the executor, worker and thread count.
    """
    n = settings.candidates if n is None else n
    seed = scn.seed if settings.seed is None else settings.seed
    rng = np.random.default_rng([seed, 4])
    t0 = time.perf_counter()
    executor = executor or InProcess()
    here = executor.choice.kind == IN_PROCESS
    threads = processes or (len(os.sched_getaffinity(0)) if here else 1)
    frac = settings.lateral_fraction
    p_lat = 1.0 if frac >= 0.5 else frac / (1 - frac)
    p_vert = 1.0 if frac <= 0.5 else (1 - frac) / frac
    job = CandidateJob(PortableScenario.from_scenario(scn), settings, p_vert, p_lat, batched, threads)
    eng = _engine(job.scenario, job.settings)
    limits = eng.robot.limits()
    phase0 = dict(_batch(job).seconds) if here and batched else None
    bar = sink(progress)
    bar.start(n, "candidates")
    rejected: dict[str, int] = {r: 0 for r in RULES}
    qs, ws, kinds, blocks = [], [], [], []
    screened = raw = shown = 0

    def chunks():
        while True:
            batch = sample_commands(rng, limits, BATCH)
            signs = np.where(rng.random(len(batch)) < 0.5, -1.0, 1.0)
            u_lat = rng.random(len(batch))
            u_vert = rng.random(len(batch))
            for a in range(0, BATCH, CANDIDATE_BLOCK):
                sl = slice(a, a + CANDIDATE_BLOCK)
                yield job, batch[sl], signs[sl], u_lat[sl], u_vert[sl]

    results = executor.ordered(candidate_block, chunks())
    try:
        for got in results:
            raw += CANDIDATE_BLOCK
            screened += got["passed"]
            for r, k in got["rejected"].items():
                rejected[r] += k
            for q, w, kind, block in got["candidates"]:
                qs.append(q)
                ws.append(w)
                kinds.append(kind)
                blocks.append(block)
            now = min(len(qs), n)
            bar.update(f"candidates {now}/{n}", step=now - shown)
            shown = now
            if len(qs) >= n:
                break
            if raw > 200 * n:  # give up only while still short of n
                raise InputError(
                    scn.path,
                    "design",
                    "settings that leave feasible configurations",
                    f"only {len(qs)} of {raw} sampled commands feasible",
                )
    finally:
        results.close()  # cancels the chunks drawn ahead
    m = max(b.shape[0] for b in blocks)
    out = np.zeros((n, m, eng.n_params))
    for i, b in enumerate(blocks[:n]):
        out[i, : b.shape[0]] = b
    stats = {
        "raw_commands": raw,
        "passed_command_rules": screened,
        "rejected_first_rule": rejected,
        "seconds": time.perf_counter() - t0,
        "threads": threads,
        "batched": batched,
        "executor": executor.choice.describe(),
    }
    if phase0 is not None:
        stats["phase_seconds"] = {k: round(v - phase0.get(k, 0.0), 4) for k, v in _batch(job).seconds.items()}
    return CandidateSet(
        np.array(qs[:n]),
        np.array(ws[:n]),
        np.array(kinds[:n], int),
        out,
        eng.theta0,
        settings,
        stats,
        eng.robot.layout.names,
    )


__all__ = [
    "DesignSettings",
    "read_design_settings",
    "load_design_scenario",
    "nominal_theta",
    "nominal_robot",
    "Feasibility",
    "InfoEngine",
    "PoseInfo",
    "CandidateSet",
    "generate_candidates",
    "scalar_block",
    "candidate_block",
    "CandidateJob",
    "SECONDS_PER_CANDIDATE",
    "lateral_wrench",
    "collision_model",
    "horizontal_clearance",
    "excluded_pairs",
    "wrist_body",
    "REFERENCE_GAP",
    "RULES",
    "COMMAND_RULES",
    "EQUILIBRIUM_RULES",
]
