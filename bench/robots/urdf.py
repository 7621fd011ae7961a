"""A calbench MJCF from a URDF and an overlay (``calbench from-urdf``), built with MjSpec.

MuJoCo compiles URDF itself (``MjSpec.from_file``): every link becomes a body, every joint a
MuJoCo joint (revolute and continuous: hinge; prismatic: slide; fixed: none), ``<inertial>`` the
body's mass, centre of mass and inertia, ``<limit lower upper>`` the joint range, ``effort`` its
``actuatorfrcrange`` and ``<dynamics>`` its damping and frictionloss; ``<mimic>`` becomes a
joint equality. Its URDF defaults differ from MJCF's (docs: modeling.rst, "URDF extensions";
XMLreference.rst, ``compiler``): ``fusestatic`` (fixed links merge into their parent and lose
their names), ``discardvisual`` (only ``<collision>`` geometry is kept) and
``inertiafromgeom="auto"``, under which a body without ``<inertial>`` gets the mass of its geoms
at 1000 kg/m^3 (a link holding a 0.25 x 0.2 x 0.2 m box comes out at 10 kg, tests/test_urdf.py)
or, without geoms, zero (then the compile fails for a moving leaf body). This module changes
what calbench needs:

* **Masses** come from the URDF's ``<inertial>`` elements only (``inertiafromgeom="false"``).
  A link that moves (below a non-fixed joint) and has no ``<inertial>`` is an error naming it,
  never a guess; the one exception is a pure frame (no geometry, fixed to its parent, such as
  ROS-Industrial's ``flange`` and ``tool0``), which has no mass by nature.
* **Every link keeps its body** (``fusestatic="false"``), so the overlay can name any link.
* **Geometry** is what MuJoCo keeps of a URDF: its ``<collision>`` shapes (the robot's envelope,
  which is what should hide a reflector from the tracker), plus the ``<visual>`` shapes when the
  URDF's own ``<mujoco><compiler discardvisual="false"/></mujoco>`` asks for them. No geom takes
  part in contacts (calbench's statics have none). Primitives are kept as they are. A mesh found
  on disk (STL, OBJ or MSH) is written into the MJCF (vertices to 1 µm), so the MJCF, and the
  campaign log that carries it, need no mesh folder; a mesh that cannot be found or read is
  left out with a warning naming the link and the file: the statics need no geometry, but that
  link then neither hides reflectors nor is drawn. ``package://PKG/...`` resolves through the
  overlay's ``[packages]``, else a folder named PKG above the URDF.
* **Joints**: the overlay's ``actuated`` hinges carry the VJM springs (paper eq. 1) with a
  placeholder stiffness (:data:`PLACEHOLDER_STIFFNESS`; a scenario's truth replaces it and
  identification never reads it; ``springref`` is set to the command per pose). Every other
  moving joint must be a loop's passive joint (no spring): an extra free joint would leave the
  statics without an equilibrium. Continuous joints get the range +-360 deg.
* **Sites, springs, loops** from the overlay (bench/robots/overlay.py), and the ``calbench:*``
  description texts (bench/model/description.py), the optional hints (wrist, links, counterweights,
  a compensator's mounts for discovery) included.

The result is checked as calbench will use it: compiled, read as a :class:`~bench.robot.Robot`
(description, loop closure at the zero pose, each compensator across one actuated hinge), and
each loop's unsprung joints between its two sites must be exactly the overlay's ``passive``.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from calbench.bench.core import CalbenchError, InputError, parse_xml
from calbench.bench.model import Robot, set_spec_names
from calbench.bench.scenario import check_length, robot_scale

from .density import Estimate, MeshReader, estimate_inertials
from .expand import urdf_text
from .importer import Conversion, RobotImporter
from .mimic import convert_balancers
from .overlay import Attach, Overlay
from .parallelogram import convert_parallelograms

PLACEHOLDER_STIFFNESS = 1.0e6  # N*m/rad on every actuated hinge until a scenario sets it
CONTINUOUS_RANGE = (-2 * math.pi, 2 * math.pi)
MESH_DIGITS = 6  # inlined mesh vertices to 1 um
MOVING_TYPES = ("revolute", "continuous", "prismatic")
_NO_INFER = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_FALSE


@dataclass(frozen=True)
class UrdfLink:
    name: str
    inertial: bool
    geometry: bool


@dataclass(frozen=True)
class UrdfJoint:
    name: str
    type: str
    parent: str
    child: str
    mimic: str | None = None


@dataclass(frozen=True)
class UrdfTree:
    """The structure of a URDF as calbench checks it (read with ElementTree, independently of
    MuJoCo's parser): links with whether they carry an ``<inertial>`` and any geometry, joints
    with their type, parent and child."""

    path: Path
    name: str
    links: dict[str, UrdfLink]
    joints: dict[str, UrdfJoint]
    xml: str = ""  # the text converted (a .xacro's expansion, the overlay's inertials in)
    expanded: bool = False  # from a .xacro

    def moving_links(self) -> set[str]:
        """Links below at least one non-fixed joint (they move with some joint)."""
        return {
            link
            for link in self.links
            if any(j is not None and self.joints[j].type != "fixed" for _, j in self._up(link))
        }

    def fixed_to_parent(self, link: str) -> bool:
        return any(j.child == link and j.type == "fixed" for j in self.joints.values())

    def _up(self, link: str) -> list[tuple[str, str | None]]:
        """(link, the joint above it) from ``link`` up to its root."""
        by_child = {j.child: j for j in self.joints.values()}
        out: list[tuple[str, str | None]] = []
        while True:
            j = by_child.get(link)
            out.append((link, j.name if j else None))
            if j is None or any(link == seen for seen, _ in out[:-1]):
                return out
            link = j.parent

    def joints_between(self, a: str, b: str) -> list[str]:
        """The moving joints whose motion changes the relative pose of links a and b: those
        from each up to their common ancestor."""
        up_a, up_b = self._up(a), self._up(b)
        links_b = [n for n, _ in up_b]
        common = next((n for n, _ in up_a if n in links_b), None)
        out = []
        for up in (up_a, up_b):
            for link, joint in up:
                if link == common:
                    break
                if joint is not None and self.joints[joint].type != "fixed":
                    out.append(joint)
        return out


# --------------------------------------------------------------------------- the URDF


def read_urdf(path: str | Path, ov: Overlay | None = None, text: tuple[str, bool] | None = None) -> UrdfTree:
    """The URDF's links and joints; InputError when it is not a URDF. A ``.xacro`` is expanded,
    the overlay's inertials written in, geom names made unique (bench/robots/expand.py); ``text``:
    that (text, from xacro) already made."""
    path = Path(path)
    text, expanded = urdf_text(path, ov) if text is None else text
    try:
        root = parse_xml(path, path, text=text)  # defusedxml: no entity bombs, no external entities
    except InputError as exc:
        raise InputError(path, "(file)", "a readable URDF (XML)", exc.got) from None
    if root.tag != "robot":
        raise InputError(path, "(root element)", "<robot>", f"<{root.tag}>")
    links = {}
    for el in root.findall("link"):
        name = el.get("name", "")
        links[name] = UrdfLink(
            name,
            el.find("inertial") is not None,
            el.find("visual") is not None or el.find("collision") is not None,
        )
    joints = {}
    for el in root.findall("joint"):
        name = el.get("name", "")
        parent, child, mimic = el.find("parent"), el.find("child"), el.find("mimic")
        joints[name] = UrdfJoint(
            name,
            el.get("type", ""),
            parent.get("link", "") if parent is not None else "",
            child.get("link", "") if child is not None else "",
            mimic.get("joint") if mimic is not None else None,
        )
    return UrdfTree(path, root.get("name", path.stem), links, joints, text, expanded)


def check_urdf(tree: UrdfTree) -> None:
    """What calbench cannot take from a URDF: couplings it would ignore, joints it cannot hold,
    moving links without a mass. InputError naming the elements."""
    for j in tree.joints.values():
        if j.mimic is not None:
            raise InputError(
                tree.path,
                f"joint {j.name!r}",
                "no <mimic> (the statics would ignore the coupling; from-urdf converts a balancer "
                "cylinder, two mimic joints that stay collinear across one joint, into a spring, and "
                "a parallelogram, a crank keeping the forearm's orientation and a rod keeping the "
                "upper arm's, into a loop; describe any other coupling as [loops] in the overlay, "
                "or remove it)",
                f"a mimic of {j.mimic!r}",
            )
        if j.type not in MOVING_TYPES + ("fixed",):
            raise InputError(
                tree.path,
                f"joint {j.name!r}",
                "a revolute, continuous, prismatic or fixed joint (calbench's robots stand on the floor)",
                j.type,
            )
    moving = tree.moving_links()
    missing = [
        n
        for n, link in tree.links.items()
        if n in moving and not link.inertial and (link.geometry or not tree.fixed_to_parent(n))
    ]
    if missing:
        raise InputError(
            tree.path,
            ("link " if len(missing) == 1 else "links ") + ", ".join(map(repr, missing)),
            "an <inertial> on every moving link, or its mass in the overlay: [inertials.LINK] "
            "mass = kg, com, inertia (measured or from the maker), or assumed_density = kg/m^3 "
            "(a guess from the meshes, marked assumed: docs/your-robot.md)",
            "none",
        )


def _moving_joints(tree: UrdfTree) -> list[str]:
    return [j.name for j in tree.joints.values() if j.type != "fixed"]


def check_overlay(tree: UrdfTree, ov: Overlay) -> None:
    """The overlay's names against the URDF: links exist, actuated joints are revolute or
    continuous, passive joints move, every moving joint is one or the other."""
    joints = tree.joints
    named = [(f"{a.key}.link", a.link) for a in ov.sites()] + ov.named_links()
    for key, link in named:
        if link not in tree.links:
            raise InputError(
                ov.path, key, f"a link of {tree.path.name} (" + ", ".join(tree.links) + ")", link
            )
    for i, name in enumerate(ov.actuated):
        j = joints.get(name)
        if j is None or j.type not in ("revolute", "continuous"):
            raise InputError(
                ov.path,
                f"actuated[{i}]",
                f"a revolute or continuous joint of {tree.path.name} "
                "(the VJM springs are torsional): "
                + ", ".join(n for n, jj in joints.items() if jj.type in ("revolute", "continuous")),
                name if j is None else f"{name} ({j.type})",
            )
    for c in ov.conventions:
        if c.joint not in ov.actuated:
            raise InputError(
                ov.path,
                c.key,
                "an actuated joint (the controller counts only those): " + ", ".join(ov.actuated),
                c.joint,
            )
    passive: set[str] = set()
    for lp in ov.loops:
        for i, name in enumerate(lp.passive):
            j = joints.get(name)
            if j is None or j.type == "fixed" or name in ov.actuated:
                why = (
                    "no such joint"
                    if j is None
                    else "a fixed joint"
                    if j.type == "fixed"
                    else "an actuated joint"
                )
                raise InputError(
                    ov.path,
                    f"{lp.key}.passive[{i}]",
                    f"a moving, not actuated joint of {tree.path.name}",
                    f"{name} ({why})",
                )
            passive.add(name)
        # the statics take a loop's passive joints to be its unsprung joints (bench/model/robot.py)
        unsprung = [n for n in tree.joints_between(lp.site1.link, lp.site2.link) if n not in ov.actuated]
        if sorted(unsprung) != sorted(lp.passive):
            raise InputError(
                ov.path,
                f"{lp.key}.passive",
                f"the joints between {lp.site1.link} and "
                f"{lp.site2.link} that are not actuated: {sorted(unsprung)}",
                list(lp.passive),
            )
    free = [n for n in _moving_joints(tree) if n not in ov.actuated and n not in passive]
    if free:
        raise InputError(
            ov.path,
            "actuated",
            f"every moving joint of {tree.path.name} actuated or a loop's "
            "passive joint (a free joint has no static equilibrium)",
            "not listed: " + ", ".join(free),
        )


# --------------------------------------------------------------------------- meshes


def _mesh_file(file: str, urdf: Path, meshdir: str, ov: Overlay) -> tuple[Path | None, str]:
    """Where a URDF mesh URI points on disk, or (None, why not)."""
    if file.startswith("package://"):
        pkg, _, rest = file[len("package://") :].partition("/")
        if pkg in ov.packages:
            return ov.packages[pkg] / rest, ""
        for folder in urdf.resolve().parents:
            if folder.name == pkg:
                return folder / rest, ""
        return None, f"no [packages] {pkg} in the overlay and no folder named {pkg!r} above the URDF"
    if file.startswith("file://"):
        file = file[len("file://") :]
    p = Path(file)
    return (p if p.is_absolute() else urdf.parent / meshdir / p), ""


def _mesh_reader(urdf: Path, text: str, ov: Overlay) -> MeshReader:
    """Meshes as from-urdf finds them (for the density estimates: bench/robots/density.py)."""
    try:
        compiler = ET.fromstring(text).find("mujoco/compiler")
    except ET.ParseError:
        compiler = None
    meshdir = compiler.get("meshdir", "") if compiler is not None else ""

    def read(file: str, scale) -> tuple[np.ndarray, np.ndarray]:
        path, why = _mesh_file(file, urdf, meshdir, ov)
        if path is None:
            raise ValueError(f"mesh {file}: {why}")
        try:
            return _load_mesh(path, scale)
        except ValueError as exc:
            raise ValueError(f"mesh {path}: " + str(exc).replace("\n", " ").removeprefix("Error: ")) from None

    return read


def _load_mesh(path: Path, scale) -> tuple[np.ndarray, np.ndarray]:
    """The mesh's vertices (scaled, in its own file frame, metres) and faces, read by MuJoCo."""
    t = mujoco.MjSpec()
    t.compiler.inertiafromgeom = _NO_INFER
    t.add_mesh(name="m", file=str(path), scale=list(scale))
    t.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_MESH, meshname="m")
    m = t.compile()
    va, vn = int(m.mesh_vertadr[0]), int(m.mesh_vertnum[0])
    fa, fn = int(m.mesh_faceadr[0]), int(m.mesh_facenum[0])
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, m.mesh_quat[0])
    # MuJoCo centres a compiled mesh on its inertial frame (mesh_pos, mesh_quat): undo it
    verts = m.mesh_pos[0] + m.mesh_vert[va : va + vn].astype(float) @ rot.reshape(3, 3).T
    return np.round(verts, MESH_DIGITS) + 0.0, m.mesh_face[fa : fa + fn].copy()


def _inline_meshes(spec: mujoco.MjSpec, tree: UrdfTree, ov: Overlay) -> list[str]:
    """Write every readable mesh into the spec; drop the geoms of the others. Warnings."""
    warnings = []
    users: dict[str, list] = {}
    for g in spec.geoms:
        if g.type == mujoco.mjtGeom.mjGEOM_MESH:
            users.setdefault(g.meshname, []).append(g)
    for mesh in list(spec.meshes):
        path, why = _mesh_file(mesh.file, tree.path, spec.meshdir, ov)
        if path is not None:
            try:
                verts, faces = _load_mesh(path, mesh.scale)
            except ValueError as exc:
                why = f"{path}: " + str(exc).replace("\n", " ").removeprefix("Error: ")
            else:
                mesh.file = ""
                mesh.scale = [1.0, 1.0, 1.0]
                mesh.uservert = verts.ravel()
                mesh.userface = faces.ravel()
                continue
        geoms = users.get(mesh.name, [])
        links = sorted({g.parent.name for g in geoms})
        warnings.append(
            f"{', '.join(links) or 'no link'}: mesh {mesh.file} left out ({why}); "
            "that geometry neither hides reflectors nor is drawn"
        )
        for g in geoms:
            spec.delete(g)
        spec.delete(mesh)
    return warnings


# --------------------------------------------------------------------------- the MJCF


def _site(spec: mujoco.MjSpec, a: Attach, rgba) -> None:
    spec.body(a.link).add_site(name=a.name, pos=list(a.pos), size=[0.02, 0.02, 0.02], rgba=rgba)


def _joints(spec: mujoco.MjSpec, tree: UrdfTree, ov: Overlay) -> None:
    conv = {c.joint: c for c in ov.conventions}
    for j in spec.joints:
        if tree.joints[j.name].type == "continuous":
            j.range = list(CONTINUOUS_RANGE)
            j.limited = mujoco.mjtLimited.mjLIMITED_TRUE
        if j.name in conv:  # the controller's angle: q = sign * q_urdf + zero
            c = conv[j.name]
            j.axis = [c.sign * float(a) for a in j.axis]
            j.ref = c.zero
            j.range = sorted(c.sign * float(r) + c.zero for r in j.range)
        j.stiffness = [PLACEHOLDER_STIFFNESS if j.name in ov.actuated else 0.0, 0.0, 0.0]  # linear (eq. 1)
        j.springref = 0.0


def _additions(spec: mujoco.MjSpec, ov: Overlay) -> None:
    """Sites, compensator tendons, loop equalities and the description texts."""
    _site(spec, ov.payload, [1.0, 0.5, 0.0, 1.0])
    if ov.flange:
        _site(spec, ov.flange, [0.0, 1.0, 0.0, 1.0])
    for r in ov.reflectors:
        _site(spec, r, [1.0, 0.0, 0.0, 1.0])
    for c in ov.compensators:
        _site(spec, c.start, [0.1, 0.6, 0.9, 1.0])
        _site(spec, c.end, [0.1, 0.6, 0.9, 1.0])
        t = spec.add_tendon(
            name=c.name,
            stiffness=c.stiffness,
            springlength=[c.preload, c.preload],
            width=0.02,
            rgba=[0.1, 0.6, 0.9, 1.0],
        )
        t.wrap_site(c.start.name)
        t.wrap_site(c.end.name)
    for lp in ov.loops:
        _site(spec, lp.site1, [0.3, 0.3, 0.3, 1.0])
        _site(spec, lp.site2, [0.3, 0.3, 0.3, 1.0])
        spec.add_equality(
            name=lp.name,
            type=mujoco.mjtEq.mjEQ_CONNECT,
            objtype=mujoco.mjtObj.mjOBJ_SITE,
            name1=lp.site1.name,
            name2=lp.site2.name,
        )
    for mount in ov.mounts:
        _site(spec, mount, [0.1, 0.6, 0.9, 1.0])
    set_spec_names(spec, "actuated", ov.actuated)
    set_spec_names(spec, "loops", [lp.name for lp in ov.loops])
    set_spec_names(spec, "compensators", [c.name for c in ov.compensators])
    set_spec_names(spec, "reflectors", [r.name for r in ov.reflectors])
    set_spec_names(spec, "payload", [ov.payload.name])
    if ov.flange:
        set_spec_names(spec, "flange", [ov.flange.name])
    set_spec_names(spec, "wrist", [ov.wrist] if ov.wrist else [])
    set_spec_names(spec, "links", ov.links)
    set_spec_names(spec, "mass_compensators", ov.mass_compensators)
    set_spec_names(spec, "compensator_sites", ov.compensator_sites or [])


def _check_built(model: mujoco.MjModel, ov: Overlay) -> Robot:
    """The model as calbench reads it; InputError naming the overlay key that does not fit."""
    try:
        robot = Robot(model, source=ov.path)
    except CalbenchError as exc:  # a loop that does not close
        d = mujoco.MjData(model)
        mujoco.mj_kinematics(model, d)
        gaps = [
            float(np.linalg.norm(d.site(lp.site1.name).xpos - d.site(lp.site2.name).xpos)) for lp in ov.loops
        ]
        worst = ov.loops[int(np.argmax(gaps))]
        raise InputError(
            ov.path,
            worst.key,
            "sites that the passive joints can bring together",
            f"{exc}; "
            f"{worst.site1.name} and {worst.site2.name} are {max(gaps):.4g} m apart at the "
            "URDF's zero pose",
        ) from None
    except ValueError as exc:  # DescriptionError and anything MuJoCo refuses
        raise InputError(
            ov.path, "(robot description)", "a description calbench can read", str(exc)
        ) from None
    for i, c in enumerate(ov.compensators):
        try:
            robot.compensator_joint(i)
        except ValueError as exc:
            raise InputError(
                ov.path,
                c.key,
                "attachments on two links with one actuated hinge between them (paper Fig. 4)",
                str(exc),
            ) from None
    return robot


def header_comment(tree: UrdfTree, ov: Overlay, estimated: tuple[Estimate, ...] = ()) -> str:
    """The MJCF's header: how it was made, where masses come from. Well-formed XML: no ``--``
    inside a comment (ElementTree and lxml refuse one; MuJoCo does not mind)."""
    source = f"{tree.path.name} (expanded by xacro)" if tree.expanded else tree.path.name
    assumed = [i.link for i in ov.inertials if i.density is None]
    masses = "the URDF's <inertial> elements"
    if assumed:
        masses += (
            f"; ASSUMED in the overlay's [inertials] for {', '.join(assumed)} (mass and centre of mass; "
            "an inertia not given is mass * (0.1 m)^2, which the statics never use)"
        )
    if estimated:
        masses += (
            "; ASSUMED, estimated from the collision geometry filled at a stated density, for "
            + ", ".join(f"{e.link} ({e.mass:.1f} kg at {e.density:g} kg/m^3)" for e in estimated)
        )
    if not assumed and not estimated:
        masses += " (nothing inferred from geometry)"
    derived = [c.name for c in ov.compensators if c.key.startswith("(URDF mimic")]
    springs = (
        f"  Balancer cylinders drawn as URDF mimic joints: the compensator springs {', '.join(derived)} "
        "(placeholder stiffness and free length; a scenario's [truth] replaces them).\n"
        if derived
        else ""
    )
    conventions = (
        "  Joint angles are the controller's, q = sign * q_urdf + zero: "
        + ", ".join(f"{c.joint} sign {c.sign:+d} zero {math.degrees(c.zero):g} deg" for c in ov.conventions)
        + ".\n"
        if ov.conventions
        else ""
    )
    text = (
        f" calbench robot built by calbench from-urdf from {source} with the overlay {ov.path.name}.\n"
        f"  Masses and inertias: {masses}.\n{springs}{conventions}  Stiffness of the actuated hinges: a placeholder "
        f"{PLACEHOLDER_STIFFNESS:g} N*m/rad; a scenario's [truth] replaces it.\n  Meshes are "
        "written inline; see bench/robots/urdf.py for the conventions. "
    )
    while "--" in text:  # a file name with dashes
        text = text.replace("--", "- -")
    return text.rstrip("- ") + " "


def build_spec(
    tree: UrdfTree, ov: Overlay, estimated: tuple[Estimate, ...] = ()
) -> tuple[mujoco.MjSpec, list[str]]:
    """The calbench MjSpec of a checked URDF and overlay, with the mesh warnings."""
    try:
        spec = mujoco.MjSpec.from_string(tree.xml)
    except ValueError as exc:
        raise InputError(
            tree.path, "(file)", "a URDF that MuJoCo reads", str(exc).replace("\n", " ")
        ) from None
    spec.compiler.inertiafromgeom = _NO_INFER
    spec.compiler.fusestatic = False
    spec.compiler.discardvisual = False
    spec.compiler.savecompiled = False  # every number saved exactly
    spec.comment = header_comment(tree, ov, estimated)
    for g in spec.geoms:
        g.contype = 0
        g.conaffinity = 0
    warnings = _inline_meshes(spec, tree, ov)
    spec.meshdir = ""
    _joints(spec, tree, ov)
    _additions(spec, ov)
    set_spec_names(spec, "assumed_masses", [n for n in assumed_links(ov, estimated) if n in tree.links])
    return spec, warnings


def assumed_links(ov: Overlay, estimated: tuple[Estimate, ...] = ()) -> list[str]:
    """The links whose masses are ASSUMED: the overlay's [inertials], given or estimated."""
    out = [i.link for i in ov.inertials if i.density is None] + [e.link for e in estimated]
    return list(dict.fromkeys(out))


def convert(urdf: str | Path, ov: Overlay) -> Conversion:
    """Build and check the calbench MJCF of ``urdf`` with overlay ``ov`` (module docstring)."""
    text, expanded = urdf_text(Path(urdf), ov)
    text, ov, notes = convert_balancers(text, ov)  # mimic cylinders -> compensator springs
    text, ov, more = convert_parallelograms(text, ov, Path(urdf))  # mimic parallelograms -> loops
    notes += more
    # masses from geometry last: the links that stay, in their final frames
    text, estimated, more = estimate_inertials(text, Path(urdf), ov, _mesh_reader(Path(urdf), text, ov))
    notes += more
    tree = read_urdf(urdf, ov, (text, expanded))
    check_urdf(tree)
    check_overlay(tree, ov)
    spec, warnings = build_spec(tree, ov, estimated)
    try:
        model = spec.compile()
    except ValueError as exc:
        raise InputError(
            tree.path, "(compile)", "a URDF that MuJoCo compiles", str(exc).replace("\n", " ")
        ) from None
    robot = _check_built(model, ov)
    scale = robot_scale(robot)
    for a in ov.sites():  # a position in mm: a reflector 300 m from its flange
        check_length(
            ov.path, f"{a.key}.pos", float(np.linalg.norm(a.pos)), scale, "offset from the link's frame"
        )
    for c in ov.compensators:
        check_length(ov.path, f"{c.key}.preload", c.preload, scale, "spring length")
    xml = spec.to_xml()
    moving = model.body_weldid != 0  # bodies not welded to the world
    return Conversion(
        xml=xml,
        warnings=tuple(warnings),
        actuated=ov.actuated,
        passive=tuple(model.joint(j).name for j in robot.passive_joint),
        moving_mass=float(model.body_mass[moving].sum()),
        geoms=int(model.ngeom),
        meshes=int(model.nmesh),
        notes=tuple(notes),
        assumed=tuple(n for n in assumed_links(ov, estimated) if n in tree.links),
    )


class UrdfImporter(RobotImporter):
    """The URDF importer (this module): :func:`convert` behind the importer interface."""

    name = "urdf"
    summary = "a URDF or a .xacro (expanded by the xacro package) and an overlay"
    suffixes = (".urdf", ".xacro")

    def convert(self, path: Path, overlay: Overlay) -> Conversion:
        return convert(path, overlay)


IMPORTER = UrdfImporter()

__all__ = [
    "PLACEHOLDER_STIFFNESS",
    "CONTINUOUS_RANGE",
    "UrdfTree",
    "UrdfLink",
    "UrdfJoint",
    "UrdfImporter",
    "IMPORTER",
    "read_urdf",
    "check_urdf",
    "check_overlay",
    "build_spec",
    "header_comment",
    "convert",
]
