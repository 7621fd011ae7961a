"""A balancer cylinder drawn as two mimic joints becomes a ``[compensators]`` spring (issue 21).

ROS-Industrial draws a heavy robot's gravity balancer as a cylinder hinged on the link before a
joint M and a piston hinged on the link after it, both ``<mimic>`` of M, both leaf links (the
ABB IRB 6640's ``joint_cylinder`` and ``joint_piston`` across ``joint_2``; the FANUC M-900iB's
left and right balancers). A cylinder and its piston slide in each other: they keep one
orientation for every angle of M, which is how they are recognised, from the URDF's numbers
alone. With their axes parallel to M's (signs s_f, s_t against M's axis, in the frame before M at
q = 0) and multipliers m_f (cylinder side) and m_t (piston side), the piston turns by
q + s_t m_t q and the cylinder by s_f m_f q, so they stay aligned when s_f m_f = 1 + s_t m_t
(the ABB: -0.25 = 1 - 1.25; the FANUC: 1.18 = 1 + 0.18). A sliding pair is no loop of hinges;
its statics are a spring along the line between the two pivots (paper eqs. 7-9): the two
joints and links go, and a compensator tendon ``balancer`` (``balancer_2``, ... for more) joins
the pivots, free length their distance at q = 0 and stiffness PLACEHOLDER_SPRING, both replaced
by the scenario's ``[truth.compensators.NAME]``. from-urdf names it in a note. Cylinders drawn on
the same two pivots (the FANUC's left and right ones, in its URDF) are one spring: the statics
see only their summed stiffness, and two parameters for it could not be identified apart.

Not converted here: mimic joints of any other pattern (a parallelogram's crank and rod turn
against each other: bench/robots/parallelogram.py makes them a loop), and a balancer across a joint that an overlay
``[compensators]`` table already spans (the overlay's own description wins).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, replace

import numpy as np

from .overlay import Attach, CompensatorSpec, Overlay

PLACEHOLDER_SPRING = 1e5  # N/m, a derived balancer's stiffness until a scenario's truth replaces it
ALIGNED = 1e-9


@dataclass(frozen=True)
class MimicJoint:
    name: str
    parent: str
    child: str
    xyz: np.ndarray
    rot: np.ndarray
    axis: np.ndarray
    multiplier: float
    master: str


def _vec(text: str | None, default=(0.0, 0.0, 0.0)) -> np.ndarray:
    return np.array([float(x) for x in text.split()]) if text else np.array(default, float)


def rpy_matrix(rpy: np.ndarray) -> np.ndarray:
    """URDF rpy: Rz(yaw) Ry(pitch) Rx(roll)."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    return rz @ ry @ rx


def mimic_joint(el: ET.Element) -> MimicJoint:
    o, a, m = el.find("origin"), el.find("axis"), el.find("mimic")
    axis = _vec(a.get("xyz") if a is not None else None, (1.0, 0.0, 0.0))
    return MimicJoint(
        el.get("name", ""),
        el.find("parent").get("link", "") if el.find("parent") is not None else "",
        el.find("child").get("link", "") if el.find("child") is not None else "",
        _vec(o.get("xyz") if o is not None else None),
        rpy_matrix(_vec(o.get("rpy") if o is not None else None)),
        axis / (np.linalg.norm(axis) or 1.0),
        float(m.get("multiplier", "1")) if m is not None else 1.0,
        m.get("joint", "") if m is not None else "",
    )


def _aligned(master: MimicJoint, f: MimicJoint, t: MimicJoint) -> bool:
    """The cylinder (on master's parent) and piston (on its child) keep one orientation."""
    a_m = master.rot @ master.axis
    s_f = float((f.rot @ f.axis) @ a_m)
    s_t = float((master.rot @ t.rot @ t.axis) @ a_m)
    if abs(abs(s_f) - 1) > ALIGNED or abs(abs(s_t) - 1) > ALIGNED:
        return False
    return abs(s_f * f.multiplier - (1.0 + s_t * t.multiplier)) < ALIGNED


def _same_pivots(c: CompensatorSpec, f: MimicJoint, t: MimicJoint) -> bool:
    """Two cylinders on the same two pivots are one spring to the statics (their stiffnesses add;
    apart they could not be told from each other)."""
    return (
        c.start.link == f.parent
        and c.end.link == t.parent
        and np.allclose(c.start.pos, f.xyz, rtol=0, atol=ALIGNED)
        and np.allclose(c.end.pos, t.xyz, rtol=0, atol=ALIGNED)
    )


def read_joints(text: str) -> tuple[ET.Element, dict[str, ET.Element], dict[str, MimicJoint]] | None:
    """The URDF's root, its joint elements and their numbers by name; None if it is no XML (the
    URDF reader reports that)."""
    try:
        root = ET.fromstring(text)
    except ET.ParseError:
        return None
    els = {el.get("name", ""): el for el in root.findall("joint")}
    return root, els, {n: mimic_joint(el) for n, el in els.items()}


def convert_balancers(text: str, ov: Overlay) -> tuple[str, Overlay, list[str]]:
    """The URDF text without its balancer cylinders, the overlay with a compensator for each, and
    a note per conversion (module docstring). Unchanged when there is none."""
    read = read_joints(text)
    if read is None:
        return text, ov, []
    root, els, joints = read
    parents = {j.parent for j in joints.values()}
    spanned = {frozenset((c.start.link, c.end.link)) for c in ov.compensators}
    found: list[tuple[MimicJoint, MimicJoint, MimicJoint]] = []
    for mname, master in joints.items():
        leaves = [j for j in joints.values() if els[j.name].find("mimic") is not None and j.master == mname]
        leaves = [j for j in leaves if j.child not in parents]
        froms = [j for j in leaves if j.parent == master.parent]
        tos = [j for j in leaves if j.parent == master.child]
        if not froms or len(froms) != len(tos) or frozenset((master.parent, master.child)) in spanned:
            continue
        pairs = list(zip(froms, tos))
        if all(_aligned(master, f, t) for f, t in pairs):
            found += [(master, f, t) for f, t in pairs]
    if not found:
        return text, ov, []
    names = [c.name for c in ov.compensators]
    derived: list[CompensatorSpec] = []
    notes: list[str] = []
    for master, f, t in found:
        for j in (f, t):
            root.remove(els[j.name])
            for link in root.findall("link"):
                if link.get("name") == j.child:
                    root.remove(link)
        twin = next((i for i, c in enumerate(derived) if _same_pivots(c, f, t)), None)
        if twin is not None:  # left and right cylinders on the same pivots: one spring
            notes[twin] += (
                f"; the cylinder {f.child}/{t.child} (mimic joints {f.name}, {t.name}) has the same pivots: "
                f"{derived[twin].name!r} stands for both (their stiffnesses summed, which is all the statics see)"
            )
            continue
        k = 1
        name = "balancer"
        while name in names:
            k += 1
            name = f"balancer_{k}"
        names.append(name)
        pivot_t = master.xyz + master.rot @ t.xyz  # in the frame of master's parent, at q = 0
        length = float(np.linalg.norm(pivot_t - f.xyz))
        key = f"(URDF mimic joints {f.name}, {t.name})"
        derived.append(
            CompensatorSpec(
                name,
                Attach(f"{name}_from", f.parent, tuple(float(x) for x in f.xyz), key),
                Attach(f"{name}_to", t.parent, tuple(float(x) for x in t.xyz), key),
                PLACEHOLDER_SPRING,
                length,
                key,
            )
        )
        notes.append(
            f"balancer cylinder {f.child}/{t.child} (mimic joints {f.name}, {t.name} of {master.name}) "
            f"became the compensator spring {name!r} between {f.parent} {np.round(f.xyz, 4).tolist()} and "
            f"{t.parent} {np.round(t.xyz, 4).tolist()}: free length {length:.4f} m, stiffness "
            f"{PLACEHOLDER_SPRING:g} N/m (placeholders: a scenario's [truth.compensators.{name}] replaces them)"
        )
    return (
        ET.tostring(root, encoding="unicode"),
        replace(ov, compensators=ov.compensators + tuple(derived)),
        notes,
    )


__all__ = ["PLACEHOLDER_SPRING", "convert_balancers"]
