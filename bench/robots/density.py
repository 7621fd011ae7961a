"""Masses estimated from a link's collision geometry at a stated density: ASSUMED (issue 21).

For a URDF without ``<inertial>`` elements (ROS-Industrial's ABB and FANUC support packages) a
first guess of each link's mass, centre of mass and inertia is its collision geometry filled
with a uniform material: the overlay's ``[inertials.LINK] density`` (kg/m^3) for one link, or
``assumed_density`` for every moving link that has neither an ``<inertial>`` nor an
``[inertials]`` table. A collision mesh is usually a convex hull, larger than the casting, and a
robot is not solid steel: the result is a guess, and it is marked ASSUMED wherever it shows (the
from-urdf notes, the MJCF's header and its ``calbench:assumed_masses``, check-robot).

Each ``<collision>`` shape, in the link frame through its ``<origin>``:

* a mesh (closed, outward faces): by the divergence theorem, summed over the tetrahedra
  (0, a, b, c) of its triangles, V = sum a.(b x c)/6, V c = sum V_t (a+b+c)/4, and the second
  moment S = sum V_t/20 (a a^T + b b^T + c c^T + (a+b+c)(a+b+c)^T); the inertia about the origin
  is rho (tr(S) 1 - S). A mesh whose edges are not each shared by two faces is not closed: its
  volume is named as approximate in the note;
* a box (x, y, z): V = xyz, I = m/12 diag(y^2+z^2, x^2+z^2, x^2+y^2); a cylinder (r, l along z):
  V = pi r^2 l, I = m diag((3r^2+l^2)/12, (3r^2+l^2)/12, r^2/2); a sphere (r): V = 4/3 pi r^3,
  I = 2/5 m r^2.

Parts are combined by the parallel-axis theorem; the ``<inertial>`` written into the link holds
the mass, the centre of mass and the full inertia about it, in the link's axes. Checked against
MuJoCo's own computation (``inertiafromgeom``, exact mesh inertia) in tests/test_density.py.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calbench.bench.core import InputError

from .mimic import rpy_matrix
from .overlay import Overlay

# (mesh file URI, scale) -> (vertices in the file's frame, metres; faces), or raises ValueError
MeshReader = Callable[[str, np.ndarray], tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class Estimate:
    """A link's mass properties from its geometry."""

    link: str
    density: float  # kg/m^3
    volume: float  # m^3
    mass: float  # kg
    com: np.ndarray  # (3,) m, link frame
    inertia: np.ndarray  # (3, 3) kg*m^2 about the centre of mass, link axes
    closed: bool  # every mesh closed (else the volume is approximate)


def mesh_moments(verts: np.ndarray, faces: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Volume V, first moment V c (3,) and second moment S (3, 3) = int x x^T dV of a closed
    triangle mesh (module docstring)."""
    a, b, c = (verts[faces[:, i]] for i in range(3))
    v = np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0
    s = a + b + c
    first = (v[:, None] * s).sum(axis=0) / 4.0
    outer = (
        np.einsum("ni,nj->nij", a, a)
        + np.einsum("ni,nj->nij", b, b)
        + np.einsum("ni,nj->nij", c, c)
        + np.einsum("ni,nj->nij", s, s)
    )
    second = (v[:, None, None] * outer).sum(axis=0) / 20.0
    return float(v.sum()), first, second


def is_closed(faces: np.ndarray) -> bool:
    """Every edge shared by exactly two faces."""
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    return bool(len(edges)) and set(Counter(map(tuple, edges)).values()) == {2}


def _primitive(geom: ET.Element) -> tuple[float, np.ndarray] | None:
    """(volume, inertia about the centre per unit mass) of a box, cylinder or sphere."""
    if geom.tag == "box":
        x, y, z = (float(t) for t in geom.get("size", "0 0 0").split())
        return x * y * z, np.diag([y * y + z * z, x * x + z * z, x * x + y * y]) / 12.0
    if geom.tag == "cylinder":
        r, h = float(geom.get("radius", "0")), float(geom.get("length", "0"))
        side = (3 * r * r + h * h) / 12.0
        return math.pi * r * r * h, np.diag([side, side, r * r / 2.0])
    if geom.tag == "sphere":
        r = float(geom.get("radius", "0"))
        return 4.0 / 3.0 * math.pi * r**3, np.eye(3) * 0.4 * r * r
    return None


def _vec(text: str | None, n: int = 3) -> np.ndarray:
    return np.array([float(x) for x in text.split()]) if text else np.zeros(n)


def link_estimate(link: ET.Element, density: float, read_mesh: MeshReader) -> Estimate | None:
    """The link's mass properties from its ``<collision>`` shapes at ``density``; None when it
    has none. ValueError (from ``read_mesh``) for a mesh that cannot be read."""
    mass, first, second, closed, parts = 0.0, np.zeros(3), np.zeros((3, 3)), True, 0
    for col in link.findall("collision"):
        origin, geometry = col.find("origin"), col.find("geometry")
        if geometry is None or len(geometry) == 0:
            continue
        rot = rpy_matrix(_vec(origin.get("rpy") if origin is not None else None))
        pos = _vec(origin.get("xyz") if origin is not None else None)
        shape = geometry[0]
        if shape.tag == "mesh":
            scale = _vec(shape.get("scale"), 3) if shape.get("scale") else np.ones(3)
            verts, faces = read_mesh(shape.get("filename", ""), scale)
            vol, fm, sm = mesh_moments(verts @ rot.T + pos, faces)
            closed &= is_closed(faces)
        else:
            prim = _primitive(shape)
            if prim is None:
                continue
            vol, unit = prim
            fm = vol * pos
            # second moment about the link origin: rotated inertia -> second moment, then shifted
            inertia_c = rot @ unit @ rot.T * vol
            sm = 0.5 * np.trace(inertia_c) * np.eye(3) - inertia_c + vol * np.outer(pos, pos)
        mass += density * vol
        first += density * fm
        second += density * sm
        parts += 1
    if parts == 0 or mass <= 0:
        return None
    com = first / mass
    about_origin = np.trace(second) * np.eye(3) - second
    inertia = about_origin - mass * (com @ com * np.eye(3) - np.outer(com, com))
    return Estimate(link.get("name", ""), density, mass / density, mass, com, inertia, closed)


def _inertial(e: Estimate) -> ET.Element:
    el = ET.Element("inertial")
    ET.SubElement(el, "origin", xyz=" ".join(repr(float(x)) for x in e.com), rpy="0 0 0")
    ET.SubElement(el, "mass", value=repr(float(e.mass)))
    i = e.inertia
    values = (i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2])
    ET.SubElement(
        el, "inertia", {k: repr(float(v)) for k, v in zip(("ixx", "iyy", "izz", "ixy", "ixz", "iyz"), values)}
    )
    return el


def _moving(root: ET.Element) -> set[str]:
    """Links below a non-fixed joint."""
    parent = {j.find("child").get("link"): j for j in root.findall("joint") if j.find("child") is not None}
    out = set()
    for link in root.findall("link"):
        name, seen = link.get("name", ""), set()
        cur = name
        while cur in parent and cur not in seen:
            seen.add(cur)
            j = parent[cur]
            if j.get("type") != "fixed":
                out.add(name)
                break
            cur = j.find("parent").get("link", "") if j.find("parent") is not None else ""
    return out


def estimate_inertials(
    text: str, path: Path, ov: Overlay, read_mesh: MeshReader
) -> tuple[str, tuple[Estimate, ...], list[str]]:
    """The URDF text with an ``<inertial>`` for every link the overlay asks to estimate (module
    docstring), the estimates and a note for each. Unchanged without such a request."""
    asked = {i.link: (i.density, i.key) for i in ov.inertials if i.density is not None}
    if not asked and ov.assumed_density is None:
        return text, (), []
    root = ET.fromstring(text)
    given = {i.link for i in ov.inertials if i.density is None}
    if ov.assumed_density is not None:
        for link in root.findall("link"):
            name = link.get("name", "")
            if (
                name in _moving(root)
                and name not in given
                and name not in asked
                and link.find("inertial") is None
            ):
                if link.find("collision") is not None:
                    asked[name] = (ov.assumed_density, "assumed_density")
    out, notes = [], []
    for link in root.findall("link"):
        name = link.get("name", "")
        if name not in asked:
            continue
        density, key = asked[name]
        try:
            est = link_estimate(link, density, read_mesh)
        except ValueError as exc:
            raise InputError(
                ov.path, key, f"collision geometry of {name} that can be read", str(exc)
            ) from None
        if est is None:
            raise InputError(
                ov.path, key, f"a link with collision geometry to fill at {density:g} kg/m^3", f"{name}: none"
            )
        for old in link.findall("inertial"):
            link.remove(old)
        link.append(_inertial(est))
        out.append(est)
        notes.append(
            f"{name}: mass {est.mass:.1f} kg ASSUMED: its collision geometry ({est.volume:.4g} m^3"
            + ("" if est.closed else ", a mesh not closed: approximate")
            + f") at {density:g} kg/m^3, centre of mass {np.round(est.com, 3).tolist()} m"
        )
    return ET.tostring(root, encoding="unicode"), tuple(out), notes


__all__ = ["Estimate", "MeshReader", "estimate_inertials", "is_closed", "link_estimate", "mesh_moments"]
