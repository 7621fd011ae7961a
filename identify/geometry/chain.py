"""A serial arm as a chain of fixed frames and revolute joints, batched over poses, in numpy.

    T(q) = P_1 Rz(q_1) P_2 Rz(q_2) ... P_n Rz(q_n) P_flange

Each P_k is the fixed frame of joint k in the frame of the joint before (the link's geometry),
joint axes are local z. Standard Denavit-Hartenberg rows (theta, d, a, alpha) map onto it with
P_1 = I and P_(k+1) = Tz(d_k) Tx(a_k) Rx(alpha_k) (the DH link transform of joint k without its
Rz(theta)); the last DH row's link transform is the flange.

Each body k (moved by joint k) has a mass and a centre of mass in its joint's rotated frame, so
that :func:`gravity_torques` gives the generalised gravity forces tau_k = sum_(j>=k) m_j g .
dc_j/dq_k (the torque the weight puts on joint k; what a compliant joint deflects under).

Units: SI (m, rad, kg, N*m).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

GRAVITY = np.array([0.0, 0.0, -9.81])  # m/s^2 in the robot's base frame (a floor-mounted base)

# Universal Robots UR10 (CB3), the published DH table (Universal Robots, "DH parameters for
# calculations of kinematics and dynamics"; the same numbers are in ur_description's
# config/ur10/physical_parameters.yaml): theta offset, d, a, alpha per joint.
UR10_DH = (
    (0.0, 0.1273, 0.0, np.pi / 2),
    (0.0, 0.0, -0.612, 0.0),
    (0.0, 0.0, -0.5723, 0.0),
    (0.0, 0.163941, 0.0, np.pi / 2),
    (0.0, 0.1157, 0.0, -np.pi / 2),
    (0.0, 0.0922, 0.0, 0.0),
)
UR10_JOINTS = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)
# Link masses (kg) as ur_description gives them; centres of mass in DH frame k (the frame at the
# end of link k), as its xacro places them: each arm link's at half its length (DH frame k has
# its origin at the far end, so +|a|/2 along x), the joint-axis offsets of the upper arm and
# forearm along z, the wrists at their joints.
UR10_MASS = (7.778, 12.93, 3.87, 1.96, 1.96, 0.202)
UR10_COM = (
    (0.0, 0.0, 0.0),
    (0.306, 0.0, 0.175),
    (0.28615, 0.0, 0.049),
    (0.0, 0.0, 0.0),
    (0.0, 0.0, 0.0),
    (0.0, 0.0, -0.0153),
)


def translation(v: np.ndarray) -> np.ndarray:
    t = np.eye(4)
    t[:3, 3] = v
    return t


def rot(axis: int, angle: np.ndarray | float) -> np.ndarray:
    """Rotation(s) about x (0), y (1) or z (2) as 4x4: shape (..., 4, 4)."""
    a = np.asarray(angle, float)
    out = np.zeros((*a.shape, 4, 4))
    out[..., 3, 3] = 1.0
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    c, s = np.cos(a), np.sin(a)
    out[..., axis, axis] = 1.0
    out[..., i, i], out[..., i, j], out[..., j, i], out[..., j, j] = c, -s, s, c
    return out


@dataclass(frozen=True)
class Chain:
    """A serial arm: fixed frames, joint names, body masses and centres of mass."""

    frames: np.ndarray  # (n + 1, 4, 4): P_1 .. P_n, then the flange
    joints: tuple[str, ...]
    mass: np.ndarray  # (n,) kg of body k (moved by joint k and the ones before)
    com: np.ndarray  # (n, 3) m, body k's centre of mass in joint k's rotated frame

    @property
    def dof(self) -> int:
        return len(self.joints)

    @classmethod
    def from_dh(cls, dh, joints, mass, com_dh) -> Chain:
        """From DH rows (theta0, d, a, alpha) and centres of mass given in DH frame k."""
        links = [translation([0, 0, d]) @ translation([a, 0, 0]) @ rot(0, al) for _, d, a, al in dh]
        frames = [rot(2, dh[0][0])] + [links[k] @ rot(2, dh[k + 1][0]) for k in range(len(dh) - 1)]
        frames.append(links[-1])
        # DH frame k = (joint k's rotated frame) @ link_k: a point c there is link_k @ c here
        com = [(links[k] @ np.append(c, 1.0))[:3] for k, c in enumerate(np.asarray(com_dh, float))]
        return cls(np.asarray(frames), tuple(joints), np.asarray(mass, float), np.asarray(com))

    def joint_frames(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World frames of every rotated joint (n_poses, dof, 4, 4) and of the flange (n_poses, 4, 4)."""
        q = np.atleast_2d(q)
        t = np.broadcast_to(np.eye(4), (len(q), 4, 4))
        out = np.empty((len(q), self.dof, 4, 4))
        for k in range(self.dof):
            t = t @ self.frames[k] @ rot(2, q[:, k])
            out[:, k] = t
        return out, t @ self.frames[-1]

    def flange_point(self, q: np.ndarray, tool: np.ndarray) -> np.ndarray:
        """A point fixed on the flange (``tool`` in the flange frame) in the base frame: (n_poses, 3)."""
        _, flange = self.joint_frames(q)
        return flange[:, :3, :3] @ np.asarray(tool, float) + flange[:, :3, 3]


def gravity_torques(
    chain: Chain,
    q: np.ndarray,
    tool_mass: float = 0.0,
    tool: np.ndarray | None = None,
    gravity: np.ndarray = GRAVITY,
):
    """Generalised gravity forces (n_poses, dof), N*m: tau_k = u_k . sum_(j>=k) (c_j - o_k) x m_j g.

    ``tool_mass`` at ``tool`` (flange frame) adds a payload (the probe) to the last body; ``gravity``
    (m/s^2) in the chain's base frame."""
    frames, flange = chain.joint_frames(q)
    coms = frames[:, :, :3, :3] @ chain.com[None, :, :, None]
    coms = coms[..., 0] + frames[:, :, :3, 3]  # (n, dof, 3) world centres of mass
    forces = chain.mass[None, :, None] * np.asarray(gravity, float)  # (1, dof, 3)
    points, weights = [coms], [np.broadcast_to(forces, coms.shape)]
    if tool_mass:
        tip = flange[:, :3, :3] @ np.asarray(tool, float) + flange[:, :3, 3]
        points.append(tip[:, None])
        weights.append(np.broadcast_to(tool_mass * np.asarray(gravity, float), tip[:, None].shape))
    pts, fs = np.concatenate(points, axis=1), np.concatenate(weights, axis=1)
    body = np.append(np.arange(chain.dof), chain.dof - 1)[: pts.shape[1]]
    tau = np.zeros((len(frames), chain.dof))
    for k in range(chain.dof):
        o, u = frames[:, k, :3, 3], frames[:, k, :3, 2]
        on = body >= k
        moment = np.cross(pts[:, on] - o[:, None], fs[:, on]).sum(axis=1)
        tau[:, k] = np.einsum("ij,ij->i", u, moment)
    return tau


def load_torques(
    chain: Chain, q: np.ndarray, force: np.ndarray, moment: np.ndarray, at: np.ndarray
) -> np.ndarray:
    """Generalised forces (n_poses, dof), N*m, of an external wrench on the flange: a force (n, 3)
    N at the point ``at`` (n, 3; flange frame) and a moment (n, 3) N*m, both in the chain's base
    frame: tau_k = u_k . ((p - o_k) x F + M), the transposed Jacobian of the point times the
    wrench (Klimchik et al. 2016, eq. (3): tau = J^T W). A payload's weight is such a force."""
    frames, flange = chain.joint_frames(q)
    at = np.asarray(at, float)
    p = np.einsum("nij,nj->ni", flange[:, :3, :3], at) + flange[:, :3, 3]
    f, m = np.asarray(force, float), np.asarray(moment, float)
    lever = p[:, None, :] - frames[:, :, :3, 3]  # (n, dof, 3)
    w = np.cross(lever, f[:, None, :]) + m[:, None, :]
    return np.einsum("nki,nki->nk", frames[:, :, :3, 2], w)


def ur10() -> Chain:
    """The UR10 from its published DH table and masses."""
    return Chain.from_dh(UR10_DH, UR10_JOINTS, UR10_MASS, UR10_COM)
