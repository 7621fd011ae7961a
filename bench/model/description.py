"""The robot description: what calbench needs to know about a robot, read from its MJCF alone.

Everything lives in the MJCF as MuJoCo's own user data, ``<custom><text name="calbench:KEY"
data="name name ..."/></custom>`` (space-separated element names; docs/contract.md, "Robot
description"):

============================  ==================================================  ========
``calbench:actuated``         the actuated hinge joints in controller order; each  required
                              carries the VJM spring (``stiffness``,
                              ``springref`` = the command, paper eq. 1); N of
                              them give ``k1 … kN``
``calbench:loops``            ``connect`` equalities between two sites that the    optional
                              statics close exactly (kinematic loops)
``calbench:compensators``     spatial tendons between two sites that are           optional
                              gravity-compensator springs (eqs. 7-9)
``calbench:reflectors``       the reflector sites the tracker reads (>= 3)         required
``calbench:payload``          the site where the load hangs                        required
``calbench:flange``           the flange site (drawn by the viewers)               optional
``calbench:mass_compensators``  bodies that are counterweights (paper §3.3: the     optional
                              design keeps their vertical off the loops' passive
                              hinges); none: the rule is not applied
``calbench:wrist``            the body whose origin is the wrist centre (design's  optional
                              min_height / min_radius); default: the body of the
                              last-but-one actuated joint
``calbench:links``            bodies whose root compliance discovery tries         optional
                              (``link_compliance``); none: not a candidate
``calbench:compensator_sites``  two sites between which discovery tries a          optional
                              compensator spring; none: not a candidate
``calbench:assumed_masses``   bodies whose mass, centre and inertia are ASSUMED    optional
                              (a guess, not the maker's: from-urdf's overlay
                              ``[inertials]``); check-robot says so
============================  ==================================================  ========

Everything else (passive joints, loop degeneracy, a compensator's joint and geometry, the
design's self-collision exclusions) is derived from the model (bench/model/robot.py,
identify/design/candidates.py). :func:`read_description` checks names and element types only;
``calbench check-robot`` (bench/robots/check.py) also checks the geometry (loops close,
reflectors not collinear and visible, statics converge).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco

PREFIX = "calbench:"


class DescriptionError(ValueError):
    """A robot description that does not describe the model; the message names the element."""


@dataclass(frozen=True)
class Description:
    """The named elements of a robot description (see the module docstring)."""

    actuated: tuple[str, ...]
    reflectors: tuple[str, ...]
    payload: str
    loops: tuple[str, ...] = ()
    compensators: tuple[str, ...] = ()
    flange: str | None = None
    mass_compensators: tuple[str, ...] = ()
    wrist: str | None = None
    links: tuple[str, ...] = ()
    compensator_sites: tuple[str, ...] = ()
    assumed_masses: tuple[str, ...] = ()


# key -> (required, how many names (None: any), element kind, what it names)
KEYS: dict[str, tuple[bool, int | None, str, str]] = {
    "actuated": (True, None, "joint", "the actuated hinge joints in controller order"),
    "loops": (False, None, "equality", "connect equalities closed by the statics"),
    "compensators": (False, None, "tendon", "spatial tendons that are compensator springs"),
    "reflectors": (True, None, "site", "the reflector sites (at least 3)"),
    "payload": (True, 1, "site", "the payload site"),
    "flange": (False, 1, "site", "the flange site"),
    "mass_compensators": (False, None, "body", "counterweight bodies (paper §3.3)"),
    "wrist": (False, 1, "body", "the body whose origin is the wrist centre"),
    "links": (False, None, "body", "bodies whose root compliance discovery tries"),
    "compensator_sites": (False, 2, "site", "two sites between which discovery tries a spring"),
    "assumed_masses": (False, None, "body", "bodies whose masses are ASSUMED (a guess, not the maker's)"),
}
_KINDS = {
    "joint": mujoco.mjtObj.mjOBJ_JOINT,
    "equality": mujoco.mjtObj.mjOBJ_EQUALITY,
    "tendon": mujoco.mjtObj.mjOBJ_TENDON,
    "site": mujoco.mjtObj.mjOBJ_SITE,
    "body": mujoco.mjtObj.mjOBJ_BODY,
}
MIN_REFLECTORS = 3


def custom_texts(model: mujoco.MjModel) -> dict[str, str]:
    """Every ``calbench:`` custom text of the model, key (without the prefix) -> data."""
    out = {}
    raw = bytes(model.text_data)
    for i in range(model.ntext):
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_TEXT, i) or ""
        if name.startswith(PREFIX):
            adr, size = int(model.text_adr[i]), int(model.text_size[i])
            out[name[len(PREFIX) :]] = raw[adr : adr + size].rstrip(b"\0").decode()
    return out


def _id(model, kind, name: str) -> int:
    return mujoco.mj_name2id(model, kind, name)


def read_description(model: mujoco.MjModel) -> Description:
    """The model's description; DescriptionError naming the first missing or wrong element."""
    texts = custom_texts(model)
    for key in texts:
        if key not in KEYS:
            raise DescriptionError(
                f"custom text {PREFIX}{key}: unknown; known: " + ", ".join(PREFIX + k for k in KEYS)
            )
    names: dict[str, tuple[str, ...]] = {}
    for key, (required, count, kind, what) in KEYS.items():
        words = tuple(texts.get(key, "").split())
        if required and not words:
            raise DescriptionError(
                f"custom text {PREFIX}{key}: required ({what}); add "
                f'<custom><text name="{PREFIX}{key}" data="..."/></custom>'
            )
        if count is not None and words and len(words) != count:
            raise DescriptionError(
                f"custom text {PREFIX}{key}: {'one' if count == 1 else count} "
                f"{kind} name{'s' if count > 1 else ''}, got {list(words)}"
            )
        if len(set(words)) != len(words):
            raise DescriptionError(f"custom text {PREFIX}{key}: a name is listed twice in {list(words)}")
        for w in words:
            if _id(model, _KINDS[kind], w) < 0:
                raise DescriptionError(f"{PREFIX}{key}: no {kind} named {w!r} in the MJCF")
        names[key] = words

    for j in names["actuated"]:
        if model.jnt_type[_id(model, _KINDS["joint"], j)] != mujoco.mjtJoint.mjJNT_HINGE:
            raise DescriptionError(f"{PREFIX}actuated: joint {j!r} must be a hinge")
    for e in names["loops"]:
        eid = _id(model, _KINDS["equality"], e)
        if (
            model.eq_type[eid] != mujoco.mjtEq.mjEQ_CONNECT
            or model.eq_objtype[eid] != mujoco.mjtObj.mjOBJ_SITE
        ):
            raise DescriptionError(
                f"{PREFIX}loops: equality {e!r} must be a <connect> between two sites (site1, site2)"
            )
    for t in names["compensators"]:
        tid = _id(model, _KINDS["tendon"], t)
        adr, num = model.tendon_adr[tid], model.tendon_num[tid]
        if num != 2 or any(model.wrap_type[adr + i] != mujoco.mjtWrap.mjWRAP_SITE for i in range(num)):
            raise DescriptionError(
                f"{PREFIX}compensators: tendon {t!r} must be a <spatial> tendon "
                "between exactly two sites (a straight spring)"
            )
    if len(names["reflectors"]) < MIN_REFLECTORS:
        raise DescriptionError(
            f"{PREFIX}reflectors: at least {MIN_REFLECTORS} sites, got {list(names['reflectors'])}"
        )
    one = {k: (v[0] if v else None) for k, v in names.items()}
    return Description(
        actuated=names["actuated"],
        reflectors=names["reflectors"],
        payload=one["payload"],
        loops=names["loops"],
        compensators=names["compensators"],
        flange=one["flange"],
        mass_compensators=names["mass_compensators"],
        wrist=one["wrist"],
        links=names["links"],
        compensator_sites=names["compensator_sites"],
        assumed_masses=names["assumed_masses"],
    )


def spec_names(spec: mujoco.MjSpec, key: str) -> list[str]:
    """The names a spec's ``calbench:<key>`` text lists (empty when absent)."""
    for t in spec.texts:
        if t.name == PREFIX + key:
            return t.data.split()
    return []


def set_spec_names(spec: mujoco.MjSpec, key: str, names) -> None:
    """Write ``calbench:<key>`` into a spec (replacing it); no names removes the text."""
    if key not in KEYS:
        raise KeyError(f"{PREFIX}{key}: not a key of the robot description ({', '.join(KEYS)})")
    names = [str(n) for n in names]
    for t in list(spec.texts):
        if t.name == PREFIX + key:
            if names:
                t.data = " ".join(names)
            else:
                spec.delete(t)
            return
    if names:
        spec.add_text(name=PREFIX + key, data=" ".join(names))


__all__ = [
    "PREFIX",
    "KEYS",
    "Description",
    "DescriptionError",
    "custom_texts",
    "read_description",
    "spec_names",
    "set_spec_names",
]
