"""`tool_frame`: the reflectors mounted off their drawn places by one vector, a truth-only
geometric effect (`[truth.effects.tool_frame]`; docs/geometry.md)."""

from __future__ import annotations

import mujoco
import numpy as np

from calbench.bench.model import spec_names

from .base import Effect, Field
from .registry import register_effect
from .zero_offsets import MAX_OFFSET


def _tool_frame_truth(t: dict) -> tuple[dict, np.ndarray]:
    return {}, np.asarray(t["offset"], dtype=float)


@register_effect(
    "tool_frame",
    truth=(Field("offset", "vector", "m", size=3, max_abs=MAX_OFFSET, doc="dx, dy, dz in each site's body"),),
    from_truth=_tool_frame_truth,
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
