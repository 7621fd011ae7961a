"""Discovery, part 5b: each estimate's exposure to what was not named (issue 22).

A model that fits is a statement about the effects that were tested, not about the robot: an
effect of the library that this plan would not name can still be there, absorbed by the
estimated parameters, and move them far beyond their std (the IRB 6640 case: a link_2 bending
below its detection threshold moves k2 by 190 %, 250 of its std). The aliasing report
(identify/discover/aliasing.py) has the pieces; this turns them into the answer per parameter:

For a library effect not in the model, with whitened columns J_e (3M, k) at the final estimate,
regressed on the estimated parameters' columns J_b: J_e = J_b B + P (B: the bias per unit of
each effect parameter, P: what no estimated parameter absorbs). An effect of size d biases the
estimate by B d, and its likelihood-ratio test sees |P d|^2 (the chi2 it leaves, to first
order). It goes UNDETECTED while |P d|^2 < T, T its threshold at the family-wise level
(identify/discover/decide.py's lr_threshold with its k), so the largest bias it can cause on
parameter j unseen is

    exposure_j = sqrt(T) * sqrt(b_j^T (P^T P)^-1 b_j),     b_j = row j of B,

the maximum of b_j . d over that ellipsoid. Where P^T P is singular along a direction b_j has a
component on (the effect absorbed exactly there: VISIBLE_SHARE_MIN of its signature or less),
the exposure is unbounded: no size of it would be seen; it is reported as such, with the effect.

How large such an ABSORBED direction may be is not the data's to say (no size of it is seen), so it
is weighed at the largest size it can have: the size at which a direction just visible (share
VISIBLE_SHARE_MIN) would be named, sqrt(T) / VISIBLE_SHARE_MIN in whitened units (where the
bounded part above ends: the two rules meet there), and no larger than the effect's prior bounds
allow (bench/model/effects/: a compliance <= 1e-6 rad/(N*m)). A parameter it moves by more than
UNBOUNDED_SIGMA std there is exposed to the effect by any amount (``unbounded_by``; the bias at
that size in ``absorbed_bias``). Weighing it at the reference size instead (the size a plan would
name if nothing absorbed it, ~1000 times smaller) missed the IRB 6640's balancer: a hidden link_2
bending [0, 3e-7, 3e-7] rad/(N*m), 130 reference sizes along the direction k2 absorbs exactly,
moved balancer_stiffness by -373 kN/m (5.7 std; -173 kN/m to first order at the estimate: the
balancer's response to a series bending is hyperbolic, K' ~ K / (1 + a cy K)) while the exposure
said 1.4 kN/m, and 5 of 20 campaigns reported it determined 4.8-5.4 std off the truth with nothing
named (benchmarks/honest_bench.py; docs/discovery.md). At its largest size that direction moves it
by 8.8 std to first order, 2.1 std in a nonlinear refit (tests/test_discover_honest.py).
The exposure of a parameter is the largest over the library's effects not named, in the
parameter's unit, in its std and in per cent of its value.

REGION. The above is first order, and made at the estimate it is a statement about one point of
a valley that may be curved: the point where the noise, and the very effect the statement is
about, put the fit. So it is made at every point the data leave open to REGION_SIGMAS (2) std
along each principal axis of the estimated parameters' covariance (:func:`region_points`, the
same +-2 std the profile check walks; 2P points, one evaluation of each effect's model at each),
and the largest is reported (``bias_at_estimate``, ``by_effect_at_estimate``: the estimate's
alone). Measured on the FANUC with a hidden J2 cubic at 3x its just-detectable size
(benchmarks/honest_bench.py): in 4 of 10 campaigns the user's model absorbed it (chi2/dof
0.9-1.06, the candidate's LR 3.4 against a threshold of 15.3) with k2 19-21 std low. There the
J2 cubic's exposure of k2 is 1.1e-8 to 1.7e-8 rad/(N*m) at the estimate (3.3e-9 on campaign 0,
where the compensator's free length went to 1.17 m against 0.83 m), 1.8e-8 at the truth, and
jumps by 10x within +-0.1 m of the free length: near s0 = 0.9 m the compensator and k2 absorb a
J2 cubic almost exactly. The region's exposure is 1.9e-8 and more on each of the four (the gaps
less 4.5 std: 1.6e-8 to 1.8e-8), so none is confidently wrong; elsewhere it grows the exposure
by a median factor the benchmark reports (docs/discovery.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from calbench.identify.core import PROFILE_SIGMAS

from .aliasing import UNEXCITED, VISIBLE_SHARE_MIN, regress
from .decide import lr_threshold
from .fit import effect_priors, label

REGION_SIGMAS = PROFILE_SIGMAS  # the exposure is evaluated this many std along each principal axis too
UNBOUNDED_SIGMA = 0.5  # an exactly absorbed effect that moves a parameter this much (std) at its
# largest size (absorbed_sizes) is named as one that could bias it by any amount unseen


def _decompose(jw: np.ndarray, est: np.ndarray, block: np.ndarray, size: np.ndarray):
    """(excited (k,), |J_e| (k,), B (n_est, k'), eigenvalues w and vectors V of P^T P, seen (k',)):
    the effect's excited columns made unit (d in units of |J_e| per parameter), regressed on the
    estimated parameters' columns. None when nothing is excited or nothing is estimated."""
    full = np.linalg.norm(block, axis=0)
    excited = full * size > UNEXCITED
    if not excited.any() or not est.any():
        return None
    cols = block[:, excited] / full[excited]
    b, perp = regress(jw[:, est], cols)
    w, v = np.linalg.eigh(perp.T @ perp)
    return excited, full, b, w, v, w > VISIBLE_SHARE_MIN**2


def absorbed_sizes(v: np.ndarray, seen: np.ndarray, cap: np.ndarray, thr: float) -> np.ndarray:
    """(k',) the largest size, in whitened units, of each unit eigen-direction (a column of ``v``)
    of P^T P that the plan absorbs exactly (module docstring): sqrt(thr) / VISIBLE_SHARE_MIN, no
    larger than the effect's prior bounds ``cap`` (per excited parameter, whitened units: the SI
    bound times the column's norm; inf: none) allow along it. 0 where ``seen``."""
    out = np.where(seen, 0.0, math.sqrt(thr) / VISIBLE_SHARE_MIN)
    with np.errstate(divide="ignore", invalid="ignore"):
        limit = np.where(np.abs(v) > 0, cap[:, None] / np.abs(v), np.inf)
    return np.minimum(out, limit.min(axis=0))


def effect_exposure(
    jw: np.ndarray,
    est: np.ndarray,
    block: np.ndarray,
    size: np.ndarray,
    thr: float,
    floor: np.ndarray,
    cap: np.ndarray | None = None,
):
    """(bounded exposure (n_est,), unbounded (n_est,) bool, bias at the absorbed directions'
    largest size (n_est,)) of the estimated parameters to one effect with whitened columns
    ``block`` (3M, k); ``size``: its parameters' typical sizes (a column whose signature at that
    size is below UNEXCITED sigma is not excited: left out); ``cap``: their largest magnitude
    (SI; None: unbounded). Unbounded: a direction the estimated parameters absorb exactly biases
    the parameter by more than ``floor`` (n_est,) at its largest size (:func:`absorbed_sizes`)."""
    n = int(est.sum())
    parts = _decompose(jw, est, block, size)
    if parts is None:
        return np.zeros(n), np.zeros(n, bool), np.zeros(n)
    excited, full, b, w, v, seen = parts
    bv = b @ v  # b_j in the eigenbasis
    bounded = np.sqrt(np.sum(bv[:, seen] ** 2 / w[seen], axis=1)) * math.sqrt(thr)
    cap = np.full(block.shape[1], np.inf) if cap is None else np.asarray(cap, float)
    reach = absorbed_sizes(v, seen, cap[excited] * full[excited], thr)
    absorbed = np.sqrt(np.sum((bv * reach) ** 2, axis=1))
    unbounded = np.any(np.abs(bv) * reach > floor[:, None], axis=1)
    return bounded, unbounded, absorbed


def worst_case(jw: np.ndarray, est: np.ndarray, block: np.ndarray, size: np.ndarray, thr: float, row: int):
    """The effect's size (k,), SI, that biases the ``row``-th estimated parameter most while its
    likelihood ratio stays at the threshold ``thr`` (to first order): the maximiser of b . d on
    the ellipsoid |P d|^2 = thr, along the directions the plan sees (module docstring)."""
    excited, full, b, w, v, seen = _decompose(jw, est, block, size)
    bv = (b @ v)[row]
    d_eig = np.where(seen, bv / np.where(seen, w, 1.0), 0.0)
    d_eig *= math.sqrt(thr) / math.sqrt(np.sum(bv[seen] ** 2 / w[seen]))
    out = np.zeros(block.shape[1])
    out[excited] = (v @ d_eig) / full[excited]
    return out


def _exposure_arrays(final, jw: np.ndarray, std: np.ndarray, columns: list[tuple], n_candidates: int) -> dict:
    """The exposure of ``final``'s estimated parameters at one point (``jw``: the whitened
    Jacobian of the base and named effects there, ``columns``: (effect, its whitened columns
    there)): per estimated parameter (index into the estimated ones), the largest bounded bias
    and its effect, the bounded bias per effect, the effects that bias it by any amount and their
    bias at the absorbed directions' largest size."""
    est = np.asarray(final.free, bool) | np.asarray(final.at_bound, bool)
    idx = np.flatnonzero(est)
    sd = np.asarray(std, float)[idx]
    # "unbounded" from a bias of half a std at the reference size (1 % of the value: no std)
    floor = np.where(np.isfinite(sd) & (sd > 0), UNBOUNDED_SIGMA * sd, 0.01 * np.abs(final.values[idx]))
    out = {"best": np.zeros(idx.size), "by": [None] * idx.size}
    out["absorbed"] = [[] for _ in idx]
    out["each"] = [{} for _ in idx]
    out["reach"] = [{} for _ in idx]
    for effect, block in columns:
        _, lower, upper, size = effect_priors(effect)
        thr = lr_threshold(len(effect.param_names), n_candidates)
        cap = np.maximum(np.abs(lower), np.abs(upper))
        bounded, unbounded, at_reach = effect_exposure(jw, est, block, size, thr, floor, cap)
        lab = label(effect)
        for k in range(idx.size):
            if unbounded[k]:
                out["absorbed"][k].append(lab)
                out["reach"][k][lab] = float(at_reach[k])
            out["each"][k][lab] = float(bounded[k])
            if bounded[k] > out["best"][k]:
                out["best"][k], out["by"][k] = bounded[k], lab
    return out


def _merge(a: dict, b: dict) -> dict:
    """The larger of two points' exposures, parameter by parameter and effect by effect (the
    effects that bias a parameter by any amount: at either point)."""
    for k in range(a["best"].size):
        if b["best"][k] > a["best"][k]:
            a["best"][k], a["by"][k] = b["best"][k], b["by"][k]
        for lab, v in b["each"][k].items():
            a["each"][k][lab] = max(a["each"][k].get(lab, 0.0), v)
        for lab in b["absorbed"][k]:
            if lab not in a["absorbed"][k]:
                a["absorbed"][k].append(lab)
            a["reach"][k][lab] = max(a["reach"][k].get(lab, 0.0), b["reach"][k][lab])
    return a


def region_points(final, jw: np.ndarray, sigmas: float = REGION_SIGMAS) -> list[np.ndarray]:
    """The points at which the exposure is evaluated besides the estimate: +-``sigmas`` std
    along each principal axis of the estimated parameters' covariance (the SVD of the Fisher
    information in relative coordinates, identify/discover/uncertainty.py's; directions in its
    numerical null space, undetermined at any size, left out), brought back inside the bounds
    along the axis where it would leave them. To first order chi2 rises by sigmas^2 there."""
    from .uncertainty import RANK_TOL, sizes

    lo, hi, _ = final.extra["bounds"]
    est = np.flatnonzero(np.asarray(final.free, bool) | np.asarray(final.at_bound, bool))
    if est.size == 0:
        return []
    size = sizes(final)[est]
    _, s, vt = np.linalg.svd(jw[:, est] * size, full_matrices=False)
    if not s.size or s[0] <= 0:
        return []
    out = []
    for si, v in zip(s, vt):
        if si <= RANK_TOL * s[0]:
            continue
        for sign in (1.0, -1.0):
            step = np.zeros(final.values.size)
            step[est] = sign * sigmas / si * v * size
            t = 1.0
            with np.errstate(divide="ignore", invalid="ignore"):
                room = np.where(
                    step > 0,
                    (hi - final.values) / step,
                    np.where(step < 0, (lo - final.values) / step, np.inf),
                )
            t = float(min(1.0, np.nanmin(np.where(room >= 0, room, 0.0))))
            if t > 0:
                out.append(final.values + t * step)
    return out


def exposure_report(
    final,
    jw: np.ndarray,
    std: np.ndarray,
    columns: list[tuple],
    n_candidates: int,
    columns_at: Callable | None = None,
) -> list[dict]:
    """Per estimated parameter of ``final``: the largest bias an effect of ``columns`` ((effect,
    its whitened columns at the final estimate), the library's effects not named that own no base
    quantity) could cause while its test does not fire (module docstring), the effect that causes
    it, and the effects that could bias it by any amount unseen. std: the final parameters' std
    (NaN: not determined).

    ``columns_at``: theta -> (chi2, whitened Jacobian of the final model, [(effect, its whitened
    columns)]) at another point: with it, the exposure is the largest over the estimate and the
    points of :func:`region_points` (the module docstring's REGION: one whose chi2 rises above the
    family-wise threshold for one parameter is taken halfway back, and left out if still above)."""
    est = np.asarray(final.free, bool) | np.asarray(final.at_bound, bool)
    idx = np.flatnonzero(est)
    got = _exposure_arrays(final, jw, std, columns, n_candidates)
    at_estimate = got["best"].copy()
    each_at_estimate = [dict(e) for e in got["each"]]
    n_points = 0
    if columns_at is not None and columns:
        thr = lr_threshold(1, n_candidates)
        for point in region_points(final, jw):
            for theta in (point, 0.5 * (point + final.values)):
                try:
                    chi2, jw_p, cols_p = columns_at(theta)
                except (ValueError, RuntimeError, np.linalg.LinAlgError):
                    break
                if chi2 - final.chi2 <= thr:
                    got = _merge(got, _exposure_arrays(final, jw_p, std, cols_p, n_candidates))
                    n_points += 1
                    break
    out = []
    for k, i in enumerate(idx):
        v, sd, best = float(final.values[i]), float(std[i]), float(got["best"][k])
        out.append(
            {
                "parameter": final.names[i],
                "unit": final.units[i],
                "bias": best,
                "sigma": best / sd if np.isfinite(sd) and sd > 0 else None,
                "percent": 100 * best / abs(v) if v else None,
                "effect": got["by"][k],
                "unbounded_by": got["absorbed"][k],
                "absorbed_bias": got["reach"][k],
                "by_effect": got["each"][k],
                "bias_at_estimate": float(at_estimate[k]),
                "by_effect_at_estimate": each_at_estimate[k],
                "region_points": n_points,
            }
        )
    return out


def with_exposure(params: list[dict], exposure: list[dict]) -> list[dict]:
    """The parameter records with their exposure (``exposure``: :func:`exposure_report`'s)."""
    by = {e["parameter"]: e for e in exposure}
    return [dict(p, exposure=by[p["name"]]) if p["name"] in by else p for p in params]


__all__ = [
    "REGION_SIGMAS",
    "absorbed_sizes",
    "effect_exposure",
    "worst_case",
    "region_points",
    "exposure_report",
    "with_exposure",
]
