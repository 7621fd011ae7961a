"""`calbench discover`: where the model and the measurements disagree, which physics is missing.

    calbench discover LOG.mcap --model ROBOT.xml [--json OUT.json] [--out-model AUGMENTED.xml]
                               [--plot RESIDUALS.png]

1. FIT the user's model as it is (the one-step estimator, identify/onestep.py) and take the
   residuals (measured minus predicted deflections).
2. WHERE they disagree: chi2 against the tracker's own noise, per pose, per reflector, per world
   direction, and the correlation of each pose's misfit with what varies over the plan
   (identify/discover_stats.py), in words and numbers.
3. NAME the missing effect: every candidate of the library (identify/discover_fit.py: the four
   docs/contract.md effects of bench/effects.py with their structural options) is added to the model
   and fitted jointly with the base parameters on the exact statics; the candidates are compared
   by the likelihood ratio (known noise: the chi2 drop, tested against chi2(k) at a family-wise
   level ALPHA_EFFECT, Bonferroni over the library) and BIC. A candidate is ACCEPTED only if it is
   significant, preferred by BIC, and removes at least MIN_EXPLAINED of the base model's excess
   chi2. The best accepted one is added and the loop repeats while the residual is still not
   noise. If the residual is not noise and no candidate is accepted: `unexplained`. If the user's
   model already fits to the noise level (chi2 p >= ALPHA_FIT): nothing is named.
4. ADD it: the augmented MJCF (the identified effect parameters and base parameters in it),
   loadable with MuJoCo.
5. SHOW the gap shrink: RMS before/after against what noise alone leaves, a PNG of per-pose
   residuals before and after, and an identify-style JSON with predicted deflections for
   `calbench view LOG --identified VIEW.json`.

Only what identify reads is read: the log without truth (no /truth/ topic, no ground_truth
record) and the MJCF for geometry (its stiffness values are overwritten by the estimates).
The selection logic here knows nothing about any particular effect.
"""
from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from calbench.bench.effects import augmented_xml, load_spec
from calbench.bench.idreport import IdentificationReport, ObservationFit, ParameterEstimate
from calbench.bench.logread import read_log
from calbench.bench.outputs import atomic_path, write_text
from calbench.bench.description import set_spec_names, spec_names
from calbench.bench.robot import Robot
from calbench.bench.view import Discovery, write_discovery_recording

from .fit import Fit, build, effect_priors, fit, label, library
from .stats import (ALPHA_EFFECT, ALPHA_FIT, MIN_EXPLAINED, chi2_p, compare, diagnose,
                             expected_rms, rms)
from ..whitening import Whitener
from ..observations import from_log
from ..onestep import one_step
from ..model import check_sites, load_model

MAX_ROUNDS = 3
UNEXPLAINED = "unexplained"


def _base_fit(src, obs, white) -> Fit:
    robot, fm = build(src, [], obs)
    r = one_step(robot, obs, step_tol=1e-3)
    lo, hi = robot.layout.lower, robot.layout.upper
    start = np.where(np.isfinite(r.theta), r.theta, r.start)
    start = np.clip(start, lo, hi)
    return fit(fm, obs.dp, white, start, lo, hi, ~np.asarray(r.identifiable, bool))


def _candidate_fit(src, obs, white, current: Fit, hold_base: np.ndarray, effect) -> Fit:
    start, lower, upper, _ = effect_priors(effect)
    applied = current.effect_params()
    _, fm = build(src, applied + [(effect, start)], obs)
    lay = fm.layout
    n_prev = current.values.size - lay.n
    lo = np.concatenate([lay.lower] + [effect_priors(e)[1] for e, _ in applied] + [lower])
    hi = np.concatenate([lay.upper] + [effect_priors(e)[2] for e, _ in applied] + [upper])
    hold = np.concatenate([hold_base, np.zeros(n_prev + start.size, bool)])
    return fit(fm, obs.dp, white, np.concatenate([current.values, start]), lo, hi, hold)


def _step_record(effect, cand: Fit, before: Fit, stats_: dict, obs) -> dict:
    params = cand.effect_params()[-1][1]
    off = cand.values.size - params.size
    sd = np.sqrt(np.abs(np.diagonal(cand.cov)[off:]))
    return {"effect": effect.name, "detail": effect.detail,
            "rms_before": rms(before.residual), "rms_after": rms(cand.residual),
            "noise_rms_before": expected_rms(obs.cov, before.dof, before.n_res),
            "noise_rms_after": expected_rms(obs.cov, cand.dof, cand.n_res),
            "parameters": [{"name": n, "unit": u, "estimate": float(v),
                            "std": float(s) if cand.free[off + i] and np.isfinite(s) else None,
                            "determined": bool(cand.free[off + i])}
                           for i, (n, u, v, s) in enumerate(zip(effect.param_names, effect.units, params, sd))],
            **{k: stats_[k] for k in ("lr", "k", "p_lr", "bic_gain", "explained", "p_fit")}}


def augmented_mjcf(src, fitted: Fit) -> str:
    """The user's MJCF with the identified base parameters and every effect written in."""
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


def discover(log_path, model=None, *, out_model=None, plot=None, view_json=None, view_rrd=None,
             max_rounds: int = MAX_ROUNDS) -> dict:
    """Run the whole workflow; returns the JSON report (docs/contract.md keys plus extras).
    ``view_rrd``: also write the Rerun recording of where the model disagreed (:func:`write_view`)."""
    t0 = time.perf_counter()
    log_path = Path(log_path)
    log = read_log(log_path)                       # no truth
    obs = from_log(log)
    robot = load_model(log, model)                 # validates the MJCF (InputError)
    check_sites(robot, obs, model or log.path)
    src = Path(model) if model is not None else log.mjcf_text
    white = Whitener.from_observations(obs)
    sigma = float(obs.noise_sigma)

    base = _base_fit(src, obs, white)
    nb = robot.layout.n
    hold_base = ~base.free[:nb] & ~base.at_bound[:nb]
    diag_before = diagnose(base, obs, sigma)
    current = base
    named: list[str] = []
    steps: list[dict] = []
    rounds: list[dict] = []
    lib = library(robot)
    hints: list[dict] = []
    for rnd in range(max_rounds):
        fits_noise = chi2_p(current.chi2, current.dof) >= ALPHA_FIT
        if fits_noise and rnd > 0:
            break
        done = {(e.name, tuple(sorted(e.options.items()))) for e, _ in current.effect_params()}
        cands = [e for e in lib if (e.name, tuple(sorted(e.options.items()))) not in done]
        results = []
        for e in cands:
            rec = {"effect": e.name, "detail": e.detail, "score": None}
            try:
                cf = _candidate_fit(src, obs, white, current, hold_base, e)
            except (ValueError, RuntimeError, NotImplementedError, np.linalg.LinAlgError) as exc:
                rec["error"] = str(exc)
                results.append((rec, None, None))
                continue
            st = compare(current, cf, len(cands))
            rec.update({"score": st["bic_gain"], "lr": st["lr"], "k": st["k"], "p_lr": st["p_lr"],
                        "explained": st["explained"], "p_fit": st["p_fit"], "accepted": st["accept"],
                        "rms_after": rms(cf.residual), "seconds": cf.seconds})
            results.append((rec, cf, st))
        ok = [(rec, cf, st) for rec, cf, st in results if st is not None and st["accept"]]
        rounds.append({"round": rnd + 1, "rms_before": rms(current.residual),
                       "candidates": sorted([r for r, _, _ in results],
                                            key=lambda r: -(r["score"] if r["score"] is not None else -np.inf))})
        if fits_noise:
            # the user's model fits to the noise level: name nothing, but say which candidate a
            # targeted likelihood-ratio test would still single out (below the noise floor)
            rounds[-1]["note"] = "the model fits to the noise level: candidates screened, none named"
            hints = [{"effect": r["effect"], "detail": r["detail"], "lr": r["lr"], "k": r["k"], "p_lr": r["p_lr"],
                      "score": r["score"]}
                     for r, _, st in results if st is not None and st["significant"] and st["bic_gain"] > 0]
            break
        if not ok:
            named.append(UNEXPLAINED)
            steps.append({"effect": UNEXPLAINED, "detail": "no candidate explains the remaining misfit",
                          "rms_before": rms(current.residual), "rms_after": rms(current.residual)})
            break
        rec, cf, st = max(ok, key=lambda t: t[2]["bic_gain"])
        eff = cf.effects[-1]
        named.append(eff.name)
        steps.append(_step_record(eff, cf, current, st, obs))
        rounds[-1]["named"] = label(eff)
        current = cf
    final = current
    diag_after = diagnose(final, obs, sigma) if final is not base else diag_before

    aug_path = None
    if final.effects:
        aug_path = Path(out_model) if out_model else log_path.with_name(log_path.stem + ".augmented.xml")
        write_text(aug_path, augmented_mjcf(src, final))
        Robot.from_file(aug_path)                  # must load
    seconds = time.perf_counter() - t0
    rep = {
        "named_effects": [n for n in named],
        "steps": steps,
        "rms_before": rms(base.residual),
        "rms_after": rms(final.residual),
        "noise_sigma": sigma,
        "candidates": rounds[0]["candidates"] if rounds else [],
        "augmented_model": str(aug_path) if aug_path else None,
        # additions
        "noise_rms_before": expected_rms(obs.cov, base.dof, base.n_res),
        "noise_rms_after": expected_rms(obs.cov, final.dof, final.n_res),
        "chi2_before": base.chi2, "dof_before": base.dof, "p_before": chi2_p(base.chi2, base.dof),
        "chi2_after": final.chi2, "dof_after": final.dof, "p_after": chi2_p(final.chi2, final.dof),
        "decision_rule": {"alpha_fit": ALPHA_FIT, "alpha_effect_familywise": ALPHA_EFFECT,
                          "min_explained_share": MIN_EXPLAINED, "score": "BIC gain = LR - k ln n"},
        "where_before": diag_before, "where_after": diag_after,
        "rounds": rounds,
        "hints": hints,
        "parameters": _parameters(final),
        "log": str(log_path), "model": str(model) if model is not None else "MJCF from the log",
        "n_observations": obs.n_obs(), "n_poses": len(obs.poses),
        "n_poses_planned": log.n_poses_planned, "lost_poses": log.lost_poses,
        "truncated": log.truncated, "completeness": log.completeness(),
        "per_pose": [{"pose": a["pose"], "rms_before": a["rms"], "rms_after": b["rms"]}
                     for a, b in zip(diag_before["per_pose"], diag_after["per_pose"])],
        "seconds": seconds,
    }
    if plot:
        rep["plot"] = str(plot_residuals(rep, plot))
    if view_json:
        write_text(view_json, view_report(final, obs, rep).to_json())
        rep["view_json"] = str(view_json)
    if view_rrd:
        rep["view_rrd"] = str(write_view(log_path, view_rrd, base, final, obs, rep))
    return rep


def _num(x):
    return None if x is None or not np.isfinite(x) else float(x)


def _parameters(f: Fit) -> list[dict]:
    sd = np.sqrt(np.abs(np.diagonal(f.cov)))
    return [{"name": n, "unit": u, "estimate": float(v), "std": _num(s) if f.free[i] else None,
             "determined": bool(f.free[i])}
            for i, (n, u, v, s) in enumerate(zip(f.names, f.units, f.values, sd))]


def write_view(log_path, rrd, base: Fit, final: Fit, obs, rep: dict) -> Path:
    """The Rerun recording of the discovery (bench/view.py, ``write_discovery_recording``): on
    the robot, every reflector's residual with the user's model and with the named effects,
    against the noise, per pose; the verdict; the final model's parameters."""
    named = tuple(s["effect"] + (f" ({s['detail']})" if s["effect"] != UNEXPLAINED and s["detail"]
                                 else "") for s in rep["steps"])
    disc = Discovery(view_report(base, obs, rep, "before"), view_report(final, obs, rep), named)
    write_discovery_recording(log_path, rrd, disc)
    return Path(rrd)


def view_report(f: Fit, obs, rep: dict, stage: str = "after") -> IdentificationReport:
    """A fitted model as an identification report, for `calbench view --identified`: its
    parameters (base and effect; ``identifiable`` = determined by the data) and the measured,
    predicted and residual deflection of every observation. ``stage``: "after" (the final
    model, with the named effects) or "before" (the user's model as it is)."""
    params = tuple(ParameterEstimate(p["name"], p["unit"], p["estimate"], p["std"],
                                     identifiable=p["determined"]) for p in _parameters(f))
    fits = tuple(ObservationFit(int(pose), r, predicted=tuple(float(x) for x in f.predicted[i]),
                                measured=tuple(float(x) for x in obs.dp[i]),
                                residual=tuple(float(x) for x in f.residual[i]))
                 for i, (pose, r) in enumerate(obs.labels))
    method = "user model as is" if stage == "before" else \
        (" + ".join(rep["named_effects"]) or "user model as is")
    return IdentificationReport(
        method="discover: " + method,
        parameters=params, residual_rms=rep[f"rms_{stage}"], noise_sigma=rep["noise_sigma"],
        chi2_per_dof=f.chi2 / f.dof if f.dof > 0 else None, chi2=float(f.chi2), dof=int(f.dof),
        expected_residual_rms=rep[f"noise_rms_{stage}"],
        whitened_residual_rms=rms(f.residual_w),
        covariance=tuple(tuple(_num(x) for x in row) for row in f.cov),
        log=rep["log"], model=rep["model"], n_poses_planned=obs.n_planned,
        n_poses_used=len(obs.poses), lost_poses=tuple(obs.lost_poses),
        truncated=bool(obs.truncated), n_observations=obs.n_obs(), seconds=rep["seconds"],
        observations=fits,
        details={"converged": bool(f.converged), "iterations": int(f.iterations),
                 "evaluations": int(f.evaluations)})


def plot_residuals(rep: dict, path) -> Path:
    """Per-pose residual RMS before and after, against what noise alone leaves (PNG)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    pp = rep["per_pose"]
    x = np.arange(len(pp))
    before = np.array([p["rms_before"] for p in pp]) * 1e6
    after = np.array([p["rms_after"] for p in pp]) * 1e6
    fig, ax = plt.subplots(figsize=(9, 4.2), dpi=110)
    ax.bar(x - 0.2, before, 0.4, label=f"user model (RMS {rep['rms_before'] * 1e6:.1f} µm)", color="#d62728")
    ax.bar(x + 0.2, after, 0.4, color="#1f77b4",
           label=("+ " + " + ".join(rep["named_effects"]) if rep["named_effects"] else "no effect named")
           + f" (RMS {rep['rms_after'] * 1e6:.1f} µm)")
    ax.axhline(rep["noise_rms_before"] * 1e6, color="k", ls="--", lw=1,
               label=f"noise alone ({rep['noise_rms_before'] * 1e6:.1f} µm)")
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


def story(rep: dict) -> str:
    um = 1e6
    lines = [f"calbench discover: {rep['log']} (model: {rep['model']}; {rep['n_poses']} poses, "
             f"{rep['n_observations']} reflector deflections, {rep['seconds']:.1f} s)",
             *([f"  campaign: {rep['completeness']}"] if rep.get("completeness") else []),
             "Where the model and the measurements disagree:"]
    lines += ["  " + w for w in rep["where_before"]["words"]]
    if rep["rounds"]:
        lines.append("Candidates (first round; score = BIC gain, > 0 favours the candidate):")
        for c in rep["rounds"][0]["candidates"]:
            if c["score"] is None:
                lines.append(f"  {c['effect']:<20}{c['detail']:<11} not applicable: {c.get('error', '')}")
                continue
            lines.append(f"  {c['effect']:<20}{c['detail']:<11} score {c['score']:9.1f}  LR {c['lr']:8.1f} "
                         f"(k={c['k']}, p={c['p_lr']:.1g})  explains {100 * c['explained']:5.1f} % of the excess  "
                         f"RMS after {c['rms_after'] * um:6.1f} um" + ("  ACCEPTED" if c["accepted"] else ""))
    for s in rep["steps"]:
        if s["effect"] == UNEXPLAINED:
            lines.append(f"Named: unexplained: a significant disagreement remains that no candidate of the "
                         f"library explains (RMS {s['rms_before'] * um:.1f} um).")
            continue
        ps = ", ".join(f"{p['name']} = {p['estimate']:.4g} {p['unit']}" + ("" if p["determined"] else " (not determined)")
                       for p in s["parameters"])
        lines.append(f"Named: {s['effect']} ({s['detail']}): {ps}; RMS {s['rms_before'] * um:.1f} -> "
                     f"{s['rms_after'] * um:.1f} um (noise alone {s['noise_rms_after'] * um:.1f} um), "
                     f"LR {s['lr']:.1f} for {s['k']} parameter(s), p = {s['p_lr']:.1g}.")
    if not rep["named_effects"]:
        lines.append("Named: nothing. The user's model already explains the data to the noise level.")
        for h in rep.get("hints", []):
            lines.append(f"  Hint below the noise floor: adding {h['effect']} {h['detail']} would lower chi2 by "
                         f"{h['lr']:.1f} for {h['k']} parameter(s) (p = {h['p_lr']:.1g}): more or better-placed "
                         "measurements would tell.")
    lines.append(f"Gap: residual RMS {rep['rms_before'] * um:.1f} um before "
                 f"({rep['rms_before'] / rep['noise_rms_before']:.2f}x noise), {rep['rms_after'] * um:.1f} um after "
                 f"({rep['rms_after'] / rep['noise_rms_after']:.2f}x the {rep['noise_rms_after'] * um:.1f} um noise "
                 f"alone leaves; tracker sigma {rep['noise_sigma'] * um:.3g} um per reading); chi2 p "
                 f"{rep['p_before']:.2g} -> {rep['p_after']:.2g}.")
    if rep["augmented_model"]:
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


__all__ = ["discover", "story", "augmented_mjcf", "plot_residuals",
           "view_report", "write_view", "clean", "UNEXPLAINED"]
