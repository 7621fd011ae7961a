"""A thin wrapper around the robot's MjModel/MjData: its description, truth parameters, commands.

The MJCF defines the geometry and names the parts calbench needs (bench/model/description.py: the
actuated joints, loops, compensator tendons, reflectors, payload); everything else is derived
from the model here:

* passive joints: the unsprung hinges and slides on a loop's path between its two sites (the
  joints of the bodies from each site up to their common ancestor), neither actuated nor
  carrying a spring (a spring's hinge, e.g. an effect's, is elastic and rests at 0);
* the rigid closed-loop configuration of a command (:meth:`Robot.rigid_qpos`);
* each compensator's joint (the one hinge between its two sites' bodies) and its triangle
  geometry (paper Fig. 4, :meth:`Robot.compensator_geometry`);
* how far a command is from a degenerate loop (:meth:`Robot.loop_conditioning`).

Everything elastic (joint stiffness, the compensator springs) is written here from a scenario's
truth or an estimator's theta (bench/model/params.py), so the file's own stiffness values never
matter. Controller angles are the model's hinge angles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from calbench.bench.core import StaticsError, check_mjcf_text, check_model_file

from .description import Description, DescriptionError, read_description
from .loop import LOOP_TOL, loop_gap
from .params import ParamLayout, Params, Spring

# A loop degenerates where its passive joints stop being determined by the motors: the loop
# Jacobian with respect to them, J_c,p (columns normalised: each joint's lever arm drops out),
# loses rank. Its inverse condition number sigma_min / sigma_max (1: the passive joints move the
# gap in orthogonal directions; 0: in one direction) must stay above LOOP_MARGIN. For a planar
# loop with two passive hinges it is tan(alpha / 2), alpha the acute angle between the two
# hinges' gap directions (for a parallelogram: between crank and upper arm), so LOOP_MARGIN =
# tan(5 deg) keeps alpha >= 10 deg. Commands closer are rejected (bench.campaign) or never
# sampled (design): bench.statics has no unique equilibrium at the degenerate pose itself.
LOOP_MARGIN = math.tan(math.radians(5.0))
LOOP_MARGIN_ANGLE = math.radians(10.0)  # alpha of LOOP_MARGIN for a planar two-hinge loop
_SNAP = 1e-9  # motor-map entries this close to an integer are that integer (a parallel linkage)
_CLOSE_ITER = 20  # Gauss-Newton steps of the loop closure before continuation
_CONTINUATION = 16  # steps of the continuation from the reference configuration
_LINEAR_PROBES = 8  # random commands that decide whether the loops close linearly


@dataclass(frozen=True)
class CompensatorGeometry:
    """Geometry of a compensator triangle (paper Fig. 4) read from the MJCF sites.

    joint: index (controller order) of the actuated hinge the spring spans; l_c: its axis to
    the attachment on the parent side; l_2: its axis to the attachment on the child side;
    offset: psi - q_joint, the compensator angle minus the joint's angle (rad).
    """

    l_c: float
    l_2: float
    offset: float
    joint: int = 1

    def angle(self, q_joint: float) -> float:
        return q_joint + self.offset

    def length(self, q_joint: float) -> float:
        """Spring length s, paper eq. (7)."""
        psi = self.angle(q_joint)
        return float(np.sqrt(self.l_c**2 + self.l_2**2 - 2 * self.l_c * self.l_2 * np.cos(psi)))


def ancestors(model: mujoco.MjModel, body: int) -> list[int]:
    """body, its parent, ..., the world (0)."""
    out = [int(body)]
    while out[-1] != 0:
        out.append(int(model.body_parentid[out[-1]]))
    return out


def path_joints(model: mujoco.MjModel, body_a: int, body_b: int) -> list[int]:
    """Joint ids of the bodies between two bodies and their common ancestor (exclusive), i.e.
    the joints whose motion changes the relative pose of the two bodies (sorted)."""
    up_a, up_b = ancestors(model, body_a), ancestors(model, body_b)
    common = next(b for b in up_a if b in up_b)
    bodies = up_a[: up_a.index(common)] + up_b[: up_b.index(common)]
    return sorted(
        int(j)
        for b in bodies
        for j in range(model.body_jntadr[b], model.body_jntadr[b] + model.body_jntnum[b])
    )


class Robot:
    """MjModel + MjData with the robot's described and derived parts resolved once."""

    def __init__(self, model: mujoco.MjModel, source: Path | None = None):
        self.model = model
        self.data = mujoco.MjData(model)
        self.source = source
        try:
            desc = read_description(model)
        except DescriptionError as exc:
            raise DescriptionError(f"{source or 'MJCF'}: {exc}") from None
        self.description: Description = desc
        name2id = mujoco.mj_name2id
        site = lambda n: name2id(model, mujoco.mjtObj.mjOBJ_SITE, n)  # noqa: E731
        self.act_joint = np.array([name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n) for n in desc.actuated])
        self.n_act = len(self.act_joint)
        self.act_qpos = model.jnt_qposadr[self.act_joint]
        self.act_dof = model.jnt_dofadr[self.act_joint]
        self.layout = ParamLayout(self.n_act, desc.compensators)
        # flat indices of (dof of motor i, column i) in dforce_dtheta's (nv, n_params) result
        self._spring_entries = self.act_dof * self.layout.n + np.arange(self.n_act)
        self.tendons = np.array(
            [name2id(model, mujoco.mjtObj.mjOBJ_TENDON, t) for t in desc.compensators], dtype=int
        )
        # each tendon's sparse row of ten_J: a fixed pattern of the model
        self._ten_pattern = []
        for t in self.tendons:
            adr, nnz = int(model.ten_J_rowadr[t]), int(model.ten_J_rownnz[t])
            self._ten_pattern.append((slice(adr, adr + nnz), model.ten_J_colind[adr : adr + nnz].copy()))
        self.payload_site = site(desc.payload)
        self.payload_name = desc.payload
        self.flange_site = site(desc.flange) if desc.flange else -1
        self.reflector_names = list(desc.reflectors)
        self.reflector_sites = np.array([site(n) for n in desc.reflectors])
        # kinematic loops closed by the statics (bench/model/loop.py), each a (site, site) pair whose
        # positions coincide: the connect equalities named by calbench:loops
        eq = [name2id(model, mujoco.mjtObj.mjOBJ_EQUALITY, e) for e in desc.loops]
        self.loops: tuple[tuple[int, int], ...] = tuple(
            (int(model.eq_obj1id[e]), int(model.eq_obj2id[e])) for e in eq
        )
        self._derive_passive()

    # -- derived structure --------------------------------------------------------------
    def _derive_passive(self) -> None:
        """Passive joints per loop (module docstring) and the loop closure's reference map."""
        m = self.model
        actuated = set(self.act_joint.tolist())
        per_loop, passive = [], []
        for (a, b), name in zip(self.loops, self.description.loops):
            js = [
                j
                for j in path_joints(m, m.site_bodyid[a], m.site_bodyid[b])
                if j not in actuated and m.jnt_stiffness[j] == 0.0
            ]
            for j in js:
                if int(m.jnt_type[j]) not in (
                    int(mujoco.mjtJoint.mjJNT_HINGE),
                    int(mujoco.mjtJoint.mjJNT_SLIDE),
                ):
                    raise DescriptionError(
                        f"{self.source or 'MJCF'}: calbench:loops: loop {name!r} passes "
                        f"through joint {m.joint(j).name!r}, which is not a hinge or slide"
                    )
            if not js:
                raise DescriptionError(
                    f"{self.source or 'MJCF'}: calbench:loops: loop {name!r} has no "
                    "passive (unsprung, not actuated) joint between its two sites"
                )
            per_loop.append(np.array(js, dtype=int))
            passive += [j for j in js if j not in passive]
        self.passive_joint = np.array(sorted(passive), dtype=int)
        self.passive_qpos = m.jnt_qposadr[self.passive_joint]
        self.passive_dof = m.jnt_dofadr[self.passive_joint]
        self.loop_passive = per_loop  # joint ids of each loop's passive joints
        self._loop_passive_dof = [m.jnt_dofadr[js] for js in per_loop]
        self._kd = mujoco.MjData(m)  # scratch for the closure (never the statics' data)
        self._ref = m.qpos0.copy()
        self._closure_map = np.zeros((len(self.passive_joint), self.n_act))
        self.linear_loops = True  # the passive joints are exact linear maps of the motors
        if len(self.passive_joint):
            self._ref = self._close(self._ref, self._ref)
            n = self._passive_map(self._ref)
            self._closure_map = np.where(np.abs(n - np.round(n)) < _SNAP, np.round(n), n)
            # a parallel linkage closes exactly along the map everywhere; decided on random
            # commands within the limits (+-180 deg at most), once
            lim = np.clip(self.limits(), -np.pi, np.pi)
            probes = lim[:, 0] + (lim[:, 1] - lim[:, 0]) * np.random.default_rng(0).random(
                (_LINEAR_PROBES, self.n_act)
            )
            self.linear_loops = all(np.abs(self._gap(self._predict(q))[0]).max() <= LOOP_TOL for q in probes)

    def _gap(self, qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d = self._kd
        d.qpos[:] = qpos
        mujoco.mj_kinematics(self.model, d)
        mujoco.mj_comPos(self.model, d)
        return loop_gap(self, d)

    def _passive_map(self, qpos: np.ndarray) -> np.ndarray:
        """d q_passive / d q_motor with the loops closed at qpos: -J_c,p^+ J_c,a."""
        _, jc = self._gap(qpos)
        return -np.linalg.pinv(jc[:, self.passive_dof], rcond=1e-10) @ jc[:, self.act_dof]

    def _newton_close(self, qpos: np.ndarray) -> np.ndarray | None:
        """Gauss-Newton on the passive joints until the gap is below LOOP_TOL; None if not."""
        qpos = qpos.copy()
        for _ in range(_CLOSE_ITER + 1):
            c, jc = self._gap(qpos)
            if not np.all(np.isfinite(c)):
                return None
            if np.abs(c).max() <= LOOP_TOL:
                return qpos
            qpos[self.passive_qpos] -= np.linalg.lstsq(jc[:, self.passive_dof], c, rcond=None)[0]
        return None

    def _close(self, qpos: np.ndarray, ref: np.ndarray) -> np.ndarray:
        """Close the loops at qpos's motor angles by moving only the passive joints: Newton from
        qpos, else a continuation from the closed configuration ``ref``."""
        out = self._newton_close(qpos)
        if out is not None:
            return out
        cur = ref.copy()
        for s in range(1, _CONTINUATION + 1):
            nxt = cur.copy()
            nxt[self.act_qpos] = ref[self.act_qpos] + s / _CONTINUATION * (
                qpos[self.act_qpos] - ref[self.act_qpos]
            )
            nxt[self.passive_qpos] += self._passive_map(cur) @ (nxt[self.act_qpos] - cur[self.act_qpos])
            cur = self._newton_close(nxt)
            if cur is None:
                raise StaticsError(
                    f"the loops {list(self.description.loops)} do not close at command "
                    f"{np.degrees(qpos[self.act_qpos]).round(3).tolist()} deg"
                )
        return cur

    # -- construction -------------------------------------------------------------------
    @classmethod
    def from_file(cls, path: str | Path) -> Robot:
        """A robot from the user's MJCF file: safe XML, whose files stay in its folder."""
        path = Path(path)
        if path.suffix.lower() != ".urdf":
            check_model_file(path)
        return cls(mujoco.MjModel.from_xml_path(str(path)), source=path)

    @classmethod
    def from_xml(cls, text: str, where: object = "MJCF text") -> Robot:
        """A robot from MJCF text (a log's attachment): safe XML that reads no file."""
        check_mjcf_text(text, where)
        return cls(mujoco.MjModel.from_xml_string(text))

    # -- parameters ---------------------------------------------------------------------
    # the model fields set_params writes (bench/statics/batched.py copies them into a batch)
    PARAM_FIELDS = ("jnt_stiffness", "tendon_stiffness", "tendon_lengthspring")

    def set_params(self, params: Params) -> None:
        """Write the truth into the model: hinge stiffness 1/k_i and the compensator springs."""
        k = np.asarray(params.compliance, dtype=float)
        if k.shape != (self.n_act,):
            raise ValueError(f"expected {self.n_act} compliances (calbench:actuated), got shape {k.shape}")
        self.model.jnt_stiffness[self.act_joint] = 1.0 / k
        for name, t in zip(self.description.compensators, self.tendons):
            if name not in params.springs:
                raise ValueError(f"no spring given for compensator tendon {name!r}")
            s = params.springs[name]
            self.model.tendon_stiffness[t] = s.stiffness
            self.model.tendon_lengthspring[t] = s.preload

    def dforce_dtheta(self, params: Params, data: mujoco.MjData | None = None) -> np.ndarray:
        """d g / d theta at fixed q (nv, n_params): how the springs' generalized force moves
        with the parameters ``set_params`` writes, theta in ``self.layout``'s order.

        Joint springs (paper eq. 1): g_i = -(q_i - q_cmd,i) / k_i, so dg_i/dk_i = (q_i - q_cmd,i)
        / k_i^2 on motor i's dof. Each compensator (eqs. 7-8, a tendon of length L and moment
        t = dL/dq): g = -K_C (L - s0) t, so dg/dK_C = -(L - s0) t and dg/ds0 = K_C t. Gravity
        and the load do not depend on theta. The pose is the one held in ``data`` (position
        stage current) and the command the springs' reference (:meth:`set_command`); this is
        the right-hand side of the implicit function theorem
        (bench.statics.StaticsSolver.tangent)."""
        d = self.data if data is None else data
        m = self.model
        k = np.asarray(params.compliance, dtype=float)
        out = np.zeros((m.nv, self.layout.n))
        dq = d.qpos.take(self.act_qpos) - m.qpos_spring.take(self.act_qpos)
        out.flat[self._spring_entries] = dq / (k * k)
        for c, (name, t) in enumerate(zip(self.description.compensators, self.tendons)):
            s = params.springs[name]
            mom = self.tendon_moment(d, c)
            col = self.n_act + 2 * c
            out[:, col] = -(float(d.ten_length[t]) - s.preload) * mom
            out[:, col + 1] = s.stiffness * mom
        return out

    def dforce_dtheta_stack(
        self, params: Params, qpos: np.ndarray, command: np.ndarray, ten_j: np.ndarray, ten_length: np.ndarray
    ) -> np.ndarray:
        """:meth:`dforce_dtheta` of n configurations at once (n, nv, n_params), from their
        stacked MjData fields (as mujoco.batch binds them): qpos (n, nq), the commands (n, n_act),
        ten_J (n, nJ, MuJoCo's sparse values) and ten_length (n, ntendon), position stage
        current. Same formulas, same order of columns."""
        n = len(qpos)
        k = np.asarray(params.compliance, dtype=float)
        out = np.zeros((n, self.model.nv, self.layout.n))
        out[:, self.act_dof, np.arange(self.n_act)] = (qpos[:, self.act_qpos] - command) / (k * k)
        moments = self.tendon_moments_stack(ten_j)
        for c, (name, t) in enumerate(zip(self.description.compensators, self.tendons)):
            s = params.springs[name]
            col = self.n_act + 2 * c
            out[:, :, col] = -(ten_length[:, t] - s.preload)[:, None] * moments[:, c]
            out[:, :, col + 1] = s.stiffness * moments[:, c]
        return out

    def params(self) -> Params:
        """The parameters the model currently holds (for the simulator's truth only)."""
        m = self.model
        return Params(
            1.0 / m.jnt_stiffness[self.act_joint].copy(),
            {
                name: Spring(float(m.tendon_stiffness[t]), float(m.tendon_lengthspring[t][0]))
                for name, t in zip(self.description.compensators, self.tendons)
            },
        )

    def limits(self) -> np.ndarray:
        """(n_act, 2) controller joint limits in rad."""
        return self.model.jnt_range[self.act_joint].copy()

    def weight(self, mass: float) -> np.ndarray:
        """(3,) world force of a mass under the model's gravity (MJCF ``<option gravity>``), N."""
        return mass * self.model.opt.gravity

    # -- loops ----------------------------------------------------------------------------
    def loop_conditioning(self, q: np.ndarray, qpos: np.ndarray | None = None) -> np.ndarray:
        """(n_loops,) inverse condition number of each loop's column-normalised Jacobian with
        respect to its passive joints at the command's rigid configuration (``qpos`` if already
        known; see LOOP_MARGIN): 1 for orthogonal gap directions, 0 at a degenerate loop."""
        if not self.loops:
            return np.zeros(0)
        _, jc = self._gap(self.rigid_qpos(q) if qpos is None else qpos)
        return self.loop_conditioning_stack(jc[None])[0]

    def loop_conditioning_stack(self, jc: np.ndarray) -> np.ndarray:
        """:meth:`loop_conditioning` (n, n_loops) from the loop Jacobians J_c (n, 3L, nv) at n
        rigid configurations (bench/statics/batched.py has them for many at once); a row that is
        not finite (a loop that did not close) counts as degenerate."""
        out = np.zeros((len(jc), len(self.loops)))
        for i, dofs in enumerate(self._loop_passive_dof):
            jp = jc[:, 3 * i : 3 * i + 3][:, :, dofs]
            norms = np.sqrt(np.einsum("nij,nij->nj", jp, jp))
            ok = np.all(norms > 0, axis=1) & np.all(np.isfinite(jp), axis=(1, 2)) & (len(dofs) <= 3)
            if ok.any():
                s = np.linalg.svd(jp[ok] / norms[ok][:, None, :], compute_uv=False)
                out[ok, i] = s[:, -1] / s[:, 0]
        return out

    def loop_ok(self, q: np.ndarray, qpos: np.ndarray | None = None) -> bool:
        """Every loop at least LOOP_MARGIN from degenerate at the command (always, without loops)."""
        return bool(np.all(self.loop_conditioning(q, qpos) >= LOOP_MARGIN))

    # -- commands -----------------------------------------------------------------------
    def set_command(self, q: np.ndarray) -> None:
        """Commanded angles become the springs' reference (VJM: the spring is at rest there)."""
        self.model.qpos_spring[self.act_qpos] = q

    def rigid_qpos(self, q: np.ndarray) -> np.ndarray:
        """The closed-loop configuration at the command with no deflection.

        The motors at q, every other joint at its MJCF reference, and the passive joints moved
        to close the loops: first by the motor map of the reference configuration (its entries
        snapped to integers within 1e-9: a parallel linkage, whose passive angles are exact
        sums and differences of motor angles, then closes exactly, e.g. a parallelogram's elbow
        = q3 - q2, and ``linear_loops`` says so), then, for other loops, by Gauss-Newton on the
        gap down to LOOP_TOL.
        """
        qpos = self._predict(np.asarray(q, dtype=float))
        if not self.linear_loops:
            qpos = self._close(qpos, self._ref)
        return qpos

    def _predict(self, q: np.ndarray) -> np.ndarray:
        """The configuration at command q with the passive joints on the reference motor map."""
        qpos = self.model.qpos0.copy()
        qpos[self.act_qpos] = q
        if len(self.passive_joint):
            ref = self._ref
            qpos[self.passive_qpos] = ref[self.passive_qpos] + self._closure_map @ (q - ref[self.act_qpos])
        return qpos

    def rigid_qpos_stack(self, q: np.ndarray, gaps=None) -> np.ndarray:
        """:meth:`rigid_qpos` of n commands (n, n_act) -> (n, nq): the reference motor map for
        all of them, then :meth:`rigid_qpos`'s closure only for the rows it leaves open by more
        than LOOP_TOL (none for a parallel linkage). ``gaps(qpos)`` gives the loop gaps (n, 3L)
        of stacked poses (e.g. on a mujoco.batch); default: this robot's kinematics row by row.
        A row whose loops cannot be closed is NaN."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        qpos = np.tile(self.model.qpos0, (len(q), 1))
        qpos[:, self.act_qpos] = q
        if len(self.passive_joint) and len(q):
            ref = self._ref
            qpos[:, self.passive_qpos] = (
                ref[self.passive_qpos] + (q - ref[self.act_qpos]) @ self._closure_map.T
            )
            if self.linear_loops:  # closed exactly by the map (rigid_qpos)
                return qpos
            c = gaps(qpos) if gaps is not None else np.array([self._gap(x)[0] for x in qpos])
            for i in np.flatnonzero(~(np.abs(c).max(axis=1) <= LOOP_TOL)):
                try:
                    qpos[i] = self._close(qpos[i], ref)
                except StaticsError:
                    qpos[i] = np.nan
        return qpos

    def tendon_moment(self, data: mujoco.MjData | None = None, which: int = 0) -> np.ndarray:
        """(nv,) dense dL/dq of compensator tendon ``which`` (description order; zeros without
        compensators). MuJoCo stores ten_J sparsely (values in data.ten_J, columns in
        model.ten_J_colind); position stage must be current."""
        d = self.data if data is None else data
        out = np.zeros(self.model.nv)
        if which < len(self._ten_pattern):
            rows, cols = self._ten_pattern[which]
            out[cols] = d.ten_J[rows]
        return out

    def tendon_moments_stack(self, ten_j: np.ndarray) -> np.ndarray:
        """:meth:`tendon_moment` of every compensator for n configurations (n, C, nv), from
        their stacked ten_J (n, nJ, MuJoCo's sparse values, as mujoco.batch binds them)."""
        out = np.zeros((len(ten_j), len(self._ten_pattern), self.model.nv))
        for c, (rows, cols) in enumerate(self._ten_pattern):
            out[:, c, cols] = ten_j[:, rows]
        return out

    def compensator_joint(self, which: int = 0) -> int:
        """Index (controller order) of the actuated hinge compensator ``which`` spans: the one
        joint between its two sites' bodies. ValueError when that is not one actuated hinge."""
        m = self.model
        t = self.tendons[which]
        a, b = m.wrap_objid[m.tendon_adr[t] : m.tendon_adr[t] + 2]
        js = path_joints(m, m.site_bodyid[a], m.site_bodyid[b])
        name = self.description.compensators[which]
        if len(js) != 1 or js[0] not in self.act_joint:
            raise ValueError(
                f"compensator {name!r} spans joints {[m.joint(j).name for j in js]}: the "
                "triangle of paper eqs. 7-11 needs exactly one actuated hinge between its sites"
            )
        return int(np.flatnonzero(self.act_joint == js[0])[0])

    def compensator_geometry(self, which: int = 0) -> CompensatorGeometry:
        """Measure l_c, l_2 and the angle offset of compensator ``which`` from the MJCF sites at
        q = 0 (geometry only: measured once per compensator, the two-step methods ask per
        solve); ValueError as :meth:`compensator_joint`."""
        cache = self.__dict__.setdefault("_geometry", {})
        if which not in cache:
            cache[which] = self._measure_compensator(which)
        return cache[which]

    def _measure_compensator(self, which: int) -> CompensatorGeometry:
        m = self.model
        i = self.compensator_joint(which)
        t = self.tendons[which]
        d = mujoco.MjData(m)
        d.qpos[:] = self.rigid_qpos(np.zeros(self.n_act))
        mujoco.mj_kinematics(m, d)
        a, b = m.wrap_objid[m.tendon_adr[t] : m.tendon_adr[t] + 2]
        joint = self.act_joint[i]
        # b: the attachment that the joint moves (its body below the joint's), a: the other
        if int(m.jnt_bodyid[joint]) in ancestors(m, m.site_bodyid[a]):
            a, b = b, a
        axis_pt = d.xanchor[joint]
        axis = d.xaxis[joint]
        va = d.site_xpos[a] - axis_pt
        vb = d.site_xpos[b] - axis_pt
        va -= axis * (va @ axis)
        vb -= axis * (vb @ axis)
        l_c, l_2 = np.linalg.norm(va), np.linalg.norm(vb)
        # signed angle from the base attachment to the arm attachment about the joint axis
        psi = np.arctan2(np.cross(va, vb) @ axis, va @ vb)
        return CompensatorGeometry(float(l_c), float(l_2), float(psi), i)


__all__ = [
    "Robot",
    "Params",
    "Spring",
    "ParamLayout",
    "CompensatorGeometry",
    "LOOP_MARGIN",
    "ancestors",
    "LOOP_MARGIN_ANGLE",
    "path_joints",
]
