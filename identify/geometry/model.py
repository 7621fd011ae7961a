"""The complete geometric model of absolute readings, and its exact Jacobian.

A reading y (a point on the flange, in the tracker frame) at joint angles q is predicted as

    y = B  P_1 E_1 Rz(q_1 + o_1 + c_1 tau_1)  ...  P_n E_n Rz(q_n + o_n + c_n tau_n)  P_f E_f  t

* ``E_k = Tr(v_k) Rx(a_k) Ry(b_k) Rz(c_k)``: the error of link frame k (``link_geometry``; k = n + 1
  is the flange frame), six numbers per frame;
* ``o_k``: the joint's zero offset (``joint_offset``);
* ``c_k tau_k``: the joint's deflection under self-weight, compliance c_k (rad/(N*m)) times the
  gravity torque tau_k of the nominal model at q (:func:`chain.gravity_torques`), the linear
  joint-compliance model of Klimchik et al. (2016), eq. (1)-(3), with the wrench of the robot's
  own weight in place of the payload's;
* ``t``: the probe (or reflector) in the flange frame (``tool_frame``);
* ``B = Tr(t_B) Rx Ry Rz(w_B) B_0``: the robot base in the tracker frame (``base_frame``). The
  tracker's registration is this frame: it is fitted with the rest, not before it.

Every parameter is a translation along an axis (dy = R u) or a rotation about an axis u through
a point o (dy = u x (y - o)): :meth:`GeometricModel.jacobian` is exact, not a finite difference,
and is checked against one in the tests. tau is an input held fixed in a fit: by default the
nominal geometry's at the commanded q. Its change with the fitted geometry and with the sag itself
is second order (mm on m lever arms), but not always below a tracker's noise: a 3 mrad sag of the
shoulder moves the arm's centres of mass by ~2 mm, which changes the torques by ~0.3 N*m and the
reading by ~10 um at 30 urad/(N*m). :meth:`GeometricModel.torques_at` gives tau at a fitted
model's own deflected pose, for a fit repeated with it (fit.py :func:`~.fit.refresh_torques`).

**Loads and several points** (:class:`Rows`). A reading may be taken under a known load (a mass
hanging at a site on the flange, or a wrench there), and of any of several points (reflectors)
on the flange, each with its own ``t_j`` (three numbers each; a single point keeps the names
``tool.x``...). The load is a second term in tau: tau_k = tau_gravity,k + u_k . ((p - o_k) x F + M)
(chain.py :func:`~.chain.load_torques`, paper eq. (3) with the payload's wrench), so a loaded and
an unloaded reading of one pose are two absolute readings whose difference the compliances
explain: the paper's loaded-minus-unloaded design inside the complete model. The load's point is
the nominal drawing's (not fitted: a 2 mm error in it changes a 700 kg load's torque by 14 N*m in
1e5, below what the readings see).

Units: SI (m, rad, N*m, N, kg).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from .chain import GRAVITY, Chain, gravity_torques, load_torques, rot, translation

LINK = ("tx", "ty", "tz", "rx", "ry", "rz")
BASE = ("tx", "ty", "tz", "rx", "ry", "rz")
TOOL = ("x", "y", "z")


def tool_names(points: Sequence[str]) -> list[str]:
    """The probe points' names in the vector: ``tool.x``.. for one point (or none named), else
    ``tool.<point>.x``.. per point, in ``points``' order."""
    if len(points) <= 1:
        return [f"tool.{s}" for s in TOOL]
    return [f"tool.{p}.{s}" for p in points for s in TOOL]


@dataclass(frozen=True)
class Rows:
    """What a reading is besides its position: the commanded angles, which point it is, and the
    load it was taken under (zero: unloaded). Force and moment in the robot base's frame (a
    campaign log's world frame); ``mass`` (kg, 0 for a wrench or none): a hanging mass, whose
    force follows gravity where the model turns it (:meth:`GeometricModel.torques_at`)."""

    q: np.ndarray  # (n, dof) rad
    point: np.ndarray  # (n,) int: index into the model's points
    force: np.ndarray  # (n, 3) N
    moment: np.ndarray  # (n, 3) N*m
    site: tuple[str, ...]  # (n,) the site the load acts at ("" where none)
    mass: np.ndarray  # (n,) kg

    def __len__(self) -> int:
        return len(self.q)

    @property
    def loaded(self) -> np.ndarray:
        """(n,) bool: a reading under a load."""
        return np.any(self.force != 0, axis=1) | np.any(self.moment != 0, axis=1)

    def take(self, rows) -> Rows:
        rows = np.asarray(rows)
        sites = tuple(np.asarray(self.site, dtype=object)[rows])
        return Rows(
            self.q[rows], self.point[rows], self.force[rows], self.moment[rows], sites, self.mass[rows]
        )


def as_rows(q) -> Rows:
    """``q`` as :class:`Rows`: a (n, dof) array is n unloaded readings of the first point."""
    if isinstance(q, Rows):
        return q
    q = np.atleast_2d(np.asarray(q, float))
    n = len(q)
    z = np.zeros((n, 3))
    return Rows(q, np.zeros(n, int), z, z, ("",) * n, np.zeros(n))


def parameter_names(chain: Chain, points: Sequence[str] = ()) -> list[str]:
    """Names of the full parameter vector, in its order."""
    n = chain.dof
    names = [f"base.{s}" for s in BASE] + tool_names(points)
    names += [f"{chain.joints[k]}.offset" for k in range(n)]
    names += [f"{chain.joints[k]}.compliance" for k in range(n)]
    frames = [*chain.joints, "flange"]
    names += [f"{frames[k]}.link_{s}" for k in range(n + 1) for s in LINK]
    return names


def kind(name: str) -> str:
    """The effect a parameter belongs to: base_frame, tool_frame, joint_offset, joint_compliance,
    compensator (a spring's stiffness and preload: statics.py), link_geometry."""
    if name.startswith("base."):
        return "base_frame"
    if name.startswith("tool."):
        return "tool_frame"
    tail = name.rsplit(".", 1)[1]
    if tail.startswith("spring_"):
        return "compensator"
    return {"offset": "joint_offset", "compliance": "joint_compliance"}.get(tail, "link_geometry")


@dataclass(frozen=True)
class GeometricModel:
    """A chain, the starting probe point(s) and base frame; the load sites for loaded readings."""

    chain: Chain
    base0: np.ndarray  # (4, 4) tracker from robot base, the start of B
    tool0: np.ndarray  # (3,) m in the flange frame, or (m, 3): one row per point of ``points``
    points: tuple[str, ...] = ()  # the points' names (several: one tool_frame each)
    sites: Mapping[str, np.ndarray] = field(default_factory=dict)  # load sites, flange frame (m)

    @property
    def tools0(self) -> np.ndarray:
        """(m, 3) the points' starts."""
        return np.atleast_2d(np.asarray(self.tool0, float))

    @property
    def n_points(self) -> int:
        return len(self.tools0)

    @property
    def names(self) -> list[str]:
        return parameter_names(self.chain, self.points if self.n_points > 1 else ())

    @property
    def joints(self) -> tuple[str, ...]:
        return self.chain.joints

    @property
    def size(self) -> int:
        return 6 + 3 * self.n_points + 8 * self.chain.dof + 6

    def _load(self, rows: Rows, gravity: np.ndarray | None = None) -> np.ndarray:
        """The loads' torques at the chain's nominal geometry; ``gravity`` (base frame) turns the
        hanging masses' forces."""
        if not np.any(rows.loaded):
            return np.zeros((len(rows), self.chain.dof))
        return self._load_on(self.chain, rows, gravity)

    def _load_on(self, chain: Chain, rows: Rows, gravity: np.ndarray | None) -> np.ndarray:
        at = np.zeros((len(rows), 3))
        for i, s in enumerate(rows.site):
            if s:
                if s not in self.sites:
                    raise ValueError(f"load site {s!r}: not a point on the flange of this model")
                at[i] = self.sites[s]
        force = rows.force.copy()
        if gravity is not None:
            hung = rows.mass > 0
            force[hung] = rows.mass[hung, None] * np.asarray(gravity, float)
        return load_torques(chain, rows.q, force, rows.moment, at)

    def torques(self, q) -> np.ndarray:
        """tau at the nominal geometry (n_poses, dof), the lever of the compliances: the robot's
        weight and each reading's load."""
        rows = as_rows(q)
        return gravity_torques(self.chain, rows.q) + self._load(rows)

    def torques_at(self, q, theta: np.ndarray, levelled: bool = True, steps: int = 3) -> np.ndarray:
        """tau (n_poses, dof) of the model ``theta`` at its own deflected pose: the calibrated chain
        (link frames and offsets) at q + c tau, by fixed-point iteration (``steps``; it contracts by
        |c dtau/dq|, ~1e-3). ``levelled``: gravity along the tracker's -z (a levelled tracker,
        as the bench's and the UR10 dataset's), turned into the robot's base by the fitted
        registration; else along the base's -z (the chain's GRAVITY). A hanging mass's weight
        turns with gravity; a wrench stays as given."""
        rows = as_rows(q)
        chain, _, b, comp = self.calibrated(theta)
        g = b[:3, :3].T @ np.array([0.0, 0.0, -np.linalg.norm(GRAVITY)]) if levelled else GRAVITY
        loaded = np.any(rows.loaded)

        def total(qq):
            tau = gravity_torques(chain, qq, gravity=g)
            if loaded:
                tau = tau + self._load_on(chain, replace(rows, q=qq), g)
            return tau

        tau = total(rows.q)
        for _ in range(steps - 1):
            tau = total(rows.q + comp * tau)
        return tau

    def calibrated(self, theta: np.ndarray):
        """See :meth:`fit.GeometryFit.calibrated` (the probe point: (3,) for one point, else
        (m, 3))."""
        base, tool, off, comp, link = self._split(np.asarray(theta, float))
        frames = []
        for k in range(self.chain.dof + 1):
            e = translation(link[k, :3]) @ rot(0, link[k, 3]) @ rot(1, link[k, 4]) @ rot(2, link[k, 5])
            frames.append(self.chain.frames[k] @ e @ (rot(2, off[k]) if k < self.chain.dof else np.eye(4)))
        chain = replace(self.chain, frames=np.asarray(frames))
        b = translation(base[:3]) @ rot(0, base[3]) @ rot(1, base[4]) @ rot(2, base[5]) @ self.base0
        tools = self.tools0 + tool
        return chain, tools[0] if np.ndim(self.tool0) == 1 else tools, b, comp.copy()

    def _split(self, theta: np.ndarray):
        n, t = self.chain.dof, 6 + 3 * self.n_points
        base, tool = theta[0:6], theta[6:t].reshape(-1, 3)
        off, comp = theta[t : t + n], theta[t + n : t + 2 * n]
        link = theta[t + 2 * n :].reshape(n + 1, 6)
        return base, tool, off, comp, link

    def predict(self, q, theta: np.ndarray, tau: np.ndarray | None = None) -> np.ndarray:
        """Predicted readings (n_poses, 3) in the tracker frame."""
        return self._run(q, theta, tau, jacobian=False)[0]

    def jacobian(self, q, theta: np.ndarray, tau: np.ndarray | None = None, columns=None):
        """(prediction (n, 3), dy/dtheta (n, 3, size)); every column, whatever ``columns`` asks
        for (exact and cheap here; statics.py computes only those)."""
        y, jac = self._run(q, theta, tau, jacobian=True)
        return y, jac

    def _run(self, q, theta, tau, jacobian: bool):
        rows = as_rows(q)
        q = rows.q
        theta = np.asarray(theta, float)
        tau = self.torques(rows) if tau is None else tau
        base, tool, off, comp, link = self._split(theta)
        n, dof, npt = len(q), self.chain.dof, self.n_points
        t = np.broadcast_to(np.eye(4), (n, 4, 4))
        # each parameter's motion in the robot base frame: a translation axis, or a rotation axis
        # through a point; gathered as (axis (n, 3), point (n, 3) or None)
        motions: list[tuple[np.ndarray, np.ndarray | None]] = []
        offset_motion: list[tuple[np.ndarray, np.ndarray]] = []

        def frame_error(t, e):
            for i in range(3):
                motions.append((t[:, :3, i].copy(), None))
            t = t @ translation(e[:3])
            for i in range(3):
                motions.append((t[:, :3, i].copy(), t[:, :3, 3].copy()))
                t = t @ rot(i, e[3 + i])
            return t

        for k in range(dof):
            t = frame_error(t @ self.chain.frames[k], link[k])
            offset_motion.append((t[:, :3, 2].copy(), t[:, :3, 3].copy()))
            t = t @ rot(2, q[:, k] + off[k] + comp[k] * tau[:, k])
        t = frame_error(t @ self.chain.frames[-1], link[dof])
        point = (self.tools0 + tool)[rows.point]  # (n, 3) each reading's point
        p = np.einsum("nij,nj->ni", t[:, :3, :3], point) + t[:, :3, 3]
        rb = rot(0, base[3]) @ rot(1, base[4]) @ rot(2, base[5])
        b = translation(base[:3]) @ rb @ self.base0
        y = p @ b[:3, :3].T + b[:3, 3]
        if not jacobian:
            return y, None
        jac = np.zeros((n, 3, self.size))
        bt = base[:3]  # the rotations of B turn about the point t_B
        # base: translations along the tracker's axes; the rotations Rx Ry Rz about axes through t_B,
        # each one's axis turned by the rotations before it
        turned = np.eye(4)
        for i in range(3):
            jac[:, i, i] = 1.0
            jac[:, :, 3 + i] = np.cross(turned[:3, i], y - bt)
            turned = turned @ rot(i, base[3 + i])
        rbw = b[:3, :3]  # tracker from robot base: maps a base-frame motion into the tracker frame

        def put(col, axis, point):
            dp = axis if point is None else np.cross(axis, p - point)
            jac[:, :, col] = dp @ rbw.T

        for j in range(npt):  # a point's columns move only its own readings
            mine = (rows.point == j)[:, None]
            for i in range(3):
                put(6 + 3 * j + i, t[:, :3, i] * mine, None)
        start = 6 + 3 * npt
        for k, (axis, point) in enumerate(offset_motion):
            put(start + k, axis, point)
            jac[:, :, start + dof + k] = jac[:, :, start + k] * tau[:, k, None]
        start += 2 * dof
        for m, (axis, point) in enumerate(motions):
            put(start + m, axis, point)
        return y, jac
