"""A parallelogram drawn as two mimic joints becomes a closed loop (issue 21).

ROS-Industrial draws a quasi-serial arm (the FANUC M-900iB's active parallelogram, paper §3.4)
as a serial tree: the elbow M between the upper arm and the forearm is an ordinary joint, and
the parallelogram's two other bars hang from it as ``<mimic>`` joints of M: the crank A on the
upper arm (M's parent) turning so that it keeps the forearm's orientation, and the rod B on the
forearm (M's child) turning so that it keeps the upper arm's. With the signs s_A, s_B of their
axes against M's (in the frame before M, at q = 0) and multipliers m_A, m_B they are recognised
from the URDF's numbers alone: s_A m_A = 1 and s_B m_B = -1, all axes parallel, no offsets (the
FANUC: ``pjoint_1`` axis +y against joint_3's -y with multiplier -1; ``pjoint_2`` +y, +1).

That tree says where the bars are, not who drives what. On the robot, motor 3 sits on the turret
and drives the crank, coaxial with the joint G above the upper arm (J2); the elbow is passive
and the rod closes the loop. So the conversion rebuilds that mechanism, as mjcf/m900ib700.xml
declares it by hand:

* the crank's joint hangs from G's parent (its origin G's origin composed with A's, at q = 0),
  takes M's name, its limits and its axis direction, and is the one motor 3 drives: its angle
  is the forearm's angle against G's parent, q_M + s_G q_G in the URDF's angles (s_G: the sign of
  G's axis against M's; the FANUC's J3 counted from the horizontal, q3_urdf - q2);
* M becomes the passive elbow ``M_elbow``, unsprung, range +-360 deg;
* the rod hangs from the crank's free end C on B, now passive: C = B's pivot + d, with
  d = (A's pivot - M's pivot) less its part along the axes (a parallelogram: the crank is as long
  as B - M, the rod as A - M). The rod's frame moves to C, with the same axes; its inertial,
  geometry and any child joints move back by as much, so nothing moves in the world;
* a ``connect`` equality ``parallelogram`` joins the rod's other end to the forearm at B's
  drawn pivot, where the drawing is closed at q = 0. The loop moves in a plane normal to the
  axes, so the two points stay one for every angle.

The statics then hold the loop closed exactly (bench/model/loop.py) and the crank carries motor
3's spring (paper eq. 1 through the loop, §3.4). Refused with the reason: a crank whose pivot is
not on G's axis (the drive could not sit on G's parent). Not converted (and refused later as a
mimic): any other pattern, including a pattern with nonzero offsets.
"""

from __future__ import annotations

import copy
import math
import xml.etree.ElementTree as ET
from dataclasses import replace

import numpy as np

from calbench.bench.core import InputError

from .mimic import ALIGNED, MimicJoint, read_joints
from .overlay import Attach, LoopSpec, Overlay

ON_AXIS = 1e-6  # m: how far off G's axis a crank pivot may be and still count as coaxial


def _rpy_of(r: np.ndarray) -> tuple[float, float, float]:
    """URDF rpy (roll, pitch, yaw) of R = Rz(yaw) Ry(pitch) Rx(roll)."""
    pitch = math.asin(max(-1.0, min(1.0, -r[2, 0])))
    if abs(r[2, 0]) < 1 - 1e-12:
        return math.atan2(r[2, 1], r[2, 2]), pitch, math.atan2(r[1, 0], r[0, 0])
    return math.atan2(-r[1, 2], r[1, 1]), pitch, 0.0  # gimbal lock: yaw folded into roll


def _fmt(v) -> str:
    return " ".join(repr(float(x) + 0.0) for x in v)


def _sign(a: np.ndarray, b: np.ndarray) -> float:
    """+-1 when unit vectors a and b are parallel, else 0."""
    s = float(a @ b)
    return math.copysign(1.0, s) if abs(abs(s) - 1.0) <= ALIGNED else 0.0


def _offset(el: ET.Element) -> float:
    m = el.find("mimic")
    return float(m.get("offset", "0")) if m is not None else 0.0


def _pattern(master: MimicJoint, crank: MimicJoint, rod: MimicJoint, els) -> bool:
    """Crank keeps the forearm's orientation, rod the upper arm's, axes parallel, no offsets."""
    a_m = master.rot @ master.axis
    s_a = _sign(crank.rot @ crank.axis, a_m)
    s_b = _sign(master.rot @ rod.rot @ rod.axis, a_m)
    return (
        s_a != 0.0
        and s_b != 0.0
        and abs(s_a * crank.multiplier - 1.0) < ALIGNED
        and abs(s_b * rod.multiplier + 1.0) < ALIGNED
        and _offset(els[crank.name]) == 0.0
        and _offset(els[rod.name]) == 0.0
    )


def _move_frame(root: ET.Element, link: str, shift: np.ndarray) -> None:
    """Move a link's frame by ``shift`` (in its own axes): everything drawn in it, its inertial,
    geometry and child joints, moves back by as much, so nothing moves in the world."""
    for el in root.findall("link"):
        if el.get("name") != link:
            continue
        for part in (*el.findall("inertial"), *el.findall("visual"), *el.findall("collision")):
            origin = part.find("origin")
            if origin is None:
                origin = ET.SubElement(part, "origin")
            xyz = np.array([float(x) for x in origin.get("xyz", "0 0 0").split()])
            origin.set("xyz", _fmt(xyz - shift))
    for el in root.findall("joint"):
        parent = el.find("parent")
        if parent is not None and parent.get("link") == link:
            origin = el.find("origin")
            if origin is None:
                origin = ET.SubElement(el, "origin")
            xyz = np.array([float(x) for x in origin.get("xyz", "0 0 0").split()])
            origin.set("xyz", _fmt(xyz - shift))


def _unique(name: str, taken) -> str:
    out, k = name, 1
    while out in taken:
        k += 1
        out = f"{name}_{k}"
    return out


def convert_parallelograms(text: str, ov: Overlay, path) -> tuple[str, Overlay, list[str]]:
    """The URDF text with each parallelogram drawn as mimic joints rebuilt as a loop, the
    overlay with its ``[loops]`` entry, and a note per conversion (module docstring).
    Unchanged when there is none; InputError (naming ``path`` and the crank's joint) for a
    crank that cannot hang from the turret."""
    read = read_joints(text)
    if read is None:
        return text, ov, []
    root, els, joints = read
    by_child = {j.child: j for j in joints.values()}
    taken = set(els)
    loops, notes = list(ov.loops), []
    for mname, master in list(joints.items()):
        mimics = [j for j in joints.values() if els[j.name].find("mimic") is not None and j.master == mname]
        cranks = [j for j in mimics if j.parent == master.parent]
        rods = [j for j in mimics if j.parent == master.child]
        if len(cranks) != 1 or len(rods) != 1 or not _pattern(master, cranks[0], rods[0], els):
            continue
        crank, rod = cranks[0], rods[0]
        g = by_child.get(master.parent)
        a_m = master.rot @ master.axis
        if g is None or els[g.name].get("type") == "fixed" or _sign(g.axis, a_m) == 0.0:
            raise InputError(
                path,
                f"joint {crank.name!r}",
                f"a parallelogram crank whose link {master.parent} turns on a joint parallel to "
                f"{mname} (the crank's motor sits on the link before it)",
                "no such joint" if g is None else f"joint {g.name!r}",
            )
        off = crank.xyz - (crank.xyz @ g.axis) * g.axis
        if np.linalg.norm(off) > ON_AXIS:
            raise InputError(
                path,
                f"joint {crank.name!r}",
                f"a parallelogram crank pivot on the axis of {g.name} (coaxial, driven from {g.parent})",
                f"{np.linalg.norm(off):.4g} m off it",
            )
        on_rod = [a.key for a in ov.sites() if a.link == rod.child]
        if on_rod:
            raise InputError(
                ov.path,
                on_rod[0],
                f"a link other than the parallelogram's rod {rod.child} (from-urdf moves its frame "
                "to the crank's end)",
                rod.child,
            )
        if crank.name in ov.actuated:
            raise InputError(
                ov.path,
                "actuated",
                f"the motor joint {mname!r} (the parallelogram's crank {crank.child} takes that name: "
                f"it is what the motor drives)",
                crank.name,
            )
        s_a = _sign(crank.rot @ crank.axis, a_m)
        s_g = _sign(g.axis, a_m)
        elbow = _unique(f"{mname}_elbow", taken)
        taken.add(elbow)
        # the crank: from G's parent, coaxial with G, named and limited as M, counted along M's axis
        el_c, el_m, el_r = els[crank.name], els[mname], els[rod.name]
        el_c.find("parent").set("link", g.parent)
        origin = el_c.find("origin")
        if origin is None:
            origin = ET.SubElement(el_c, "origin")
        origin.set("xyz", _fmt(g.xyz + g.rot @ crank.xyz))
        origin.set("rpy", _fmt(_rpy_of(g.rot @ crank.rot)))
        axis = el_c.find("axis")
        if axis is None:
            axis = ET.SubElement(el_c, "axis")
        axis.set("xyz", _fmt(s_a * crank.axis))
        el_c.remove(el_c.find("mimic"))
        for lim in el_c.findall("limit"):
            el_c.remove(lim)
        if el_m.find("limit") is not None:
            el_c.append(copy.deepcopy(el_m.find("limit")))
        el_c.set("type", el_m.get("type", "revolute"))
        el_c.set("name", mname)
        el_m.set("name", elbow)
        el_m.set("type", "continuous")
        # the rod: hinged at the crank's free end C (its frame moved there, same axes), closing
        # on the forearm at its drawn pivot B
        d = crank.xyz - master.xyz
        d -= (d @ a_m) * a_m  # in the rod's plane (along the axes nothing moves)
        r_rod = master.rot @ rod.rot  # the rod's axes in M's parent frame, at q = 0
        shift = r_rod.T @ d  # C in the rod's frame as drawn
        p_c = master.xyz + master.rot @ rod.xyz + d
        el_r.remove(el_r.find("mimic"))
        el_r.set("type", "continuous")
        el_r.find("parent").set("link", crank.child)
        origin = el_r.find("origin")
        if origin is None:
            origin = ET.SubElement(el_r, "origin")
        origin.set("xyz", _fmt(crank.rot.T @ (p_c - crank.xyz)))
        origin.set("rpy", _fmt(_rpy_of(crank.rot.T @ r_rod)))
        _move_frame(root, rod.child, shift)
        name = _unique("parallelogram", {lp.name for lp in loops})
        key = f"(URDF mimic joints {crank.name}, {rod.name})"
        loops.append(
            LoopSpec(
                name,
                Attach(f"{name}_site1", rod.child, tuple(float(x) + 0.0 for x in -shift), key),
                Attach(f"{name}_site2", master.child, tuple(float(x) + 0.0 for x in rod.xyz), key),
                (elbow, rod.name),
                key,
            )
        )
        sign = "+" if s_g > 0 else "-"
        notes.append(
            f"parallelogram {crank.child}/{rod.child} (mimic joints {crank.name}, {rod.name} of {mname}) "
            f"became the loop {name!r}: the crank {crank.child} now turns on {g.parent} coaxial with {g.name}, "
            f"on the joint {mname} that its motor drives, whose angle is the URDF's {mname} {sign} {g.name} "
            f"(the angle of {master.child} against {g.parent}); the elbow is the passive joint {elbow!r} "
            f"(was {mname}); the rod {rod.child} hangs from the crank's end on the passive {rod.name} (its "
            f"frame moved there, by {np.round(shift, 4).tolist()} m in its axes) and a connect joins its "
            f"other end to {master.child} {np.round(rod.xyz, 4).tolist()}"
        )
    if not notes:
        return text, ov, []
    return ET.tostring(root, encoding="unicode"), replace(ov, loops=tuple(loops)), notes


__all__ = ["convert_parallelograms"]
