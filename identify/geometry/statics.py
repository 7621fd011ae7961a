"""The complete model of absolute readings on any calbench robot: kinematic loops and compensator
springs included, each reading an equilibrium of calbench's statics (docs/geometry.md).

The numpy chain of model.py is a serial arm whose joints bend under its own weight by c_k tau_k.
A robot with a parallelogram (the FANUC: a `connect` equality closes crank, rod and forearm) or a
compensator spring (the FANUC's and the KR 270's balancer tendon) is not one: its forearm's pitch
is set by the loop, and its second joint bends under gravity's torque AND the spring's. Here a
reading is the reflector's position in the robot's static equilibrium, as the bench solves it
(bench/statics: the KKT Newton solver, loops held closed as hard constraints, paper eq. (17)),
on the user's MJCF with the geometric parameters written into the compiled model:

    y = B  x_site( q_eq(q; o, E, c, K_C, s0), t )

* ``o_k`` (``joint_offset``): the body that carries actuated joint k turned by o_k about the
  hinge (bench/model/effects/geometric.py joint_offset, the same edit a bench truth hides);
* ``E_b`` (``link_geometry``): the frame of each body an actuated joint turns, off by six numbers
  (frame_error), applied after the offset's turn as a truth that lists joint_offset first does;
* ``c_k`` (``joint_compliance``): the actuated joints' compliances, deltas from identify's generic
  start (bench/model/params.py: 1e-7 rad/(N*m); never the MJCF's values). A spring's force shows
  in the readings only through a compliant joint, so the compliances start there, not at zero;
* per compensator tendon (``compensator``, paper eqs. 7-11) its stiffness K_C (N/m) and
  P = K_C s0 (N, s0 its preload length), in which the spring's force K_C L - P is linear (as
  identify/methods/onestep.py iterates), starting at no spring (0, 0): a strong spring guessed
  wrong makes the arm buckle at some poses (no equilibrium), a spring grown from none does not.
  A K_C below 1e-3 N/m is held there, with s0 = P / K_C, so that P alone is a constant force;
* ``t`` (``tool_frame``): each reflector's place in its body, a delta from the drawing (three
  numbers per reflector: several reflectors are several points);
* ``B``: the robot base in the tracker frame (``base_frame``, the registration), as in model.py.

A reading may be loaded (model.py :class:`~.model.Rows`): its equilibrium is then solved under
the load as well (a mass's weight or a wrench at its site, bench/statics' ``Load``), as the bench
solves a campaign's loaded state, so the load is a second known force term in the statics. The
readings of one command and load share one equilibrium, whatever reflectors they read.

q_eq is the equilibrium of the commanded pose under the robot's own weight with the joint springs
1/c_k at rest at the command (a compliance is held at 1e-10 rad/(N*m) or more: stiffer, the
statics cannot meet its tolerance in double). So the gravity
and spring torques are those of the model's own deflected pose and geometry, and the loop is
closed by the geometry being fitted: nothing is linearised.

A frame of a body inside a loop (between a loop site's body and the loop's root, e.g. the
FANUC's upper arm and crank) keeps only its in-plane numbers: the shifts across its joint's axis
and the turn about it. A shift along the axis or a turn about another axis opens the loop out of
its plane, which the statics' planar constraint basis does not close (bench/model/loop.py: the
solve is not acceptable, a bench truth with such an edit is refused alike); their columns are
zero, so the base set never takes them.

The Jacobian: the registration's columns are exact (model.py); every other column is a forward
difference of the equilibria (steps of 1e-5 in the geometric parameters, m and rad, ~1e-2 of
their size; 1e-8 rad/(N*m), 100 N/m and 10 N for a spring), each a fresh solve to the statics'
tolerance (a force residual of 1e-10 of the weights, ~3e-11 m at a reflector). So a column is
known to ~1e-5 (the steps' curvature and SOLVE_NOISE / step), not to rounding as model.py's:
the base set is taken with RANK_TOL = 1e-5 here (a direction the readings see 1e5 times less
than the best one is not identified), and a column no larger than the solves' scatter (a
compliance the weight puts no torque on, as the FANUC's first axis) is zero. Only the
parameters asked for are differenced.

Checked against an independent computation in tests/test_geometry_statics.py: the same edits made
in the MJCF by the bench's effects (MjSpec, compiled) and solved by the bench's campaign.

Units: SI (m, rad, rad/(N*m), N/m).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from calbench.bench.core import InputError
from calbench.bench.model import Robot
from calbench.bench.model.effects import body_quat, frame_error, load_spec, turned_frame
from calbench.bench.statics import Load, StaticsError, StaticsSolver
from calbench.identify.core import fit_rigid

from .chain import rot, translation
from .model import BASE, LINK, Rows, as_rows, tool_names

RIGID = 1e-10  # rad/(N*m): the least compliance written (stiffer would not converge)
MIN_COMPLIANCE = 1e-9  # rad/(N*m): the fit's bound (bounds)
STEP = 1e-5  # m or rad: the forward-difference step of a geometric parameter
STEP_COMPLIANCE = 1e-8  # rad/(N*m)
STEP_SPRING = (100.0, 10.0)  # N/m and N: K_C's and P's (balancers: 1e4-1e6 N/m, 1e3-1e6 N)
MIN_SPRING = 1e-3  # N/m: the least K_C written (P / K_C the preload length)
SOLVE_NOISE = 1e-10  # m: a reflector's scatter between two solves of one equilibrium (measured ~3e-11)
RANK_TOL = 1e-5  # the base set's rank tolerance here: above the differences' noise (SOLVE_NOISE / STEP)


@dataclass(frozen=True)
class _Layout:
    """Where each group sits in the parameter vector."""

    n: int  # actuated joints
    springs: int  # compensator tendons
    points: int = 1  # reflectors, three numbers each

    @property
    def tool(self) -> slice:
        return slice(6, 6 + 3 * self.points)

    @property
    def offset(self) -> slice:
        s = self.tool.stop
        return slice(s, s + self.n)

    @property
    def compliance(self) -> slice:
        s = self.offset.stop
        return slice(s, s + self.n)

    @property
    def spring(self) -> slice:
        s = self.compliance.stop
        return slice(s, s + 2 * self.springs)

    @property
    def link(self) -> slice:
        return slice(self.spring.stop, None)

    @property
    def size(self) -> int:
        return self.link.start + 6 * self.n


def _loop_bodies(model: mujoco.MjModel, robot: Robot) -> set[int]:
    """The bodies between each loop site's body and the two sites' common ancestor."""
    out: set[int] = set()
    for a, b in robot.loops:
        up = []
        for s in (a, b):
            chain, x = [], int(model.site_bodyid[s])
            while x > 0:
                chain.append(x)
                x = int(model.body_parentid[x])
            up.append(chain)
        common = set(up[0]) & set(up[1])
        for chain in up:
            out.update(x for x in chain if x not in common)
    return out


class StaticsModel:
    """The complete model of one reflector's absolute readings on a calbench robot, each an
    equilibrium of the bench's statics (module docstring). The interface of model.GeometricModel
    (names, size, predict, jacobian, torques), so that fit.py's calibrate and discovery fit it."""

    self_consistent = True  # its torques are its own equilibrium's: refresh_torques has nothing to do
    rank_tol = RANK_TOL
    column_floor = 0.0  # its noise columns are zeroed (jacobian), and its units differ by 1e10

    def __init__(
        self, robot: Robot, point: str | Sequence[str], q, base0: np.ndarray | None = None, where=""
    ):
        m = robot.model
        self.points = (point,) if isinstance(point, str) else tuple(point)
        self.robot, self.where, self.point = robot, where, self.points[0]
        self.source: Path | str | None = None  # the MJCF (path or text): calibrated_xml edits it
        self.sites = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, p) for p in self.points]
        for p, sid in zip(self.points, self.sites, strict=True):
            if sid < 0:
                raise InputError(where, f"site {p}", "a site of the robot", None)
        self.joints = tuple(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, int(j)) for j in robot.act_joint)
        self.body_ids = [int(m.jnt_bodyid[j]) for j in robot.act_joint]
        self.bodies = tuple(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b) for b in self.body_ids)
        self.tendons = tuple(robot.description.compensators)
        self.lay = _Layout(len(self.joints), len(self.tendons), len(self.points))
        self._pos0 = m.body_pos[self.body_ids].copy()
        self._quat0 = m.body_quat[self.body_ids].copy()
        self._site0 = m.site_pos[self.sites].copy()  # (points, 3)
        self._jpos = m.jnt_pos[robot.act_joint].copy()
        self._axis = m.jnt_axis[robot.act_joint].copy()
        self.solver = StaticsSolver(robot)
        self.layout = robot.layout
        self.compliance0 = self.layout.generic_start()[: self.lay.n]
        self._last: dict[bytes, np.ndarray] = {}  # the last equilibrium of each command and load
        # link rotations that would tilt a loop out of its plane: not parameters (zero columns)
        inside = _loop_bodies(m, robot)
        self._frozen = set()
        # the first body's turns across its axis tilt the whole arm: the registration's turns but
        # for the tilt against gravity, which the sag shows 1e-3 as strongly (the bench's campaigns
        # and a levelled robot have none): not parameters
        first = self._axis[0] / np.linalg.norm(self._axis[0])
        for i in range(3):
            if abs(first[i]) < 1.0 - 1e-9:
                self._frozen.add(self.lay.link.start + 3 + i)
        for k, b in enumerate(self.body_ids):
            if b in inside:
                axis = self._axis[k] / np.linalg.norm(self._axis[k])
                for i in range(3):
                    if abs(axis[i]) > 1e-9:  # a shift with a share along the axis
                        self._frozen.add(self.lay.link.start + 6 * k + i)
                    if abs(axis[i]) < 1.0 - 1e-9:  # a turn about another axis
                        self._frozen.add(self.lay.link.start + 6 * k + 3 + i)
        self.base0 = np.eye(4) if base0 is None else np.asarray(base0, float)  # see registered()

    # -- the vector ------------------------------------------------------------------------------
    @property
    def names(self) -> list[str]:
        names = [f"base.{s}" for s in BASE] + tool_names(self.points)
        names += [f"{j}.offset" for j in self.joints] + [f"{j}.compliance" for j in self.joints]
        names += [f"{t}.spring_{s}" for t in self.tendons for s in ("stiffness", "force")]
        names += [f"{j}.link_{s}" for j in self.joints for s in LINK]
        return names

    @property
    def size(self) -> int:
        return self.lay.size

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounds of theta for the fit: every compliance at least MIN_COMPLIANCE and a spring's
        K_C at least 0 (near a rigid joint the statics' equilibria grow ill-conditioned, and a
        fit that strays there finds none); the rest free."""
        lo, hi = np.full(self.size, -np.inf), np.full(self.size, np.inf)
        lo[self.lay.compliance] = MIN_COMPLIANCE - self.compliance0
        lo[self.lay.spring.start : self.lay.spring.stop : 2] = 0.0
        return lo, hi

    def value(self, i: int, theta: np.ndarray) -> float:
        """Parameter i as a person reads it: a compliance's value, not its delta from the generic
        start (the rest are theirs already; a spring's s0 is P / K_C: :meth:`springs`)."""
        if self.lay.compliance.start <= i < self.lay.compliance.stop:
            return float(self.compliance0[i - self.lay.compliance.start] + theta[i])
        return float(theta[i])

    def torques(self, q) -> np.ndarray:
        """No input torques: each reading is its own equilibrium (placeholder of model.py's)."""
        return np.zeros((len(as_rows(q)), self.lay.n))

    def torques_at(self, q, theta: np.ndarray, **kw) -> np.ndarray:
        return self.torques(q)

    def springs(self, theta: np.ndarray) -> np.ndarray:
        """(K_C, s0) per compensator, flattened, from theta's (K_C, P = K_C s0)."""
        kp = np.asarray(theta, float)[self.lay.spring].reshape(-1, 2)
        k = np.maximum(kp[:, 0], MIN_SPRING)
        return np.column_stack([k, kp[:, 1] / k]).ravel()

    # -- writing theta into the compiled model -------------------------------------------------
    def write(self, theta: np.ndarray) -> None:
        """The geometric parameters into the model's frames, the compliances and springs into its
        stiffnesses (Robot.set_params)."""
        theta = np.asarray(theta, float)
        m = self.robot.model
        off, link = theta[self.lay.offset], theta[self.lay.link].reshape(self.lay.n, 6)
        for k, b in enumerate(self.body_ids):
            pos, quat = turned_frame(self._pos0[k], self._quat0[k], self._jpos[k], self._axis[k], off[k])
            m.body_pos[b], m.body_quat[b] = frame_error(pos, quat, link[k])
        m.site_pos[self.sites] = self._site0 + theta[self.lay.tool].reshape(-1, 3)
        if self.robot.loops:
            # the robot's loop closure map is taken from its frames when it is built (a
            # parallelogram's elbow = q3 - q2 exactly): built again on the edited frames, or its
            # rigid start leaves the loop open by the edit and the statics' Newton finds no way in
            self.robot = Robot(m, self.robot.source)
            self.solver = StaticsSolver(self.robot)
        comp = np.maximum(self.compliance0 + theta[self.lay.compliance], RIGID)
        self.robot.set_params(self.layout.params(np.concatenate([comp, self.springs(theta)])))

    def equilibria(self, q, theta: np.ndarray) -> np.ndarray:
        """Each reading's reflector, world position (n, 3), at its command's equilibrium under its
        load and theta."""
        return self._frames(as_rows(q), theta)[0]

    def _load(self, rows: Rows, i: int) -> Load | None:
        if not rows.site[i] or not (np.any(rows.force[i]) or np.any(rows.moment[i])):
            return None
        sid = mujoco.mj_name2id(self.robot.model, mujoco.mjtObj.mjOBJ_SITE, rows.site[i])
        if sid < 0:
            raise InputError(self.where, f"load site {rows.site[i]}", "a site of the robot", None)
        return Load(rows.force[i].copy(), rows.moment[i].copy(), sid)

    def _frames(self, rows: Rows, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(positions (n, 3), orientations (n, 3, 3)) of each reading's reflector in the world at
        its equilibrium; one solve per distinct command and load."""
        self.write(theta)
        rb = self.robot
        d = rb.data
        n = len(rows)
        pos, rot_ = np.empty((n, 3)), np.empty((n, 3, 3))
        states: dict[bytes, list[int]] = {}
        for i in range(n):
            key = (
                rows.q[i].tobytes()
                + rows.force[i].tobytes()
                + rows.moment[i].tobytes()
                + rows.site[i].encode()
            )
            states.setdefault(key, []).append(i)
        for key, members in states.items():
            i = members[0]
            load = self._load(rows, i)
            eq = self._solve(rows.q[i], load, None)
            if eq is None and key in self._last:  # from the last equilibrium of this state
                eq = self._solve(rows.q[i], load, self._last[key])
            if eq is None:
                what = "loaded " if load is not None else ""
                raise ValueError(
                    f"no static equilibrium at {what}reading {i} (command {np.degrees(rows.q[i]).round(3)} deg)"
                )
            self._last[key] = eq.qpos.copy()
            d.qpos[:] = eq.qpos
            mujoco.mj_kinematics(rb.model, d)
            for j in members:
                s = self.sites[rows.point[j]]
                pos[j] = d.site_xpos[s]
                rot_[j] = d.site_xmat[s].reshape(3, 3)
        return pos, rot_

    def _solve(self, q: np.ndarray, load: Load | None, qpos0: np.ndarray | None):
        """The statics' equilibrium at command q under the load (from the rigid pose, or from
        qpos0), or None."""
        try:
            eq = self.solver.solve(q, load, qpos0=qpos0)
        except StaticsError:
            return None
        return eq if eq.acceptable else None

    def registered(self, q, y: np.ndarray) -> StaticsModel:
        """The same model with B_0 the closed-form rigid registration of the nominal model's
        equilibria (theta = 0) on the readings (fit.py initial_model's)."""
        p = self.equilibria(q, np.zeros(self.size))
        reg = fit_rigid(y, p, np.broadcast_to(np.eye(3) * 1e-8, (len(y), 3, 3)))
        self.base0 = np.eye(4)
        self.base0[:3, :3] = reg.rotation.T
        self.base0[:3, 3] = -reg.rotation.T @ reg.position
        return self

    def base(self, theta: np.ndarray) -> np.ndarray:
        """B: the tracker from the robot base (4x4) at theta."""
        return self._base(np.asarray(theta, float))

    def _base(self, theta: np.ndarray) -> np.ndarray:
        b = theta[:6]
        return translation(b[:3]) @ rot(0, b[3]) @ rot(1, b[4]) @ rot(2, b[5]) @ self.base0

    # -- the model.GeometricModel interface ----------------------------------------------------
    def predict(self, q, theta: np.ndarray, tau=None) -> np.ndarray:
        theta = np.asarray(theta, float)
        b = self._base(theta)
        return self.equilibria(q, theta) @ b[:3, :3].T + b[:3, 3]

    def jacobian(self, q, theta: np.ndarray, tau=None, columns=None):
        """(prediction (n, 3), dy/dtheta (n, 3, size)); ``columns``: only these are computed (the
        others are zero). A reflector's own columns are exact where no load acts at it (its
        place moves no equilibrium); the rest are forward differences of fresh equilibria."""
        rows = as_rows(q)
        theta = np.asarray(theta, float)
        cols = range(self.size) if columns is None else [int(c) for c in columns]
        x, frames = self._frames(rows, theta)
        b = self._base(theta)
        y = x @ b[:3, :3].T + b[:3, 3]
        jac = np.zeros((len(rows), 3, self.size))
        turned = np.eye(4)
        for i in range(3):
            jac[:, i, i] = 1.0
            jac[:, :, 3 + i] = np.cross(turned[:3, i], y - theta[:3])
            turned = turned @ rot(i, theta[3 + i])
        loaded_at = {s for s, f in zip(rows.site, rows.loaded, strict=True) if f}
        noise = 10.0 * SOLVE_NOISE * np.sqrt(x.size)
        for c in cols:
            if c < 6 or c in self._frozen:
                continue
            if self.lay.tool.start <= c < self.lay.tool.stop:
                j, axis = divmod(c - self.lay.tool.start, 3)
                if self.points[j] not in loaded_at:
                    mine = (rows.point == j)[:, None]
                    jac[:, :, c] = (frames[:, :, axis] * mine) @ b[:3, :3].T
                    continue
            h = self._step(c, theta)
            th = theta.copy()
            th[c] += h
            try:
                d = self.equilibria(rows, th) - x
            except ValueError:  # the forward step leaves some equilibrium: the backward one
                th[c], h = theta[c] - h, -h
                d = self.equilibria(rows, th) - x
            if np.linalg.norm(d) > noise:  # else: the solves' scatter, no motion
                jac[:, :, c] = (d / h) @ b[:3, :3].T
        self.write(theta)
        return y, jac

    def _step(self, c: int, theta: np.ndarray) -> float:
        if self.lay.compliance.start <= c < self.lay.compliance.stop:
            return STEP_COMPLIANCE
        if self.lay.spring.start <= c < self.lay.spring.stop:
            return STEP_SPRING[(c - self.lay.spring.start) % 2]
        return STEP


def statics_model(
    path: str | Path | None, xml: str | None, point: str | Sequence[str], q, y, where: str
) -> StaticsModel:
    """The statics model of the MJCF at ``path`` (or the text ``xml``) registered on readings y at
    commands q (an array, or :class:`~.model.Rows`: loads and several reflectors)."""
    robot = Robot.from_file(path) if path is not None else Robot.from_xml(xml, where)
    model = StaticsModel(robot, point, q, where=where)
    model.source = Path(path) if path is not None else xml
    return model.registered(q, y)


def _stiffness(old, k: float):
    """A spec stiffness set to k: a number, or (MuJoCo 4's polynomial) [k, 0, 0]."""
    if np.ndim(old) == 0:
        return float(k)
    out = np.zeros(len(old))
    out[0] = k
    return out


def calibrated_xml(model: StaticsModel, theta: np.ndarray) -> str:
    """The user's MJCF with a fit written in (its frames edited as :meth:`StaticsModel.write`
    edits the compiled model, hinge stiffness 1/c, each compensator's K_C and s0): the calibrated
    robot for every other verb, as discover writes its augmented model."""
    spec = load_spec(model.source)
    theta = np.asarray(theta, float)
    lay = model.lay
    off, link = theta[lay.offset], theta[lay.link].reshape(lay.n, 6)
    comp = np.maximum(model.compliance0 + theta[lay.compliance], RIGID)
    for k, name in enumerate(model.joints):
        j = spec.joint(name)
        body = j.parent
        pos, quat = turned_frame(body.pos, body_quat(spec, body), j.pos, j.axis, off[k])
        body.pos, body.quat = frame_error(pos, quat, link[k])
        j.stiffness = _stiffness(j.stiffness, 1.0 / comp[k])
    for name, t in zip(model.points, theta[lay.tool].reshape(-1, 3), strict=True):
        site = spec.site(name)
        site.pos = np.asarray(site.pos, float) + t
    for name, (kc, s0) in zip(model.tendons, model.springs(theta).reshape(-1, 2), strict=True):
        ten = spec.tendon(name)
        ten.stiffness, ten.springlength = _stiffness(ten.stiffness, kc), [float(s0), float(s0)]
    spec.compiler.savecompiled = False
    return spec.to_xml()


__all__ = ["StaticsModel", "calibrated_xml", "statics_model"]
