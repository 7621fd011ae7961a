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
    "is_weight",
]
