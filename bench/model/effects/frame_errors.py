"""`link_geometry` and `base_frame`: a body's frame off its drawn place, truth-only geometric
effects (`[truth.effects.link_geometry]`, `[truth.effects.base_frame]`; docs/geometry.md)."""

from __future__ import annotations

from collections.abc import Callable

import mujoco
import numpy as np

from .base import Effect, Field
from .edits import spec_body, spec_root_body
from .registry import register_effect
from .zero_offsets import MAX_OFFSET

FRAME_PARAMS = ("dx", "dy", "dz", "rx", "ry", "rz")
FRAME_UNITS = ("m", "m", "m", "rad", "rad", "rad")
OFFSET = Field(
    "offset", "vector", "m, rad", size=6, max_abs=MAX_OFFSET, doc="dx, dy, dz (m), rx, ry, rz (rad)"
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
        nominal["body"] = (np.array(body.pos, dtype=float), np.array(body.quat, dtype=float))
        nominal["name"] = body.name
        body.pos, body.quat = frame_error(body.pos, body.quat, p)

    def set_(robot, p, o):
        if "body" not in nominal:
            raise ValueError(f"{name}: set_params needs the model its apply built")
        b = mujoco.mj_name2id(robot.model, mujoco.mjtObj.mjOBJ_BODY, nominal["name"])
        robot.model.body_pos[b], robot.model.body_quat[b] = frame_error(*nominal["body"], p)

    return Effect(name, FRAME_PARAMS, options, FRAME_UNITS, apply, set_)


def _link_geometry_truth(t: dict) -> tuple[dict, np.ndarray]:
    return {"link": str(t["link"])}, np.asarray(t["offset"], dtype=float)


@register_effect(
    "link_geometry",
    truth=(Field("link", "string", doc="the body whose frame is off"), OFFSET),
    from_truth=_link_geometry_truth,
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
