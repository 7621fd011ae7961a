"""The robot's drawable shapes read from its MJCF: one record per geom, in its body's frame.

Both viewers draw the robot from these (bench/view.py as Rerun archetypes, bench/foxglove.py
as Foxglove scene primitives), so the reading of MuJoCo's geom arrays lives here once.
MuJoCo conventions kept as they are: capsules and cylinders lie along the geom's z axis,
``size`` = [radius, half-length]; boxes and ellipsoids carry half sizes; quaternions are
w, x, y, z. Planes (the floor) are not drawn. Units: metres; colours RGBA in 0..1.
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
        size = {"box": s[:3], "capsule": s[:2], "cylinder": s[:2], "mesh": s[:3],
                "ellipsoid": s[:3] if typ == mujoco.mjtGeom.mjGEOM_ELLIPSOID else s[[0, 0, 0]]}[kind]
        matid = model.geom_matid[g]
        rgba = (model.mat_rgba[matid] if matid >= 0 else model.geom_rgba[g]).astype(float)
        verts = faces = None
        if kind == "mesh":
            m = int(model.geom_dataid[g])
            va, vn = model.mesh_vertadr[m], model.mesh_vertnum[m]
            fa, fn = model.mesh_faceadr[m], model.mesh_facenum[m]
            verts = model.mesh_vert[va:va + vn].astype(float)
            faces = model.mesh_face[fa:fa + fn].astype(np.uint32)
        out.append(GeomShape(g, int(model.geom_bodyid[g]), model.geom(g).name or f"geom{g}", kind,
                             size.copy(), model.geom_pos[g].astype(float),
                             model.geom_quat[g].astype(float), rgba, verts, faces))
    return out


def tendon_sites(model: mujoco.MjModel) -> list[tuple[str, list[int]]]:
    """(name, site ids) of every spatial tendon routed through two or more sites: drawn as a
    polyline between the sites (the compensator spring)."""
    out = []
    for t in range(model.ntendon):
        adr, num = model.tendon_adr[t], model.tendon_num[t]
        sites = [int(model.wrap_objid[a]) for a in range(adr, adr + num)
                 if model.wrap_type[a] == mujoco.mjtWrap.mjWRAP_SITE]
        if len(sites) >= 2:
            out.append((model.tendon(t).name or f"tendon{t}", sites))
    return out


__all__ = ["GeomShape", "geom_shapes", "tendon_sites"]
