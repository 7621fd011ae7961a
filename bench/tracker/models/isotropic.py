"""``model = "isotropic"`` (the default): every reading's error independent, sigma on every axis.

C(y) = sigma^2 I (bench/tracker/base.py, eq. 1), whatever the point: what the paper's
unweighted least squares assumes of its random errors (Klimchik et al. 2016, eq. 6: one sigma
for every coordinate of every deflection). A deflection of one reading per state then has the
covariance 2 sigma^2 I per reflector.
"""

from __future__ import annotations

import numpy as np

from calbench.bench.tracker import TrackerModel, TrackerSpec


class IsotropicTracker(TrackerModel):
    name = "isotropic"
    summary = "σ the same on every axis"
    sigma_per_axis = True

    def covariance(self, spec: TrackerSpec, y: np.ndarray) -> np.ndarray:
        eye = np.broadcast_to(np.eye(3), (len(y), 3, 3))
        return spec.sigma**2 * eye.copy()

    def describe(self, spec: TrackerSpec) -> str:
        return f"isotropic, σ = {spec.sigma * 1e6:.3g} µm per axis"


MODEL = IsotropicTracker()

__all__ = ["IsotropicTracker", "MODEL"]
