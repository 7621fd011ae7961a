"""``model = "spec"``: every reading's error independent, growing with range as a datasheet says.

C(y) = sd^2 u u^T + st^2 (I - u u^T) (bench/tracker/base.py, eq. 1), u the unit line of sight,
sd = a_d + b_d rho along it (the distance meter) and st = a_t + b_t rho across it (the angle
encoders), rho the range: the ``distance`` and ``transverse`` laws [a m, b m/m] of an ISO
10360-10 style specification, read as 1 sigma (defaults: the Leica AT500's, bench/tracker/base.py).
"""

from __future__ import annotations

import numpy as np

from calbench.bench.tracker import TrackerModel, TrackerSpec


def spec_covariance(spec: TrackerSpec, points_tracker: np.ndarray) -> np.ndarray:
    """The single-point covariance (n, 3, 3) of the distance and transverse laws
    (``spec.distance``, ``spec.transverse``): sd^2 u u^T + st^2 (I - u u^T)."""
    p = np.asarray(points_tracker, dtype=float)
    eye = np.broadcast_to(np.eye(3), (len(p), 3, 3))
    rng = np.linalg.norm(p, axis=1)
    if np.any(rng == 0):
        raise ValueError("a point at the tracker origin has no line of sight")
    u = p / rng[:, None]
    uu = u[:, :, None] * u[:, None, :]
    sd = spec.distance[0] + spec.distance[1] * rng
    st = spec.transverse[0] + spec.transverse[1] * rng
    return sd[:, None, None] ** 2 * uu + st[:, None, None] ** 2 * (eye - uu)


def describe_laws(spec: TrackerSpec) -> str:
    """The distance and transverse laws in words, µm: "distance 10 µm + 0.3 µm/m, transverse ..."."""
    (ad, bd), (at, bt) = spec.distance, spec.transverse
    return f"distance {ad * 1e6:.3g} µm + {bd * 1e6:.3g} µm/m, transverse {at * 1e6:.3g} µm + {bt * 1e6:.3g} µm/m"


class SpecTracker(TrackerModel):
    name = "spec"
    summary = "σ growing with range"

    def covariance(self, spec: TrackerSpec, y: np.ndarray) -> np.ndarray:
        return spec_covariance(spec, y)

    def describe(self, spec: TrackerSpec) -> str:
        return f"spec, 1σ {describe_laws(spec)} of range, independent readings"


MODEL = SpecTracker()

__all__ = ["SpecTracker", "spec_covariance", "describe_laws", "MODEL"]
