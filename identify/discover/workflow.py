"""`calbench discover`: where the model and the measurements disagree, which physics is missing.

    calbench discover LOG.mcap --model ROBOT.xml [--json OUT.json] [--out-model AUGMENTED.xml]
                               [--plot RESIDUALS.png]

1. FIT the user's model as it is, exactly as `calbench identify` fits it (identify/discover/basefit.py:
   the one-step estimator, its parameter set and weighting; the same chi2 and RMS), and take the
   residuals (measured minus predicted deflections).
2. WHERE they disagree: chi2 against the tracker's own noise, per pose, per reflector, per world
   direction, and the correlation of each pose's misfit with what varies over the plan
   (identify/discover/stats.py), in words and numbers.
3. NAME the missing effect: every candidate of the library (identify/discover/fit.py: the
   effects bench/model/effects/ registers for discovery, with their structural options) is added to
   the model and fitted jointly with the base parameters on the exact statics, from several
   starts (identify/discover/search.py), and tested by its likelihood ratio at the family-wise
   level on every run (identify/discover/decide.py: no global chi2 gate). The best accepted
   candidate is added and the loop repeats while a candidate is still accepted; a near-tie that
   the next round does not resolve is `ambiguous` (both named in ``ambiguous``); a residual that
   is not noise (chi2 p below decide.py's ALPHA_MISFIT) with no candidate accepted is
   `unexplained`.
4. ADD it: the augmented MJCF (every parameter of the final joint refit in it), loadable with
   MuJoCo; the text prints the same final values (a step's values when it was named are kept
   as ``parameters_at_naming``).
5. SAY what the fit does not tell: honest std and the determined combinations where only a
   combination is seen (identify/discover/uncertainty.py), and the aliasing of every library
   effect not named plus ``load_scale`` (identify/discover/aliasing.py).
6. SHOW the gap shrink (identify/discover/narrative.py): RMS before/after against what noise alone
   leaves, a PNG of per-pose residuals, an identify-style JSON for `calbench view --identified`.

Only what identify reads is read: the log without truth (no /truth/ topic, no ground_truth
record) and the MJCF for geometry (its stiffness values are overwritten by the estimates).
Nothing here knows about any particular effect. :func:`discover_observations` is the whole
search on in-memory observations (no file), for benchmarks and notebooks.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calbench.bench.core import sink, write_text
from calbench.bench.log import read_log
from calbench.bench.model import Robot, log_robot, set_spec_names, spec_names
from calbench.bench.model.effects import augmented_xml, load_spec, priors
from calbench.bench.view import Discovery, write_discovery_recording
from calbench.identify.core import Observations, Whitener, check_sites, from_log

from .aliasing import aliasing_report, with_exact
from .basefit import base_fit, base_record, hold_mask
from .decide import (
    ALPHA_DISCOVERY,
    ALPHA_EFFECT,
    ALPHA_MISFIT,
    AMBIGUOUS_BIC,
    AMBIGUOUS_SPREAD,
    MIN_EXPLAINED,
    compare,
    lr_threshold,
    near_ties,
    score_p,
    score_statistic,
)
from .exposure import exposure_report, with_exposure
from .fit import Fit, build, effect_priors, fit_augmented, label, library, whitened
from .narrative import clean, plot_residuals, story, view_report
from .search import fit_candidate, polish, warm_point
from .stats import ALPHA_FIT, chi2_p, diagnose, expected_rms, rms
from .uncertainty import (
    MAX_RELATIVE_STD,
    checked,
    determination,
    self_check,
    split_by_ties,
    unexplained_misfit,
)

MAX_ROUNDS = 3
UNEXPLAINED = "unexplained"
AMBIGUOUS = "ambiguous"
HINT_P = 0.01  # a candidate below the family-wise level but at this nominal p is a hint
POLISH_SHARE = 0.5  # a candidate whose LR reaches this share of its threshold is fitted to convergence


@dataclass
class Candidate:
    """One candidate of a round: its record, fit (None: not applicable) and statistics."""

    record: dict
    fit: Fit | None = None
    stats: dict | None = None

    @property
    def label(self) -> str:
        return self.record["effect"] + (f"[{self.record['detail']}]" if self.record["detail"] else "")


def run_round(
    src, obs, white, current: Fit, hold_base: np.ndarray, fresh: np.ndarray, lib, progress=None, name=""
) -> list[Candidate]:
    """Fit and test every library candidate not yet in the model (``progress``: a
    bench.core.ProgressSink told of each, the round called ``name``)."""
    done = {label(e) for e, _ in current.effect_params()}
    cands = [e for e in lib if label(e) not in done]
    bar = sink(progress)
    bar.start(len(cands), name)
    out = []
    for e in cands:
        c = Candidate({"effect": e.name, "detail": e.detail, "score": None})
        try:
            c.fit = fit_candidate(src, obs, white, current, hold_base, e, fresh)
        except (ValueError, RuntimeError, NotImplementedError, np.linalg.LinAlgError) as exc:
            c.record["error"] = str(exc)
            out.append(c)
            bar.update(f"{name}: {label(e)}")
            continue
        # at the current model, with the Jacobian the fit started from: the fit does not move it
        score = score_statistic(current, e, c.fit.extra.get("warm_jw"), white)
        st = compare(current, c.fit, len(cands), score)
        if st["k"] > 0 and st["lr"] >= POLISH_SHARE * lr_threshold(st["k"], len(cands)):
            c.fit = polish(c.fit, obs, white)  # near or past its threshold: the exact LR
            st = compare(current, c.fit, len(cands), score)
        c.stats = st
        c.record.update(
            {
                "score": st["bic_gain"],
                "lr": st["lr"],
                "k": st["k"],
                "p_lr": st["p_lr"],
                **{k: st[k] for k in ("score_statistic", "score_rank", "p_score") if k in st},
                "alpha": st["alpha"],
                "explained": st["explained"],
                "p_fit": st["p_fit"],
                "significant": st["significant"],
                "accepted": st["accept"],
                "rms_after": rms(c.fit.residual),
                "start": c.fit.extra.get("start"),
                "evaluations": c.fit.extra.get("evaluations"),
                "seconds": c.fit.seconds,
            }
        )
        out.append(c)
        bar.update(f"{name}: {label(e)}")
    return out


def _params(
    f: Fit, det=None, lo: int = 0, hi: int | None = None, split: dict | None = None, check: dict | None = None
) -> list[dict]:
    """Parameter records of f[lo:hi] with the honest std of ``det`` (uncertainty.py); ``split``:
    the values under each tied candidate where an `ambiguous` verdict leaves one undetermined;
    ``check``: the self-check (uncertainty.self_check), each checked parameter's line."""
    split = split or {}
    checked_ = (check or {}).get("parameters", {})
    det = determination(f, f.extra["jw"]) if det is None else det
    hi = f.values.size if hi is None else hi
    profile = getattr(det, "profile", {})
    return [
        {
            "name": f.names[i],
            "unit": f.units[i],
            "estimate": float(f.values[i]),
            "std": float(det.std[i]) if det.determined[i] else None,
            "determined": bool(det.determined[i]),
            **({"chi2_rise_at_2_fisher_std": profile[i]} if i in profile else {}),
            **({"valley": det.valley[i]} if i in det.valley else {}),
            **({"under_tied_candidates": split[i]} if i in split else {}),
            **({"self_check": checked_[f.names[i]]} if f.names[i] in checked_ else {}),
        }
        for i in range(lo, hi)
    ]


def _effect_params(f: Fit, det, effect) -> list[dict]:
    """The records of ``effect``'s parameters in f, named as the effect names them."""
    for e, s in f.effect_slices():
        if e is effect:
            return [dict(r, name=pn) for r, pn in zip(_params(f, det, s.start, s.stop), e.param_names)]
    raise KeyError(effect.name)


def _step(c: Candidate, before: Fit, obs) -> dict:
    f = c.fit
    det = determination(f, f.extra["jw"])
    eff = f.effects[-1]
    return {
        "effect": eff.name,
        "detail": eff.detail,
        "rms_before": rms(before.residual),
        "rms_after": rms(f.residual),
        "noise_rms_before": expected_rms(obs.cov, before.dof, before.n_res),
        "noise_rms_after": expected_rms(obs.cov, f.dof, f.n_res),
        "parameters_at_naming": _effect_params(f, det, eff),
        "start": f.extra.get("start"),
        **{k: c.stats[k] for k in ("lr", "k", "p_lr", "alpha", "bic_gain", "explained", "p_fit")},
    }


def _ties_resolved(
    src, obs, white, with_best: Fit, hold_base, fresh, ties: list[dict], cands: list[Candidate], n_tests: int
) -> list[dict]:
    """The ties that stay ties: a tied candidate still accepted once the best is in the model
    explains something else (both effects are there, the next round names it) and is dropped."""
    by_label = {c.label: c for c in cands}
    keep = [ties[0]]
    for t in ties[1:]:
        eff = by_label[t["candidate"]].fit.effects[-1]
        try:
            both = polish(fit_candidate(src, obs, white, with_best, hold_base, eff, fresh), obs, white)
        except (ValueError, RuntimeError, NotImplementedError, np.linalg.LinAlgError):
            keep.append(t)
            continue
        st = compare(
            with_best, both, n_tests, score_statistic(with_best, eff, both.extra.get("warm_jw"), white)
        )
        t["lr_on_top_of_best"] = st["lr"]
        if not st["accept"]:
            keep.append(t)
    return keep if len(keep) > 1 else []


def first_round_events(obs: Observations, src) -> dict:
    """The first round's events that any verdict of :func:`discover_observations` needs
    (decide.py): a candidate whose first-order score passes its Bonferroni level, a candidate
    without a first-order test (a new spring) whose LR does, or the user's model's chi2 below
    ALPHA_MISFIT. An effect is named only with its LR and its score past the level, `ambiguous`
    only with one named, `unexplained` only with the misfit, so where ``event`` is False,
    discovery names nothing: on campaigns with nothing hidden the share of events bounds the
    false-alarm rate from above, for the user's model's fit and one candidate fit per spring
    instead of every candidate's (benchmarks/discover_null_bench.py --first-order). Returns
    {event, p_score (by candidate), p_lr_no_first_order (by candidate), p_before, alpha}."""
    white = Whitener.from_observations(obs)
    base = base_fit(src, obs, white)
    lib = library(base.robot)
    alpha = ALPHA_EFFECT / max(len(lib), 1)
    p_score, p_lr = {}, {}
    for e in lib:
        try:
            if all(p.first_order for p in priors(e)):
                w = warm_point(src, obs, white, base, e)
                s, rank = score_statistic(base, e, w.jw, white)
                p_score[label(e)] = score_p(s, rank)
                continue
            f = fit_candidate(src, obs, white, base, hold_mask(base), e, base.extra["fresh_start"])
        except (ValueError, RuntimeError, NotImplementedError, np.linalg.LinAlgError):
            continue  # run_round records the error: no statistic, no verdict
        st = compare(base, f, len(lib))
        if st["k"] > 0 and st["lr"] >= POLISH_SHARE * lr_threshold(st["k"], len(lib)):
            st = compare(base, polish(f, obs, white), len(lib))
        p_lr[label(e)] = st["p_lr"]
    p_before = chi2_p(base.chi2, base.dof)
    event = (
        min(p_score.values(), default=1.0) < alpha
        or min(p_lr.values(), default=1.0) < alpha
        or p_before < ALPHA_MISFIT
    )
    return {
        "event": bool(event),
        "p_score": p_score,
        "p_lr_no_first_order": p_lr,
        "p_before": p_before,
        "alpha": alpha,
    }


def discover_observations(
    obs: Observations, src, *, max_rounds: int = MAX_ROUNDS, with_base: bool = False, progress=None
):
    """The whole search on observations (no file read or written): the report (without the
    log, model, plot and file entries) and the final fit (and the user's model's fit, with
    ``with_base``). src: the user's MJCF (path or text); ``progress``: told of each candidate
    tested, round by round (bench.core.ProgressSink)."""
    t0 = time.perf_counter()
    white = Whitener.from_observations(obs)
    sigma = float(obs.noise_sigma)
    base = base_fit(src, obs, white)
    lib = library(base.robot)
    hold_base = hold_mask(base)
    fresh = base.extra["fresh_start"]
    current = base
    named, steps, rounds, hints, ambiguous = [], [], [], [], []
    tie_fits: list[tuple[str, Fit]] = []
    last: list[Candidate] = []
    for rnd in range(max_rounds):
        cands = run_round(src, obs, white, current, hold_base, fresh, lib, progress, f"round {rnd + 1}")
        last = cands
        ok = [c for c in cands if c.stats is not None and c.stats["accept"]]
        rounds.append(
            {
                "round": rnd + 1,
                "rms_before": rms(current.residual),
                "chi2_before": current.chi2,
                "candidates": sorted(
                    [c.record for c in cands],
                    key=lambda r: -(r["score"] if r["score"] is not None else -np.inf),
                ),
            }
        )
        if not ok:
            hints = [
                {
                    k: c.record[k]
                    for k in (
                        "effect",
                        "detail",
                        "lr",
                        "k",
                        "p_lr",
                        "alpha",
                        "score",
                        "score_statistic",
                        "p_score",
                    )
                    if k in c.record
                }
                for c in cands
                if c.stats is not None and c.stats["k"] > 0 and c.stats["p_lr"] < HINT_P
            ]
            if chi2_p(current.chi2, current.dof) < ALPHA_MISFIT:
                named.append(UNEXPLAINED)
                steps.append(
                    {
                        "effect": UNEXPLAINED,
                        "detail": "no candidate explains the remaining misfit",
                        "rms_before": rms(current.residual),
                        "rms_after": rms(current.residual),
                    }
                )
            break
        best = max(ok, key=lambda c: c.stats["bic_gain"])
        ties = near_ties(
            (best.label, best.fit, best.stats),
            [(c.label, c.fit, c.stats) for c in cands if c is not best and c.fit is not None],
        )
        if ties:
            ties = _ties_resolved(src, obs, white, best.fit, hold_base, fresh, ties, cands, len(cands))
        if ties:
            by_label = {c.label: c.fit for c in cands}
            tie_fits = [(t["candidate"], by_label[t["candidate"]]) for t in ties]
            ambiguous.append({"round": rnd + 1, "candidates": ties})
            named.append(AMBIGUOUS)
            steps.append(
                {
                    "effect": AMBIGUOUS,
                    "detail": " or ".join(t["candidate"] for t in ties),
                    "rms_before": rms(current.residual),
                    "rms_after": rms(current.residual),
                    "candidates": ties,
                }
            )
            rounds[-1]["ambiguous"] = [t["candidate"] for t in ties]
            break
        named.append(best.fit.effects[-1].name)
        steps.append(_step(best, current, obs))
        rounds[-1]["named"] = best.label
        current = best.fit
    final = current
    det = checked(final, obs, white)  # base and effect parameters together
    split = {}
    if tie_fits:  # ambiguous: what the tied candidates disagree on is not determined under either
        split = split_by_ties(final, det, [(lab, f, checked(f, obs, white)) for lab, f in tie_fits])
    check = self_check(final, obs, white, det)  # what fails is not determined
    misfit = unexplained_misfit(final, det, final.chi2, final.dof) if UNEXPLAINED in named else None
    for s, (e, _) in zip(
        [s for s in steps if s["effect"] not in (UNEXPLAINED, AMBIGUOUS)], final.effect_params()
    ):
        s["parameters"] = _effect_params(final, det, e)  # the final joint refit: as in the MJCF
    fresh_cols = [
        (c.fit.effects[-1], c.fit.extra["warm_jw"][:, -len(c.fit.effects[-1].param_names) :])
        for c in last
        if c.fit is not None and c.fit.extra.get("warm_of") is final
    ]
    if len(fresh_cols) < sum(1 for c in last if c.fit is not None):
        fresh_cols = alias_columns(src, obs, white, final, lib)
    aliasing = aliasing_report(final, final.extra["jw"], det.std, fresh_cols, obs, white, max(len(last), 1))
    own = {label(c.fit.effects[-1]) for c in last if c.fit is not None and owns_base(c.fit)}
    exposed = [(e, b) for e, b in fresh_cols if label(e) not in own]
    every = _effect_models(src, obs, final, [e for e, _ in fresh_cols])  # each built once
    aliasing = with_exact(aliasing, every, white, final, final.extra["jw"], max(len(last), 1))
    models = [m for m in every if label(m[0]) not in own]
    exposure = exposure_report(
        final,
        final.extra["jw"],
        det.std,
        exposed,
        len(last) or 1,
        region_columns(src, obs, white, final, [e for e, _ in exposed], models),
        refit_response(src, obs, white, final, models),
        fitted_ends(final, [c for c in last if c.label not in own]),
        candidate_profiles(obs, white, final, [c for c in last if c.label not in own]),
        springs_of(final),
        sprung_joint_effects(final, [e for e, _ in exposed]),
    )
    final.model.evaluate(final.values, jacobian=False)  # the model back at the estimate
    diag_before = diagnose(base, obs, sigma)
    diag_after = diagnose(final, obs, sigma) if final is not base else diag_before
    rep = {
        "named_effects": named,
        "steps": steps,
        "base_fit": base_record(base),
        "rms_before": rms(base.residual),
        "rms_after": rms(final.residual),
        "noise_sigma": sigma,
        "candidates": rounds[0]["candidates"] if rounds else [],
        "ambiguous": ambiguous,
        "aliasing": aliasing,
        "noise_rms_before": expected_rms(obs.cov, base.dof, base.n_res),
        "noise_rms_after": expected_rms(obs.cov, final.dof, final.n_res),
        "chi2_before": base.chi2,
        "dof_before": base.dof,
        "p_before": chi2_p(base.chi2, base.dof),
        "chi2_after": final.chi2,
        "dof_after": final.dof,
        "p_after": chi2_p(final.chi2, final.dof),
        "decision_rule": {
            "alpha_discovery": ALPHA_DISCOVERY,
            "alpha_effect_familywise": ALPHA_EFFECT,
            "bonferroni_over": "the round's candidates",
            "first_order_confirmation": "Rao's score at the current model passes alpha too",
            "global_gate": None,
            "alpha_misfit": ALPHA_MISFIT,
            "alpha_fit": ALPHA_FIT,
            "min_explained_share": MIN_EXPLAINED,
            "score": "BIC gain = LR - k ln n",
            "ambiguous_bic": AMBIGUOUS_BIC,
            "ambiguous_lr_spread": AMBIGUOUS_SPREAD,
            "max_relative_std": MAX_RELATIVE_STD,
        },
        "where_before": diag_before,
        "where_after": diag_after,
        "rounds": rounds,
        "hints": hints,
        "parameters": with_exposure(_params(final, det, split=split, check=check), exposure),
        "self_check": check,
        **({"unexplained_misfit": misfit} if misfit else {}),
        "combinations": det.combinations,
        "combinations_not_quadratic": det.rejected,
        "n_observations": obs.n_obs(),
        "n_poses": len(obs.poses),
        "per_pose": [
            {"pose": a["pose"], "rms_before": a["rms"], "rms_after": b["rms"]}
            for a, b in zip(diag_before["per_pose"], diag_after["per_pose"])
        ],
        "evaluations": int(
            sum(c["evaluations"] or 0 for r in rounds for c in r["candidates"] if "evaluations" in c)
        ),
        "seconds": time.perf_counter() - t0,
    }
    return (rep, final, base) if with_base else (rep, final)


def fitted_ends(final: Fit, cands: list[Candidate]) -> list[tuple[str, np.ndarray]]:
    """(label, the values of ``final``'s parameters) of every start of every candidate fitted on
    top of ``final`` whose fit explains the readings at least as well as ``final`` (and of each
    candidate's best fit): truths with the effect that the data favour over the model
    (identify/discover/exposure.py, FITTED)."""
    out = []
    n = final.values.size
    for c in cands:
        if c.fit is None or c.fit.extra.get("warm_of") is not final:
            continue
        out.append((c.label, c.fit.values[:n]))
        out += [(c.label, v[:n]) for chi2, v in c.fit.extra.get("ends", []) if chi2 <= final.chi2]
    return out


def springs_of(f: Fit) -> np.ndarray:
    """(P,) bool: the compensator springs' stiffness and free length among ``f``'s parameters."""
    out = np.zeros(f.values.size, bool)
    out[f.robot.layout.spring_index] = True
    return out


def sprung_joint_effects(f: Fit, effects: list) -> dict[str, frozenset[int]]:
    """{label: (the index of that joint's compliance,)} for each of ``effects`` acting on a joint
    a compensator spring spans (exposure.py's SPRUNG JOINT)."""
    joints = set()
    for c in range(len(f.robot.layout.compensators)):
        try:
            joints.add(f.robot.compensator_joint(c) + 1)
        except ValueError:
            continue  # a spring across more than one hinge: no single joint to name
    return {
        label(e): frozenset({e.options["joint"] - 1}) for e in effects if e.options.get("joint") in joints
    }


def candidate_profiles(obs, white, final: Fit, cands: list[Candidate]):
    """(label, parameter index, its std, chi2 level) -> exposure.py's :func:`profile_reach` in
    that candidate's fit on top of ``final`` (None: no such fit)."""
    from .exposure import PROFILE_ITER, profile_reach

    by = {c.label: c.fit for c in cands if c.fit is not None and c.fit.extra.get("warm_of") is final}

    def reach(lab: str, i: int, sigma: float, thr: float) -> float | None:
        f = by.get(lab)
        if f is None:
            return None
        lo, hi, hold = f.extra["bounds"]

        def held(v: np.ndarray):
            h = np.array(hold, bool).copy()
            h[i] = True
            g = fit_augmented(f.model, obs.dp, white, v, lo, hi, h, max_iter=PROFILE_ITER)
            return g.chi2, g.values

        return profile_reach(held, f.values, f.chi2, i, float(final.values[i]), sigma, thr, lo[i], hi[i])

    return reach


def base_exposure(src, obs: Observations, std: np.ndarray) -> list[dict]:
    """The exposure (identify/discover/exposure.py) of the user's model's parameters, fitted as
    identify fits them (basefit.py), to every library effect that owns no base quantity; std:
    the parameters' reported std (identify's), NaN where not determined. For `identify --exposure`."""
    white = Whitener.from_observations(obs)
    base = base_fit(src, obs, white)
    lib = library(base.robot)
    cols = []
    for e, block in alias_columns(src, obs, white, base, lib):
        _, fm = build(src, [(e, effect_priors(e)[0])], obs)
        if not fm._base_overridden(np.concatenate([base.values, effect_priors(e)[0]])).any():
            cols.append((e, block))
    models = _effect_models(src, obs, base, [e for e, _ in cols])
    return exposure_report(
        base,
        base.extra["jw"],
        np.asarray(std, float),
        cols,
        len(lib) or 1,
        region_columns(src, obs, white, base, [e for e, _ in cols], models),
        refit_response(src, obs, white, base, models),
    )


def _effect_models(src, obs, final: Fit, effects: list) -> list[tuple]:
    """(effect, ``final``'s model with it added at its prior start, that start) for each of
    ``effects`` that builds (each model built once)."""
    models = []
    for e in effects:
        start = effect_priors(e)[0]
        try:
            models.append((e, build(src, final.effect_params() + [(e, start)], obs)[1], start))
        except (ValueError, RuntimeError, NotImplementedError, np.linalg.LinAlgError):
            continue
    return models


def region_columns(src, obs, white, final: Fit, effects: list, models: list | None = None):
    """theta -> (chi2, whitened Jacobian of ``final``'s model, [(effect, its whitened columns)])
    at theta, for each of ``effects`` added to ``final``'s model at its prior start (each model
    built once; ``models``: :func:`_effect_models`' if built): the exposure's evaluation away from
    the estimate (exposure.py's region)."""
    models = _effect_models(src, obs, final, effects) if models is None else models
    yw = white.vec(obs.dp)

    def at(theta: np.ndarray):
        fw, jw = whitened(final.model, white, theta)
        cols = []
        for e, fm, start in models:
            try:
                cols.append((e, whitened(fm, white, np.concatenate([theta, start]))[1][:, -start.size :]))
            except (ValueError, RuntimeError, NotImplementedError, np.linalg.LinAlgError):
                continue  # no equilibrium with this effect there: the others still count
        return float(np.sum((yw - fw) ** 2)), jw, cols

    return at


def refit_response(src, obs, white, final: Fit, models: list):
    """(effect, theta, d) -> (``final``'s model refitted from theta to the noise-free readings
    ``final``'s model plus the effect at size d predict at theta, the chi2 it leaves): the
    exposure's nonlinear worst case (exposure.py's SIZE). The effect's part is differenced
    against the effect at its prior start (where its columns are taken: a compliance's start is
    not 0), so d = 0 is the model itself (chi2 0). ``models``: :func:`_effect_models`'.
    The refits run on their own copy of ``final``'s model, and a model whose statics failed on
    the way (no equilibrium far from the estimate) is rebuilt: the forward models keep each
    pose's last equilibrium as the next one's start, and one left half-updated broke the
    estimate's own evaluation afterwards (FANUC with its compensator). Raises ValueError for an
    effect without a model, and what the statics raise."""
    from calbench.identify.core import levenberg_marquardt

    from .fit import COST_TOL, DISCOVER_RANK_TOL
    from .uncertainty import REPLICA_STEP_TOL

    by = {label(e): (e, fm, start) for e, fm, start in models}
    own = [build(src, final.effect_params(), obs)[1]]
    lo, hi, hold = final.extra["bounds"]
    scale = np.where(np.abs(final.values) > 0, np.abs(final.values), final.model._fd_size)

    def respond(effect, theta: np.ndarray, d: np.ndarray):
        if label(effect) not in by:
            raise ValueError(f"no model with {label(effect)}")
        e, fm, start = by[label(effect)]
        try:
            f, _ = fm.evaluate(np.concatenate([theta, np.asarray(d, float) + start]), jacobian=False)
            f0, _ = fm.evaluate(np.concatenate([theta, start]), jacobian=False)
            f1, _ = own[0].evaluate(theta, jacobian=False)
            sol = levenberg_marquardt(
                lambda th: whitened(own[0], white, th),
                white.vec(f1 + (f - f0)),
                np.asarray(theta, float),
                scale,
                lower=lo,
                upper=hi,
                hold=hold,
                step_tol=REPLICA_STEP_TOL,
                cost_tol=COST_TOL * 1e-3,
                rank_tol=DISCOVER_RANK_TOL,
                max_iter=30,
            )
        except (ValueError, RuntimeError, np.linalg.LinAlgError):
            own[0] = build(src, final.effect_params(), obs)[1]
            by[label(effect)] = (e, build(src, final.effect_params() + [(e, start)], obs)[1], start)
            raise
        return sol.x, float(sol.cost)

    return respond


def owns_base(f: Fit) -> bool:
    """Whether the last effect of a candidate fit writes over a base quantity (the compensator
    candidate on a model that has one): it is the base parameters again, not an effect they absorb."""
    return bool(f.model._base_overridden(f.values).any())


def alias_columns(src, obs, white, final: Fit, lib) -> list[tuple]:
    """(effect, its whitened columns at the final model) for every library effect not in it."""
    done = {label(e) for e, _ in final.effect_params()}
    out = []
    for e in lib:
        if label(e) in done:
            continue
        start = effect_priors(e)[0]
        try:
            _, fm = build(src, final.effect_params() + [(e, start)], obs)
            _, jw = whitened(fm, white, np.concatenate([final.values, start]))
        except (ValueError, RuntimeError, NotImplementedError, np.linalg.LinAlgError):
            continue
        out.append((e, jw[:, -start.size :]))
    return out


def augmented_mjcf(src, fitted: Fit) -> str:
    """The user's MJCF with the identified base parameters and every effect written in
    (measurement-side effects are named in its header only: they change no part of the robot)."""
    spec = load_spec(Path(src) if isinstance(src, Path) else src)
    rb: Robot = fitted.robot
    lay = rb.layout
    k = fitted.values[lay.compliance]
    for name, ki in zip(rb.description.actuated, k):
        j = spec.joint(name)
        if j is not None:
            j.stiffness[0] = 1.0 / ki
    for c, name in enumerate(lay.compensators):
        t = spec.tendon(name)
        kc, s0 = lay.stiffness_index[c], lay.preload_index[c]
        if t is not None and fitted.free[kc]:
            t.stiffness[0] = fitted.values[kc]
            t.springlength = [fitted.values[s0], fitted.values[s0]]
    effects = fitted.effect_params()
    tendons = {t.name for t in spec.tendons}
    for e, p in effects:
        e.apply(spec, p)
    # a spring tendon an effect added (the compensator) is a compensator of the augmented robot
    added = [t.name for t in spec.tendons if t.name not in tendons]
    if added:
        set_spec_names(spec, "compensators", spec_names(spec, "compensators") + added)
    return augmented_xml(spec, effects)


def write_view(log_path, rrd, base: Fit, final: Fit, obs, rep: dict) -> Path:
    """The Rerun recording of the discovery (bench/view/recording.py, ``write_discovery_recording``): on
    the robot, every reflector's residual with the user's model and with the named effects,
    against the noise, per pose; the verdict; the final model's parameters."""
    named = tuple(
        s["effect"]
        + (f" ({s['detail']})" if s["effect"] not in (UNEXPLAINED, AMBIGUOUS) and s["detail"] else "")
        for s in rep["steps"]
    )
    disc = Discovery(
        view_report(base, obs, rep, "before", _params(base)), view_report(final, obs, rep), named
    )
    write_discovery_recording(log_path, rrd, disc)
    return Path(rrd)


def discover(
    log_path,
    model=None,
    *,
    out_model=None,
    plot=None,
    view_json=None,
    view_rrd=None,
    max_rounds: int = MAX_ROUNDS,
    progress=None,
) -> dict:
    """Run the whole workflow on a log; returns the JSON report (docs/contract.md keys plus
    extras) and writes the augmented MJCF (when an effect is named), the plot, the view JSON and,
    with ``view_rrd``, the Rerun recording of where the model disagreed (:func:`write_view`);
    ``progress``: as :func:`discover_observations`'s."""
    t0 = time.perf_counter()
    log_path = Path(log_path)
    log = read_log(log_path)  # no truth
    obs = from_log(log)
    robot = log_robot(log, model)  # validates the MJCF (InputError)
    check_sites(robot, obs, model or log.path)
    src = Path(model) if model is not None else log.mjcf_text
    rep, final, base = discover_observations(
        obs, src, max_rounds=max_rounds, with_base=True, progress=progress
    )
    aug_path = None
    if final.effects:
        aug_path = Path(out_model) if out_model else log_path.with_name(log_path.stem + ".augmented.xml")
        write_text(aug_path, augmented_mjcf(src, final))
        Robot.from_file(aug_path)  # must load
    rep.update(
        {
            "augmented_model": str(aug_path) if aug_path else None,
            "log": str(log_path),
            "model": str(model) if model is not None else "MJCF from the log",
            "n_poses_planned": log.n_poses_planned,
            "lost_poses": log.lost_poses,
            "truncated": log.truncated,
            "completeness": log.completeness(),
            "seconds": time.perf_counter() - t0,
        }
    )
    if plot:
        rep["plot"] = str(plot_residuals(rep, plot))
    if view_json:
        write_text(view_json, view_report(final, obs, rep).to_json())
        rep["view_json"] = str(view_json)
    if view_rrd:
        rep["view_rrd"] = str(write_view(log_path, view_rrd, base, final, obs, rep))
    return rep


__all__ = [
    "discover",
    "discover_observations",
    "first_round_events",
    "base_fit",
    "run_round",
    "story",
    "augmented_mjcf",
    "plot_residuals",
    "view_report",
    "write_view",
    "clean",
    "UNEXPLAINED",
    "AMBIGUOUS",
    "alias_columns",
    "base_exposure",
]
