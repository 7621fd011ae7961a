"""`tracker_drift`: a measurement-side effect, the loaded readings offset (`[truth.effects.tracker_drift]`)."""

from __future__ import annotations

import numpy as np

from .base import Effect, Field, ObservationRows, Prior, no_edit
from .registry import register_effect


def _drift_truth(t: dict) -> tuple[dict, np.ndarray]:
    return {}, np.asarray(t["offset"], dtype=float)


DRIFT_PRIOR = Prior(start=0.0, lower=-np.inf, upper=np.inf, size=1e-5, linear=True)  # m: 10 um


@register_effect(
    "tracker_drift",
    truth=(Field("offset", "vector", "m", size=3, doc="bx, by, bz in the tracker frame"),),
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

    def measure(p, o, readings: ObservationRows):
        return np.tile(np.asarray(readings.tracker_rotation, float) @ p, (len(readings.rows), 1))

    return Effect("tracker_drift", ("bx", "by", "bz"), {}, ("m", "m", "m"), no_edit, no_edit, measure)
