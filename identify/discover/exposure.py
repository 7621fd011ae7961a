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
order). Its test compares the LR with T, its threshold at the family-wise level
(identify/discover/decide.py's lr_threshold with its k); the LR is that |P d|^2 plus the noise,
noncentral chi2 with k dof, so an effect leaving |P d|^2 = T is still missed half the time. It
counts as UNDETECTED while the test misses it at least MISS_RATE (1 in 20) of the time: while
|P d|^2 < T_u, the noncentrality whose noncentral chi2 stays below T with probability MISS_RATE
(:func:`unseen_chi2`; T_u = 31 for T = 15.3 and k = 1, (sqrt(T) + 1.645)^2 there). Sizing at T
instead left two KUKA KR 270 campaigns confidently wrong (J3 cubic at 3x, module docstring's SIZE:
the truth left chi2 18.9 > T = 15.3 noise-free and was missed, k3 38 std off where the exposure
said 33). The largest bias it can cause on parameter j unseen is

    exposure_j = sqrt(T_u) * sqrt(b_j^T (P^T P)^-1 b_j),     b_j = row j of B,

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

SIZE. The region still takes the effect's columns at size zero: where the effect's own response
is not linear in its size, the worst undetected size biases the estimate by another amount, and
leaves another chi2, than its columns say. A joint cubic is such an effect: the drive's stiffening
3 c theta^2 at the gravity deflection theta (~2 mrad) reaches ~25 % of K at the size a KUKA KR 270
campaign just detects, and the cubic's deflection saturates. Measured there (J3 cubic,
benchmarks/honest_bench.py, campaign replicate 1): the first-order worst size moves k3 by 22 std
with chi2 15.3 (the threshold); the nonlinear response at that size leaves chi2 ~11 and the
size the threshold allows moves k3 by 32-34 std; at the truth (chi2 18.9, missed by the noise)
by 38 std. Columns taken at another base point do not see it: the cubic's bias per unit size
and its visible part both scale as k^4 at size zero, so their ratio, the exposure, does not move.
So where an effect's first-order exposure of a parameter exceeds REGION_SIGMAS std (the truth, if
that biased, lies outside the region above), :func:`nonlinear_exposure` checks it on the exact
statics: the user's model is refitted to the noise-free readings the model plus the effect at a
size s d* predict (d* the first-order worst case, both signs) at a truth theta_t, and
(theta_t, s) are solved (:func:`truth_consistent`, Broyden's method from the first-order
Jacobian) so that the refit lands on the estimate and leaves chi2 = T_u (above): the bias
there is what the effect can do unseen with the estimate where it is. Where the truth-to-estimate map is not one for
one, the estimate moved REGION_SIGMAS std along the parameter's covariance column (the noise's
likeliest way there) is solved too. The larger of the first-order and nonlinear bias is
reported (``by_effect``; the nonlinear one alone in ``by_effect_nonlinear``). A solve that does
not converge, or a direction that leaves the effect's prior bounds (a negative compliance) or the
statics' equilibrium, leaves the first-order statement alone. A one-parameter effect's solve is
shared by the parameters it exposes. Cost: ~90-110 refits, 1.5-2 s on a KR 270 campaign (the
exposure otherwise 0.6 s), 4 s on the FANUC's (its compensator's statics; otherwise 1 s).
Measured with it (benchmarks/honest_bench.py, 10 campaigns a cell): KR 270 J5 cubic at 3x,
confidently wrong 4 -> 0 of 10; J3 cubic 3 -> 2 (the two left: the truth leaves chi2 18.9 > T
= 15.3 noise-free, missed by the test's own noise; sized at T_u, top of this docstring, 2 -> 0);
FANUC J2 cubic 0 of 10, no errors; the exposures grow by a median factor 1.0 (90th
percentile 1.2-2.1, ``nonlinear_growth`` in the benchmark).

FITTED. Every statement above is made about the user's model's valley; the data also say
something directly. Each library effect not named was fitted on top of the final model, from
several starts (identify/discover/search.py), and its fit explains the readings at least as well:
a truth the test did not name. Where it moves a parameter by more than the statements above,
that move is the effect's exposure of it (``by_effect_fitted``). Measured on the ABB IRB 6640
with a hidden J2 cubic at 3x (benchmarks/honest_bench.py): the user's model put the balancer's
free length at 0.579 +- 0.0045 m against a true 0.40 m, the first-order exposure said 0.020 m
and the nonlinear check did not converge; the J2 cubic's fit from softened springs puts it at
0.446 m (LR 15.5, at the naming threshold). Every start's fit that explains the readings at
least as well as the final model counts, not only the best: on replicate 7 the J2 cubic fits
chi2 148.0 in the stiff basin (free length 0.57 m) and 148.5 from the soft start (0.33 m; the
truth's basin, 148.05 at its own minimum) against the user's model's 160.0: the data cannot tell
the two apart, and the exposure says so (0.25 m). ``bias_before_fits`` is the exposure without
them and without PROFILE (below): what `calbench identify --exposure` reports, which fits no
candidate.

PROFILE. A compensator spring's stiffness and free length are where the user's model is least
linear: a stiffer spring with a moved free length bends its torque over a plan's few joint-2
angles into another shape, and the valley it leaves is curved far beyond +-2 std. Measured on the
ABB IRB 6640 with a hidden J2 cubic at 1x its just-detectable size (benchmarks/honest_bench.py,
replicate 0): nothing named, the free length 0.588 +- 0.011 m against a true 0.40 m (17 std), the
cubic's exposure 0.040 m over the region, and every statement above made within it. Noise-free,
a cubic of 0.1x (chi2 0.06: invisible) already moves the user's fit from 0.40 to 0.485 m, 1x to
0.565 m: the map from truth to estimate is steepest at the truth, far from where the first order
is made. The data say it directly: with the cubic free (its candidate fit), the chi2 profile of
the free length stays within 13.4 of its minimum from 0.35 to 0.59 m. So for each spring
parameter (``profiled``) and each effect whose first-order exposure of it exceeds REGION_SIGMAS
std, the candidate's profile is walked out (:func:`profile_reach`) to where it rises by T_u (the
chi2 an undetected effect leaves unseen); what it reaches beyond sqrt(T_u) std of the user's
model (the parameter's own spread at that level, which the exposure does not count) is the
effect's exposure of it (``by_effect_profile``).

SPRUNG JOINT. On the joint a compensator spring acts on, a drive's cubic and the spring trade
against each other along the same curved valley, and the profile of a parameter that is not a
spring reaches what none of the statements above sees. Measured on the FANUC with a hidden J2
cubic at 9x its just-detectable size (4.0e9 N*m/rad^3, benchmarks/honest_bench.py, replicate 0):
nothing named, k2 0.070 +- 0.0012 µrad/(N*m) against a true 0.12 (42 std), the J2 cubic's
exposure of k2 1.1e-8 at first order and over the region; its candidate fits (FITTED) all stayed
in one basin. With the cubic and the springs free, k2's profile stays within T_u of the
candidate's minimum out to 510 std. So for the effects ``coupled`` names (the workflow: each
effect acting on the joint a compensator spans, bench/model/robot.py's compensator_joint, with
that joint's compliance), the parameter is profiled as a spring is where its first-order
exposure exceeds REGION_SIGMAS std (1-3 s on a FANUC campaign). Stepping out in one jump from
the exposure already known lost the valley (campaign 0: the refit from 15 std out stayed in the
candidate's basin), so did not bisecting the edge (the same campaign with the cubic 2 % larger:
the walk stopped at its first failed step, k2's exposure 1.1e-8 against a gap of 5.0e-8; with the
bisection 3.0e-7), and profiling every parameter the effect exposes, not only its joint's, doubled
the test suite's discovery time.

UNCONFIRMED. Where that solve is tried (a sign within the prior bounds) and none converges, the
effect is listed in ``unconfirmed_by``: the first-order statement stands, not confirmed on the
exact statics. It is not taken as a larger bias: the solve rarely converges where the first
order is already right (measured, benchmarks/honest_bench.py with 5 null campaigns a robot: on
every FANUC and KR 270 campaign k2..k6 and the compensator's parameters had an unconfirmed
effect), so counting a failure as "any amount" would make almost every parameter unbounded.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from scipy import optimize, stats

from calbench.identify.core import PROFILE_SIGMAS

from .aliasing import UNEXCITED, VISIBLE_SHARE_MIN, regress
from .decide import lr_threshold
from .fit import effect_priors, label

MISS_RATE = 0.05  # an effect the naming test misses at least this often counts as undetected
REGION_SIGMAS = PROFILE_SIGMAS  # the exposure is evaluated this many std along each principal axis too
NONLINEAR_ITER = 10  # Broyden steps of a nonlinear worst case (truth_consistent)
NONLINEAR_TOL = 0.25  # std: the nonlinear worst case's landing tolerance on the estimate
NONLINEAR_CHI2_TOL = 0.02  # its tolerance on log(chi2 / threshold) / 2 (the size within 2 %)
REGION_SHIFT = 0.5  # std: a truth-to-estimate map moving the bias this much over the region is walked
PROFILE_STEPS = 8  # a spring's PROFILE walks out to 2**PROFILE_STEPS std each side at most
PROFILE_ITER = 30  # iterations of each profile point's fit (warm from the previous point)
PROFILE_SIGMA = 0.5  # std: a spring is profiled for the effects whose first order moves it more
PROFILE_BISECT = 3  # halvings of the step where a profile first rises beyond its level
UNBOUNDED_SIGMA = 0.5  # an exactly absorbed effect that moves a parameter this much (std) at its
# largest size (absorbed_sizes) is named as one that could bias it by any amount unseen


def unseen_chi2(k: int, n_candidates: int) -> float:
    """T_u: the largest chi2 |P d|^2 (noise-free) that an effect of k parameters can leave and
    still be missed by its naming test (LR > lr_threshold) at least MISS_RATE of the time: the
    noncentrality lambda with P(noncentral chi2(k, lambda) < T) = MISS_RATE (module docstring)."""
    t = lr_threshold(k, n_candidates)
    if not math.isfinite(t):
        return t
    return float(
        optimize.brentq(lambda lam: stats.ncx2.cdf(t, k, lam) - MISS_RATE, 1e-9, (math.sqrt(t) + 8.0) ** 2)
    )


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
        thr = unseen_chi2(len(effect.param_names), n_candidates)
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


def _raise_to(got: dict, k: int, lab: str, bias: float) -> None:
    """Raise parameter k's exposure to ``lab`` and its largest exposure to ``bias`` where larger."""
    if bias > got["each"][k].get(lab, 0.0):
        got["each"][k][lab] = bias
    if bias > got["best"][k]:
        got["best"][k], got["by"][k] = bias, lab


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
    respond: Callable | None = None,
    fitted: list[tuple[str, np.ndarray]] | None = None,
    profile: Callable | None = None,
    profiled: np.ndarray | None = None,
    coupled: dict[str, frozenset[int]] | None = None,
) -> list[dict]:
    """Per estimated parameter of ``final``: the largest bias an effect of ``columns`` ((effect,
    its whitened columns at the final estimate), the library's effects not named that own no base
    quantity) could cause while its test does not fire (module docstring), the effect that causes
    it, and the effects that could bias it by any amount unseen. std: the final parameters' std
    (NaN: not determined).

    ``columns_at``: theta -> (chi2, whitened Jacobian of the final model, [(effect, its whitened
    columns)]) at another point: with it, the exposure is the largest over the estimate and the
    points of :func:`region_points` (the module docstring's REGION: one whose chi2 rises above the
    family-wise threshold for one parameter is taken halfway back, and left out if still above).
    ``fitted``: (effect label, the values of ``final``'s parameters in that candidate's fit on top
    of ``final``): the module docstring's FITTED shift, a floor of the effect's exposure.
    ``profile``: (effect label, parameter index, its std, chi2 level) -> how far from the estimate
    the effect's candidate fit lets the parameter go (:func:`profile_reach`), or None; used for
    the parameters ``profiled`` ((P,) bool) marks (the module docstring's PROFILE), and for the
    effects ``coupled`` maps to parameter indices, those (the module docstring's SPRUNG JOINT)."""
    est = np.asarray(final.free, bool) | np.asarray(final.at_bound, bool)
    idx = np.flatnonzero(est)
    coupled = coupled or {}
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
    first_order = got["best"].copy()
    nonlinear = [{} for _ in idx]
    unconfirmed: list[list[str]] = [[] for _ in idx]
    n_refits, solved = 0, {}
    if respond is not None:
        sd = np.asarray(std, float)[idx]
        for effect, block in columns:
            lab = label(effect)
            thr = unseen_chi2(len(effect.param_names), n_candidates)
            for k in range(idx.size):
                if not (np.isfinite(sd[k]) and got["each"][k].get(lab, 0.0) > REGION_SIGMAS * sd[k]):
                    continue  # a truth that near is inside the region the first order was made over
                try:
                    bias, calls, failed = nonlinear_exposure(
                        final,
                        jw,
                        std,
                        effect,
                        block,
                        thr,
                        k,
                        lambda th, d, e=effect: respond(e, th, d),
                        solved,
                    )
                except (ValueError, RuntimeError, np.linalg.LinAlgError):
                    unconfirmed[k].append(lab)
                    continue
                n_refits += calls
                nonlinear[k][lab] = bias
                if failed:
                    unconfirmed[k].append(lab)
                _raise_to(got, k, lab, bias)
    modelled = got["best"].copy()  # what identify --exposure reports: no candidate fitted
    profiles: list[dict] = [{} for _ in idx]
    if profile is not None and profiled is not None:
        sd = np.asarray(std, float)[idx]
        for effect, _ in columns:
            lab = label(effect)
            thr = unseen_chi2(len(effect.param_names), n_candidates)
            for k, i in enumerate(idx):
                gate = (
                    PROFILE_SIGMA if profiled[i] else REGION_SIGMAS if i in coupled.get(lab, ()) else np.inf
                )
                if not (np.isfinite(sd[k]) and got["each"][k].get(lab, 0.0) > gate * sd[k]):
                    continue  # an effect whose first order hardly moves the parameter
                reach = profile(lab, int(i), float(sd[k]), thr)  # a spring, or SPRUNG JOINT's compliance
                if reach is None:
                    continue
                beyond = max(0.0, reach - math.sqrt(thr) * float(sd[k]))
                profiles[k][lab] = beyond
                _raise_to(got, k, lab, beyond)
    shifts: list[dict] = [{} for _ in idx]
    for lab, values in fitted or []:
        for k, i in enumerate(idx):
            shift = abs(float(values[i] - final.values[i]))
            if lab not in got["each"][k] or not np.isfinite(shift):
                continue  # an effect the exposure does not weigh (it owns a base quantity)
            shifts[k][lab] = max(shifts[k].get(lab, 0.0), shift)
            _raise_to(got, k, lab, shift)
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
                "bias_first_order": float(first_order[k]),
                "by_effect_nonlinear": nonlinear[k],
                "unconfirmed_by": unconfirmed[k],
                "by_effect_fitted": shifts[k],
                "by_effect_profile": profiles[k],
                "bias_before_fits": float(modelled[k]),
                "nonlinear_refits": n_refits,
            }
        )
    return out


def _covariance(jw: np.ndarray, est: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """(n_est, n_est) the estimated parameters' covariance from the whitened Jacobian (the
    pseudo-inverse of the Fisher information in relative coordinates ``scale``, directions below
    identify/discover/uncertainty.py's RANK_TOL left out, as :func:`region_points`)."""
    from .uncertainty import RANK_TOL

    _, s, vt = np.linalg.svd(jw[:, est] * scale, full_matrices=False)
    keep = s > RANK_TOL * (s[0] if s.size else 0.0)
    vs = vt[keep] / s[keep, None]
    return (vs.T @ vs) * np.outer(scale, scale)


def truth_consistent(respond, target, theta0, d, thr, unit, idx, first, jac=None, iters=NONLINEAR_ITER):
    """The nonlinear counterpart of the first-order worst case (module docstring, SIZE): the truth
    theta_t and the scale s of the effect's size ``d`` (SI, (k,)) such that the user's model,
    refitted to the noise-free readings of the model plus the effect at s d at theta_t, lands on
    ``target`` (within NONLINEAR_TOL std) and leaves chi2 = ``thr`` (log chi2 / 2 within
    NONLINEAR_CHI2_TOL). ``respond(theta, d) -> (refit (n,), chi2)``; ``theta0``: the first guess
    (target - ``first``, ``first`` (n,) the first-order bias); ``unit``: the estimated
    parameters' (indices ``idx``) std. Broyden's method on u = ((theta_t - target) / unit,
    log s), from the Jacobian first order predicts (``jac``: a previous solve's, for a nearby
    target): the refit moves one for one with theta_t, the bias scales with s, chi2 with s^2.
    Returns (bias (n,), chi2, s, Jacobian) at the solution; None if it does not converge or the
    model has no equilibrium on the way."""
    n = idx.size

    def resid(u):
        th = np.array(target, float)
        th[idx] = target[idx] + u[:n] * unit
        x, chi2 = respond(th, math.exp(u[n]) * d)
        r = np.r_[(x[idx] - target[idx]) / unit, 0.5 * math.log(max(chi2, 1e-300) / thr)]
        return r, x - th, chi2

    tol = np.r_[np.full(n, NONLINEAR_TOL), NONLINEAR_CHI2_TOL]
    u = np.r_[(theta0[idx] - target[idx]) / unit, 0.0]
    if jac is None:
        jac = np.eye(n + 1)
        jac[:n, n] = first[idx] / unit
    jac = np.array(jac, float)
    try:
        r, bias, chi2 = resid(u)
        for _ in range(iters):
            if np.all(np.abs(r) < tol):
                return bias, chi2, math.exp(u[n]), jac
            du = -np.linalg.lstsq(jac, r, rcond=None)[0]
            du[n] = float(np.clip(du[n], -1.0, 1.0))  # the size changes by e at most per step
            r2, bias, chi2 = resid(u + du)
            jac += np.outer((r2 - r) - jac @ du, du) / max(float(du @ du), 1e-300)
            u, r = u + du, r2
    except (ValueError, RuntimeError, np.linalg.LinAlgError):
        return None
    return (bias, chi2, math.exp(u[n]), jac) if np.all(np.abs(r) < tol) else None


def nonlinear_exposure(
    final, jw, std, effect, block, thr, row, respond, cache=None
) -> tuple[float, int, bool]:
    """(largest |bias| of the ``row``-th estimated parameter, number of refits) the ``effect``
    (whitened columns ``block`` at the estimate) can cause with its likelihood ratio at ``thr``
    in the nonlinear model (module docstring, SIZE): along the first-order worst direction, both
    signs, with the truth consistent with the estimate; and where the truth-to-estimate map is
    not one for one (its Jacobian, from the solve, moves the bias by more than REGION_SHIFT std
    over the region), with the estimate REGION_SIGMAS std off along the parameter's covariance
    column (the noise's most likely way of moving it there). 0 where no solve converges: the
    first-order statement stands alone: so where the worst direction leaves the effect's prior
    bounds (a negative compliance) within twice its size. ``cache``: a dict keeping the solves
    at the estimate for the effect's other parameters (a one-parameter effect's worst direction
    is the same for all). The third value: True when a solve at the estimate was tried (a sign
    within the bounds) and none converged (module docstring, UNCONFIRMED)."""
    from .uncertainty import sizes

    est = np.asarray(final.free, bool) | np.asarray(final.at_bound, bool)
    idx = np.flatnonzero(est)
    n = idx.size
    start, lower, upper, size = effect_priors(effect)
    d = worst_case(jw, est, block, size, thr, row)
    cache = {} if cache is None else cache
    sd = np.asarray(std, float)[idx]
    scale = sizes(final)[idx]
    cov = _covariance(jw, est, scale)
    unit = np.where(np.isfinite(sd) & (sd > 0), sd, np.sqrt(np.maximum(np.diag(cov), 0)) + 1e-12 * scale)
    col = cov[:, row] / math.sqrt(cov[row, row]) if cov[row, row] > 0 else np.zeros(n)
    calls = [0]

    def counted(theta, size_):
        calls[0] += 1
        return respond(theta, size_)

    best, tried, solved = 0.0, 0, 0
    for sign in (1.0, -1.0):
        if np.any(start + 2 * sign * d < lower) or np.any(start + 2 * sign * d > upper):
            continue
        tried += 1
        key = (label(effect), tuple(np.round(sign * d / np.linalg.norm(d), 9)))
        if key not in cache:
            first = np.zeros(final.values.size)
            first[idx] = np.linalg.lstsq(jw[:, idx], block @ (sign * d), rcond=None)[0]
            cache[key] = truth_consistent(
                counted, final.values, final.values - first, sign * d, thr, unit, idx, first
            )
        got = cache[key]
        if got is None:
            continue
        solved += 1
        bias, _, s, jac = got
        best = max(best, abs(bias[idx[row]]))
        step = REGION_SIGMAS * col / unit  # the region's target shift, in units
        moved = np.linalg.lstsq(jac[:n, :n], step, rcond=None)[0]  # theta_t's shift (chi2 aside)
        if abs(step[row] - moved[row]) <= REGION_SHIFT:
            continue
        for side in (1.0, -1.0):
            target = np.array(final.values, float)
            target[idx] += side * REGION_SIGMAS * col
            there = truth_consistent(
                counted, target, target - bias, s * sign * d, thr, unit, idx, bias, jac=jac
            )
            if there is not None:
                best = max(best, abs(there[0][idx[row]]))
    return best, calls[0], tried > 0 and solved == 0


def profile_reach(
    held: Callable,
    start: np.ndarray,
    chi2_min: float,
    i: int,
    center: float,
    sigma: float,
    thr: float,
    lo,
    hi,
) -> float:
    """How far from ``center`` (the user's estimate of parameter ``i``) its chi2 profile in a
    candidate's augmented model stays within ``thr`` of the lowest chi2 met (the module
    docstring's PROFILE): the parameter held at points stepping away from center by 2 sigma,
    doubling (up to 2^PROFILE_STEPS sigma and its bounds ``lo``, ``hi``), the rest refitted warm
    from the previous point by ``held(values) -> (chi2, values)``, from the candidate's fit
    ``start`` (chi2 ``chi2_min``); where a point rises beyond ``thr`` or has no equilibrium, the
    step is halved (PROFILE_BISECT times) from the last point within."""
    far = 0.0
    for side in (1.0, -1.0):
        v, best, good, step = np.array(start, float), chi2_min, 0.0, 2.0 * sigma
        halvings = 0
        while step > 0 and abs(good) < sigma * 2.0**PROFILE_STEPS:
            x = center + side * (good + step)
            edge = x <= lo or x >= hi
            trial = v.copy()
            trial[i] = min(max(x, lo), hi)
            try:
                chi2, w = held(trial)
            except (ValueError, RuntimeError, np.linalg.LinAlgError):
                chi2, w = np.inf, None
            if chi2 - min(best, chi2) > thr or w is None:
                if halvings >= PROFILE_BISECT:
                    break
                step, halvings = step / 2, halvings + 1  # the edge lies within this step
                continue
            v, best = np.array(w, float), min(best, chi2)
            good = abs(float(v[i]) - center)
            far = max(far, good)
            if edge:
                break
            step = step if halvings else 2 * step  # doubling until the edge is first met
    return far


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
    "truth_consistent",
    "nonlinear_exposure",
    "NONLINEAR_TOL",
    "NONLINEAR_CHI2_TOL",
    "exposure_report",
    "with_exposure",
]
