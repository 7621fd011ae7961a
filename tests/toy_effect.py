"""A toy effect in one file: everything adding an effect takes (docs/architecture.md, "How to add an
effect"). Importing this module registers it; nothing else in calbench names it.

`toy_hung_mass`: a mass that always hangs at the payload site (a tool changer nobody weighed),
offset by ``offset`` (m, in the payload body's frame) when given. Physics: a jointless child body
of the payload site's body at that point, holding the mass as a point (MuJoCo welds it to the
body), so its weight loads the arm in every state exactly as a hung load of that mass does
(bench.statics.Load.mass: the weight at the payload site). Parameter m in kg.
"""

from __future__ import annotations

import mujoco
import numpy as np

from calbench.bench.model import spec_names
from calbench.bench.model.effects import Effect, Field, register_effect

NAME = "toy_hung_mass"
BODY = "toy_hung_mass"
POINT_INERTIA = 1e-9  # kg*m^2: a point mass (MuJoCo wants a positive inertia)


def _from_truth(t: dict) -> tuple[dict, np.ndarray]:
    offset = tuple(float(x) for x in t.get("offset", (0.0, 0.0, 0.0)))
    return {"offset": offset}, np.array([t["mass"]])


@register_effect(
    NAME,
    truth=(
        Field("mass", "number", "kg", positive=True, doc="the hung mass"),
        Field("offset", "vector", "m", size=3, required=False, doc="from the payload site, body frame"),
    ),
    from_truth=_from_truth,
)
def toy_hung_mass(offset: tuple = (0.0, 0.0, 0.0)) -> Effect:
    """The toy's factory: the structural option is where the mass hangs."""

    def apply(spec, p, o):
        payload = spec_names(spec, "payload")
        site = spec.site(payload[0])
        body = site.parent.add_body(
            name=BODY, pos=list(np.asarray(site.pos, float) + np.asarray(o["offset"]))
        )
        body.explicitinertial = True
        body.mass = p[0]
        body.ipos = [0.0, 0.0, 0.0]
        body.inertia = [POINT_INERTIA] * 3

    def set_(robot, p, o):
        robot.model.body_mass[mujoco.mj_name2id(robot.model, mujoco.mjtObj.mjOBJ_BODY, BODY)] = p[0]

    return Effect(NAME, ("m",), {"offset": tuple(offset)}, ("kg",), apply, set_)
