"""`tool_compliance`: the tool bending on its mount, a truth-only effect (`[truth.effects.tool_compliance]`)."""

from __future__ import annotations

import numpy as np

from calbench.bench.model import spec_names

from .base import Effect, Field
from .edits import AXES, add_hinge, hinge_compliances, spec_body
from .registry import register_effect


def _tool_truth(t: dict) -> tuple[dict, np.ndarray]:
    c = np.asarray(t["compliance"], dtype=float)
    axes = "".join(a for a, ci in zip("yz", c) if ci != 0.0)
    return {"axes": axes}, c[c != 0.0]


TOOL_BODY = "tool"
TOOL_MASS = 1.0  # kg on the moving tool body (MuJoCo needs mass there)


@register_effect(
    "tool_compliance",
    truth=(Field("compliance", "vector", "rad/(N*m)", size=2, nonneg=True, doc="cy, cz; 0 = rigid"),),
    from_truth=_tool_truth,
)
def tool_compliance(axes: str = "yz", body: str | None = None, mount: tuple | None = None) -> Effect:
    """Bending of the tool on its mount at the flange (a TRUTH-ONLY effect: it is not one of
    docs/contract.md's discovery candidates; the discovery tests use it as a disagreement that no
    candidate explains).

    Physics: a child body `tool` of the payload site's body (``body``, the FANUC's link6) at the
    mount point (``mount`` in that body's frame; default the flange site, else the body's
    origin) carries hinges `tool_ry`, `tool_rz` about the body's y and z (stiffness 1/c,
    springref 0) and takes over the body's payload and reflector sites (calbench:payload,
    calbench:reflectors; same world positions), so the load bends the tool by c times its
    moment about the mount point, and the reflectors on the tool see it. The tool's mass stays
    on the body (the new body holds a 1 kg point mass at the mount).
    Parameters cy, cz in rad/(N*m), for the axes listed.
    """
    if not axes or any(a not in "yz" for a in axes) or len(set(axes)) != len(axes):
        raise ValueError(f"tool_compliance: axes must be a non-empty subset of 'yz', got {axes!r}")
    axes = "".join(a for a in "yz" if a in axes)
    mount = None if mount is None else tuple(float(x) for x in mount)

    def apply(spec, p, o):
        payload = spec_names(spec, "payload")
        if not payload or spec.site(payload[0]) is None:
            raise ValueError("tool_compliance: the robot description names no payload site")
        b = spec_body(spec, o["body"]) if o["body"] else spec.site(payload[0]).parent
        flange = spec_names(spec, "flange")
        at = o["mount"]
        if at is None:
            f = spec.site(flange[0]) if flange else None
            at = (
                tuple(np.asarray(f.pos, float))
                if f is not None and f.parent.name == b.name
                else (0.0, 0.0, 0.0)
            )
        if spec.body(TOOL_BODY) is not None:
            raise ValueError("tool_compliance is already applied")
        tool = b.add_body(name=TOOL_BODY, pos=list(at))
        for a, c in zip(o["axes"], p):
            add_hinge(tool, f"tool_r{a}", np.eye(3)[AXES.index(a)], c)
        tool.explicitinertial = True
        tool.mass = TOOL_MASS
        tool.ipos = [0.0, 0.0, 0.0]
        tool.iquat = [1.0, 0.0, 0.0, 0.0]
        tool.inertia = [1e-3, 1e-3, 1e-3]
        carried = set(payload) | set(spec_names(spec, "reflectors"))
        moving = [s for s in b.sites if s.name in carried]
        for s in moving:
            keep = dict(
                name=s.name,
                pos=list(np.asarray(s.pos, float) - np.asarray(at)),
                quat=list(s.quat),
                size=list(s.size),
                rgba=list(s.rgba),
            )
            spec.delete(s)
            tool.add_site(**keep)

    options = {"axes": axes, "body": body, "mount": mount}
    return hinge_compliances("tool_compliance", axes, options, apply, lambda robot, o, a: f"tool_r{a}")
