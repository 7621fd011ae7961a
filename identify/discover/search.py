"""Discovery, part 2: the global fit of one candidate effect (multi-start).

A candidate fit that starts only at "no effect", from base parameters already bent to absorb
the missing effect, can stop in a local minimum: a hardening cubic on J2 named with the wrong
sign and its K_C bent several-fold, or an effect missed that a fit started near the truth
finds (on the paper plan, J2's cubic: LR 19 from the warm start, 39 from the spread one). So
each candidate is fitted from several starts and the lowest chi2 wins:

* WARM: the current model's values (base and already named effects) with the new effect at its
  prior start (bench/model/effects/: its "absent" value or a small size);
* SPREAD over the effect's range and sign: the effect's parameters at the magnitude whose
  signature the base parameters cannot absorb would explain the current model's whole excess
  chi2 (sqrt(chi2 - dof) standard deviations of the tracker, at least MIN_SIGNATURE = 5; the
  signature is the whitened Jacobian column at the warm start projected off the base columns:
  the same projection as the aliasing report, identify/discover/aliasing.py), with both signs
  where the bounds allow, the rest of the model at its warm values. A spread start that has no
  static equilibrium (a softening term past its stability limit: near it the linearised
  magnitude overshoots) is moved back towards the warm start, BACKOFF of the way, up to
  BACKOFF_TRIES times. The magnitudes come from the data and
  the plan, so no effect needs a hand-tuned range: the cubic terms on J2 (deflections ~1 deg)
  and on J4 (~0.02 deg) get starts four orders of magnitude apart. Parameters whose signature
  the base absorbs almost entirely (projected/full < VISIBLE_SHARE) are not spread (no
  magnitude of them is seen: the aliasing report names them); ``linear`` ones (the measurement
  side: chi2 is quadratic in them) need no spread;
* FRESH: the base parameters from their own fresh start (the base fit's data-derived start,
  identify/methods/onestep.py: the two-step estimate or generic values), not the bent values.
* SOFT: where the model has compensator springs and the base absorbs most of the effect's
  signature at the warm start (its unabsorbed share below SOFT_SHARE), the springs' stiffnesses
  SOFT_FACTOR times softer, the rest warm, fitted unscreened for up to SOFT_ITER iterations, on
  a model of its own (its far equilibria, cached for warm starts, would otherwise be where the
  next fit of the candidate starts from: the FANUC's profile check then found no equilibrium). A
  spring is the one base part whose response is far from linear in its parameters, and a spring
  made stiff with a moved free length bends its torque over the plan's few joint-2 angles into
  the shape of a drive's cubic: measured on the ABB IRB 6640 (J2 cubic at 3x its just-detectable
  size, benchmarks/honest_bench.py, replicate 1), the user's model put the balancer at 12.8 MN/m
  and 0.579 m against a true 0.5 MN/m and 0.40 m, every warm and spread start of the J2 cubic
  stayed in that basin (best chi2 99.4, LR 11, the cubic of the wrong sign), and 5 of 10
  campaigns named nothing with the free length 34-40 std off. From the balancer 30 or 100 times
  softer the fit reaches chi2 94.9 (the cubic 1.33e11 against a true 0.87e11, the balancer at
  0.59 MN/m and 0.446 m) in 63 evaluations, 0.4 s; 10 times softer stays in the stiff basin. The
  Gauss-Newton promise at such a start (102.8 against the warm fit's 102.1) would screen it out.

Cost. A spread or fresh start is SCREENED by one evaluation: it is fitted only when the chi2 its
Gauss-Newton step promises (the linearised model's minimum there) beats the best fit so far by
SCREEN_MARGIN. Every search fit runs at most SEARCH_ITER iterations and stops when a step gains
less than SEARCH_COST_TOL of chi2. The workflow POLISHES (:func:`polish`: to convergence at
identify/discover/fit.py's tolerances) only the candidates whose likelihood ratio comes near
their threshold, before deciding (identify/discover/workflow.py): below, no decision depends on
the last digits (an unpolished fit's chi2 is an upper bound, its LR a lower one, so the caps
never make a false alarm more likely).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from calbench.bench.model.effects import Effect, priors
from calbench.identify.core import Fit, Whitener

from .fit import build, effect_priors, fit_augmented, whitened

MIN_SIGNATURE = 5.0  # sigma: the smallest unabsorbed signature of a spread start
VISIBLE_SHARE = 0.05  # |projected column| / |column| below which spreading gains nothing
SCREEN_MARGIN = 1.0  # chi2: what a screened start must promise to gain over the best fit
SEARCH_ITER = 8  # iterations of each start's fit
SEARCH_COST_TOL = 0.05  # chi2: a search fit ends when a step gains less (the polish: fit.COST_TOL)
BACKOFF, BACKOFF_TRIES = 0.25, 4  # a spread start without an equilibrium moves this share of the way
SOFT_SHARE = 0.2  # unabsorbed share of the effect's signature below which the SOFT start is tried
SOFT_FACTOR = 100.0  # the SOFT start's springs are this many times softer than the warm ones
SOFT_ITER = 40  # iterations of the SOFT start's fit (it travels from one basin to another)
ERRORS = (ValueError, RuntimeError, np.linalg.LinAlgError)


@dataclass(frozen=True)
class Start:
    """One starting point of a candidate fit; ``screened``: fitted only if it promises."""

    label: str
    values: np.ndarray
    screened: bool = True
    max_iter: int = SEARCH_ITER
    own_model: bool = False  # fitted on a model of its own (its far equilibria stay out of the others')


def unabsorbed_norms(
    jw: np.ndarray, base_cols: np.ndarray, cols: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(|column|, |column projected off the span of base_cols|) of the whitened Jacobian's
    ``cols``: a parameter change d moves chi2 by (|projected| d)^2 to first order once the base
    parameters have absorbed what they can."""
    jb = jw[:, base_cols]
    q = np.linalg.qr(jb)[0] if jb.size else np.zeros((jw.shape[0], 0))
    je = jw[:, cols]
    return np.linalg.norm(je, axis=0), np.linalg.norm(je - q @ (q.T @ je), axis=0)


def spread_signature(current: Fit) -> float:
    """The spread starts' unabsorbed signature (sigma): what would explain the current model's
    whole excess chi2 over its dof, at least MIN_SIGNATURE."""
    return float(max(MIN_SIGNATURE, np.sqrt(max(current.chi2 - current.dof, 0.0))))


def candidate_starts(
    effect: Effect,
    warm: np.ndarray,
    jw: np.ndarray,
    base_free: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    fresh_base: np.ndarray | None,
    signature: float = MIN_SIGNATURE,
    springs: np.ndarray | None = None,
) -> list[Start]:
    """The warm, spread, fresh and soft starts (module docstring) for ``effect``, appended last to
    the parameter vector; lower / upper bound every parameter; signature: of the spread starts;
    springs: the indices of the base springs' stiffnesses (the soft start's)."""
    n = len(effect.param_names)
    cols = np.arange(warm.size - n, warm.size)
    starts = [Start("warm", warm.copy(), screened=False)]
    full, perp = unabsorbed_norms(jw, np.flatnonzero(base_free), cols)
    spread = (perp > VISIBLE_SHARE * np.maximum(full, 1e-300)) & ~np.array([p.linear for p in priors(effect)])
    if spread.any():
        c, lo, hi = cols[spread], lower[cols[spread]], upper[cols[spread]]
        for sign in (1.0, -1.0):
            if np.all((hi if sign > 0 else -lo) > 0):
                v = warm.copy()
                v[c] = np.clip(sign * signature / perp[spread], lo, hi)
                starts.append(Start(f"{'+' if sign > 0 else '-'}{signature:.3g} sigma", v))
    if fresh_base is not None:
        v = warm.copy()
        v[: fresh_base.size] = fresh_base
        starts.append(Start("fresh", np.clip(v, lower, upper)))
    absorbed = np.any(perp < SOFT_SHARE * np.maximum(full, 1e-300))
    if springs is not None and springs.size and absorbed and np.all(warm[springs] > 0):
        v = warm.copy()
        v[springs] = warm[springs] / SOFT_FACTOR
        starts.append(
            Start(
                "soft springs", np.clip(v, lower, upper), screened=False, max_iter=SOFT_ITER, own_model=True
            )
        )
    return starts


def promised_chi2(yw: np.ndarray, fw: np.ndarray, jw: np.ndarray, free: np.ndarray) -> float:
    """The chi2 at the minimum of the model linearised at (fw, jw) over the free columns."""
    r = yw - fw
    jf = jw[:, free]
    if not jf.size:
        return float(r @ r)
    u, s, _ = np.linalg.svd(jf / np.maximum(np.linalg.norm(jf, axis=0), 1e-300), full_matrices=False)
    u = u[:, s > 1e-10 * s[0]] if s.size and s[0] > 0 else u[:, :0]
    return float(r @ r - np.sum((u.T @ r) ** 2))


def start_eval(
    fm, white: Whitener, st: Start, warm: np.ndarray, record: list
) -> tuple[np.ndarray, np.ndarray]:
    """Evaluate a spread or fresh start; a start without a static equilibrium (a softening
    term past the stability limit: the linearised magnitude overshoots) is moved towards the
    warm start by BACKOFF, up to BACKOFF_TRIES times. Raises the last failure."""
    v = st.values
    for i in range(BACKOFF_TRIES + 1):
        try:
            return whitened(fm, white, v)
        except ERRORS:
            if i == BACKOFF_TRIES or st.label == "fresh":
                raise
            record.append({"start": st.label, "error": "no static equilibrium: backed off", "evaluations": 1})
            v = warm + BACKOFF * (v - warm)
            object.__setattr__(st, "values", v)


@dataclass(frozen=True)
class WarmPoint:
    """A candidate's model and bounds, and its warm start with the whitened model and Jacobian
    there (:func:`warm_point`)."""

    model: object
    lower: np.ndarray
    upper: np.ndarray
    values: np.ndarray
    fw: np.ndarray
    jw: np.ndarray
    start: np.ndarray  # the effect's prior start
    applied: list  # the current model's effects and their values


def warm_point(src, obs, white: Whitener, current: Fit, effect: Effect) -> WarmPoint:
    """Where a candidate fit starts: the current model's values with ``effect`` appended at its
    prior start, within every bound; :func:`fit_candidate` starts there and decide.py's
    score_statistic linearises there (its Jacobian is the fit's ``warm_jw``)."""
    start, lower, upper, _ = effect_priors(effect)
    applied = current.effect_params()
    _, fm = build(src, applied + [(effect, start)], obs)
    lay = fm.layout
    lo = np.concatenate([lay.lower] + [effect_priors(e)[1] for e, _ in applied] + [lower])
    hi = np.concatenate([lay.upper] + [effect_priors(e)[2] for e, _ in applied] + [upper])
    warm = np.clip(np.concatenate([current.values, start]), lo, hi)
    fw, jw = whitened(fm, white, warm)
    return WarmPoint(fm, lo, hi, warm, fw, jw, start, applied)


def fit_candidate(
    src,
    obs,
    white: Whitener,
    current: Fit,
    hold_base: np.ndarray,
    effect: Effect,
    fresh_base: np.ndarray | None = None,
) -> Fit:
    """The best (lowest chi2) fit of the current model plus ``effect`` over its starts.
    ``extra["starts"]`` lists every start (label, chi2 or promised chi2, evaluations, error),
    ``extra["start"]`` the winner's, ``extra["ends"]`` every fitted start's (chi2, values): the
    exposure weighs each (identify/discover/exposure.py, FITTED). Raises what :func:`build` raises when the effect does not
    apply to the model, RuntimeError when no start has an equilibrium."""
    t0 = time.perf_counter()
    w = warm_point(src, obs, white, current, effect)
    fm, lo, hi, warm = w.model, w.lower, w.upper, w.values
    fw, jw, start, applied = w.fw, w.jw, w.start, w.applied
    lay = fm.layout
    hold = np.concatenate([hold_base, np.zeros(lo.size - lay.n, bool)])
    base_free = np.r_[current.free, np.zeros(start.size, bool)]
    fresh = None if fresh_base is None else np.clip(fresh_base, lay.lower, lay.upper)
    yw = white.vec(obs.dp)
    best, record, ends = None, [], []
    springs = lay.stiffness_index[current.free[lay.stiffness_index]] if len(lay.compensators) else None
    for st in candidate_starts(
        effect, warm, jw, base_free, lo, hi, fresh, spread_signature(current), springs
    ):
        try:
            model = build(src, applied + [(effect, start)], obs)[1] if st.own_model else fm
            ev = (fw, jw) if st.label == "warm" else start_eval(model, white, st, warm, record)
            if st.screened and best is not None:
                promise = promised_chi2(yw, *ev, ~hold)
                if promise > best.chi2 - SCREEN_MARGIN:
                    record.append({"start": st.label, "promised_chi2": promise, "evaluations": 1})
                    continue
            f = fit_augmented(
                model,
                obs.dp,
                white,
                st.values,
                lo,
                hi,
                hold,
                start_eval=ev,
                max_iter=st.max_iter,
                cost_tol=SEARCH_COST_TOL,
            )
        except ERRORS as exc:
            record.append({"start": st.label, "error": str(exc), "evaluations": 1})
            continue
        record.append(
            {"start": st.label, "chi2": f.chi2, "evaluations": f.evaluations + (st.label != "warm")}
        )
        ends.append((f.chi2, f.values))
        if best is None or f.chi2 < best.chi2:
            best, label = f, st.label
    if best is None:
        raise RuntimeError(f"{effect.name}: no start of the candidate fit has a static equilibrium")
    best.extra.update(
        starts=record,
        ends=ends,
        start=label,
        warm_jw=jw,
        warm_of=current,
        polished=False,
        bounds=(lo, hi, hold),
        evaluations=int(sum(r.get("evaluations", 0) for r in record)) + 1,
    )
    best.seconds = time.perf_counter() - t0
    return best


def polish(f: Fit, obs, white: Whitener) -> Fit:
    """A search fit refined to convergence (identify/discover/fit.py's tolerances) from where
    it stopped; the better of the two (a polished fit's chi2 is never worse)."""
    if f.extra.get("polished"):
        return f
    lo, hi, hold = f.extra["bounds"]
    t0 = time.perf_counter()
    try:
        p = fit_augmented(f.model, obs.dp, white, f.values, lo, hi, hold)
    except ERRORS:
        p = f
    best = p if p.chi2 <= f.chi2 else f
    extra = dict(f.extra)
    extra["starts"] = f.extra["starts"] + [
        {
            "start": "polish " + f.extra["start"],
            "chi2": p.chi2,
            "evaluations": p.evaluations if p is not f else 0,
        }
    ]
    extra.update(
        polished=True,
        evaluations=f.extra["evaluations"] + (p.evaluations if p is not f else 0),
        jw=best.extra["jw"],
    )
    best.extra = extra
    best.seconds = f.seconds + time.perf_counter() - t0
    return best


__all__ = [
    "MIN_SIGNATURE",
    "spread_signature",
    "Start",
    "unabsorbed_norms",
    "candidate_starts",
    "promised_chi2",
    "fit_candidate",
    "polish",
]
