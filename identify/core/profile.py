"""Is chi2 quadratic where a Fisher std says it is? The profile check of identification and discovery.

A reported std is the inverse Fisher information at the estimate: honest only where chi2 is close
to quadratic over a few standard deviations. Where it is checked, not assumed: each parameter is
held at estimate +- PROFILE_SIGMAS Fisher stds and the others refitted (the caller's ``refit``:
identify/methods/onestep.py's one-step model, identify/discover/fit.py's model with effects); a quadratic
profile rises by PROFILE_SIGMAS^2 = 4 there. A rise outside [PROFILE_LOW, PROFILE_HIGH] x 4 (a
factor 2 either way), a point past the parameter's bound or a refit that fails marks the
parameter as not quadratic.

What a caller does with a marked parameter is its own decision: discovery reports it "not
determined" (identify/discover/uncertainty.py); identification reports it "not determined" too,
with the rises as the reason (identify/methods/onestep.py, measured there).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np

PROFILE_SIGMAS = 2.0  # the profile is checked this many Fisher stds from the estimate
PROFILE_LOW, PROFILE_HIGH = 0.5, 2.0  # its rise there, over the quadratic's, must lie within these

# refit(start, i) -> chi2 of the fit with parameter i held at start[i] and the others refitted
# from start; it may raise ValueError, RuntimeError or LinAlgError (no fit there)
Refit = Callable[[np.ndarray, int], float]


@dataclass
class Profile:
    """The check's outcome: ``bad`` (P,) marks parameters whose profile is not quadratic;
    ``rises`` {index: [rise at +PROFILE_SIGMAS sd, rise at -PROFILE_SIGMAS sd]}, None where the
    point is past a bound or the refit failed."""

    bad: np.ndarray
    rises: dict = field(default_factory=dict)


def quadratic(rise: float | None) -> bool:
    """Whether a rise at PROFILE_SIGMAS Fisher stds is within the factor allowed of the quadratic's."""
    return rise is not None and PROFILE_LOW * PROFILE_SIGMAS**2 <= rise <= PROFILE_HIGH * PROFILE_SIGMAS**2


def profile_check(
    refit: Refit,
    values: np.ndarray,
    chi2: float,
    std: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    indices: Iterable[int],
) -> Profile:
    """The check (module docstring) for the parameters ``indices`` of a fit at ``values`` with
    minimum ``chi2`` and Fisher stds ``std``; a parameter without a finite std is skipped."""
    values = np.asarray(values, dtype=float)
    bad = np.zeros(values.size, bool)
    rises: dict = {}
    for i in indices:
        if not (np.isfinite(std[i]) and std[i] > 0):
            continue
        rises[i] = []
        for sign in (1.0, -1.0):
            v = values.copy()
            v[i] += sign * PROFILE_SIGMAS * std[i]
            rise = None
            if lower[i] <= v[i] <= upper[i]:
                try:
                    rise = float(refit(v, i) - chi2)
                except (ValueError, RuntimeError, np.linalg.LinAlgError):
                    rise = None
            rises[i].append(rise)
            bad[i] |= not quadratic(rise)
    return Profile(bad, rises)


__all__ = ["PROFILE_SIGMAS", "PROFILE_LOW", "PROFILE_HIGH", "Profile", "Refit", "quadratic", "profile_check"]
