"""A library of hidden physical effects, each a named edit of the robot's MJCF (mujoco.MjSpec).

The bench puts them in the simulated truth (`[truth.effects.*]`, docs/contract.md); the discovery
workflow later uses the SAME functions as its library of candidate effects. The library holds
no selection logic: an :class:`Effect` knows its parameters (SI), how to edit a spec
(:meth:`Effect.apply`, then compile) and how to write the same values into an already compiled
model without recompiling (:meth:`Effect.set_params`, the fast path for fitting). Both give the
same model.

Adding an effect = one factory function decorated with :func:`register`, which carries
everything about it: the scenario parser (`from_truth`, if the truth may carry it), the
structural options discovery tries (`discover`, a list or a function of the robot; none = a
truth-only effect) and, where the per-unit defaults (:data:`UNIT_PRIORS`) do not fit, its
parameters' priors. Nothing else in the project needs to change.

Effects know no robot by name: what they need comes from the robot description the MJCF
carries (bench/model/description.py: the actuated joints, the payload and reflector sites, the
optional ``calbench:links`` and ``calbench:compensator_sites``) or from the model's tree (the
body fixed to the world that carries the arm).

MEASUREMENT-SIDE effects (`tracker_drift`) change what the instrument reports, not the robot:
they leave the spec alone and add a term to every predicted deflection instead
(:meth:`Effect.deflection_term`, given the :class:`Readings` it applies to); the bench adds the
same term to the simulated loaded readings. They register exactly like the others.

Every new joint has ref 0 and springref 0, so its qpos0 and qpos_spring are 0 and
:meth:`bench.robot.Robot.rigid_qpos` leaves it at 0 (only the actuated and passive joints are
filled, by name). A compliance of exactly 0 in a scenario's truth means "rigid": that hinge is
not created at all (no dof). A fitting structure that does hold a hinge whose compliance is set
to 0 locks it with a spring of stiffness 1/RIGID_COMPLIANCE (1e12 N*m/rad, ~1e5 x the drives).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from .description import set_spec_names, spec_names
from .params import LEGACY_COMPENSATOR as COMPENSATOR
from .robot import Robot

RIGID_COMPLIANCE = 1e-12  # rad/(N*m): the lock used for a present hinge set to compliance 0
AXES = "xyz"
BEAM_SUFFIX = "_beam"
HUB_MASS_FRACTION = 1e-3  # MuJoCo needs mass on a moving body: the hub keeps this share
BASE_POINT_MASS = 1.0  # kg at the base's hinge point when the base has no mass of its own
_TMP_PREFIX = "__effects_move__"


# --------------------------------------------------------------------------- the Effect type


@dataclass(frozen=True)
class Readings:
    """What a measurement-side effect acts on: the observation rows of a campaign, one
    (pose index, reflector name) per measured deflection, and the tracker's orientation
    (world-from-tracker rotation, bench.tracker.tracker_rotation)."""

    rows: tuple[tuple[int, str], ...]
    tracker_rotation: np.ndarray


def _no_edit(*_args) -> None:
    """The spec and model edit of a measurement-side effect: none."""


@dataclass(frozen=True)
class Effect:
    """One candidate physical effect: a structural choice (options) and SI parameters.

    name: the docs/contract.md effect name; param_names / units: its parameters, in order;
    options: structural choices (which link, which axes, which joint). A robot-side effect edits
    the spec (``_apply``) and writes its parameters into a compiled model (``_set``), and may
    write nothing but spring stiffnesses and rest lengths there (discovery keeps the springs'
    part of the stiffness matrix analytic, identify/discover/fit.py). A measurement-side effect
    has ``_measure`` instead: params, options, :class:`Readings` -> (M, 3) world-frame term added
    to every deflection.
    """

    name: str
    param_names: tuple[str, ...]
    options: dict
    units: tuple[str, ...] = ()
    _apply: Callable[[mujoco.MjSpec, np.ndarray, dict], None] = field(default=None, repr=False, compare=False)
    _set: Callable[[Robot, np.ndarray, dict], None] = field(default=None, repr=False, compare=False)
    _measure: Callable[[np.ndarray, dict, Readings], np.ndarray] | None = field(
        default=None, repr=False, compare=False
    )

    def _check(self, params) -> np.ndarray:
        p = np.atleast_1d(np.asarray(params, dtype=float))
        if p.shape != (len(self.param_names),):
            raise ValueError(
                f"{self.name}: expected {len(self.param_names)} parameters "
                f"{self.param_names}, got {p.tolist()}"
            )
        if not np.isfinite(p).all():
            raise ValueError(f"{self.name}: parameters must be finite, got {p.tolist()}")
        return p

    def apply(self, spec: mujoco.MjSpec, params) -> None:
        """Edit the spec in place (compile afterwards)."""
        self._apply(spec, self._check(params), self.options)

    def set_params(self, robot: Robot, params) -> None:
        """Write the parameters into a model that `apply` already built (no recompile)."""
        self._set(robot, self._check(params), self.options)

    @property
    def measurement_side(self) -> bool:
        """True when the effect changes the readings, not the robot (no spec edit)."""
        return self._measure is not None

    def deflection_term(self, params, readings: Readings) -> np.ndarray:
        """(M, 3) m, world frame: what a measurement-side effect adds to each measured
        deflection (loaded minus unloaded reading); zeros for a robot-side effect."""
        if self._measure is None:
            return np.zeros((len(readings.rows), 3))
        return np.asarray(self._measure(self._check(params), self.options, readings), dtype=float)

    @property
    def detail(self) -> str:
        """Short human description of the structural choice, e.g. "forearm" or "j3"."""
        if "link" in self.options:
            return str(self.options["link"])
        if "joint" in self.options:
            return f"j{self.options['joint']}"
        return ""


@dataclass(frozen=True)
class Prior:
    """What a fit assumes of one effect parameter: where it starts (its "absent" value, or a
    generic size where absent makes the others meaningless), its bounds, a typical size
    (finite-difference steps at zero) and whether the deflections are linear in it (then a
    candidate fit needs no multi-start, identify/discover/search.py). SI units."""

    start: float
    lower: float
    upper: float
    size: float
    linear: bool = False  # the deflections are linear in it: one start finds the optimum


# Per physical UNIT: the default priors of any effect parameter with that unit. A new effect with
# a new unit adds one line (or passes its own priors to @register).
UNIT_PRIORS: dict[str, Prior] = {
    # compliance: >= 0, and at most 1e-6 rad/(N*m) (a spring softer than any drive of this
    # robot is a broken part, not a compliance); starts at a typical size so that hinges that
    # only move together (upper-arm x and z, braced by the coupler rod) are not locked
    "rad/(N*m)": Prior(start=1e-8, lower=1e-12, upper=1e-6, size=1e-8),
    "N*m/rad^3": Prior(start=0.0, lower=-np.inf, upper=np.inf, size=1e12),  # cubic: none
    "N/m": Prior(start=1e6, lower=1.0, upper=1e9, size=1e6),  # spring rate
    "m": Prior(start=1.0, lower=1e-3, upper=10.0, size=1.0),  # free length
}

REGISTRY: dict[str, Callable[..., Effect]] = {}
_FROM_TRUTH: dict[str, Callable[[dict], tuple[dict, np.ndarray]]] = {}
# effect -> the structural options discovery tries on a robot (a function of the Robot)
DISCOVERY_OPTIONS: dict[str, Callable[[Robot], list[dict]]] = {}
_PRIORS: dict[str, dict[str, Prior]] = {}  # effect -> parameter name -> prior override


def register(
    name: str,
    from_truth: Callable[[dict], tuple[dict, np.ndarray]] | None = None,
    *,
    discover: list[dict] | Callable[[Robot], list[dict]] | None = None,
    priors: dict[str, Prior] | None = None,
):
    """Decorator: add an effect factory (keyword options -> Effect) to the library.

    from_truth maps a scenario table (bench.scenario, SI) to (factory options, parameters).
    discover gives the structural options (factory keyword arguments) that discovery tries as
    candidates: a list, or a function of the robot returning one (e.g. one per actuated
    joint); None keeps the effect out of discovery (truth only). priors overrides
    :data:`UNIT_PRIORS` for named parameters."""

    def deco(factory: Callable[..., Effect]) -> Callable[..., Effect]:
        REGISTRY[name] = factory
        if from_truth is not None:
            _FROM_TRUTH[name] = from_truth
        if discover is not None:
            fixed = None if callable(discover) else tuple(dict(o) for o in discover)
            DISCOVERY_OPTIONS[name] = discover if fixed is None else (lambda robot: [dict(o) for o in fixed])
        if priors:
            _PRIORS[name] = dict(priors)
        return factory

    return deco


def priors(effect: Effect) -> list[Prior]:
    """The prior of each of the effect's parameters: its registered override, else its unit's."""
    own = _PRIORS.get(effect.name, {})
    return [own.get(n) or UNIT_PRIORS[u] for n, u in zip(effect.param_names, effect.units)]


def discovery_library(robot: Robot) -> list[Effect]:
    """Every discovery candidate on this robot: each registered effect with each of the
    structural options it declares for the robot."""
    return [REGISTRY[name](**opts) for name, options in DISCOVERY_OPTIONS.items() for opts in options(robot)]


def effect_from_truth(name: str, table: dict) -> tuple[Effect, np.ndarray]:
    """The Effect and its true parameters from one `scn.effects[name]` entry (SI values)."""
    if name not in _FROM_TRUTH:
        raise KeyError(f"unknown effect {name!r}; known: {sorted(_FROM_TRUTH)}")
    options, params = _FROM_TRUTH[name](table)
    effect = REGISTRY[name](**options)
    return effect, effect._check(params)


# --------------------------------------------------------------------------- applying


class EffectRobot(Robot):
    """A Robot compiled from an edited spec; keeps the effects and the edited MJCF."""

    def __init__(self, model, xml: str, effects, source: Path | None = None):
        super().__init__(model, source)
        self.xml = xml
        self.effects = list(effects)

    def to_xml(self) -> str:
        """The augmented MJCF (valid, loadable) with the effects' parameters written in."""
        return self.xml


def load_spec(xml_or_path) -> mujoco.MjSpec:
    """MjSpec from a path (Path, or a str naming an existing file) or from MJCF text."""
    if isinstance(xml_or_path, mujoco.MjSpec):
        return xml_or_path.copy()
    if isinstance(xml_or_path, Path) or (isinstance(xml_or_path, str) and "<mujoco" not in xml_or_path):
        return mujoco.MjSpec.from_file(str(xml_or_path))
    return mujoco.MjSpec.from_string(xml_or_path)


def apply_effects(xml_or_path, effects: list[tuple[Effect, np.ndarray]]) -> EffectRobot:
    """Load the MJCF, apply each (effect, params) in order, compile, wrap in a Robot.

    The returned robot's `to_xml()` is the edited MJCF (spec.to_xml()); loading it gives the
    same model. Raises ValueError (MuJoCo compile errors, unknown links/joints)."""
    spec = load_spec(xml_or_path)
    for effect, params in effects:
        effect.apply(spec, params)
    model = spec.compile()
    source = (
        Path(xml_or_path)
        if isinstance(xml_or_path, Path) or (isinstance(xml_or_path, str) and "<mujoco" not in xml_or_path)
        else None
    )
    return EffectRobot(model, augmented_xml(spec, effects), effects, source)


def augmented_xml(spec: mujoco.MjSpec, effects: list[tuple[Effect, np.ndarray]]) -> str:
    """The edited spec as MJCF, every number exact (compiler savecompiled="false"; the default
    saves compiled values rounded to ~6 digits), headed by a comment naming the effects."""
    lines = [
        f"  {e.name} {e.options}: "
        + ", ".join(f"{n} = {float(v)!r} {u}" for n, v, u in zip(e.param_names, np.atleast_1d(p), e.units))
        for e, p in effects
    ]
    if lines:
        spec.comment = "\n  Augmented by calbench (bench/model/effects.py) with:\n" + "\n".join(lines) + "\n"
    spec.compiler.savecompiled = False
    return spec.to_xml()


# --------------------------------------------------------------------------- spec helpers


def _joint_id(robot: Robot, name: str) -> int:
    jid = mujoco.mj_name2id(robot.model, mujoco.mjtObj.mjOBJ_JOINT, name)
    if jid < 0:
        raise ValueError(f"the model has no joint {name!r}: apply the effect (and recompile) first")
    return jid


def _body(spec: mujoco.MjSpec, name: str):
    b = spec.body(name)
    if b is None:
        raise ValueError(f"the MJCF has no body {name!r}")
    return b


def _root_body(spec: mujoco.MjSpec) -> str:
    """The body fixed to the world that carries the arm: the first actuated joint's ancestor
    whose parent is the world (calbench:actuated)."""
    names = spec_names(spec, "actuated")
    j = spec.joint(names[0]) if names else None
    if j is None:
        raise ValueError("the MJCF's robot description names no actuated joint (calbench:actuated)")
    b = j.parent
    while b.parent is not None and b.parent.name != "world":
        b = b.parent
    return b.name


def root_body_name(robot: Robot) -> str:
    """:func:`_root_body` of a compiled robot."""
    m = robot.model
    b = int(m.jnt_bodyid[robot.act_joint[0]])
    while m.body_parentid[b] != 0:
        b = int(m.body_parentid[b])
    return m.body(b).name


def _stiffness(c: float) -> float:
    """Spring stiffness (N*m/rad) of a compliance c (rad/(N*m)); c = 0 locks the hinge."""
    if c < 0:
        raise ValueError(f"a compliance must be >= 0, got {c}")
    return 1.0 / max(float(c), RIGID_COMPLIANCE)


def _add_hinge(body, name: str, axis, compliance: float, pos=(0.0, 0.0, 0.0)):
    j = body.add_joint(name=name, type=mujoco.mjtJoint.mjJNT_HINGE, axis=list(axis), pos=list(pos))
    j.ref = 0.0
    j.springref = 0.0
    j.stiffness[0] = _stiffness(compliance)
    j.damping[0] = 0.0
    j.limited = mujoco.mjtLimited.mjLIMITED_FALSE
    return j


def _children(body) -> list:
    out, b = [], body.first_body()
    while b is not None:
        out.append(b)
        b = body.next_body(b)
    return out


_EQ_FIELDS = ("name", "type", "objtype", "name1", "name2", "data", "solref", "solimp", "active")


def _move_bodies(spec: mujoco.MjSpec, names: list[str], new_parent) -> None:
    """Reparent the named body subtrees (with everything in them) under `new_parent` at the same
    local pose. MjSpec has no in-place move: copy, delete, attach the copy, restore the names,
    and re-create the equality constraints that the deletion removed."""
    src = spec.copy()
    for t in list(src.tendons):  # attach would bring the copy's tendons/equalities along
        src.delete(t)
    for e in list(src.equalities):
        src.delete(e)
    for e in list(src.texts) + list(src.numerics) + list(src.tuples):  # the robot description: kept once
        src.delete(e)
    eqs = [{f: getattr(e, f) for f in _EQ_FIELDS} for e in spec.equalities]
    eqs = [{k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in e.items()} for e in eqs]
    counts = (len(spec.tendons), len(spec.actuators), len(spec.sensors), len(spec.excludes))
    for n in names:
        spec.delete(spec.body(n))
    if (len(spec.tendons), len(spec.actuators), len(spec.sensors), len(spec.excludes)) != counts:
        raise NotImplementedError(
            f"moving {names} would drop tendons/actuators/sensors/excludes that reference them"
        )
    for n in names:
        frame = new_parent.add_frame()
        frame.attach_body(src.body(n), _TMP_PREFIX, "")
    for kind in (
        mujoco.mjtObj.mjOBJ_BODY,
        mujoco.mjtObj.mjOBJ_JOINT,
        mujoco.mjtObj.mjOBJ_GEOM,
        mujoco.mjtObj.mjOBJ_SITE,
        mujoco.mjtObj.mjOBJ_CAMERA,
        mujoco.mjtObj.mjOBJ_LIGHT,
        mujoco.mjtObj.mjOBJ_FRAME,
    ):
        for el in new_parent.find_all(kind):
            if el.name.startswith(_TMP_PREFIX):
                el.name = el.name[len(_TMP_PREFIX) :]
    leftover = spec.find_default(_TMP_PREFIX + "main")  # the copy's (empty) default class
    if leftover is not None:
        try:
            spec.delete(leftover)
        except Exception:  # noqa: BLE001  (cosmetic only: an unused, empty class)
            pass
    have = {e.name for e in spec.equalities}
    for e in eqs:
        if e["name"] and e["name"] in have:
            continue
        new = spec.add_equality()
        for f in _EQ_FIELDS:
            setattr(new, f, e[f])


# --------------------------------------------------------------------------- link_compliance


def _link_truth(t: dict) -> tuple[dict, np.ndarray]:
    c = np.asarray(t["compliance"], dtype=float)
    axes = "".join(a for a, ci in zip(AXES, c) if ci != 0.0)  # 0 = rigid: no hinge at all
    return {"link": t["link"], "axes": axes}, c[c != 0.0]


def _beam_hinge(link: str, axis: str) -> str:
    return f"{link}_r{axis}"


@register(
    "link_compliance",
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
        body = _body(spec, o["link"])
        if spec.body(o["link"] + BEAM_SUFFIX) is not None:
            raise ValueError(f"link_compliance on {o['link']} is already applied")
        beam = body.add_body(name=o["link"] + BEAM_SUFFIX)
        for a, c in zip(o["axes"], p):
            _add_hinge(beam, _beam_hinge(o["link"], a), np.eye(3)[AXES.index(a)], c, o["pivot"])
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
        moving = [b.name for b in _children(body) if b.name != beam.name and _has_joint(b)]
        if moving:
            _move_bodies(spec, moving, beam)

    def set_(robot, p, o):
        for a, c in zip(o["axes"], p):
            robot.model.jnt_stiffness[_joint_id(robot, _beam_hinge(o["link"], a))] = _stiffness(c)

    pivot = tuple(float(x) for x in pivot)
    if len(pivot) != 3:
        raise ValueError(f"link_compliance: pivot must be a 3-vector, got {pivot!r}")
    return Effect(
        "link_compliance",
        tuple(f"c{a}" for a in axes),
        {"link": link, "axes": axes, "pivot": pivot},
        ("rad/(N*m)",) * len(axes),
        apply,
        set_,
    )


def _has_joint(body) -> bool:
    """Does the subtree carry a joint (i.e. is it the rest of the serial chain)?"""
    return bool(body.find_all(mujoco.mjtObj.mjOBJ_JOINT))


# --------------------------------------------------------------------------- base_compliance


def _base_truth(t: dict) -> tuple[dict, np.ndarray]:
    c = np.asarray(t["compliance"], dtype=float)
    axes = "".join(a for a, ci in zip("xy", c) if ci != 0.0)
    return {"axes": axes}, c[c != 0.0]


@register("base_compliance", from_truth=_base_truth, discover=lambda robot: [{"body": root_body_name(robot)}])
def base_compliance(axes: str = "xy", body: str | None = None) -> Effect:
    """Tilt of the robot's base on its foundation (anchor bolts, floor plate).

    Physics: the base body (default: the body fixed to the world that carries the arm),
    gets hinges `<base>_rx`, `<base>_ry` about its frame's x and y (world x and y for the
    FANUC) through its origin (the floor point under axis 1), stiffness 1/c, springref 0. The whole robot then tilts by c times the
    moment, about that point, of everything it carries (gravity of all links, the load): for a
    wrench (F at p, M) the tilt is c_x (p x F + M)_x and c_y (p x F + M)_y. If the base has no
    mass of its own (it needs some to move in MuJoCo) it gets a 1 kg point mass at the hinge
    point, which exerts no moment about the hinges at any tilt.

    Parameters cx, cy in rad/(N*m), for the axes listed.
    """
    if not axes or any(a not in "xy" for a in axes) or len(set(axes)) != len(axes):
        raise ValueError(f"base_compliance: axes must be a non-empty subset of 'xy', got {axes!r}")
    axes = "".join(a for a in "xy" if a in axes)

    def apply(spec, p, o):
        name = o["body"] or _root_body(spec)
        b = _body(spec, name)
        if b.find_all(mujoco.mjtObj.mjOBJ_JOINT) and any(j.name.startswith(name + "_r") for j in b.joints):
            raise ValueError("base_compliance is already applied")
        for a, c in zip(o["axes"], p):
            _add_hinge(b, f"{name}_r{a}", np.eye(3)[AXES.index(a)], c)
        if not (float(b.mass) > 0):
            b.explicitinertial = True
            b.mass = BASE_POINT_MASS
            b.ipos = [0.0, 0.0, 0.0]
            b.iquat = [1.0, 0.0, 0.0, 0.0]
            b.inertia = [1.0, 1.0, 1.0]

    def set_(robot, p, o):
        name = o["body"] or root_body_name(robot)
        for a, c in zip(o["axes"], p):
            robot.model.jnt_stiffness[_joint_id(robot, f"{name}_r{a}")] = _stiffness(c)

    return Effect(
        "base_compliance",
        tuple(f"c{a}" for a in axes),
        {"axes": axes, "body": body},
        ("rad/(N*m)",) * len(axes),
        apply,
        set_,
    )


# --------------------------------------------------------------------------- joint_nonlinearity


def _nonlin_truth(t: dict) -> tuple[dict, np.ndarray]:
    return {"joint": int(t["joint"])}, np.array([float(t["cubic"])])


@register(
    "joint_nonlinearity",
    from_truth=_nonlin_truth,
    discover=lambda robot: [{"joint": j} for j in range(1, robot.n_act + 1)],
)
def joint_nonlinearity(joint: int = 2) -> Effect:
    """A hardening (cubic > 0) or softening (< 0) drive spring on actuated axis `joint` (1..N,
    the robot's calbench:actuated order).

    Physics: torque = K theta + cubic theta^3, theta = joint angle - command. MuJoCo's joint
    stiffness polynomial gives force -(a x + b x^2 + c x^3) with x = qpos - qpos_spring
    (MJCF stiffness="a b c"; mjModel keeps a in jnt_stiffness and b, c in
    jnt_stiffnesspoly[j] = [b, c], mjNPOLY = 2 in MuJoCo 4.0.1). The effect writes only c; the
    linear K (Robot.set_params) is left untouched. Parameter cubic in N*m/rad^3.
    """
    if isinstance(joint, bool) or not isinstance(joint, (int, np.integer)) or joint < 1:
        raise ValueError(f"joint_nonlinearity: joint must be an actuated axis 1..N, got {joint!r}")

    def apply(spec, p, o):
        names = spec_names(spec, "actuated")
        if joint > len(names):
            raise ValueError(
                f"joint_nonlinearity: the robot has {len(names)} actuated joints "
                f"(calbench:actuated), not {joint}"
            )
        spec.joint(names[joint - 1]).stiffness[2] = p[0]

    def set_(robot, p, o):
        if joint > robot.n_act:
            raise ValueError(f"joint_nonlinearity: the robot has {robot.n_act} actuated joints, not {joint}")
        robot.model.jnt_stiffnesspoly[robot.act_joint[joint - 1], 1] = p[0]

    return Effect("joint_nonlinearity", ("cubic",), {"joint": joint}, ("N*m/rad^3",), apply, set_)


# --------------------------------------------------------------------------- compensator


def _comp_truth(t: dict) -> tuple[dict, np.ndarray]:
    return {}, np.array([float(t["stiffness"]), float(t["preload"])])


@register(
    "compensator",
    from_truth=_comp_truth,
    discover=lambda robot: [{}] if robot.description.compensator_sites else [],
)
def compensator() -> Effect:
    """A spring gravity compensator (paper eqs. 7-11), for a model that lacks one: discovery
    tries it where the robot description names its mounts (``calbench:compensator_sites``;
    the FANUC's balancer mounts, l_c = 0.90 m and l_2 = 0.45 m from the J2 axis).

    Physics: a linear spring tendon between the two sites: force K_C (s - s0) along the line
    between them, s its length. The tendon (named `compensator`) is added if the model has none
    between those sites; on a model that has one, only its K_C and s0 are set. Parameters K_C
    in N/m, s0 in m.
    """

    def apply(spec, p, o):
        sites = spec_names(spec, "compensator_sites")
        if len(sites) != 2 or any(spec.site(x) is None for x in sites):
            raise ValueError(
                "compensator: the robot description names no two sites to mount a "
                "spring between (calbench:compensator_sites)"
            )
        t = next((t for t in spec.tendons if sorted(w.target.name for w in t.path) == sorted(sites)), None)
        if t is None:
            t = spec.add_tendon(name=COMPENSATOR)
            t.wrap_site(sites[0])
            t.wrap_site(sites[1])
            t.width = 0.03
            t.rgba = [0.1, 0.6, 0.9, 1.0]
        t.stiffness[0] = p[0]
        t.springlength = [p[1], p[1]]

    def set_(robot, p, o):
        m = robot.model
        sites = sorted(
            mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, x) for x in robot.description.compensator_sites
        )
        t = next(
            (
                t
                for t in range(m.ntendon)
                if sorted(m.wrap_objid[m.tendon_adr[t] : m.tendon_adr[t] + m.tendon_num[t]]) == sites
            ),
            -1,
        )
        if len(sites) != 2 or t < 0:
            raise ValueError(
                "the model has no spring between its calbench:compensator_sites: apply the "
                "effect (and recompile) first"
            )
        robot.model.tendon_stiffness[t] = p[0]
        robot.model.tendon_lengthspring[t] = p[1]

    return Effect("compensator", ("K_C", "s0"), {}, ("N/m", "m"), apply, set_)


def without_compensator(xml_or_path) -> str:
    """The MJCF with its compensator tendons (calbench:compensators) removed from the model and
    the description; the mounting sites stay (calbench:compensator_sites): a user's model that
    lacks the effect above (for testing that discovery names it). Returns XML text."""
    spec = load_spec(xml_or_path)
    for name in spec_names(spec, "compensators"):
        spec.delete(spec.tendon(name))
    set_spec_names(spec, "compensators", [])
    spec.compiler.savecompiled = False  # keep full precision (see EffectRobot.to_xml)
    return spec.to_xml()


# --------------------------------------------------------------------------- tool_compliance


def _tool_truth(t: dict) -> tuple[dict, np.ndarray]:
    c = np.asarray(t["compliance"], dtype=float)
    axes = "".join(a for a, ci in zip("yz", c) if ci != 0.0)
    return {"axes": axes}, c[c != 0.0]


TOOL_BODY = "tool"
TOOL_MASS = 1.0  # kg on the moving tool body (MuJoCo needs mass there)


@register("tool_compliance", from_truth=_tool_truth)
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
        b = _body(spec, o["body"]) if o["body"] else spec.site(payload[0]).parent
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
            _add_hinge(tool, f"tool_r{a}", np.eye(3)[AXES.index(a)], c)
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

    def set_(robot, p, o):
        for a, c in zip(o["axes"], p):
            robot.model.jnt_stiffness[_joint_id(robot, f"tool_r{a}")] = _stiffness(c)

    return Effect(
        "tool_compliance",
        tuple(f"c{a}" for a in axes),
        {"axes": axes, "body": body, "mount": mount},
        ("rad/(N*m)",) * len(axes),
        apply,
        set_,
    )


# --------------------------------------------------------------------------- tracker_drift


def _drift_truth(t: dict) -> tuple[dict, np.ndarray]:
    return {}, np.asarray(t["offset"], dtype=float)


DRIFT_PRIOR = Prior(start=0.0, lower=-np.inf, upper=np.inf, size=1e-5, linear=True)  # m: 10 um


@register(
    "tracker_drift",
    from_truth=_drift_truth,
    discover=[{}],
    priors={"bx": DRIFT_PRIOR, "by": DRIFT_PRIOR, "bz": DRIFT_PRIOR},
)
def tracker_drift() -> Effect:
    """A constant offset b between the unloaded and the loaded readings, in the tracker frame
    (thermal drift of the instrument or of the reflector nests between the two readings of each
    pose): a MEASUREMENT-SIDE effect. It moves no part of the robot; every measured deflection
    is the robot's plus R b (R: world-from-tracker rotation), so its Jacobian is R for every row
    and it is linear in b. Nothing in the MJCF changes (the augmented model's header names it).
    Parameters bx, by, bz in m.
    """

    def measure(p, o, readings: Readings):
        return np.tile(np.asarray(readings.tracker_rotation, float) @ p, (len(readings.rows), 1))

    return Effect("tracker_drift", ("bx", "by", "bz"), {}, ("m", "m", "m"), _no_edit, _no_edit, measure)


# --------------------------------------------------------------------------- geometry
# A real robot's first error (docs/geometry.md): truth-only effects that a bench truth hides and
# identify --geometry recovers. Each edits body or site frames of the spec; set_params writes the
# same frames into a compiled model from the nominal ones apply saw.


def _offset_truth(t: dict) -> tuple[dict, np.ndarray]:
    offsets = np.asarray(t["offset"], dtype=float)
    return {"joints": len(offsets)}, offsets


def _offset_frame(pos, quat, jpos, axis, angle) -> tuple[np.ndarray, np.ndarray]:
    """A body frame turned by ``angle`` about its hinge (axis and point in the body frame)."""
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    turn, new_quat = np.zeros(4), np.zeros(4)
    mujoco.mju_axisAngle2Quat(turn, axis, float(angle))
    mujoco.mju_mulQuat(new_quat, np.asarray(quat, dtype=float), turn)
    rot, moved = np.zeros(9), np.zeros(3)
    mujoco.mju_quat2Mat(rot, turn)
    mujoco.mju_rotVecQuat(
        moved, np.asarray(jpos, dtype=float) - rot.reshape(3, 3) @ jpos, np.asarray(quat, dtype=float)
    )
    return np.asarray(pos, dtype=float) + moved, new_quat / np.linalg.norm(new_quat)


@register("joint_offset", from_truth=_offset_truth)
def joint_offset(joints: int = 6) -> Effect:
    """A zero offset o_k on every actuated joint (calbench:actuated order): the link turns by
    q_k + o_k when commanded q_k. The body that carries the hinge is turned by o_k about the
    hinge's axis and point, which is the same as the hinge reading o_k less (the rotations about one
    axis commute). Parameters o1..oN in rad."""
    nominal: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def apply(spec, p, o):
        names = spec_names(spec, "actuated")
        if len(names) != joints:
            raise ValueError(f"joint_offset: {joints} offsets for {len(names)} actuated joints")
        for name, angle in zip(names, p, strict=True):
            j = spec.joint(name)
            body = j.parent
            nominal[name] = (np.array(body.pos, dtype=float), np.array(body.quat, dtype=float))
            body.pos, body.quat = _offset_frame(body.pos, body.quat, j.pos, j.axis, angle)

    def set_(robot, p, o):
        for k, angle in enumerate(p):
            jid = robot.act_joint[k]
            name = mujoco.mj_id2name(robot.model, mujoco.mjtObj.mjOBJ_JOINT, jid)
            if name not in nominal:
                raise ValueError("joint_offset: set_params needs the model its apply built")
            b = robot.model.jnt_bodyid[jid]
            pos0, quat0 = nominal[name]
            jpos, axis = robot.model.jnt_pos[jid], robot.model.jnt_axis[jid]
            robot.model.body_pos[b], robot.model.body_quat[b] = _offset_frame(pos0, quat0, jpos, axis, angle)

    names = tuple(f"o{k + 1}" for k in range(joints))
    return Effect("joint_offset", names, {"joints": joints}, ("rad",) * joints, apply, set_)


def _tool_frame_truth(t: dict) -> tuple[dict, np.ndarray]:
    return {}, np.asarray(t["offset"], dtype=float)


@register("tool_frame", from_truth=_tool_frame_truth)
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


def _frame_error(pos, quat, p) -> tuple[np.ndarray, np.ndarray]:
    """A body frame P made P Tr(dx, dy, dz) Rx Ry Rz: the error E of docs/geometry.md."""
    quat = np.asarray(quat, dtype=float) / np.linalg.norm(quat)
    moved = np.zeros(3)
    mujoco.mju_rotVecQuat(moved, np.asarray(p[:3], dtype=float), quat)
    out = quat.copy()
    for axis, angle in zip(np.eye(3), p[3:], strict=True):
        turn, nxt = np.zeros(4), np.zeros(4)
        mujoco.mju_axisAngle2Quat(turn, axis, float(angle))
        mujoco.mju_mulQuat(nxt, out, turn)
        out = nxt
    return np.asarray(pos, dtype=float) + moved, out / np.linalg.norm(out)


FRAME_PARAMS = ("dx", "dy", "dz", "rx", "ry", "rz")
FRAME_UNITS = ("m", "m", "m", "rad", "rad", "rad")


def _frame_effect(name: str, body_of: Callable[[mujoco.MjSpec], str], options: dict) -> Effect:
    """A body's frame (its place in its parent) off by six numbers: :func:`_frame_error`."""
    nominal: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def apply(spec, p, o):
        body = _body(spec, body_of(spec))
        nominal["body"] = (np.array(body.pos, dtype=float), np.array(body.quat, dtype=float))
        nominal["name"] = body.name
        body.pos, body.quat = _frame_error(body.pos, body.quat, p)

    def set_(robot, p, o):
        if "body" not in nominal:
            raise ValueError(f"{name}: set_params needs the model its apply built")
        b = mujoco.mj_name2id(robot.model, mujoco.mjtObj.mjOBJ_BODY, nominal["name"])
        robot.model.body_pos[b], robot.model.body_quat[b] = _frame_error(*nominal["body"], p)

    return Effect(name, FRAME_PARAMS, options, FRAME_UNITS, apply, set_)


def _link_geometry_truth(t: dict) -> tuple[dict, np.ndarray]:
    return {"link": str(t["link"])}, np.asarray(t["offset"], dtype=float)


@register("link_geometry", from_truth=_link_geometry_truth)
def link_geometry(link: str = "") -> Effect:
    """The frame of body ``link`` in its parent off by (dx, dy, dz) m and (rx, ry, rz) rad: a link
    longer, shorter or twisted against the drawing. Its children move with it."""
    return _frame_effect("link_geometry", lambda spec: link, {"link": link})


def _base_frame_truth(t: dict) -> tuple[dict, np.ndarray]:
    return {}, np.asarray(t["offset"], dtype=float)


@register("base_frame", from_truth=_base_frame_truth)
def base_frame() -> Effect:
    """The robot's base (the body fixed to the world that carries the arm) off its drawn place by
    (dx, dy, dz) m and (rx, ry, rz) rad: the whole arm moves against the world and the tracker."""
    return _frame_effect("base_frame", _root_body, {})


__all__ = [
    "Effect",
    "EffectRobot",
    "Readings",
    "tracker_drift",
    "REGISTRY",
    "register",
    "effect_from_truth",
    "apply_effects",
    "Prior",
    "UNIT_PRIORS",
    "DISCOVERY_OPTIONS",
    "priors",
    "discovery_library",
    "load_spec",
    "augmented_xml",
    "link_compliance",
    "base_compliance",
    "joint_nonlinearity",
    "compensator",
    "tool_compliance",
    "joint_offset",
    "tool_frame",
    "link_geometry",
    "base_frame",
    "RIGID_COMPLIANCE",
]
