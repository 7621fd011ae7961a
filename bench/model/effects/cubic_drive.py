"""`joint_nonlinearity`: a cubic term in one drive's spring (`[truth.effects.joint_nonlinearity]`)."""

from __future__ import annotations

import numpy as np

from calbench.bench.model import spec_names

from .base import Effect, Field
from .registry import register_effect


def _nonlin_truth(t: dict) -> tuple[dict, np.ndarray]:
    return {"joint": int(t["joint"])}, np.array([float(t["cubic"])])


@register_effect(
    "joint_nonlinearity",
    truth=(
        Field("joint", "integer", lo=1, doc="the actuated axis, 1..N: the robot decides"),
        Field("cubic", "number", "N*m/rad^3", doc="> 0 hardening, < 0 softening"),
    ),
    from_truth=_nonlin_truth,
    discover=lambda robot: [{"joint": j} for j in range(1, robot.n_act + 1)],
)
def joint_nonlinearity(joint: int = 2) -> Effect:
    """A hardening (cubic > 0) or softening (< 0) drive spring on actuated axis `joint` (1..N,
    the robot's calbench:actuated order).

    Physics: torque = K theta + cubic theta^3, theta = joint angle - command. MuJoCo's joint
    stiffness polynomial gives force -(a x + b x^2 + c x^3) with x = qpos - qpos_spring
    (MJCF stiffness="a b c"; mjModel keeps a in jnt_stiffness and b, c in
    jnt_stiffnesspoly[j] = [b, c], mjNPOLY = 2 in MuJoCo 4.0.1). The effect writes only c; the
    linear K (Robot.set_params) is left untouched. Parameter cubic in N*m/rad^3.
    """
    if isinstance(joint, bool) or not isinstance(joint, (int, np.integer)) or joint < 1:
        raise ValueError(f"joint_nonlinearity: joint must be an actuated axis 1..N, got {joint!r}")

    def apply(spec, p, o):
        names = spec_names(spec, "actuated")
        if joint > len(names):
            raise ValueError(
                f"joint_nonlinearity: the robot has {len(names)} actuated joints "
                f"(calbench:actuated), not {joint}"
            )
        spec.joint(names[joint - 1]).stiffness[2] = p[0]

    def set_(robot, p, o):
        if joint > robot.n_act:
            raise ValueError(f"joint_nonlinearity: the robot has {robot.n_act} actuated joints, not {joint}")
        robot.model.jnt_stiffnesspoly[robot.act_joint[joint - 1], 1] = p[0]

    return Effect("joint_nonlinearity", ("cubic",), {"joint": joint}, ("N*m/rad^3",), apply, set_)
