"""Helpers the robot-side effects share to edit a spec: hinges, bodies, moving subtrees.

Every new joint has ref 0 and springref 0, so its qpos0 and qpos_spring are 0 and
:meth:`bench.model.Robot.rigid_qpos` leaves it at 0 (only the actuated and passive joints are
filled, by name). A compliance of exactly 0 in a scenario's truth means "rigid": that hinge is
not created at all (no dof). A fitting structure that does hold a hinge whose compliance is set
to 0 locks it with a spring of stiffness 1/RIGID_COMPLIANCE (1e12 N*m/rad, ~1e5 x the drives).
"""

from __future__ import annotations

import mujoco
import numpy as np

from calbench.bench.model import Robot, spec_names

from .base import Effect

RIGID_COMPLIANCE = 1e-12  # rad/(N*m): the lock used for a present hinge set to compliance 0
AXES = "xyz"
_TMP_PREFIX = "__effects_move__"


def joint_id(robot: Robot, name: str) -> int:
    jid = mujoco.mj_name2id(robot.model, mujoco.mjtObj.mjOBJ_JOINT, name)
    if jid < 0:
        raise ValueError(f"the model has no joint {name!r}: apply the effect (and recompile) first")
    return jid


def spec_body(spec: mujoco.MjSpec, name: str):
    b = spec.body(name)
    if b is None:
        raise ValueError(f"the MJCF has no body {name!r}")
    return b


def spec_root_body(spec: mujoco.MjSpec) -> str:
    """The body fixed to the world that carries the arm: the first actuated joint's ancestor
    whose parent is the world (calbench:actuated)."""
    names = spec_names(spec, "actuated")
    j = spec.joint(names[0]) if names else None
    if j is None:
        raise ValueError("the MJCF's robot description names no actuated joint (calbench:actuated)")
    b = j.parent
    while b.parent is not None and b.parent.name != "world":
        b = b.parent
    return b.name


def root_body_name(robot: Robot) -> str:
    """:func:`spec_root_body` of a compiled robot."""
    m = robot.model
    b = int(m.jnt_bodyid[robot.act_joint[0]])
    while m.body_parentid[b] != 0:
        b = int(m.body_parentid[b])
    return m.body(b).name


def stiffness_of(c: float) -> float:
    """Spring stiffness (N*m/rad) of a compliance c (rad/(N*m)); c = 0 locks the hinge."""
    if c < 0:
        raise ValueError(f"a compliance must be >= 0, got {c}")
    return 1.0 / max(float(c), RIGID_COMPLIANCE)


def add_hinge(body, name: str, axis, compliance: float, pos=(0.0, 0.0, 0.0)):
    j = body.add_joint(name=name, type=mujoco.mjtJoint.mjJNT_HINGE, axis=list(axis), pos=list(pos))
    j.ref = 0.0
    j.springref = 0.0
    j.stiffness[0] = stiffness_of(compliance)
    j.damping[0] = 0.0
    j.limited = mujoco.mjtLimited.mjLIMITED_FALSE
    return j


def child_bodies(body) -> list:
    out, b = [], body.first_body()
    while b is not None:
        out.append(b)
        b = body.next_body(b)
    return out


_EQ_FIELDS = ("name", "type", "objtype", "name1", "name2", "data", "solref", "solimp", "active")


def move_bodies(spec: mujoco.MjSpec, names: list[str], new_parent) -> None:
    """Reparent the named body subtrees (with everything in them) under `new_parent` at the same
    local pose. MjSpec has no in-place move: copy, delete, attach the copy, restore the names,
    and re-create the equality constraints that the deletion removed."""
    src = spec.copy()
    for t in list(src.tendons):  # attach would bring the copy's tendons/equalities along
        src.delete(t)
    for e in list(src.equalities):
        src.delete(e)
    for e in list(src.texts) + list(src.numerics) + list(src.tuples):  # the robot description: kept once
        src.delete(e)
    eqs = [{f: getattr(e, f) for f in _EQ_FIELDS} for e in spec.equalities]
    eqs = [{k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in e.items()} for e in eqs]
    counts = (len(spec.tendons), len(spec.actuators), len(spec.sensors), len(spec.excludes))
    for n in names:
        spec.delete(spec.body(n))
    if (len(spec.tendons), len(spec.actuators), len(spec.sensors), len(spec.excludes)) != counts:
        raise NotImplementedError(
            f"moving {names} would drop tendons/actuators/sensors/excludes that reference them"
        )
    for n in names:
        frame = new_parent.add_frame()
        frame.attach_body(src.body(n), _TMP_PREFIX, "")
    for kind in (
        mujoco.mjtObj.mjOBJ_BODY,
        mujoco.mjtObj.mjOBJ_JOINT,
        mujoco.mjtObj.mjOBJ_GEOM,
        mujoco.mjtObj.mjOBJ_SITE,
        mujoco.mjtObj.mjOBJ_CAMERA,
        mujoco.mjtObj.mjOBJ_LIGHT,
        mujoco.mjtObj.mjOBJ_FRAME,
    ):
        for el in new_parent.find_all(kind):
            if el.name.startswith(_TMP_PREFIX):
                el.name = el.name[len(_TMP_PREFIX) :]
    leftover = spec.find_default(_TMP_PREFIX + "main")  # the copy's (empty) default class
    if leftover is not None:
        try:
            spec.delete(leftover)
        except Exception:  # noqa: BLE001  (cosmetic only: an unused, empty class)
            pass
    have = {e.name for e in spec.equalities}
    for e in eqs:
        if e["name"] and e["name"] in have:
            continue
        new = spec.add_equality()
        for f in _EQ_FIELDS:
            setattr(new, f, e[f])


def hinge_compliances(name: str, axes: str, options: dict, apply, hinge) -> Effect:
    """An effect whose parameters are compliances c<axis> (rad/(N*m)), one per axis listed, of
    hinges that ``apply`` adds; ``hinge(robot, options, axis)`` names each in the compiled model,
    where :meth:`Effect.set_params` writes its stiffness 1/c."""

    def set_(robot, p, o):
        for a, c in zip(o["axes"], p):
            robot.model.jnt_stiffness[joint_id(robot, hinge(robot, o, a))] = stiffness_of(c)

    return Effect(name, tuple(f"c{a}" for a in axes), options, ("rad/(N*m)",) * len(axes), apply, set_)
