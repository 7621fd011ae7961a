"""`base_compliance`: the robot's base tilting on its foundation (`[truth.effects.base_compliance]`)."""

from __future__ import annotations

import mujoco
import numpy as np

from .base import Effect, Field
from .edits import (
    AXES,
    add_hinge,
    hinge_compliances,
    root_body_name,
    spec_body,
    spec_root_body,
)
from .registry import register_effect

BASE_POINT_MASS = 1.0  # kg at the base's hinge point when the base has no mass of its own


def _base_truth(t: dict) -> tuple[dict, np.ndarray]:
    c = np.asarray(t["compliance"], dtype=float)
    axes = "".join(a for a, ci in zip("xy", c) if ci != 0.0)
    return {"axes": axes}, c[c != 0.0]


@register_effect(
    "base_compliance",
    truth=(Field("compliance", "vector", "rad/(N*m)", size=2, nonneg=True, doc="cx, cy; 0 = rigid"),),
    from_truth=_base_truth,
    discover=lambda robot: [{"body": root_body_name(robot)}],
)
def base_compliance(axes: str = "xy", body: str | None = None) -> Effect:
    """Tilt of the robot's base on its foundation (anchor bolts, floor plate).

    Physics: the base body (default: the body fixed to the world that carries the arm),
    gets hinges `<base>_rx`, `<base>_ry` about its frame's x and y (world x and y for the
    FANUC) through its origin (the floor point under axis 1), stiffness 1/c, springref 0. The whole robot then tilts by c times the
    moment, about that point, of everything it carries (gravity of all links, the load): for a
    wrench (F at p, M) the tilt is c_x (p x F + M)_x and c_y (p x F + M)_y. If the base has no
    mass of its own (it needs some to move in MuJoCo) it gets a 1 kg point mass at the hinge
    point, which exerts no moment about the hinges at any tilt.

    Parameters cx, cy in rad/(N*m), for the axes listed.
    """
    if not axes or any(a not in "xy" for a in axes) or len(set(axes)) != len(axes):
        raise ValueError(f"base_compliance: axes must be a non-empty subset of 'xy', got {axes!r}")
    axes = "".join(a for a in "xy" if a in axes)

    def apply(spec, p, o):
        name = o["body"] or spec_root_body(spec)
        b = spec_body(spec, name)
        if b.find_all(mujoco.mjtObj.mjOBJ_JOINT) and any(j.name.startswith(name + "_r") for j in b.joints):
            raise ValueError("base_compliance is already applied")
        for a, c in zip(o["axes"], p):
            add_hinge(b, f"{name}_r{a}", np.eye(3)[AXES.index(a)], c)
        if not (float(b.mass) > 0):
            b.explicitinertial = True
            b.mass = BASE_POINT_MASS
            b.ipos = [0.0, 0.0, 0.0]
            b.iquat = [1.0, 0.0, 0.0, 0.0]
            b.inertia = [1.0, 1.0, 1.0]

    def hinge(robot, o, a):
        return f"{o['body'] or root_body_name(robot)}_r{a}"

    return hinge_compliances("base_compliance", axes, {"axes": axes, "body": body}, apply, hinge)
