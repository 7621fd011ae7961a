"""`link_compliance`: bending and torsion springs at the root of a link (`[truth.effects.link_compliance]`)."""

from __future__ import annotations

import mujoco
import numpy as np

from .base import Effect, Field
from .edits import (
    AXES,
    add_hinge,
    child_bodies,
    hinge_compliances,
    move_bodies,
    spec_body,
)
from .registry import register_effect

BEAM_SUFFIX = "_beam"
HUB_MASS_FRACTION = 1e-3  # MuJoCo needs mass on a moving body: the hub keeps this share


def _link_truth(t: dict) -> tuple[dict, np.ndarray]:
    c = np.asarray(t["compliance"], dtype=float)
    axes = "".join(a for a, ci in zip(AXES, c) if ci != 0.0)  # 0 = rigid: no hinge at all
    return {"link": t["link"], "axes": axes}, c[c != 0.0]


def _beam_hinge(link: str, axis: str) -> str:
    return f"{link}_r{axis}"


@register_effect(
    "link_compliance",
    truth=(
        Field("link", "string", doc="a body of the robot (its MJCF decides)"),
        Field(
            "compliance", "vector", "rad/(N*m)", size=3, nonneg=True, doc="cx, cy, cz; 0 = rigid, no hinge"
        ),
    ),
    from_truth=_link_truth,
    discover=lambda robot: [{"link": b} for b in robot.description.links],
)
def link_compliance(link: str, axes: str = AXES, pivot: tuple = (0.0, 0.0, 0.0)) -> Effect:
    """Bending and torsion springs at the root of a link: any body of the arm (discovery tries
    the robot's ``calbench:links``; the FANUC's upper arm and forearm).

    Physics: the link is split at its root into a HUB and a BEAM. The hub keeps the link's
    existing joint (the FANUC's j2 / elbow), its sites (e.g. a compensator's or a loop's
    attachment) and its jointless child bodies (e.g. the FANUC's rear wrist motors); a new child
    body `<link>_beam`, at the link's origin with the link's own frame, holds hinges
    `<link>_rx/_ry/_rz` about the link frame's x, y, z (stiffness 1/c, springref 0), the link's
    mass (a 1e-3 share stays on the hub at its origin, mass and first moment preserved) and the
    rest of the serial chain (the child bodies that carry joints). So the root springs
    carry the moment of everything outboard of the root (beam weight, wrist, payload) about
    the root point, and deflect the beam by c * moment about each axis (eq. 1 with three more
    virtual springs). Geoms stay on the hub (drawing and line of sight only).

    Why a hub: a hinge coaxial with the free passive `elbow` (forearm y) carries no moment, and
    an upper-arm y hinge beyond the compensator attachment is exactly a k2 in series. With the
    attachments on the hub, the forearm springs lie outside the parallelogram loop (they bend
    the beam, not the loop) and the upper-arm springs lie inside it (the elbow is on the beam):
    out-of-plane bending and torsion of the upper arm then make the loop spatial and the rigid
    coupler rod braces part of them. Link frames of mjcf/m900ib700.xml: upper arm z along the
    arm (z torsion, y in-plane bending, x lateral bending); forearm x along the forearm
    (x torsion, y in-plane bending = pitch, z lateral bending).

    What the paper's plan can tell apart (linear projection of the loaded-minus-unloaded
    reflector motion on k1..k6, K_C, s0): the forearm's y spring at the root is exactly a k3
    (the parallelogram turns the forearm about the elbow either way) and the upper arm's y
    spring is ~95 % a k2; the forearm's x/z and the upper arm's x+z springs are not. An upper
    arm x or z spring ALONE is fully braced by the rigid coupler rod (no motion at all); together
    they leave one combined mode. `pivot` (link frame, m) moves the hinges off the joint, e.g.
    towards the beam's pseudo-rigid-body point; the default is the root, the link's origin.

    Parameters cx, cy, cz in rad/(N*m), for the axes listed in `axes` only.
    """
    if not isinstance(link, str) or not link:
        raise ValueError(f"link_compliance: link must be a body name, got {link!r}")
    if not axes or any(a not in AXES for a in axes) or len(set(axes)) != len(axes):
        raise ValueError(f"link_compliance: axes must be a non-empty subset of 'xyz', got {axes!r}")
    axes = "".join(a for a in AXES if a in axes)

    def apply(spec, p, o):
        body = spec_body(spec, o["link"])
        if spec.body(o["link"] + BEAM_SUFFIX) is not None:
            raise ValueError(f"link_compliance on {o['link']} is already applied")
        beam = body.add_body(name=o["link"] + BEAM_SUFFIX)
        for a, c in zip(o["axes"], p):
            add_hinge(beam, _beam_hinge(o["link"], a), np.eye(3)[AXES.index(a)], c, o["pivot"])
        # the link's inertia goes to the beam; the hub keeps a small share at its origin
        m, ipos = float(body.mass), np.array(body.ipos, dtype=float)
        if m > 0:
            f = HUB_MASS_FRACTION
            beam.explicitinertial = True
            beam.mass = m * (1 - f)
            beam.ipos = ipos / (1 - f)
            beam.iquat = np.array(body.iquat)
            beam.inertia = np.array(body.inertia) * (1 - f)
            body.mass = m * f
            body.ipos = [0.0, 0.0, 0.0]
            body.inertia = np.array(body.inertia) * f
        moving = [b.name for b in child_bodies(body) if b.name != beam.name and _has_joint(b)]
        if moving:
            move_bodies(spec, moving, beam)

    pivot = tuple(float(x) for x in pivot)
    if len(pivot) != 3:
        raise ValueError(f"link_compliance: pivot must be a 3-vector, got {pivot!r}")
    options = {"link": link, "axes": axes, "pivot": pivot}
    return hinge_compliances(
        "link_compliance", axes, options, apply, lambda robot, o, a: _beam_hinge(o["link"], a)
    )


def _has_joint(body) -> bool:
    """Does the subtree carry a joint (i.e. is it the rest of the serial chain)?"""
    return bool(body.find_all(mujoco.mjtObj.mjOBJ_JOINT))
