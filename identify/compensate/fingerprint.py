"""A robot's geometry fingerprint: which robot an identification belongs to.

SHA-256 over the compiled model's structure and geometry (body, joint and site names, frames,
joint axes, masses and inertias, tendons' attachment sites), rounded to 1e-9, and never its
elastic values (stiffness, spring lengths: those are what identification estimates and set_params
overwrites). The same MJCF always gives the same digest; a site added for a tool changes it, so
the digest is taken of the user's robot before any such edit.
"""

from __future__ import annotations

import hashlib

import mujoco
import numpy as np

from calbench.bench.model import Robot

_FIELDS = (
    "body_parentid",
    "body_pos",
    "body_quat",
    "body_mass",
    "body_ipos",
    "body_inertia",
    "jnt_type",
    "jnt_bodyid",
    "jnt_pos",
    "jnt_axis",
    "site_bodyid",
    "site_pos",
    "wrap_objid",
)


def robot_sha256(robot: Robot) -> str:
    m = robot.model
    h = hashlib.sha256()
    for kind, n in ((mujoco.mjtObj.mjOBJ_BODY, m.nbody), (mujoco.mjtObj.mjOBJ_JOINT, m.njnt)):
        for i in range(n):
            h.update((mujoco.mj_id2name(m, kind, i) or "").encode() + b"\0")
    for f in _FIELDS:
        a = np.asarray(getattr(m, f), dtype=float)
        h.update(f.encode() + (np.round(a, 9) + 0.0).astype("<f8").tobytes())
    return h.hexdigest()


__all__ = ["robot_sha256"]
