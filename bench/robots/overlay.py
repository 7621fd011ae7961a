"""The overlay of ``calbench from-urdf``: what a URDF cannot say about a robot, in TOML.

A URDF gives the links, joints, inertials and geometry; calbench also needs to know which
joints are the controller's axes, where the reflectors and the payload sit, and whether a
spring compensator or a closed kinematic loop is part of the robot (a URDF is a tree: a loop's
last link is a separate branch whose end the MJCF joins with a ``connect`` equality). The
overlay says so (docs/contract.md, "From a URDF")::

    actuated = ["joint_1", "joint_2", ...]       # controller order
    [payload]             link = "tool0"  pos = [x, y, z]
    [flange]              link, pos             # optional
    [reflectors.NAME]     link, pos             # three or more, in this order
    [compensators.NAME]   stiffness, preload, from = {link, pos}, to = {link, pos}   # optional
    [loops.NAME]          passive = [...], site1 = {link, pos}, site2 = {link, pos}  # optional
    [packages]            NAME = "folder"       # optional: where package://NAME/ and $(find NAME) point
    [xacro]               NAME = "value"        # optional: a .xacro's arguments (xacro NAME:=value);
                                                #   a value may hold $(find PKG)
    [inertials.LINK]      mass, com = [x, y, z], inertia = [ixx, iyy, izz(, ixy, ixz, iyz)]
                                                # optional: ASSUMED masses for a URDF without them,
                          or density = kg/m^3   #   or estimated from the link's collision geometry
    assumed_density = kg/m^3                    # optional: that estimate for every moving link
                                                #   with neither an <inertial> nor a table
    [conventions.JOINT]   zero = deg, sign = 1 or -1    # optional: the controller's angle of an
                                                # actuated joint, q_controller = sign * q_urdf + zero
    wrist = "link_5"                            # optional hints for design and discovery:
    links = ["link_2", "link_3"]                #   calbench:wrist, :links, :mass_compensators
    mass_compensators = ["counterweight"]       #   (links of the URDF)
    compensator_sites = "NAME" or {from = {link, pos}, to = {link, pos}}   # :compensator_sites

Positions are metres in the named link's URDF frame. Everything is validated like a scenario
(bench/scenario/parse.py): an :class:`~bench.errors.InputError` naming the file, the key and what was
expected. Whether the links and joints exist is the URDF's business (bench/robots/urdf.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calbench.bench.core import InputError, Table, describe, parse_toml, read_text
from calbench.bench.scenario import check_density

TOP_KEYS = (
    "actuated",
    "payload",
    "flange",
    "reflectors",
    "compensators",
    "loops",
    "packages",
    "xacro",
    "wrist",
    "links",
    "mass_compensators",
    "compensator_sites",
    "inertials",
    "conventions",
    "assumed_density",
)
PAYLOAD_SITE = "payload"
FLANGE_SITE = "flange"
MOUNT_SITES = ("compensator_mount_from", "compensator_mount_to")


@dataclass(frozen=True)
class Attach:
    """A point (a MuJoCo site) on a URDF link: ``pos`` in metres in the link's frame; ``key``
    says where in the overlay it was given (for messages)."""

    name: str
    link: str
    pos: tuple[float, float, float]
    key: str


@dataclass(frozen=True)
class CompensatorSpec:
    """A straight spring between two points (paper eqs. 7-9): stiffness K_C (N/m) and preload
    length s0 (m) are the initial values written into the MJCF; a scenario's truth replaces them."""

    name: str
    start: Attach
    end: Attach
    stiffness: float
    preload: float
    key: str


@dataclass(frozen=True)
class LoopSpec:
    """A loop closed by a ``connect`` equality between two points, and the unsprung joints that
    the URDF tree leaves open between them."""

    name: str
    site1: Attach
    site2: Attach
    passive: tuple[str, ...]
    key: str


@dataclass(frozen=True)
class InertialSpec:
    """A link's mass (kg), centre of mass (m, link frame) and inertia (kg*m^2 about the centre
    of mass, link axes: ixx, iyy, izz, ixy, ixz, iyz), given in the overlay because the URDF has
    none: ASSUMED values (the header of the MJCF and from-urdf's summary say so). Without an
    inertia, ASSUMED_GYRATION: the statics use only the mass and its centre, never the inertia.
    With ``density`` instead (mass 0 here), all three are estimated from the link's collision
    geometry at that density (bench/robots/density.py), ASSUMED as well."""

    link: str
    mass: float
    com: tuple[float, float, float]
    inertia: tuple[float, float, float, float, float, float] | None
    key: str
    density: float | None = None  # kg/m^3: estimate mass, com, inertia from the link's geometry


@dataclass(frozen=True)
class ConventionSpec:
    """How the controller counts an actuated joint: q_controller = sign * q_urdf + zero (zero in
    rad here, degrees in the overlay). The MJCF's joint then reads the controller's angle (its
    axis times sign, its ``ref`` the zero), so scenarios are written in the controller's angles."""

    joint: str
    zero: float
    sign: int
    key: str


ASSUMED_GYRATION = 0.1  # m: radius of gyration of an overlay inertial given without an inertia


@dataclass(frozen=True)
class Overlay:
    """A validated overlay (see the module docstring)."""

    path: Path
    actuated: tuple[str, ...]
    payload: Attach
    reflectors: tuple[Attach, ...]
    flange: Attach | None = None
    compensators: tuple[CompensatorSpec, ...] = ()
    loops: tuple[LoopSpec, ...] = ()
    packages: dict[str, Path] = field(default_factory=dict)
    # optional hints (bench/model/description.py): links named as they are, and the two sites between
    # which discovery tries a compensator spring: a compensator's own, or mounts of their own
    wrist: str | None = None
    links: tuple[str, ...] = ()
    mass_compensators: tuple[str, ...] = ()
    compensator_sites: tuple[str, str] | None = None
    mounts: tuple[Attach, ...] = ()
    inertials: tuple[InertialSpec, ...] = ()
    conventions: tuple[ConventionSpec, ...] = ()
    assumed_density: float | None = None  # kg/m^3 for every moving link without a mass
    xacro_args: dict[str, str] = field(default_factory=dict)  # a .xacro's arguments, as typed

    def sites(self) -> list[Attach]:
        """Every site the overlay adds, in the order they are added to the MJCF."""
        out = [self.payload, *([self.flange] if self.flange else []), *self.reflectors]
        for c in self.compensators:
            out += [c.start, c.end]
        for lp in self.loops:
            out += [lp.site1, lp.site2]
        return out + list(self.mounts)

    def named_links(self) -> list[tuple[str, str]]:
        """(overlay key, link) of every link the hints name."""
        return ([("wrist", self.wrist)] if self.wrist else []) + [
            (f"{key}[{i}]", link)
            for key in ("links", "mass_compensators")
            for i, link in enumerate(getattr(self, key))
        ]


def _name(c: Table, name: str, what: str) -> str:
    """A table key used as an MJCF name: the description texts are space-separated."""
    if not name or any(ch.isspace() for ch in name):
        raise c.fail(name, f"a {what} name without spaces", name)
    return name


def _names(c: Table, key: str, what: str) -> tuple[str, ...]:
    value = c.raw(key)
    expected = f"a non-empty array of {what} names (strings)"
    if not isinstance(value, list) or not value:
        raise c.fail(key, expected, describe(value))
    for i, v in enumerate(value):
        if not isinstance(v, str) or not v:
            raise InputError(c.file, f"{c.key(key)}[{i}]", f"a {what} name (a non-empty string)", describe(v))
        if v in value[:i]:
            raise InputError(c.file, f"{c.key(key)}[{i}]", f"each {what} once", v)
    return tuple(value)


def _attach(parent: Table, key: str, site: str) -> Attach:
    c = parent.sub(key)
    c.only(("link", "pos"))
    link = c.string("link")
    if not link:
        raise c.fail("link", "a link name of the URDF", link)
    pos = c.vector("pos", 3)
    return Attach(site, link, (float(pos[0]), float(pos[1]), float(pos[2])), c.prefix)


def _compensator(tables: Table, name: str) -> CompensatorSpec:
    c = tables.sub(name)
    c.only(("stiffness", "preload", "from", "to"))
    return CompensatorSpec(
        name,
        _attach(c, "from", f"{name}_from"),
        _attach(c, "to", f"{name}_to"),
        c.number("stiffness", positive=True),
        c.number("preload", positive=True),
        c.prefix,
    )


def _loop(tables: Table, name: str) -> LoopSpec:
    c = tables.sub(name)
    c.only(("passive", "site1", "site2"))
    return LoopSpec(
        name,
        _attach(c, "site1", f"{name}_site1"),
        _attach(c, "site2", f"{name}_site2"),
        _names(c, "passive", "joint"),
        c.prefix,
    )


def _mounts(
    top: Table, compensators: tuple[CompensatorSpec, ...]
) -> tuple[tuple[str, str], tuple[Attach, ...]]:
    """``compensator_sites``: the name of an overlay compensator (its two sites) or a table
    {from, to} of two new sites (:data:`MOUNT_SITES`)."""
    value = top.raw("compensator_sites")
    if isinstance(value, str):
        for c in compensators:
            if c.name == value:
                return (c.start.name, c.end.name), ()
        raise top.fail(
            "compensator_sites",
            "the name of a [compensators.NAME] table ("
            + (", ".join(c.name for c in compensators) or "none")
            + ") or a table {from, to}",
            value,
        )
    c = top.sub("compensator_sites")
    c.only(("from", "to"))
    mounts = (_attach(c, "from", MOUNT_SITES[0]), _attach(c, "to", MOUNT_SITES[1]))
    return MOUNT_SITES, mounts


def _inertial(tables: Table, link: str) -> InertialSpec:
    c = tables.sub(link)
    c.only(("mass", "com", "inertia", "density"))
    if c.has("density"):
        if c.has("mass") or c.has("com") or c.has("inertia"):
            raise c.fail(
                "density",
                "either a density (kg/m^3: estimated from the geometry) or mass and com, not both",
                "both",
            )
        rho = c.number("density", positive=True)
        check_density(c.file, c.key("density"), rho)
        return InertialSpec(link, 0.0, (0.0, 0.0, 0.0), None, c.prefix, rho)
    com = c.vector("com", 3)
    inertia = None
    if c.has("inertia"):
        raw = c.raw("inertia")
        v = c.vector("inertia", 6 if isinstance(raw, list) and len(raw) == 6 else 3)
        if np.any(v[:3] <= 0):
            raise c.fail("inertia", "ixx, iyy, izz > 0 (kg*m^2), optionally ixy, ixz, iyz", list(v))
        inertia = tuple(float(x) for x in np.concatenate([v, np.zeros(6 - len(v))]))
    return InertialSpec(
        link,
        c.number("mass", positive=True),
        (float(com[0]), float(com[1]), float(com[2])),
        inertia,
        c.prefix,
    )


def _convention(tables: Table, joint: str) -> ConventionSpec:
    c = tables.sub(joint)
    c.only(("zero", "sign"))
    zero = c.number("zero") if c.has("zero") else 0.0
    sign = c.raw("sign") if c.has("sign") else 1
    if isinstance(sign, bool) or sign not in (1, -1):
        raise c.fail("sign", "1 or -1 (the controller counts the joint the URDF's way, or the other)", sign)
    return ConventionSpec(joint, math.radians(zero), int(sign), c.prefix)


def _density(top: Table) -> float:
    rho = top.number("assumed_density", positive=True)
    check_density(top.file, top.key("assumed_density"), rho)
    return rho


def _named_tables(top: Table, key: str, what: str) -> list[tuple[Table, str]]:
    if not top.has(key):
        return []
    tables = top.sub(key)
    return [(tables, _name(tables, name, what)) for name in tables.table]


def parse_overlay(text: str, path: str | Path) -> Overlay:
    """Validate overlay ``text`` read from ``path`` (used in messages and for ``[packages]``
    folders, which are relative to it)."""
    path = Path(path)
    top = parse_toml(text, path)
    top.only(TOP_KEYS)
    actuated = _names(top, "actuated", "joint")
    payload = _attach(top, "payload", PAYLOAD_SITE)
    flange = _attach(top, "flange", FLANGE_SITE) if top.has("flange") else None
    reflectors = tuple(
        _attach(t, name, name) for t, name in _named_tables(top, "reflectors", "reflector site")
    )
    if len(reflectors) < 3:
        raise top.fail("reflectors", "at least 3 [reflectors.NAME] tables (link, pos)", f"{len(reflectors)}")
    compensators = tuple(_compensator(t, n) for t, n in _named_tables(top, "compensators", "tendon"))
    loops = tuple(_loop(t, n) for t, n in _named_tables(top, "loops", "equality"))
    packages: dict[str, Path] = {}
    if top.has("packages"):
        pk = top.sub("packages")
        for name in pk.table:
            packages[name] = (path.parent / pk.string(name)).resolve()
    xacro_args: dict[str, str] = {}
    if top.has("xacro"):
        xa = top.sub("xacro")
        xacro_args = {name: xa.string(name) for name in xa.table}
    sites, mounts = _mounts(top, compensators) if top.has("compensator_sites") else (None, ())
    wrist = top.string("wrist") if top.has("wrist") else None
    if wrist == "":
        raise top.fail("wrist", "a link name of the URDF", wrist)
    ov = Overlay(
        path,
        actuated,
        payload,
        reflectors,
        flange,
        compensators,
        loops,
        packages,
        wrist=wrist,
        links=_names(top, "links", "link") if top.has("links") else (),
        mass_compensators=_names(top, "mass_compensators", "link") if top.has("mass_compensators") else (),
        compensator_sites=sites,
        mounts=mounts,
        inertials=tuple(_inertial(t, n) for t, n in _named_tables(top, "inertials", "link")),
        conventions=tuple(_convention(t, n) for t, n in _named_tables(top, "conventions", "joint")),
        assumed_density=_density(top) if top.has("assumed_density") else None,
        xacro_args=xacro_args,
    )
    seen: dict[str, str] = {}
    for s in ov.sites():
        if s.name in seen:
            raise InputError(
                path,
                s.key,
                f"a site name other than {s.name!r}, which {seen[s.name]} "
                "already gives (site names must be unique)",
                s.name,
            )
        seen[s.name] = s.key
    return ov


def load_overlay(path: str | Path) -> Overlay:
    """Read and validate the overlay file at ``path``."""
    path = Path(path)
    return parse_overlay(read_text(path, "overlay"), path)


__all__ = [
    "Attach",
    "CompensatorSpec",
    "LoopSpec",
    "Overlay",
    "InertialSpec",
    "ConventionSpec",
    "ASSUMED_GYRATION",
    "parse_overlay",
    "load_overlay",
    "PAYLOAD_SITE",
    "FLANGE_SITE",
]
