"""A thin wrapper around the robot's MjModel/MjData: names, truth parameters, commands.

The MJCF (mjcf/m900ib700.xml) defines the geometry; everything elastic (joint stiffness, the
compensator spring) is written here from a scenario's truth, so the file's own stiffness values
never matter. Controller angles are the model's hinge angles: q3 is the crank of the active
parallelogram and the passive `elbow` and `rod` hinges follow from the loop (see the MJCF).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

ACTUATED = ("j1", "j2", "j3", "j4", "j5", "j6")
PASSIVE = ("elbow", "rod")
COMPENSATOR = "compensator"
LOOP = "parallelogram"
PAYLOAD_SITE = "payload"
FLANGE_SITE = "flange"
REFLECTOR_PREFIX = "refl_"
# The parallelogram degenerates (its crank parallel to the upper arm) at q3 - q2 = -120 deg and
# 60 deg; commands keep this margin away (bench.campaign rejects them, design never samples them).
PARALLELOGRAM_MARGIN = np.radians(10.0)
_PARALLEL_OFFSET = np.radians(120.0)   # minus the q3 - q2 at which the crank lies along the arm


def parallelogram_angle(q: np.ndarray) -> float:
    """Angle between crank and upper arm (rad, mod pi); 0 is the degenerate parallelogram."""
    return float(np.mod(q[2] - q[1] + _PARALLEL_OFFSET, np.pi))


@dataclass(frozen=True)
class Params:
    """Elastostatic parameters in SI: the six actuator compliances (rad/(N*m)) and the
    compensator spring (K_C in N/m, preload length s0 in m). Paper eqs. (1) and (8)."""

    compliance: np.ndarray
    compensator_stiffness: float
    compensator_preload: float

    def as_dict(self) -> dict:
        return {
            "compliance": [float(x) for x in self.compliance],
            "compensator": {
                "stiffness": float(self.compensator_stiffness),
                "preload": float(self.compensator_preload),
            },
        }


@dataclass(frozen=True)
class CompensatorGeometry:
    """Geometry of the compensator triangle of paper Fig. 4 read from the MJCF sites.

    l_c: J2 axis to the turret attachment; l_2: J2 axis to the arm attachment;
    offset: psi - q2, the compensator angle minus the controller's q2 (rad).
    """

    l_c: float
    l_2: float
    offset: float

    def angle(self, q2: float) -> float:
        return q2 + self.offset

    def length(self, q2: float) -> float:
        """Spring length s, paper eq. (7)."""
        psi = self.angle(q2)
        return float(np.sqrt(self.l_c**2 + self.l_2**2 - 2 * self.l_c * self.l_2 * np.cos(psi)))


class Robot:
    """MjModel + MjData with the robot's named parts resolved once."""

    def __init__(self, model: mujoco.MjModel, source: Path | None = None):
        self.model = model
        self.data = mujoco.MjData(model)
        self.source = source
        jid = lambda n: mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n)  # noqa: E731
        self.act_joint = np.array([jid(n) for n in ACTUATED])
        self.passive_joint = np.array([jid(n) for n in PASSIVE])
        if (self.act_joint < 0).any() or (self.passive_joint < 0).any():
            raise ValueError(f"{source}: the MJCF must name joints {ACTUATED + PASSIVE}")
        self.n_act = len(self.act_joint)
        self.act_qpos = model.jnt_qposadr[self.act_joint]
        self.act_dof = model.jnt_dofadr[self.act_joint]
        # flat indices of (dof of motor i, column i) in dforce_dtheta's (nv, n_act + 2) result
        self._spring_entries = self.act_dof * (self.n_act + 2) + np.arange(self.n_act)
        self.passive_qpos = model.jnt_qposadr[self.passive_joint]
        self.tendon = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_TENDON, COMPENSATOR)
        if self.tendon >= 0:  # the tendon's sparse row of ten_J: a fixed pattern of the model
            adr, nnz = int(model.ten_J_rowadr[self.tendon]), int(model.ten_J_rownnz[self.tendon])
            self._ten_rows = slice(adr, adr + nnz)
            self._ten_cols = model.ten_J_colind[adr: adr + nnz].copy()
        self.loop = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_EQUALITY, LOOP)
        site = lambda n: mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, n)  # noqa: E731
        self.payload_site = site(PAYLOAD_SITE)
        self.flange_site = site(FLANGE_SITE)
        self.reflector_names = [
            model.site(i).name for i in range(model.nsite) if model.site(i).name.startswith(REFLECTOR_PREFIX)
        ]
        self.reflector_sites = np.array([site(n) for n in self.reflector_names])
        # kinematic loops closed by the statics (bench/loop.py), each a (site, site) pair whose
        # positions coincide: here the parallelogram's coupler rod end and its anchor
        self.loops: tuple[tuple[int, int], ...] = (
            (site("rod_end"), site("rod_anchor"))
            if self.loop < 0
            else (int(model.eq_obj1id[self.loop]), int(model.eq_obj2id[self.loop])),
        )

    # -- construction -------------------------------------------------------------------
    @classmethod
    def from_file(cls, path: str | Path) -> "Robot":
        path = Path(path)
        return cls(mujoco.MjModel.from_xml_path(str(path)), source=path)

    @classmethod
    def from_xml(cls, text: str) -> "Robot":
        return cls(mujoco.MjModel.from_xml_string(text))

    # -- parameters ---------------------------------------------------------------------
    def set_params(self, params: Params) -> None:
        """Write the truth into the model: hinge stiffness 1/k_i and the compensator spring."""
        k = np.asarray(params.compliance, dtype=float)
        self.model.jnt_stiffness[self.act_joint] = 1.0 / k
        if self.tendon >= 0:
            self.model.tendon_stiffness[self.tendon] = params.compensator_stiffness
            self.model.tendon_lengthspring[self.tendon] = params.compensator_preload

    def dforce_dtheta(self, params: Params, data: mujoco.MjData | None = None) -> np.ndarray:
        """d g / d theta at fixed q (nv, n_act + 2): how the springs' generalized force moves with
        the parameters ``set_params`` writes, theta = [compliances, K_C, s0] in that order.

        Joint springs (paper eq. 1): g_i = -(q_i - q_cmd,i) / k_i, so dg_i/dk_i = (q_i - q_cmd,i)
        / k_i^2 on motor i's dof. Compensator (eqs. 7-8, a tendon of length L and moment
        t = dL/dq): g = -K_C (L - s0) t, so dg/dK_C = -(L - s0) t and dg/ds0 = K_C t; both zero
        without the tendon. Gravity and the load do not depend on theta. The pose is the one
        held in ``data`` (position stage current) and the command the springs' reference
        (:meth:`set_command`); this is the right-hand side of the implicit function theorem
        (bench.statics.StaticsSolver.tangent)."""
        d = self.data if data is None else data
        m = self.model
        k = np.asarray(params.compliance, dtype=float)
        out = np.zeros((m.nv, self.n_act + 2))
        dq = d.qpos.take(self.act_qpos) - m.qpos_spring.take(self.act_qpos)
        out.flat[self._spring_entries] = dq / (k * k)
        if self.tendon >= 0:
            t = self.tendon_moment(d)
            length = float(d.ten_length[self.tendon])
            out[:, self.n_act] = -(length - params.compensator_preload) * t
            out[:, self.n_act + 1] = params.compensator_stiffness * t
        return out

    def params(self) -> Params:
        """The parameters the model currently holds (for the simulator's truth only)."""
        k_c = float(self.model.tendon_stiffness[self.tendon]) if self.tendon >= 0 else 0.0
        s0 = float(self.model.tendon_lengthspring[self.tendon][0]) if self.tendon >= 0 else 0.0
        return Params(1.0 / self.model.jnt_stiffness[self.act_joint].copy(), k_c, s0)

    def limits(self) -> np.ndarray:
        """(n_act, 2) controller joint limits in rad."""
        return self.model.jnt_range[self.act_joint].copy()

    def parallelogram_ok(self, q: np.ndarray) -> bool:
        """The command keeps PARALLELOGRAM_MARGIN away from a degenerate parallelogram (where the
        loop has no unique equilibrium: bench.statics raises StaticsError there)."""
        ang = parallelogram_angle(q)
        return bool(min(ang, np.pi - ang) >= PARALLELOGRAM_MARGIN)

    def weight(self, mass: float) -> np.ndarray:
        """(3,) world force of a mass under the model's gravity (MJCF ``<option gravity>``), N."""
        return mass * self.model.opt.gravity

    # -- commands -----------------------------------------------------------------------
    def set_command(self, q: np.ndarray) -> None:
        """Commanded angles become the springs' reference (VJM: the spring is at rest there)."""
        self.model.qpos_spring[self.act_qpos] = q

    def rigid_qpos(self, q: np.ndarray) -> np.ndarray:
        """The closed-loop configuration at the command with no deflection.

        Parallelogram (MJCF comment): forearm pitch = crank = q3, so elbow = q3 - q2 and the
        coupler rod stays parallel to the upper arm: rod = q2 - q3.
        """
        qpos = self.model.qpos0.copy()
        qpos[self.act_qpos] = q
        qpos[self.passive_qpos] = [q[2] - q[1], q[1] - q[2]]
        return qpos

    def tendon_moment(self, data: mujoco.MjData | None = None) -> np.ndarray:
        """(nv,) dense dL/dq of the compensator tendon. MuJoCo 4 stores ten_J sparsely
        (values in data.ten_J, columns in model.ten_J_colind); position stage must be current."""
        d = self.data if data is None else data
        out = np.zeros(self.model.nv)
        if self.tendon >= 0:
            out[self._ten_cols] = d.ten_J[self._ten_rows]
        return out

    def compensator_geometry(self) -> CompensatorGeometry:
        """Measure l_c, l_2 and the angle offset from the MJCF sites at q = 0 (geometry only)."""
        m = self.model
        d = mujoco.MjData(m)
        d.qpos[:] = self.rigid_qpos(np.zeros(self.n_act))
        mujoco.mj_kinematics(m, d)
        a, b = m.wrap_objid[m.tendon_adr[self.tendon] : m.tendon_adr[self.tendon] + 2]
        j2 = self.act_joint[1]
        axis_pt = d.xanchor[j2]
        axis = d.xaxis[j2]
        va = d.site_xpos[a] - axis_pt
        vb = d.site_xpos[b] - axis_pt
        va -= axis * (va @ axis)
        vb -= axis * (vb @ axis)
        l_c, l_2 = np.linalg.norm(va), np.linalg.norm(vb)
        # signed angle from the turret attachment to the arm attachment about the J2 axis
        psi = np.arctan2(np.cross(va, vb) @ axis, va @ vb)
        return CompensatorGeometry(float(l_c), float(l_2), float(psi))
