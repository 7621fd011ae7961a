"""`compensator`: a spring gravity compensator, for a model that lacks one (a discovery candidate;
a scenario's truth gives it in `[truth.compensator]`, not as a hidden effect)."""

from __future__ import annotations

import mujoco

from calbench.bench.model import LEGACY_COMPENSATOR as COMPENSATOR
from calbench.bench.model import set_spec_names, spec_names

from .apply import load_spec
from .base import Effect
from .registry import register_effect


@register_effect(
    "compensator",
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
