"""Discovery, part 0: the user's model as it is, fitted exactly as `calbench identify` fits it.

One base fit for identification and discovery (issue 22): the estimate is identify/methods/onestep.py's
:func:`one_step` with its defaults (the same estimator, start, stopping rule and tracker weighting
as `calbench identify --method one-step`), so both report the same chi2 and residual RMS on the same
log and model. Its parameter set is identify's too:

* a parameter the rank analysis cannot see (identify/core/identifiability.py's :func:`analyze`) is
  HELD at its start in every later candidate fit, as the one-step holds it;
* a parameter the rank sees but the noise buries (relative std above 1: :func:`resolve`, e.g. a
  balancer that a plan with few joint-2 angles cannot separate from k2) is ESTIMATED with the others,
  as the one-step estimates it, and reported "not determined" with identify's reason. Holding it at a
  generic start instead (what discovery did before) left the IRB 6640 case of the issue at
  263.6 um RMS where identify leaves 31.3 um, and made a "compensator" candidate out of the gap.

The result is a discovery :class:`Fit` (theta coordinates, identify/discover/fit.py's forward model
with no effect) evaluated at identify's estimate; ``extra["identify"]`` keeps the one-step fit and
:func:`base_record` says in the report which parameters were held or not determined, and why.
"""

from __future__ import annotations

import numpy as np

from calbench.identify.core import Fit, Observations, Whitener, analyze, at_bounds, covariance
from calbench.identify.methods import one_step

from .fit import DISCOVER_RANK_TOL, build, whitened


def rank_free(r: Fit) -> np.ndarray:
    """(P,) bool: the parameters identify's one-step estimated (the rank analysis saw them),
    whether or not the noise then left them undetermined."""
    ident = r.ident
    free = np.asarray(ident.identifiable, bool)
    if ident.unresolved is not None:
        free = free | np.asarray(ident.unresolved, bool)
    return free


def base_fit(src, obs: Observations, white: Whitener) -> Fit:
    """The user's model as it is: identify's one-step estimate (module docstring) as a discovery
    fit; ``extra["fresh_start"]``: the one-step's data-derived start, ``extra["identify"]``: its fit."""
    robot, fm = build(src, [], obs)
    r = one_step(robot, obs)
    lay = robot.layout
    lo, hi = lay.lower, lay.upper
    values = np.asarray(r.values, float).copy()
    fw, jw = whitened(fm, white, values)
    yw = white.vec(obs.dp)
    resid_w = yw - fw
    at_low, at_high = at_bounds(values, lo, hi)
    estimated = rank_free(r)
    free = estimated & ~at_low & ~at_high
    scale = np.where(np.abs(values) > 0, np.abs(values), 1.0)
    cov, _ = covariance(jw * scale, free, scale, DISCOVER_RANK_TOL)
    ident = np.zeros(values.size, bool)
    idx = np.flatnonzero(free)
    if idx.size:
        ident[idx] = analyze((jw * scale)[:, idx], tuple(str(i) for i in idx)).identifiable
    rw = resid_w.reshape(-1, 3)
    return Fit(
        values,
        cov,
        free,
        white.unwhiten(rw),
        rw,
        float(resid_w @ resid_w),
        resid_w.size,
        int(r.rank),  # identify's: the same dof
        r.iterations,
        r.evaluations + 1,
        r.converged,
        r.seconds,
        names=tuple(lay.names),
        units=tuple(lay.units),
        predicted=white.unwhiten(fw.reshape(-1, 3)),
        at_bound=estimated & (at_low | at_high),
        start=r.start,
        start_method=r.start_method,
        model=fm,
        robot=robot,
        extra={
            "jw": jw,
            "fresh_start": np.clip(r.start, lo, hi),
            "identify": r,
            "bounds": (lo, hi, ~estimated),
        },
    )


def hold_mask(base: Fit) -> np.ndarray:
    """(n_base,) bool: the base parameters every candidate fit holds (those identify held)."""
    return np.asarray(base.extra["bounds"][2], bool).copy()


def base_record(base: Fit) -> dict:
    """What the report says of the base fit: the estimator, its chi2, dof and RMS (identify's), and
    every base parameter identify held or left undetermined, with its reason."""
    r: Fit = base.extra["identify"]
    est = rank_free(r)
    return {
        "estimator": "one-step (identify/methods/onestep.py), as `calbench identify` fits it",
        "start": r.start_method,
        "chi2": float(r.chi2),
        "dof": int(r.dof),
        "rms": float(np.sqrt(np.mean(r.residual**2))),
        "converged": bool(r.converged),
        "held": {n: r.reasons.get(n, "not seen by the plan") for n, e in zip(r.names, est) if not e},
        "not_determined": {
            n: r.reasons.get(n, "not determined")
            for n, e, d in zip(r.names, est, r.identifiable)
            if e and not d
        },
    }


__all__ = ["base_fit", "base_record", "hold_mask", "rank_free"]
