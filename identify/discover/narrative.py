"""Discovery, part 6: what a person reads: the story (text), the per-pose plot, the view report.

Everything here reads the report dict of identify/discover/workflow.py, so the text, the JSON
and the augmented MJCF say the same numbers: each named effect's parameters are the FINAL joint
refit's (``steps[i]["parameters"]``), the values written into the augmented MJCF.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from calbench.bench.core import atomic_path
from calbench.bench.log import IdentificationReport, ObservationFit, ParameterEstimate

from .stats import rms

UM = 1e6


def _num(x):
    return None if x is None or not np.isfinite(x) else float(x)


def view_report(
    f, obs, rep: dict, stage: str = "after", parameters: list[dict] | None = None
) -> IdentificationReport:
    """A fitted model as an identification report, for `calbench view --identified`: its
    parameters (base and effect; ``identifiable`` = determined by the data; the report's final
    ones unless ``parameters`` is given) and the measured, predicted and residual deflection of
    every observation. ``stage``: "after" (the final model, with the named effects) or "before"
    (the user's model as it is)."""
    params = tuple(
        ParameterEstimate(p["name"], p["unit"], p["estimate"], p["std"], identifiable=p["determined"])
        for p in (rep["parameters"] if parameters is None else parameters)
    )
    fits = tuple(
        ObservationFit(
            int(pose),
            r,
            predicted=tuple(float(x) for x in f.predicted[i]),
            measured=tuple(float(x) for x in obs.dp[i]),
            residual=tuple(float(x) for x in f.residual[i]),
        )
        for i, (pose, r) in enumerate(obs.labels)
    )
    method = (
        "user model as is" if stage == "before" else (" + ".join(rep["named_effects"]) or "user model as is")
    )
    return IdentificationReport(
        method="discover: " + method,
        parameters=params,
        residual_rms=rep[f"rms_{stage}"],
        noise_sigma=rep["noise_sigma"],
        chi2_per_dof=f.chi2 / f.dof if f.dof > 0 else None,
        chi2=float(f.chi2),
        dof=int(f.dof),
        expected_residual_rms=rep[f"noise_rms_{stage}"],
        whitened_residual_rms=rms(f.residual_w),
        covariance=tuple(tuple(_num(x) for x in row) for row in f.cov),
        log=rep["log"],
        model=rep["model"],
        n_poses_planned=obs.n_planned,
        n_poses_used=len(obs.poses),
        lost_poses=tuple(obs.lost_poses),
        truncated=bool(obs.truncated),
        n_observations=obs.n_obs(),
        seconds=rep["seconds"],
        observations=fits,
        details={
            "converged": bool(f.converged),
            "iterations": int(f.iterations),
            "evaluations": int(f.evaluations),
        },
    )


def plot_residuals(rep: dict, path) -> Path:
    """Per-pose residual RMS before and after, against what noise alone leaves (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    pp = rep["per_pose"]
    x = np.arange(len(pp))
    before = np.array([p["rms_before"] for p in pp]) * UM
    after = np.array([p["rms_after"] for p in pp]) * UM
    fig, ax = plt.subplots(figsize=(9, 4.2), dpi=110)
    ax.bar(x - 0.2, before, 0.4, label=f"user model (RMS {rep['rms_before'] * UM:.1f} µm)", color="#d62728")
    ax.bar(
        x + 0.2,
        after,
        0.4,
        color="#1f77b4",
        label=("+ " + " + ".join(rep["named_effects"]) if rep["named_effects"] else "no effect named")
        + f" (RMS {rep['rms_after'] * UM:.1f} µm)",
    )
    ax.axhline(
        rep["noise_rms_before"] * UM,
        color="k",
        ls="--",
        lw=1,
        label=f"noise alone ({rep['noise_rms_before'] * UM:.1f} µm)",
    )
    ax.set_xticks(x, [str(p["pose"]) for p in pp])
    ax.set_xlabel("pose")
    ax.set_ylabel("residual RMS per coordinate (µm)")
    ax.set_title("calbench discover: measured minus predicted deflection, per pose")
    ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=path.suffix.lstrip(".") or "png")
    plt.close(fig)
    return path


def _value(p: dict) -> str:
    s = f"{p['name']} = {p['estimate']:.4g}"
    if p["std"] is not None:
        s += f" ± {p['std']:.2g}"
    return s + f" {p['unit']}" + ("" if p["determined"] else " (not determined)")


def _combination(c: dict) -> str:
    # a term is shown when it matters at the parameter's own size (SI coefficients mix units)
    w = {n: abs(v) * c.get("sizes", {}).get(n, 1.0) for n, v in c["combination"].items()}
    terms = " + ".join(
        (f"{v:.3g}·" if abs(v - 1) > 1e-12 else "") + n
        for n, v in c["combination"].items()
        if w[n] > 1e-3 * max(w.values())
    )
    return f"{terms} = {c['estimate']:.4g} ± {c['std']:.2g}"


def _biases(a: dict, n: int = 2) -> str:
    top = [b for b in a["biases"] if b["at_reference_sigma"] is not None][:n]
    return ", ".join(
        f"{b['parameter']} {b['at_reference_sigma']:+.2g} sigma"
        + (f" ({b['at_reference_percent']:+.2g} %)" if b["at_reference_percent"] is not None else "")
        for b in top
    )


def _exact_parts(r: dict) -> tuple[str | None, str | None]:
    """(from which size a visible effect parameter is named, why a sign of it never is): the
    column's size, or, where the deflections are not linear in it and the exact statics
    disagree, per sign (aliasing.py, EXACT)."""
    first = r.get("detectable_magnitude_first_order")
    if "exact" not in r or all(x["magnitude"] == first for x in r["exact"]):
        return f"{r['parameter']} from {r['detectable_magnitude']:.2g} {r['unit']}", None
    named, never = [], []
    for x in r["exact"]:
        sign = "+" if x["sign"] > 0 else "-"
        if x["never_named"]:
            top, lost = x["lambda_max"], x.get("no_equilibrium_from")
            why = [f"its LR reaches {top:.2g} at most"] if top is not None else []
            why += [f"no static equilibrium from {sign}{lost:.2g}"] if lost is not None else []
            never.append(f"{r['parameter']} {sign} ({'; '.join(why)})")
        else:
            named.append(f"{sign}{x['magnitude']:.2g}")
    said = f"(exact statics; first order said {first:.2g})"
    return (
        (f"{r['parameter']} from {' or '.join(named)} {r['unit']} {said}" if named else None),
        ("; ".join(never) + ("" if named else f" {said}") if never else None),
    )


def alias_lines(aliasing: list[dict]) -> list[str]:
    """One line per effect: what this plan cannot see of it and what that would bias."""
    groups: dict[tuple, list[dict]] = {}
    for a in aliasing:
        groups.setdefault((a["effect"], a["detail"]), []).append(a)
    out = []
    for (effect, detail), rows in groups.items():
        name = effect + (f" {detail}" if detail else "")
        if any("error" in r for r in rows):
            out.append(f"  {name}: not computed ({rows[0]['error'][:80]})")
            continue
        if effect == "load_scale":
            per = ", ".join(
                f"{b['parameter']} {b['per_percent_mass_relative_percent']:+.2g} %"
                for b in rows[0]["biases"][:6]
                if b.get("per_percent_mass_relative_percent") is not None
            )
            a = rows[0]
            seen = (
                f"the rest leaves a misfit (not a name) from a mass {100 * a['detectable_magnitude']:.2g} % off"
                if a["visible"]
                else "no size of it leaves a misfit"
            )
            out.append(
                f"  load_scale (payload mass known to +-x %): never named (deflections alone cannot tell "
                f"it from the compliances); {100 * (1 - a['visible_share']):.3g} % of its signature is "
                f"absorbed, {seen}; a mass 1 % high biases {per}"
            )
            continue
        if not any(r.get("excited", True) for r in rows):
            out.append(f"  {name}: not excited by this plan (no load moves it)")
            continue
        exact = [_exact_parts(r) for r in rows if r["visible"]]
        seen = [a for a, _ in exact if a]
        never = [b for _, b in exact if b]
        hidden = [
            f"{r['parameter']} (at {r['reference_magnitude']:.2g} {r['unit']}: {_biases(r)})"
            for r in rows
            if not r["visible"] and r.get("excited", True)
        ]
        parts = (
            (["named " + ", ".join(seen)] if seen else [])
            + (["never named at any size: " + "; ".join(never)] if never else [])
            + (["absorbed exactly, never seen: " + "; ".join(hidden)] if hidden else [])
        )
        out.append(f"  {name}: " + "; ".join(parts))
    return out


def base_lines(bf: dict | None) -> list[str]:
    """The user's model's fit, as identify's (identify/discover/basefit.py), and what it held."""
    if not bf:
        return []
    out = [
        f"  The user's model is fitted as `calbench identify` fits it ({bf['estimator'].split(' ')[0]}, "
        f"start {bf['start']}): chi2 {bf['chi2']:.1f} for {bf['dof']} dof, RMS {bf['rms'] * UM:.1f} um."
    ]
    out += [f"  Held where identify holds it: {n}: {why}" for n, why in bf["held"].items()]
    out += [
        f"  Estimated, not determined (as identify says): {n}: {why}"
        for n, why in bf["not_determined"].items()
    ]
    return out


def tie_lines(params: list[dict]) -> list[str]:
    """An `ambiguous` verdict: each parameter the tied candidates disagree on, every value."""
    out = []
    for p in params:
        under = p.get("under_tied_candidates")
        if not under:
            continue
        vals = "; ".join(
            f"{lab}: {u['estimate']:.4g}"
            + (f" ± {u['std']:.2g}" if u["std"] is not None else " (not determined)")
            for lab, u in under.items()
        )
        out.append(f"  {p['name']} not determined under either candidate ({p['unit']}): {vals}")
    if out:
        out.insert(
            0, "The tied candidates disagree beyond their std (so neither value is reported as determined):"
        )
    return out


def hint_line(h: dict) -> str:
    """One hint: a candidate the readings lean towards but that is not named, and why (its LR
    below the family-wise level, or past it only with what the current model leaves undetermined
    moved along its valley: its first-order score below it; identify/discover/decide.py)."""
    what = f"  Hint: adding {h['effect']} {h['detail']} would lower chi2 by {h['lr']:.1f} for {h['k']} parameter(s)"
    if h["p_lr"] < h["alpha"] and h.get("p_score") is not None:
        return (
            f"{what} (p = {h['p_lr']:.1g}, past the family-wise {h['alpha']:.1g}), but not at first "
            f"order: at your model's estimate the readings give it {h['score_statistic']:.1f} "
            f"(p = {h['p_score']:.1g}); the rest of the gain needs the model moved far from there (a "
            "weakly determined spring along its valley, typically), where a campaign with nothing "
            "missing gains this much more often than the level allows. Not named; a plan that "
            "determines your model's parameters better would tell."
        )
    return (
        f"{what} (p = {h['p_lr']:.1g}, below the family-wise threshold: needs < {h['alpha']:.1g}): more "
        "or better-placed measurements would tell."
    )


def valley_lines(params: list[dict]) -> list[str]:
    """Each parameter a walk along an undetermined one carried beyond its quadratic
    (identify/core/profile.py's VALLEY): the walked parameter, how far, for what chi2, the range."""
    out = []
    for p in params:
        v = p.get("valley")
        if v:
            lo, hi = v["range"]
            out.append(
                f"  {p['name']}: with {v['walked']} walked, it goes {v['distance_std']:.3g} of its Fisher std "
                f"for a chi2 rise of {v['chi2_rise']:.3g} (a quadratic: {min(v['distance_std'], 4.5) ** 2:.3g}); "
                f"range {lo:.4g} to {hi:.4g} {p['unit']}"
            )
    if out:
        out.insert(0, "Not determined along a valley the Fisher std does not see (so no std is reported):")
    return out


def self_check_lines(check: dict | None) -> list[str]:
    """The verdict of the self-check of the reported model (identify/discover/uncertainty.py's
    self_check): passed, or which parameters and combinations failed (and are reported as not
    determined), with the replicas' spread and mean against the reported std."""
    if not check:
        return []
    head = (
        f"Self-check ({check['replicas']} replicas re-simulated from the reported model and refitted): "
        f"every reported std within {check['std_factor']:g}x of the replicas' spread and their mean "
        f"within {check['bias_sigma_max']:g} std of the estimate"
    )
    if check["passed"]:
        return [head + ": passed."]
    out = [head + ": FAILED for " + ", ".join(check["failed"]) + " (reported as not determined):"]
    return out + ["  " + line for line in self_check_failures(check)]


def self_check_failures(check: dict) -> list[str]:
    """One line per quantity a self-check failed: the replicas' spread and mean against its std."""
    out = []
    for n in check["failed"]:
        p = check["parameters"][n]
        if p["std_ratio"] is None:
            out.append(f"{n}: only {p['replicas']} of the replicas could be refitted")
        else:
            out.append(
                f"{n}: spread / reported std {p['std_ratio']:.2f}, mean - estimate {p['bias_sigma']:+.2f} std"
            )
    return out


def exposure_lines(params: list[dict]) -> list[str]:
    """Each determined parameter's exposure: the largest bias an effect of the library that this
    plan would not name could cause (identify/discover/exposure.py)."""
    out = []
    for p in params:
        e = p.get("exposure")
        if not p["determined"] or not e:
            continue
        row = f"  {p['name']} = {p['estimate']:.4g} ± {p['std']:.2g} {p['unit']}"
        if e["effect"] and e["bias"] > 0:
            row += f"; an undetected {e['effect']} could move it by up to {e['bias']:.2g}"
            if e["sigma"] is not None:
                row += f" ({e['sigma']:.2g} std"
                row += f", {e['percent']:.2g} %)" if e["percent"] is not None else ")"
            if e.get("by_effect_profile", {}).get(e["effect"]) == e["bias"]:
                row += ", as far as its candidate's chi2 profile reaches"
            elif e.get("by_effect_fitted", {}).get(e["effect"]) == e["bias"]:
                row += ", where its candidate's own fit puts it"
        if e["unbounded_by"]:
            row += "; by any amount, along a direction this plan cannot see: " + ", ".join(e["unbounded_by"])
        out.append(row)
    if out:
        out.insert(
            0,
            "Exposure of each determined parameter to the library's effects not named (the largest "
            "bias one could cause while its test stays silent, first order, at the estimate and "
            "+-2 std along each principal axis of its covariance; further where the effect's own "
            "candidate fit, or for a spring its chi2 profile, reaches further):",
        )
    return out


def story(rep: dict) -> str:
    lines = [
        f"calbench discover: {rep['log']} (model: {rep['model']}; {rep['n_poses']} poses, "
        f"{rep['n_observations']} reflector deflections, {rep['seconds']:.1f} s)",
        *([f"  campaign: {rep['completeness']}"] if rep.get("completeness") else []),
        "Where the model and the measurements disagree:",
    ]
    lines += base_lines(rep.get("base_fit"))
    lines += ["  " + w for w in rep["where_before"]["words"]]
    if rep["rounds"]:
        lines.append(
            "Candidates (first round; every one tested at the family-wise level "
            f"{rep['decision_rule']['alpha_effect_familywise']:g}; score = BIC gain, > 0 favours it):"
        )
        for c in rep["rounds"][0]["candidates"]:
            if c["score"] is None:
                lines.append(f"  {c['effect']:<20}{c['detail']:<11} not applicable: {c.get('error', '')}")
                continue
            lines.append(
                f"  {c['effect']:<20}{c['detail']:<11} score {c['score']:9.1f}  LR {c['lr']:8.1f} "
                f"(k={c['k']}, p={c['p_lr']:.1g})"
                + (
                    f"  first order {c['score_statistic']:6.1f} (p={c['p_score']:.1g})"
                    if "p_score" in c
                    else ""
                )
                + f"  explains {100 * c['explained']:5.1f} % of the excess  "
                f"RMS after {c['rms_after'] * UM:6.1f} um" + ("  ACCEPTED" if c["accepted"] else "")
            )
    for s in rep["steps"]:
        if s["effect"] == "unexplained":
            lines.append(
                f"Named: unexplained: a significant disagreement remains that no candidate of the "
                f"library explains (RMS {s['rms_before'] * UM:.1f} um). No parameter is reported as "
                "determined: every std would assume a model the readings reject"
                + (
                    f" (chi2/dof {rep['unexplained_misfit']['birge_ratio'] ** 2:.2f})."
                    if rep.get("unexplained_misfit")
                    else "."
                )
            )
            lines += [hint_line(h) for h in rep.get("hints", [])]
            continue
        if s["effect"] == "ambiguous":
            lines.append(
                "Named: ambiguous: "
                + " and ".join(f"{t['candidate']} (LR {t['lr']:.1f}, k={t['k']})" for t in s["candidates"])
                + " explain the data almost equally well (BIC gains within "
                f"{rep['decision_rule']['ambiguous_bic']:g} or LR difference inside its sampling spread); "
                "more or better-placed measurements would tell them apart."
            )
            continue
        ps = ", ".join(_value(p) for p in s["parameters"])
        what = f"{s['effect']} ({s['detail']})" if s["detail"] else s["effect"]
        lines.append(
            f"Named: {what}: {ps}; RMS {s['rms_before'] * UM:.1f} -> "
            f"{s['rms_after'] * UM:.1f} um (noise alone {s['noise_rms_after'] * UM:.1f} um), "
            f"LR {s['lr']:.1f} for {s['k']} parameter(s), p = {s['p_lr']:.1g}."
        )
    if rep.get("combinations"):
        lines.append("Determined only in combination (the split is not):")
        lines += ["  " + _combination(c) for c in rep["combinations"]]
    for c in rep.get("combinations_not_quadratic", []):
        if c.get("rejected_by") == "self-check":
            continue  # said by self_check_lines
        lines.append(
            f"Not determined, not even in combination: {' + '.join(c['combination'])} (chi2 rises "
            + ", ".join("none" if r is None else f"{r:.2g}" for r in c["chi2_rise_at_2_std"])
            + " at +-2 std of its linear combination, 4 if quadratic: its std would be dishonest)"
        )
    lines += tie_lines(rep["parameters"])
    lines += valley_lines(rep["parameters"])
    lines += self_check_lines(rep.get("self_check"))
    lines += exposure_lines(rep["parameters"])
    if not rep["named_effects"]:
        lines.append(
            "Named: nothing. No candidate passes its tests (likelihood ratio and first-order score); the user's model explains "
            "the data to the noise level."
        )
        for h in rep.get("hints", []):
            lines.append(hint_line(h))
    if rep.get("aliasing"):
        lines.append(
            "What a model that fits does not tell you (aliasing of every effect not named: the "
            "size this plan names it from, or what it would bias unseen, in sigma and %, at the size "
            "a plan would name if nothing absorbed it):"
        )
        lines += alias_lines(rep["aliasing"])
    lines.append(
        f"Gap: residual RMS {rep['rms_before'] * UM:.1f} um before "
        f"({rep['rms_before'] / rep['noise_rms_before']:.2f}x noise), {rep['rms_after'] * UM:.1f} um after "
        f"({rep['rms_after'] / rep['noise_rms_after']:.2f}x the {rep['noise_rms_after'] * UM:.1f} um noise "
        f"alone leaves; tracker sigma {rep['noise_sigma'] * UM:.3g} um per reading); chi2 p "
        f"{rep['p_before']:.2g} -> {rep['p_after']:.2g}."
    )
    if rep.get("augmented_model"):
        lines.append(f"Augmented model: {rep['augmented_model']}")
    if rep.get("plot"):
        lines.append(f"Per-pose residuals before/after: {rep['plot']}")
    if rep.get("view_rrd"):
        lines.append(f"Where the model disagreed, on the robot (Rerun): rerun {rep['view_rrd']}")
    if rep.get("view_json"):
        lines.append(f"Rerun view: calbench view {rep['log']} --identified {rep['view_json']}")
    return "\n".join(lines)


def clean(x):
    """JSON-safe copy: numpy scalars/arrays to Python, NaN and infinities to null."""
    if isinstance(x, dict):
        return {str(k): clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [clean(v) for v in x]
    if isinstance(x, np.ndarray):
        return clean(x.tolist())
    if isinstance(x, (np.bool_, bool)):
        return bool(x)
    if isinstance(x, (np.integer, int)):
        return int(x)
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(x) else None
    return x


__all__ = [
    "story",
    "base_lines",
    "tie_lines",
    "valley_lines",
    "exposure_lines",
    "self_check_lines",
    "self_check_failures",
    "alias_lines",
    "plot_residuals",
    "view_report",
    "clean",
]
