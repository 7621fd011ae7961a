"""`joint_offset`: each actuated joint's zero off its nominal place, a truth-only geometric effect
(`[truth.effects.joint_offset]`; docs/geometry.md). identify --geometry recovers it."""

from __future__ import annotations

import mujoco
import numpy as np

from calbench.bench.model import spec_names

from .base import Effect, Field
from .registry import register_effect

MAX_OFFSET = 0.1  # rad (5.7 deg): a geometric error, not a different robot (docs/geometry.md)


def _offset_truth(t: dict) -> tuple[dict, np.ndarray]:
    offsets = np.asarray(t["offset"], dtype=float)
    return {"joints": len(offsets)}, offsets


def turned_frame(pos, quat, jpos, axis, angle) -> tuple[np.ndarray, np.ndarray]:
    """A body frame (pos, quat in its parent) turned by ``angle`` about its hinge (axis and
    point in the body frame)."""
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    jpos = np.asarray(jpos, dtype=float)
    turn, new_quat = np.zeros(4), np.zeros(4)
    mujoco.mju_axisAngle2Quat(turn, axis, float(angle))
    mujoco.mju_mulQuat(new_quat, np.asarray(quat, dtype=float), turn)
    rot, moved = np.zeros(9), np.zeros(3)
    mujoco.mju_quat2Mat(rot, turn)
    mujoco.mju_rotVecQuat(moved, jpos - rot.reshape(3, 3) @ jpos, np.asarray(quat, dtype=float))
    return np.asarray(pos, dtype=float) + moved, new_quat / np.linalg.norm(new_quat)


@register_effect(
    "joint_offset",
    truth=(Field("offset", "vector", "rad", max_abs=MAX_OFFSET, doc="o1..oN, one per actuated joint"),),
    from_truth=_offset_truth,
)
def joint_offset(joints: int = 6) -> Effect:
    """A zero offset o_k on every actuated joint (calbench:actuated order): the link turns by
    q_k + o_k when commanded q_k. The body that carries the hinge is turned by o_k about the
    hinge's axis and point, which is the same as the hinge reading o_k less (rotations about one
    axis commute). Parameters o1..oN in rad."""
    nominal: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def apply(spec, p, o):
        names = spec_names(spec, "actuated")
        if len(names) != joints:
            raise ValueError(f"joint_offset: {joints} offsets for {len(names)} actuated joints")
        for name, angle in zip(names, p, strict=True):
            j = spec.joint(name)
            body = j.parent
            nominal[name] = (np.array(body.pos, dtype=float), np.array(body.quat, dtype=float))
            body.pos, body.quat = turned_frame(body.pos, body.quat, j.pos, j.axis, angle)

    def set_(robot, p, o):
        for k, angle in enumerate(p):
            jid = robot.act_joint[k]
            name = mujoco.mj_id2name(robot.model, mujoco.mjtObj.mjOBJ_JOINT, jid)
            if name not in nominal:
                raise ValueError("joint_offset: set_params needs the model its apply built")
            b = robot.model.jnt_bodyid[jid]
            pos0, quat0 = nominal[name]
            jpos, axis = robot.model.jnt_pos[jid], robot.model.jnt_axis[jid]
            robot.model.body_pos[b], robot.model.body_quat[b] = turned_frame(pos0, quat0, jpos, axis, angle)

    names = tuple(f"o{k + 1}" for k in range(joints))
    return Effect("joint_offset", names, {"joints": joints}, ("rad",) * joints, apply, set_)
