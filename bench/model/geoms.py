"""The robot's drawable shapes read from its MJCF: one record per geom, in its body's frame.

Both viewers draw the robot from these (bench/view/recording.py as Rerun archetypes, bench/log/foxglove.py
as Foxglove scene primitives), so the reading of MuJoCo's geom arrays lives here once.
MuJoCo conventions kept as they are: capsules and cylinders lie along the geom's z axis,
``size`` = [radius, half-length]; boxes and ellipsoids carry half sizes; quaternions are
w, x, y, z. Planes (the floor) are not drawn. Units: metres; colours RGBA in 0..1.

The MJCF gives the reflectors as sites only (a site has no drawn shape), so
:func:`reflector_posts` adds what a person expects to see: a post from the nearest surface of
the reflector's body to the reflector.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

KINDS = {
    mujoco.mjtGeom.mjGEOM_BOX: "box",
    mujoco.mjtGeom.mjGEOM_CAPSULE: "capsule",
    mujoco.mjtGeom.mjGEOM_CYLINDER: "cylinder",
    mujoco.mjtGeom.mjGEOM_SPHERE: "ellipsoid",
    mujoco.mjtGeom.mjGEOM_ELLIPSOID: "ellipsoid",
    mujoco.mjtGeom.mjGEOM_MESH: "mesh",
}


@dataclass(frozen=True)
class GeomShape:
    """One drawable geom. ``size``: box and ellipsoid half sizes (3,) (a sphere as three equal
    radii); capsule and cylinder [radius, half-length]. ``pos``/``quat`` (wxyz) place it in
    its body's frame. Meshes carry ``vertices`` (k, 3) in the geom frame and ``faces`` (f, 3)."""

    geom: int
    body: int
    name: str
    kind: str
    size: np.ndarray
    pos: np.ndarray
    quat: np.ndarray
    rgba: np.ndarray
    vertices: np.ndarray | None = None
    faces: np.ndarray | None = None


def geom_shapes(model: mujoco.MjModel) -> list[GeomShape]:
    """Every drawable geom of ``model`` (planes and geoms of unknown type left out)."""
    out = []
    for g in range(model.ngeom):
        typ = int(model.geom_type[g])
        kind = KINDS.get(typ)
        if kind is None or (kind == "mesh" and model.geom_dataid[g] < 0):
            continue
        s = model.geom_size[g].astype(float)
        size = {
            "box": s[:3],
            "capsule": s[:2],
            "cylinder": s[:2],
            "mesh": s[:3],
            "ellipsoid": s[:3] if typ == mujoco.mjtGeom.mjGEOM_ELLIPSOID else s[[0, 0, 0]],
        }[kind]
        matid = model.geom_matid[g]
        rgba = (model.mat_rgba[matid] if matid >= 0 else model.geom_rgba[g]).astype(float)
        verts = faces = None
        if kind == "mesh":
            m = int(model.geom_dataid[g])
            va, vn = model.mesh_vertadr[m], model.mesh_vertnum[m]
            fa, fn = model.mesh_faceadr[m], model.mesh_facenum[m]
            verts = model.mesh_vert[va : va + vn].astype(float)
            faces = model.mesh_face[fa : fa + fn].astype(np.uint32)
        out.append(
            GeomShape(
                g,
                int(model.geom_bodyid[g]),
                model.geom(g).name or f"geom{g}",
                kind,
                size.copy(),
                model.geom_pos[g].astype(float),
                model.geom_quat[g].astype(float),
                rgba,
                verts,
                faces,
            )
        )
    return out


@dataclass(frozen=True)
class ReflectorPost:
    """A post holding reflector ``name`` (MJCF site ``site``) on body ``body``: a straight rod
    from ``start`` (on the surface of the body's nearest geom) to ``end`` (the site), both in
    the body's frame."""

    site: int
    body: int
    name: str
    start: np.ndarray
    end: np.ndarray


def _nearest_on_geom(shape: GeomShape, p: np.ndarray) -> np.ndarray:
    """The point of ``shape``'s surface (or inside it) nearest to ``p``, both in the body frame.
    Exact for boxes, capsules and spheres; cylinders are taken as capsules, ellipsoids as
    spheres of their largest half size, meshes by their nearest vertex (close enough to anchor a
    post)."""
    R = np.empty(9)
    mujoco.mju_quat2Mat(R, shape.quat)
    R = R.reshape(3, 3)
    local = R.T @ (p - shape.pos)
    if shape.kind == "box":
        near = np.clip(local, -shape.size, shape.size)
    elif shape.kind in ("capsule", "cylinder"):
        r, h = shape.size
        axis = np.array([0.0, 0.0, np.clip(local[2], -h, h)])
        off = local - axis
        n = np.linalg.norm(off)
        near = axis + (off * min(1.0, r / n) if n > 0 else 0.0)
    elif shape.kind == "mesh":
        near = shape.vertices[np.argmin(np.linalg.norm(shape.vertices - local, axis=1))]
    else:  # ellipsoid, sphere
        n = np.linalg.norm(local)
        near = local * min(1.0, float(np.max(shape.size)) / n) if n > 0 else local
    return shape.pos + R @ near


def reflector_posts(model: mujoco.MjModel, shapes: list[GeomShape], sites: list[int]) -> list[ReflectorPost]:
    """A post for each reflector site, from the nearest drawn geom of its body (``shapes`` as
    :func:`geom_shapes` returns them); a body without geoms gets a post from its origin."""
    out = []
    for s in sites:
        body = int(model.site_bodyid[s])
        end = model.site_pos[s].astype(float)
        mine = [g for g in shapes if g.body == body]
        cands = [_nearest_on_geom(g, end) for g in mine] or [np.zeros(3)]
        start = min(cands, key=lambda c: float(np.linalg.norm(c - end)))
        out.append(ReflectorPost(int(s), body, model.site(s).name or f"site{s}", start, end))
    return out


def tendon_sites(model: mujoco.MjModel) -> list[tuple[str, list[int]]]:
    """(name, site ids) of every spatial tendon routed through two or more sites: drawn as a
    polyline between the sites (the compensator spring)."""
    out = []
    for t in range(model.ntendon):
        adr, num = model.tendon_adr[t], model.tendon_num[t]
        sites = [
            int(model.wrap_objid[a])
            for a in range(adr, adr + num)
            if model.wrap_type[a] == mujoco.mjtWrap.mjWRAP_SITE
        ]
        if len(sites) >= 2:
            out.append((model.tendon(t).name or f"tendon{t}", sites))
    return out


__all__ = ["GeomShape", "geom_shapes", "ReflectorPost", "reflector_posts", "tendon_sites"]
