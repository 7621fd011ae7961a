"""Discovery, part 5: aliasing. What "the model fits" does not tell you.

Some effects cannot be seen by a given plan, because the estimated parameters absorb them
exactly, and then they bias those parameters silently: a cubic term on J1 when every pull loads
J1 with the same torque (a k1 change), a payload mass error (on the paper plan exactly a common
scale of k2..k6), an in-plane upper-arm bending (~95 % a k2). For every library effect that is
not named, and for ``load_scale``, at the final model:

* J_e, the effect parameter's whitened Jacobian column at its prior start (bench/model/effects/),
  is regressed on the estimated parameters' columns J_b (base and named effects):
  J_e = J_b B + J_perp. B is the BIAS PER UNIT of the effect parameter: how far the fit moves
  each estimated parameter to absorb it.
* visible_share = |J_perp| / |J_e|: the share of its signature left for a test to see
  (VISIBLE_SHARE_MIN below: "absorbed exactly", the plan cannot see it at any magnitude);
  detectable_magnitude = sqrt(T) / |J_perp|, T the likelihood-ratio threshold of one parameter
  at the family-wise level (identify/discover/decide.py): the smallest magnitude this plan
  would name.
* reference_magnitude = sqrt(T) / |J_e|: an effect this large would be named if nothing
  absorbed it; the bias it causes at that magnitude is given per parameter in the parameter's
  standard deviations and in per cent of its value (the "k1 23 % low" kind of statement).

``load_scale`` is a relative error s of every hung weight (poses whose load is a vertical force
with no moment: the payload's mass known only to +-x %); its column is d dp / d s by central
differences of the exact model with the weights scaled by 1 +- LOAD_STEP. It is reported with
the bias per per-cent of mass: deflections alone can never tell a mass error from compliances,
so it is never named; its ``detectable_magnitude`` is the error from which the sliver of its
signature the parameters cannot absorb leaves a significant misfit.

EXACT. A parameter the deflections are not linear in (a joint cubic: bench/model/effects/'s
Prior.linear) is named from another size than its column says: the cubic's stiffening 3 c
theta^2 saturates its deflection, its softening heads for a loss of equilibrium.
:func:`exact_detection` checks the first-order detectable_magnitude on the exact statics, each
sign within the prior's bounds: the effect's noise-free signature at the size, off the estimated
parameters' columns, |P (f(s) - f(0))|^2, is the test's noncentrality lambda (exact in the
effect's response, first order in what the fit absorbs; a refit of the final model to those
readings, tests/test_aliasing_exact.py, agrees within a few per cent on the KR 270, and leaves
less where a spring's valley absorbs more: the FANUC's J2 cubic, docs/discovery.md). Where lambda
at the first-order size is off the threshold by more than EXACT_RTOL, the size is walked
(EXACT_STEPS times it: up where lambda is short of T, down where it is past it or the statics
have no equilibrium) and bisected on log size to lambda = T; short of T where the statics lose
equilibrium, the edge is bisected too. A sign whose lambda never reaches T up to the largest step
(or before its statics lose equilibrium) is never named at any size, and says so with its
largest lambda. Each size is solved from the equilibrium at the columns' point, which is unique:
a warm start from another size found another branch of a softening cubic's equilibria (a J4 cubic
"named from 6e8", 100 times below its linear size); solving each cold costs 4x as much. Measured
on the KUKA KR 270 paper plan: a J6 cubic's first-order size (1.6e12 N*m/rad^3) leaves lambda
1.4 against T = 15.3, a stiffening one never more than 2.1 (never named); a J3 cubic is named from
2.2x its first-order size. The benchmark's "just detectable" cubics use the same function.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from calbench.bench.statics import Load
from calbench.identify.core import Whitener, design_from_observations

from .decide import lr_threshold
from .fit import AugmentedForward, effect_priors

VISIBLE_SHARE_MIN = 1e-3  # below: absorbed exactly (no magnitude of it can be seen)
UNEXCITED = 1e-6  # sigma: a signature this small at the parameter's typical size is not excited
LOAD_STEP = 1e-3  # relative step of the weights for d dp / d s
EXACT_RTOL = 0.25  # |lambda / T - 1| at the first-order size beyond which the size is solved for
EXACT_STEPS = (1.0, 3.0, 10.0, 30.0, 100.0)  # multiples of the first-order size walked up
EXACT_BISECT = 5  # halvings of the log-size bracket (size within a factor 1.04 of a 3x step)


def _regress(jw: np.ndarray, est: np.ndarray, col: np.ndarray) -> tuple[np.ndarray, float, float]:
    """(B over the estimated columns, |col|, |col projected off them|)."""
    jb = jw[:, est]
    if not jb.size:
        return np.zeros(0), float(np.linalg.norm(col)), float(np.linalg.norm(col))
    b, perp = regress(jb, col)
    return b, float(np.linalg.norm(col)), float(np.linalg.norm(perp))


def regress(jb: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(B, P) with cols = jb B + P, P orthogonal to jb's span; cols (n,) or (n, k). On unit
    columns of jb: the SI columns of a compliance and of a spring's N/m differ by ~1e12, and
    lstsq's cut-off on the raw columns drops the small one (the spring: it then absorbs nothing)."""
    norms = np.linalg.norm(jb, axis=0)
    norms = np.where(norms > 0, norms, 1.0)
    bn = np.linalg.lstsq(jb / norms, cols, rcond=None)[0]
    perp = cols - (jb / norms) @ bn
    return (bn.T / norms).T, perp


def alias_record(
    name: str,
    detail: str,
    parameter: str,
    unit: str,
    col: np.ndarray,
    final,
    jw: np.ndarray,
    est: np.ndarray,
    std: np.ndarray,
    threshold: float,
    size: float,
) -> dict:
    """The aliasing entry of one effect parameter (module docstring) against the final fit. A
    parameter whose signature at its typical ``size`` is below UNEXCITED sigma is not excited by
    the plan at all (e.g. a J1 term under vertical loads only): neither visible nor biasing."""
    b, full, perp = _regress(jw, est, col)
    if full * size <= UNEXCITED:
        return {
            "effect": name,
            "detail": detail,
            "parameter": parameter,
            "unit": unit,
            "visible": False,
            "visible_share": 0.0,
            "excited": False,
            "detectable_magnitude": None,
            "reference_magnitude": None,
            "biases": [],
        }
    share = perp / full
    visible = share > VISIBLE_SHARE_MIN
    ref = math.sqrt(threshold) / full
    biases = []
    for j, coef in zip(np.flatnonzero(est), b):
        v, sd = float(final.values[j]), float(std[j])
        biases.append(
            {
                "parameter": final.names[j],
                "per_unit": float(coef),
                "at_reference_sigma": float(coef * ref / sd) if np.isfinite(sd) and sd > 0 else None,
                "at_reference_percent": float(100 * coef * ref / v) if v else None,
            }
        )
    biases.sort(key=lambda x: -abs(x["at_reference_sigma"] or 0.0))
    return {
        "effect": name,
        "detail": detail,
        "parameter": parameter,
        "unit": unit,
        "visible": bool(visible),
        "visible_share": float(share),
        "excited": True,
        "detectable_magnitude": float(math.sqrt(threshold) / perp) if visible else None,
        "reference_magnitude": float(ref),
        "biases": biases,
    }


def noncentrality(
    fm: AugmentedForward, white: Whitener, values: np.ndarray, f0w: np.ndarray, jb: np.ndarray
) -> float:
    """lambda of a hidden effect (module docstring, EXACT): the whitened noise-free signature the
    model ``fm`` (final model plus the effect) predicts at ``values`` against ``f0w`` (the final
    model's whitened prediction), off the estimated parameters' whitened columns ``jb``."""
    dp, _ = fm.evaluate(values, jacobian=False)
    _, perp = regress(jb, white.vec(dp) - f0w)
    return float(perp @ perp)


def _bracket(
    at, first: float, threshold: float, inside
) -> tuple[float | None, float | None, list, float | None]:
    """(lo, hi, lambdas met, the smallest size met without an equilibrium) for :func:`exact_detection`:
    lambda(lo) < T <= lambda(hi), walking EXACT_STEPS from the first-order size, down where it is
    named or has no equilibrium, up where it is not; hi None: never named within the walk."""
    l1 = at(first)
    seen, lost = ([] if l1 is None else [l1]), (first if l1 is None else None)
    if l1 is not None and l1 < threshold:  # up
        lo = first
        for k in EXACT_STEPS[1:]:
            m = k * first
            if not inside(m):
                break
            lk = at(m)
            if lk is None:
                return lo, None, seen, m
            seen.append(lk)
            if lk >= threshold:
                return lo, m, seen, lost
            lo = m
        return lo, None, seen, lost
    hi = None if l1 is None else first  # down
    for k in EXACT_STEPS[1:]:
        m = first / k
        lk = at(m)
        if lk is None:
            lost = m
            continue
        seen.append(lk)
        if lk < threshold:
            return m, hi, seen, lost
        hi = m
    return None, hi, seen, lost


def exact_detection(
    effect,
    fm: AugmentedForward,
    white: Whitener,
    final,
    jw: np.ndarray,
    est: np.ndarray,
    i: int,
    first: float,
    threshold: float,
) -> list[dict]:
    """Per sign within the prior's bounds, the size of the effect's ``i``-th parameter from which
    the plan names it on the exact statics (module docstring, EXACT), from its first-order
    detectable magnitude ``first``: {sign, magnitude (None: never), lambda_first_order (lambda at
    ``first``), lambda_max (the largest met), never_named, no_equilibrium_from (the smallest size
    met without a static equilibrium, else None)}. Sizes count from the prior's start, where the
    columns are taken."""
    start, lower, upper, _ = effect_priors(effect)
    ref = np.concatenate([final.values, start])  # the columns' point
    f0, _ = fm.evaluate(ref, jacobian=False)
    f0w = white.vec(f0)
    jb = jw[:, est]

    def lam(value: float) -> float | None:
        v = start.copy()
        v[i] = value
        try:  # from the columns' point, whose equilibrium is unique: never another size's branch
            fm.evaluate(ref, jacobian=False)
        except (ValueError, RuntimeError, np.linalg.LinAlgError):
            fm.forget()
        try:
            return noncentrality(fm, white, np.concatenate([final.values, v]), f0w, jb)
        except (ValueError, RuntimeError, np.linalg.LinAlgError):  # no equilibrium there
            return None

    out = []
    for sign in (1.0, -1.0):

        def inside(m: float, sign=sign) -> bool:
            return bool(lower[i] <= start[i] + sign * m <= upper[i])

        if not inside(first):
            continue

        def at(m: float, sign=sign) -> float | None:
            return lam(start[i] + sign * m)

        l1 = at(first)
        rec = {
            "sign": sign,
            "magnitude": first,
            "lambda_first_order": l1,
            "lambda_max": l1,
            "never_named": False,
            "no_equilibrium_from": None,
        }
        if l1 is None or abs(l1 / threshold - 1.0) > EXACT_RTOL:
            lo, hi, seen, lost = _bracket(at, first, threshold, inside)
            if hi is None and lo is not None and lost is not None and lost > lo:
                # short of T where the statics lose equilibrium: lambda rises steeply towards
                # the edge (a softening cubic), so the edge is bisected for a size named before it
                for _ in range(EXACT_BISECT):
                    mid = math.sqrt(lo * lost)
                    lm = at(mid)
                    if lm is None:
                        lost = mid
                        continue
                    seen.append(lm)
                    if lm >= threshold:
                        hi = mid
                        break
                    lo = mid
            rec.update(lambda_max=max(seen) if seen else None, no_equilibrium_from=lost)
            if hi is None:
                rec.update(magnitude=None, never_named=True)
            else:
                lo = hi / EXACT_STEPS[-1] if lo is None else lo  # named below the walk: its floor
                for _ in range(EXACT_BISECT):
                    mid = math.sqrt(lo * hi)
                    lm = at(mid)
                    if lm is not None and lm >= threshold:
                        hi = mid
                    else:
                        lo = mid
                rec["magnitude"] = hi
        out.append(rec)
    fm.evaluate(ref, jacobian=False)  # the model back at the columns' point
    return out


def with_exact(
    aliasing: list[dict], models: list[tuple], white: Whitener, final, jw: np.ndarray, n_candidates: int
) -> list[dict]:
    """``aliasing`` (:func:`aliasing_report`) with every visible parameter the deflections are not
    linear in checked on the exact statics (module docstring, EXACT): ``exact`` holds
    :func:`exact_detection`'s record per sign, ``detectable_magnitude`` becomes the smallest size
    named over the signs (``detectable_magnitude_first_order`` keeps the column's), None when no
    sign is ever named (``never_named``). models: (effect, its forward model, start) per effect."""
    from calbench.bench.model.effects import priors

    est = np.asarray(final.free, bool) | np.asarray(final.at_bound, bool)
    thr = lr_threshold(1, n_candidates)
    by = {(e.name, e.detail): (e, fm) for e, fm, _ in models}
    for a in aliasing:
        got = by.get((a["effect"], a["detail"]))
        if got is None or not a.get("visible") or a.get("detectable_magnitude") is None:
            continue
        e, fm = got
        i = list(e.param_names).index(a["parameter"])
        if priors(e)[i].linear:
            continue
        exact = exact_detection(e, fm, white, final, jw, est, i, a["detectable_magnitude"], thr)
        if not exact:  # no sign of the first-order size within the prior's bounds: as it was
            continue
        named = [r["magnitude"] for r in exact if r["magnitude"] is not None]
        a["exact"] = exact
        a["detectable_magnitude_first_order"] = a["detectable_magnitude"]
        a["detectable_magnitude"] = min(named) if named else None
        a["never_named"] = not named
    return aliasing


def effect_aliasing(
    effect, col_block: np.ndarray, final, jw: np.ndarray, est: np.ndarray, std: np.ndarray, threshold: float
) -> list[dict]:
    """Entries for each parameter of a library effect; col_block: its whitened columns (3M, k)."""
    size = effect_priors(effect)[3]
    return [
        alias_record(
            effect.name, effect.detail, n, u, col_block[:, i], final, jw, est, std, threshold, size[i]
        )
        for i, (n, u) in enumerate(zip(effect.param_names, effect.units))
    ]


def is_weight(load: Load) -> bool:
    """A hung weight: a vertical downward force and no moment."""
    f, m = np.asarray(load.force, float), np.asarray(load.moment, float)
    return bool(
        f[2] < 0
        and np.allclose(f[:2], 0.0, atol=1e-9 * abs(f[2]))
        and np.allclose(m, 0.0, atol=1e-9 * abs(f[2]))
    )


def load_scale_column(final, obs, white: Whitener) -> np.ndarray | None:
    """d (L^-1 dp) / d s for a relative scale s of every hung weight, at the final model;
    None when the plan hangs no weight."""
    robot = final.robot
    design = design_from_observations(robot, obs)
    if not any(is_weight(d.load) for d in design):
        return None
    effects = [e for e, _ in final.effect_params()]
    out = []
    for s in (1 + LOAD_STEP, 1 - LOAD_STEP):
        scaled = [
            replace(d, load=Load(d.load.force * s, d.load.moment * s, d.load.site))
            if is_weight(d.load)
            else d
            for d in design
        ]
        fm = AugmentedForward(robot, scaled, effects, final.model.readings)
        dp, _ = fm.evaluate(final.values, jacobian=False)
        out.append(white.vec(dp))
    final.model.write(final.values)
    return (out[0] - out[1]) / (2 * LOAD_STEP)


def aliasing_report(
    final, jw: np.ndarray, std: np.ndarray, columns: list[tuple], obs, white: Whitener, n_candidates: int
) -> list[dict]:
    """Aliasing of every (effect, its whitened columns at the final model) in ``columns`` and of
    load_scale (per 1 % of the hung weights' mass). std: the final parameters' std (NaN where
    not determined)."""
    est = np.asarray(final.free, bool) | np.asarray(final.at_bound, bool)
    thr = lr_threshold(1, n_candidates)
    out = []
    for effect, block in columns:
        out += effect_aliasing(effect, block, final, jw, est, std, thr)
    try:
        col = load_scale_column(final, obs, white)
    except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:  # e.g. a near-rigid spring's statics
        out.append(
            {
                "effect": "load_scale",
                "detail": "hung weights",
                "parameter": "scale",
                "unit": "1",
                "error": f"the scaled-load statics failed: {exc}",
            }
        )
        col = None
    if col is not None:
        rec = alias_record("load_scale", "hung weights", "scale", "1", col, final, jw, est, std, thr, 1.0)
        for b in rec["biases"]:
            b["per_percent_mass"] = 0.01 * b["per_unit"]
            b["per_percent_mass_relative_percent"] = (
                (100 * 0.01 * b["per_unit"] / float(final.values[final.names.index(b["parameter"])]))
                if final.values[final.names.index(b["parameter"])]
                else None
            )
        rec["note"] = (
            "the payload mass is known only to +-x %: deflections alone never tell a mass error "
            "from the compliances; a mass x % high biases them as listed per per cent"
        )
        out.append(rec)
    return out


__all__ = [
    "regress",
    "VISIBLE_SHARE_MIN",
    "alias_record",
    "effect_aliasing",
    "load_scale_column",
    "aliasing_report",
    "exact_detection",
    "is_weight",
    "noncentrality",
    "with_exact",
]
