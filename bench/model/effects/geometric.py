"""Geometric errors, effects a bench truth hides, identify --geometry recovers and discover names
(docs/geometry.md): `joint_offset` (each actuated joint's zero off), `tool_frame` (the reflectors
off their drawn places by one vector), `link_geometry` (a body's frame off in its parent) and
`base_frame` (the arm off its place). Each edits frames of the spec; its set_params writes the
same frames into a compiled model from the nominal ones its apply saw.

Discovery tries the first three on absolute readings (``readings="absolute"``: `calbench discover
--geometry`, identify/discover/geometric.py): all the joint offsets as one candidate, each
actuated joint's body frame, the reflectors' common offset. `base_frame` is no candidate there:
with the tracker registration fitted in every model, an arm off its place is the registration."""

from __future__ import annotations

from collections.abc import Callable

import mujoco
import numpy as np

from calbench.bench.model import spec_names

from .base import Effect, Field
from .edits import spec_body, spec_root_body
from .registry import register_effect

MAX_OFFSET = 0.1  # rad (5.7 deg): a geometric error, not a different robot (docs/geometry.md)


def body_quat(spec: mujoco.MjSpec, body) -> np.ndarray:
    """The body's orientation in its parent as a quaternion, made the one its spec holds. A body
    oriented by ``euler`` (or another alternative: the FANUC's upper arm) keeps ``quat`` = 1 in the
    spec and its turn in ``alt``, which wins at compile: an edit of ``quat`` alone would be lost.
    So the compiled orientation is written into ``quat`` and ``alt`` set to it."""
    if body.alt.type != mujoco.mjtOrientation.mjORIENTATION_QUAT:
        model = spec.compile()
        body.quat = model.body_quat[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, body.name)]
        body.alt.type = mujoco.mjtOrientation.mjORIENTATION_QUAT
    return np.array(body.quat, dtype=float)


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
    discover=lambda robot: [{"joints": robot.n_act}],
    readings="absolute",
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
            nominal[name] = (np.array(body.pos, dtype=float), body_quat(spec, body))
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


def _tool_frame_truth(t: dict) -> tuple[dict, np.ndarray]:
    return {}, np.asarray(t["offset"], dtype=float)


@register_effect(
    "tool_frame",
    truth=(Field("offset", "vector", "m", size=3, max_abs=MAX_OFFSET, doc="dx, dy, dz in each site's body"),),
    from_truth=_tool_frame_truth,
    discover=[{}],
    readings="absolute",
)
def tool_frame() -> Effect:
    """The reflectors (calbench:reflectors) mounted off their nominal places by one common vector
    (dx, dy, dz) in m, in each site's body frame: a probe or reflector plate not where the
    drawing puts it."""
    nominal: dict[str, np.ndarray] = {}

    def apply(spec, p, o):
        for name in spec_names(spec, "reflectors"):
            site = spec.site(name)
            nominal[name] = np.array(site.pos, dtype=float)
            site.pos = nominal[name] + p

    def set_(robot, p, o):
        for name, pos0 in nominal.items():
            robot.model.site_pos[mujoco.mj_name2id(robot.model, mujoco.mjtObj.mjOBJ_SITE, name)] = pos0 + p

    return Effect("tool_frame", ("dx", "dy", "dz"), {}, ("m", "m", "m"), apply, set_)


FRAME_PARAMS = ("dx", "dy", "dz", "rx", "ry", "rz")
FRAME_UNITS = ("m", "m", "m", "rad", "rad", "rad")
OFFSET = Field(
    "offset", "vector", "m and rad", size=6, max_abs=MAX_OFFSET, doc="dx, dy, dz (m), rx, ry, rz (rad)"
)


def frame_error(pos, quat, p) -> tuple[np.ndarray, np.ndarray]:
    """A body frame P made P Tr(dx, dy, dz) Rx Ry Rz: the error E of docs/geometry.md."""
    quat = np.asarray(quat, dtype=float) / np.linalg.norm(quat)
    moved = np.zeros(3)
    mujoco.mju_rotVecQuat(moved, np.asarray(p[:3], dtype=float), quat)
    out = quat.copy()
    for axis, angle in zip(np.eye(3), p[3:], strict=True):
        turn, nxt = np.zeros(4), np.zeros(4)
        mujoco.mju_axisAngle2Quat(turn, axis, float(angle))
        mujoco.mju_mulQuat(nxt, out, turn)
        out = nxt
    return np.asarray(pos, dtype=float) + moved, out / np.linalg.norm(out)


def _frame_effect(name: str, body_of: Callable[[mujoco.MjSpec], str], options: dict) -> Effect:
    """A body's frame (its place in its parent) off by six numbers: :func:`frame_error`."""
    nominal: dict = {}

    def apply(spec, p, o):
        body = spec_body(spec, body_of(spec))
        nominal["body"] = (np.array(body.pos, dtype=float), body_quat(spec, body))
        nominal["name"] = body.name
        body.pos, body.quat = frame_error(body.pos, body.quat, p)

    def set_(robot, p, o):
        if "body" not in nominal:
            raise ValueError(f"{name}: set_params needs the model its apply built")
        b = mujoco.mj_name2id(robot.model, mujoco.mjtObj.mjOBJ_BODY, nominal["name"])
        robot.model.body_pos[b], robot.model.body_quat[b] = frame_error(*nominal["body"], p)

    return Effect(name, FRAME_PARAMS, options, FRAME_UNITS, apply, set_)


def actuated_bodies(robot) -> list[str]:
    """The names of the bodies the actuated joints turn, in calbench:actuated order."""
    m = robot.model
    return [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, int(m.jnt_bodyid[j])) for j in robot.act_joint]


def _link_geometry_truth(t: dict) -> tuple[dict, np.ndarray]:
    return {"link": str(t["link"])}, np.asarray(t["offset"], dtype=float)


@register_effect(
    "link_geometry",
    truth=(Field("link", "string", doc="the body whose frame is off"), OFFSET),
    from_truth=_link_geometry_truth,
    discover=lambda robot: [{"link": name} for name in actuated_bodies(robot)],
    readings="absolute",
)
def link_geometry(link: str = "") -> Effect:
    """The frame of body ``link`` in its parent off by (dx, dy, dz) m and (rx, ry, rz) rad: a link
    longer, shorter or twisted against the drawing. Its children move with it."""
    return _frame_effect("link_geometry", lambda spec: link, {"link": link})


def _base_frame_truth(t: dict) -> tuple[dict, np.ndarray]:
    return {}, np.asarray(t["offset"], dtype=float)


@register_effect("base_frame", truth=(OFFSET,), from_truth=_base_frame_truth)
def base_frame() -> Effect:
    """The robot's base (the body fixed to the world that carries the arm) off its drawn place by
    (dx, dy, dz) m and (rx, ry, rz) rad: the whole arm moves against the world and the tracker."""
    return _frame_effect("base_frame", spec_root_body, {})
