"""Which commanded configurations a plan may use: the named feasibility rules (issue 4, §2).

Feasibility rules (each named; :func:`Feasibility.check` returns the violated ones):

* ``joint_limits``: q inside the MJCF's controller ranges (q4, q6 sampled in [-180, 180]).
* ``degenerate_loop``: every kinematic loop at least ``bench.robot.LOOP_MARGIN`` from degenerate
  (``bench.robot.Robot.loop_ok``: the inverse condition number of its passive-joint Jacobian;
  on the FANUC q3 - q2 at least 10 deg away from the degenerate -120 / 60 deg).
* ``min_height`` / ``min_radius``: the WRIST CENTRE (the origin of the robot's calbench:wrist
  body, by default of the body of the last-but-one actuated joint: on a six-axis arm the J5
  axis, the point of the paper's Fig. 6; the FANUC's link5) at z >= min_height and at least
  min_radius from axis 1 (distance from the first actuated joint's axis line), at the commanded
  (rigid) pose. Paper: 0.5 m and 1 m, the defaults for a robot of 2.5 m reach or more; a
  smaller robot's scale with its reach (:func:`robot_reach`, DesignSettings.for_reach).
* ``self_collision``: MuJoCo collision detection on a copy of the MJCF with every geom made
  collidable (contype = conaffinity = 1, margin = ``clearance``), at the rigid pose and at both
  equilibria. Not counted (:func:`excluded_pairs`, derived from the model, no table): parent-
  child pairs (MuJoCo's own filter, which includes bodies welded to their parent, e.g. the
  FANUC's counterweight on the crank, but never filters a child of the world's weld group: we
  exclude those pairs ourselves, a URDF's ``base_link`` against ``link_1``, the FANUC's base
  against the turret; :func:`world_parent_pairs`); the bodies of a kinematic loop among themselves (the
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

import math
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from calbench.bench.core import StaticsError
from calbench.bench.model import LOOP_MARGIN, Robot, ancestors
from calbench.bench.scenario import Scenario, parse_scenario
from calbench.bench.statics import Equilibrium, Load, StaticsSolver
from calbench.bench.tracker import (
    visible_sites,
)

from .settings import DesignSettings, nominal_robot, read_design_settings

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


def wrist_body(robot: Robot) -> int:
    """The body whose origin is the wrist centre: calbench:wrist, else the body of the
    last-but-one actuated joint (a six-axis arm's J5; the joint itself with fewer than two)."""
    m = robot.model
    if robot.description.wrist:
        return mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, robot.description.wrist)
    return int(m.jnt_bodyid[robot.act_joint[max(robot.n_act - 2, 0)]])


def robot_reach(robot: Robot) -> float:
    """R (m): an upper bound of the wrist centre's distance from axis 1 over every command, from
    the reference pose (q = 0): the chain of joint anchors on the kinematic tree's path from the
    wrist centre up to axis 1's body, its segment lengths summed, plus the radial distance from
    axis 1 of the chain's last anchor (each joint turns its segment rigidly: the triangle
    inequality). The FANUC M-900iB: 2.87 m, the KR 270: 2.70 m, a UR10: 1.32 m (data sheets:
    2.83, 2.70, 1.30 m to the flange)."""
    m = robot.model
    d = mujoco.MjData(m)
    d.qpos[:] = robot.rigid_qpos(np.zeros(robot.n_act))
    mujoco.mj_kinematics(m, d)
    j1 = robot.act_joint[0]
    origin, axis = d.xanchor[j1], d.xaxis[j1]
    body, top = wrist_body(robot), int(m.jnt_bodyid[j1])
    chain = [d.xpos[body].copy()]
    while body not in (top, 0):
        adr = m.body_jntadr[body]
        chain += [d.xanchor[j].copy() for j in range(adr, adr + m.body_jntnum[body])]
        body = int(m.body_parentid[body])
    v = chain[-1] - origin
    radial = float(np.linalg.norm(v - (v @ axis) * axis))
    return radial + float(sum(np.linalg.norm(a - b) for a, b in zip(chain, chain[1:])))


def lateral_wrench(q1: float, sign: float, force: float) -> np.ndarray:
    return np.array([-math.sin(q1) * sign * force, math.cos(q1) * sign * force, 0.0, 0.0, 0.0, 0.0])


def sample_commands(rng: np.random.Generator, limits: np.ndarray, n: int) -> np.ndarray:
    """n commands uniform in the joint ranges, each clipped to [-180, 180] deg (a hinge's
    statics is periodic: the FANUC's q4, q6 range over +-360)."""
    lo, hi = np.maximum(limits[:, 0], -np.pi), np.minimum(limits[:, 1], np.pi)
    return lo + (hi - lo) * rng.random((n, len(limits)))


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


def mujoco_filters(model: mujoco.MjModel, b1: int, b2: int) -> bool:
    """Whether MuJoCo's own contact filter drops every contact between bodies b1 and b2: the
    same weld group (bodies welded together), or parent and child weld groups, where neither is
    the world's (MuJoCo never filters a pair whose parent is welded to the world: a URDF's
    ``base_link`` against ``link_1``). The rule of mj_collision's body filter (filterparent on)."""
    w1, w2 = int(model.body_weldid[b1]), int(model.body_weldid[b2])
    if w1 == w2:
        return True
    p1, p2 = (int(model.body_weldid[model.body_parentid[w]]) for w in (w1, w2))
    return w1 != 0 and w2 != 0 and (w1 == p2 or w2 == p1)


def world_parent_pairs(model: mujoco.MjModel) -> set[tuple[str, str]]:
    """Parent-child pairs MuJoCo does not filter: each body of a weld group hanging by a joint
    from the world's weld group (the world and the bodies welded to it, e.g. ``base_link``)
    against each body of the world's group, bodies with geoms only. MuJoCo filters the same pair
    for a jointed parent; across joint 1 the meshes of every ROS-Industrial robot touch."""
    geoms = [b for b in range(model.nbody) if model.body_geomnum[b] > 0]
    world = [b for b in geoms if model.body_weldid[b] == 0]
    out = set()
    for b in geoms:
        w = int(model.body_weldid[b])
        if w != 0 and model.body_weldid[model.body_parentid[w]] == 0:
            out |= {(model.body(a).name, model.body(b).name) for a in world}
    return out


def excluded_pairs(robot: Robot, robot_path: Path) -> tuple[tuple[str, str], ...]:
    """Body pairs the self-collision rule does not count (module docstring), derived from the
    model: the parent-child pairs MuJoCo does not filter (:func:`world_parent_pairs`), the bodies
    of each loop among themselves, and the pairs within REFERENCE_GAP at the reference
    configuration (the rigid pose at q = 0; every contact MuJoCo reports there, since MuJoCo
    has filtered its own pairs already). Sorted name pairs."""
    m = robot.model
    pairs = world_parent_pairs(m)
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
        self.settings = settings.for_reach(robot_reach(robot))  # the defaults scaled
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


# --------------------------------------------------------------------------- why commands fail


@dataclass
class RuleTally:
    """Each rule on its own over a sample of commands (not the first failing rule): how many it
    rejected and the pair, limit or value that did it. The equilibrium rules are tallied on the
    commands that pass every command rule (at most ``equilibria`` of them), with the scenario's
    payload hung at the payload site."""

    sampled: int
    failed: dict[str, int] = field(default_factory=dict)
    culprit: dict[str, str] = field(default_factory=dict)
    passed_command: int = 0  # commands that pass every command rule
    solved: int = 0  # of those, how many had their equilibria checked
    feasible: int = 0  # of those, how many pass every rule
    wrist_rules: str = ""  # min_height and min_radius as applied, and the reach they scale with

    def tried(self, rule: str) -> int:
        return self.solved if rule in EQUILIBRIUM_RULES and rule not in COMMAND_RULES else self.sampled

    def summary(self) -> str:
        """One line: the rules that reject, each with its count and culprit."""
        bad = [r for r in RULES if self.failed.get(r)]
        parts = [
            f"{r} rejects {self.failed[r]} of {self.tried(r)}"
            + (f" ({self.culprit[r]})" if self.culprit.get(r) else "")
            for r in bad
        ]
        return "; ".join(parts) or "no rule rejects any"

    def lines(self) -> list[str]:
        """Per rule, the share of the sample it lets pass, for people."""
        out = []
        for r in RULES:
            n = self.tried(r)
            if n == 0:
                out.append(f"    {r:<26} not tried (no command passed the command rules)")
                continue
            share = 100.0 * (n - self.failed.get(r, 0)) / n
            extra = f"  ({self.culprit[r]})" if self.failed.get(r) and self.culprit.get(r) else ""
            out.append(f"    {r:<26} {share:5.1f} % of {n} pass{extra}")
        return out


def _top(counter: Counter, n: int) -> str:
    (what, k), *_ = counter.most_common(1)
    return f"{what} in {k} of {n}"


def tally_rules(feas: Feasibility, solver: StaticsSolver, mass: float, q: np.ndarray, equilibria: int = 24):
    """The :class:`RuleTally` of commands q (n, joints) rad, on the feasibility rules ``feas``
    (its robot's statics ``solver``, a payload ``mass`` kg for the loaded state)."""
    rb, st = feas.robot, feas.settings
    q = np.atleast_2d(np.asarray(q, float))
    n = len(q)
    t = RuleTally(n)
    qpos, wrist, loops, pairs = [], [], [], Counter()
    collides = np.zeros(n, bool)
    for i, qi in enumerate(q):
        try:
            x = rb.rigid_qpos(qi)
            ok = rb.loop_ok(qi, x)
        except StaticsError:  # a loop that does not close: degenerate
            x, ok = rb.rigid_qpos(np.zeros(rb.n_act)), False
        qpos.append(x)
        wrist.append(feas.wrist_centre(x))
        loops.append(ok)
        hit = {tuple(sorted(p)) for p in feas.collides(x)}
        collides[i] = bool(hit)
        pairs.update("-".join(p) for p in hit)
    wrist = np.array(wrist)
    bad = feas.command_violations(q, wrist, collides, loops)
    lim = feas.limits
    names = rb.description.actuated
    for k, r in enumerate(COMMAND_RULES):
        t.failed[r] = int(bad[:, k].sum())
    out_of = Counter(
        f"{names[j]} outside [{math.degrees(lim[j, 0]):.0f}, {math.degrees(lim[j, 1]):.0f}] deg"
        for qi in q
        for j in np.flatnonzero((qi < lim[:, 0] - 1e-9) | (qi > lim[:, 1] + 1e-9))
    )
    if out_of:
        t.culprit["joint_limits"] = _top(out_of, n)
    if rb.loops:
        t.culprit["degenerate_loop"] = (
            f"loop {', '.join(rb.description.loops)} conditioning below {LOOP_MARGIN:.3f}: near degenerate"
        )
    wname = rb.model.body(feas.wrist).name
    t.wrist_rules = (
        f"min_height {st.min_height:.3g} m, min_radius {st.min_radius:.3g} m; reach {robot_reach(rb):.2f} m"
    )
    t.culprit["min_height"] = (
        f"wrist centre {wname} below {st.min_height:.3g} m; highest {wrist[:, 2].max():.2f} m"
    )
    t.culprit["min_radius"] = (
        f"wrist centre {wname} within {st.min_radius:.3g} m of axis 1; farthest {feas.radius(wrist).max():.2f} m"
    )
    if pairs:
        t.culprit["self_collision"] = _top(pairs, n)
    good = np.flatnonzero(~bad.any(axis=1))
    t.passed_command = len(good)
    load = Load.mass(rb, mass)
    hidden, eq_pairs = Counter(), Counter()
    for i in good[:equilibria]:
        t.solved += 1
        try:
            e0 = solver.solve(q[i])
            e1 = solver.solve(q[i], load, warm=e0)
        except (StaticsError, np.linalg.LinAlgError, RuntimeError):
            t.failed["statics"] = t.failed.get("statics", 0) + 1
            continue
        viol, seen = feas.check_equilibria(e0, e1)
        for r in viol:
            if r != "self_collision":
                t.failed[r] = t.failed.get(r, 0) + 1
        if "self_collision" in viol:
            eq_pairs.update({"-".join(sorted(p)) for e in (e0, e1) for p in feas.collides(e.qpos)})
            t.failed["self_collision"] += 1
        hidden.update(rb.description.reflectors[j] for j in np.flatnonzero(~seen))
        t.feasible += not viol
    if hidden:
        t.culprit["visibility"] = _top(Counter({f"{k} hidden": v for k, v in hidden.items()}), t.solved)
    if eq_pairs and not pairs:
        t.culprit["self_collision"] = "at the equilibria: " + _top(eq_pairs, t.solved)
    t.culprit["statics"] = "no converged equilibrium (unloaded or loaded)"
    t.culprit["compensator_discontinuity"] = (
        f"a mass compensator's vertical within {st.compensator_margin:g} m of a passive hinge"
    )
    return t


def robot_tally(path: Path, tracker, mass: float, n: int = 256, seed: int = 0) -> RuleTally:
    """`check-robot`'s look at design: :func:`tally_rules` on n commands sampled as design
    samples them, with design's default settings (for that payload: its lateral pull), the tracker at ``tracker`` (m), a payload
    ``mass`` (kg) and the MJCF's own stiffness values as the prior."""
    robot = Robot.from_file(path)
    p = robot.params()
    springs = "".join(
        f"[truth.compensators.{k}]\nstiffness = {v.stiffness!r}\npreload = {v.preload!r}\n"
        for k, v in p.springs.items()
    )
    text = (
        f'robot = "{Path(path).resolve().as_posix()}"\nseed = {seed}\n'
        f"[truth]\ncompliance = {[float(c) for c in p.compliance]}\n{springs}"
        f"[tracker]\nsigma = 2e-5\nposition = {[float(x) for x in tracker]}\n"
        f"[load]\nmass = {float(mass)!r}\n[[pose]]\nq = {[0.0] * robot.n_act}\n"
    )
    scn = parse_scenario(text, Path(path).with_name("(check-robot)"))
    rb = nominal_robot(scn)
    feas = Feasibility(rb, scn, read_design_settings(scn.path, text))  # design's defaults for that load
    q = sample_commands(np.random.default_rng([seed, 5]), rb.limits(), n)
    return tally_rules(feas, StaticsSolver(rb, tol=1e-10), mass, q)


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
