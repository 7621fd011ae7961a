"""`calbench report`: the calibration report a metrology engineer hands over with the robot.

    calbench report LOG.mcap [--identified ID.json] [--discover D.json] [--design PLAN.json]
                    --out REPORT.html

One HTML file that opens offline: inline CSS, every figure an SVG data URI (identify/report/htmlplots.py),
no script and no external URL. Sections: the campaign (robot, plan, tracker, lost poses, from the
log without its truth), the parameters (estimate, std, 95 % interval, the unidentifiable ones
with the reason), their correlation matrix, the residuals per pose and reflector against the
noise level, discovery's verdict with its before/after (and its aliasing warnings when the
report carries them), the design's certificate, and the commands that reproduce every number.
A section whose input was not given says which command produces it. The same inputs give the
same bytes (no clock, deterministic SVG), so a report can be checked by rebuilding it.

Why our own builder on Jinja2 rather than MuJoCo's ``mujoco.sysid`` report: that builder shows
the genre (Jinja2 sections for a parameter table with confidence, the covariance, the
optimisation trace), but its page loads a web font from an external URL and draws with Plotly
(a CDN script, or 3.5 MB of JavaScript inlined), so it does not open offline as one small file;
its sections take ``mujoco.sysid`` ParameterDicts and time-series rollouts, not an
elastostatic identification read from JSON; and it would bring the ``mujoco[sysid]`` extras
in. Jinja2 alone (autoescaping the template) and the matplotlib we already use give a 200 kB
self-contained page.

Inputs are checked before anything is written: a missing or unreadable file, JSON that is not
the named command's report, or an output path equal to an input raise InputError (exit 2)
naming the file; the HTML is written atomically (bench/core/outputs.py).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import shlex
from importlib.resources import files
from pathlib import Path

import numpy as np
from scipy.stats import chi2 as chi2_dist

from calbench.bench.core import InputError, check_outputs, unit_display, write_text
from calbench.bench.log import CampaignLog, IdentificationReport, has_truth, read_log
from calbench.bench.view import measured_deflections
from calbench.identify.discover import ALPHA_FIT as MISFIT_P  # chi2 p below which the model is rejected
from calbench.identify.discover import (
    alias_lines,
    base_lines,
    exposure_lines,
    self_check_lines,
    tie_lines,
    valley_lines,
)

from . import htmlplots
from .identification import noise_source
from .provenance import provenance

Z95 = 1.959963984540054  # two-sided 95 % quantile of the standard normal
KINDS = {
    "identify": ("calbench identify --json", ("method", "parameters", "noise_sigma")),
    "discover": ("calbench discover --json", ("named_effects", "rms_before", "rms_after")),
    "design": ("calbench design --json", ("criterion", "poses")),
}


# ---------------------------------------------------------------------------------------------
# inputs
# ---------------------------------------------------------------------------------------------


def read_json_report(path: str | os.PathLike, kind: str) -> dict:
    """A JSON report of ``kind`` (identify, discover, design), checked for its defining keys."""
    path = Path(path)
    what, keys = KINDS[kind]
    try:
        doc = json.loads(path.read_text())
    except OSError as e:
        raise InputError(path, "file", f"a readable JSON file ({what})", e.strerror) from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise InputError(path, "file", f"JSON ({what})", str(e)) from None
    if not isinstance(doc, dict):
        raise InputError(path, "file", f"a JSON object ({what})", type(doc).__name__)
    missing = [k for k in keys if k not in doc]
    if missing:
        found = ", ".join(sorted(doc)[:6]) or "none"
        raise InputError(
            path, missing[0], f"the {what} report (keys {', '.join(keys)})", f"an object with keys {found}"
        )
    lists = {"identify": "parameters", "discover": "named_effects", "design": "poses"}[kind]
    if not isinstance(doc[lists], list):
        raise InputError(path, lists, "a list", type(doc[lists]).__name__)
    return doc


def read_identify_report(path: str | os.PathLike) -> IdentificationReport:
    """The ``identify --json`` report: its defining keys checked (a discover report also has
    ``parameters``), then read as the typed report the viewer reads too."""
    read_json_report(path, "identify")
    return IdentificationReport.read(path)


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


# ---------------------------------------------------------------------------------------------
# formatting
# ---------------------------------------------------------------------------------------------


def _finite(x) -> float | None:
    if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
        return None
    return float(x)


def decimals(std: float | None) -> int:
    """Decimals that show ``std`` to two significant digits (3 without a std)."""
    if not std or std <= 0:
        return 3
    return max(0, 1 - math.floor(math.log10(std)))


def num(x: float | None, dec: int) -> str:
    return "–" if x is None else f"{x:.{dec}f}"


def um(x) -> str:
    x = _finite(x)
    return "–" if x is None else f"{x * 1e6:.1f}"


# ---------------------------------------------------------------------------------------------
# sections (each a plain dict for the template)
# ---------------------------------------------------------------------------------------------


def campaign_section(log: CampaignLog, simulated: bool) -> dict:
    h = log.header
    tr = log.tracker_spec()  # the one parse of the header's tracker (TrackerSpec)
    names = list(h.get("reflectors") or [])
    lost = log.lost_poses
    defl = measured_deflections(log)
    seen: dict[tuple[int, str], set] = {}
    repeats: dict[int, int] = {}
    for m in log.measurements:
        seen.setdefault((m.pose, m.state), set()).update(r for r, v in zip(m.reflectors, m.visible) if v)
        repeats[m.pose] = max(repeats.get(m.pose, 0), m.repeat + 1)
    rows = []
    for p in log.complete_poses:
        q = log.poses[p].unloaded if p in log.poses else None
        w = log.wrenches.get(p)
        if w is None:
            load = "–"
        elif w.mass is not None:
            load = f"{w.mass:g} kg payload"
        else:
            load = "force [" + ", ".join(f"{f:.0f}" for f in w.force) + "] N"
        rows.append(
            {
                "pose": p,
                "q": "" if q is None else ", ".join(f"{x:.1f}" for x in np.degrees(q)),
                "load": load,
                "repeats": repeats.get(p, 0),
                "seen": f"{len(seen.get((p, 'unloaded'), ()))}/"
                f"{len(seen.get((p, 'loaded'), ()))} of {len(names)}",
                "deflection": [
                    ("–" if n not in defl.get(p, {}) else f"{np.linalg.norm(defl[p][n]) * 1e3:.3f}")
                    for n in names
                ],
            }
        )
    noise = tr.error_model.describe(tr)
    return {
        "scenario": h.get("scenario_name", "?"),
        "robot": h.get("robot", "?"),
        "reflectors": names,
        "payload_site": h.get("payload_site", "?"),
        "tracker_position": ", ".join(f"{x:.3f}" for x in tr.position),
        "tracker_yaw": f"{math.degrees(tr.yaw):.1f}",
        "tracker_noise": noise,
        "seed": h.get("seed"),
        "simulated": simulated,
        "planned": log.n_poses_planned,
        "complete": len(log.complete_poses),
        "lost": lost,
        "truncated": log.truncated,
        "n_readings": len(log.measurements),
        "rows": rows,
    }


CHI2_95 = Z95**2  # chi2(1) 95 % quantile: the profile interval's rise


def profile_interval(
    est: float, std: float, prof: dict, lower: float | None
) -> tuple[float | None, float | None]:
    """The 95 % interval a chi2 profile that is not quadratic gives (identify/core/profile.py's
    check: its rise r at +-2 Fisher std on each side): on each side, the quadratic through that
    rise, est +- 2 std sqrt(3.84 / r); a side without a rise (past its bound, or no fit) or with
    none reaches the bound (``lower``, None: unbounded). Clipped to ``lower`` (a spring's
    stiffness is not negative). Two points per side: an approximation, flagged as such."""
    out = []
    for sign, key in ((-1.0, "rise_minus"), (1.0, "rise_plus")):
        r = prof.get(key)
        if r is None or not r > 0:
            out.append(lower if sign < 0 else None)
            continue
        v = est + sign * 2.0 * std * math.sqrt(CHI2_95 / r)
        out.append(max(v, lower) if (sign < 0 and lower is not None) else v)
    return out[0], out[1]


def parameters_section(ident: IdentificationReport) -> dict:
    rows, rel_names, rel = [], [], []
    profiles = ident.details.get("profile") or {}
    for p in ident.parameters:
        label, f = unit_display(p.unit)
        est, std, truth = p.estimate, p.std, p.truth
        ok = est is not None and p.identifiable
        d = decimals(std * f if std else None)
        z = p.z if p.z is not None else ((est - truth) / std if ok and std and truth is not None else None)
        prof = profiles.get(p.name)
        bent = bool(ok and std is not None and prof and not prof.get("quadratic", True))
        if bent:  # every elastic parameter of the model is positive (bench/model/params.py)
            lo, hi = profile_interval(est, std, prof, 0.0)
            ci = f"[{num(lo * f, d)}, {num(hi * f, d) if hi is not None else '∞'}] (profile)"
        elif ok and std is not None:
            ci = f"[{num((est - Z95 * std) * f, d)}, {num((est + Z95 * std) * f, d)}]"
        else:
            ci = "–"
        rows.append(
            {
                "name": p.name,
                "unit": label,
                "identifiable": ok,
                "reason": p.reason or "",
                "estimate": num(est * f, d) if ok else "",
                "std": num(std * f, d) if ok and std is not None else "–",
                "ci": ci,
                "not_quadratic": bent,
                "rises": (
                    ", ".join(
                        "none" if prof.get(k) is None else f"{prof[k]:.2f}"
                        for k in ("rise_plus", "rise_minus")
                    )
                    if bent
                    else ""
                ),
                "rel": f"{abs(std / est) * 100:.2g}" if ok and std is not None and est else "–",
                "truth": num(truth * f, d) if truth is not None else "–",
                "z": f"{z:+.2f}" if z is not None else "–",
                "z_flag": z is not None and abs(z) > 3,
            }
        )
        rel_names.append(p.name)
        rel.append(abs(std / est) * 100 if ok and std is not None and est else None)
    chi2, dof = ident.chi2, ident.dof
    p_fit = float(chi2_dist.sf(chi2, dof)) if chi2 is not None and dof else None
    return {
        "method": ident.method,
        "rows": rows,
        "has_truth": ident.has_truth(),
        "misfit": p_fit is not None and p_fit < MISFIT_P,
        "chi2": f"{chi2:.1f}" if chi2 is not None else "–",
        "p": f"{p_fit:.2g}" if p_fit is not None else "–",
        "unidentifiable": [r for r in rows if not r["identifiable"]],
        "not_quadratic": [r for r in rows if r["not_quadratic"]],
        "profile_checked": bool(profiles),
        "chi2_per_dof": (f"{ident.chi2_per_dof:.3f}" if ident.chi2_per_dof is not None else "–"),
        "dof": dof,
        "residual_rms": um(ident.residual_rms),
        "expected_rms": um(ident.expected_residual_rms),
        "noise_source": noise_source(ident),
        "model": ident.model or "",
        "n_observations": ident.n_observations,
        "chart": htmlplots.relative_std_bars(rel_names, rel) if any(rel) else None,
    }


def correlation_section(ident: IdentificationReport) -> dict:
    names = [p.name for p in ident.parameters]
    if ident.covariance is None or len(ident.covariance) != len(names):
        return {"available": False, "why": "the identify report carries no covariance matrix"}
    C = np.array([[np.nan if x is None else x for x in row] for row in ident.covariance], float)
    d = np.diag(C)
    good = np.isfinite(d) & (d > 0)
    keep = [i for i in range(len(names)) if good[i] and np.all(np.isfinite(C[i, good]))]
    if len(keep) < 2:
        return {"available": False, "why": "fewer than two identifiable parameters"}
    sub = C[np.ix_(keep, keep)]
    s = np.sqrt(np.diag(sub))
    corr = np.clip(sub / np.outer(s, s), -1, 1)
    kn = [names[i] for i in keep]
    strong = [
        {"a": kn[i], "b": kn[j], "rho": f"{corr[i, j]:+.3f}"}
        for i in range(len(kn))
        for j in range(i + 1, len(kn))
        if abs(corr[i, j]) >= 0.9
    ]
    return {
        "available": True,
        "chart": htmlplots.correlation_heatmap(kn, corr),
        "left_out": [n for i, n in enumerate(names) if i not in keep],
        "strong": strong,
    }


def residuals_section(ident: IdentificationReport, reflectors: list[str]) -> dict:
    obs = [o for o in ident.observations if o.residual is not None]
    expected = ident.expected_residual_rms
    if not obs or expected is None:
        return {"available": False, "why": "the identify report carries no per-observation residuals"}
    names = list(reflectors) or sorted({o.reflector for o in obs})
    poses = sorted({o.pose for o in obs})
    grid = np.full((len(names), len(poses)), np.nan)
    for o in obs:
        if o.reflector in names:
            grid[names.index(o.reflector), poses.index(o.pose)] = (
                np.sqrt(np.mean(np.square(o.residual))) * 1e6
            )
    exp_um = expected * 1e6
    per_refl = []
    for i, n in enumerate(names):
        v = grid[i][np.isfinite(grid[i])]
        if v.size:
            rms = float(np.sqrt(np.mean(v**2)))
            per_refl.append(
                {
                    "reflector": n,
                    "n": int(v.size),
                    "rms": f"{rms:.1f}",
                    "ratio": f"{rms / exp_um:.2f}",
                    "worst": f"{v.max():.1f} (pose {poses[int(np.nanargmax(grid[i]))]})",
                }
            )
    return {
        "available": True,
        "expected": f"{exp_um:.1f}",
        "map": htmlplots.residual_map(poses, names, grid, exp_um),
        "bars": htmlplots.residual_per_pose(poses, names, grid, exp_um),
        "per_reflector": per_refl,
        "outliers": list(ident.outliers),
        "threshold": ident.outlier_threshold_sigma,
    }


def _generic_rows(x) -> list[dict]:
    """Any JSON (a list of objects, an object of objects or of values) as rows of name/value
    text pairs, for report fields whose layout this page does not fix (hints)."""

    def text(v):
        if isinstance(v, float):
            return f"{v:.4g}"
        return v if isinstance(v, str) else json.dumps(v, separators=(", ", ": "))

    if isinstance(x, dict):
        return [{"name": str(k), "value": text(v)} for k, v in x.items()]
    if isinstance(x, list):
        out = []
        for v in x:
            if isinstance(v, dict):
                head = v.get("effect") or v.get("name") or ""
                rest = {k: w for k, w in v.items() if k not in ("effect", "name")}
                out.append(
                    {"name": str(head), "value": "; ".join(f"{k}: {text(w)}" for k, w in rest.items())}
                )
            else:
                out.append({"name": "", "value": text(v)})
        return out
    return [{"name": "", "value": text(x)}]


def aliasing_rows(aliasing: list[dict]) -> list[dict]:
    """The aliasing warnings in the words `calbench discover` prints (one row per effect: the
    size this plan names it from, or what it would bias unseen), not the JSON's raw numbers."""
    rows = []
    for line in alias_lines(aliasing):
        name, _, words = line.strip().partition(": ")
        rows.append({"name": name, "value": typeset(words)})
    return rows


def typeset(words: str) -> str:
    """The terminal's ASCII units and symbols (the discover story's) as the page writes them."""
    for ascii_, uni in (
        (" sigma", " σ"),
        ("+-", "±"),
        ("N*m", "N·m"),
        ("^3", "³"),
        (" um", " µm"),
        ("chi2", "χ²"),
    ):
        words = words.replace(ascii_, uni)
    return words


def ambiguous_rows(ambiguous: list[dict]) -> list[dict]:
    """Each round's near-tie (docs/contract.md's ``ambiguous``) as one row of words."""
    return [
        {
            "name": f"round {a['round']}",
            "value": " and ".join(
                f"{t['candidate']} (LR {t['lr']:.1f}, k = {t['k']}, BIC gain {t['bic_gain']:.1f})"
                for t in a["candidates"]
            ),
        }
        for a in ambiguous
    ]


def honesty_lines(disc: dict, path) -> list[str]:
    """Discovery's own statements of what it does not know (identify/discover/narrative.py's
    words): the base fit's held and undetermined parameters, what tied candidates disagree on,
    combinations whose profile is not quadratic, the self-check of the reported model, each
    determined parameter's exposure."""
    try:
        params = disc.get("parameters") or []
        lines = (
            base_lines(disc.get("base_fit"))
            + tie_lines(params)
            + valley_lines(params)
            + self_check_lines(disc.get("self_check"))
            + exposure_lines(params)
        )
        undetermined = [p["name"] for p in params if not p["determined"]]
        if undetermined:
            lines.append(
                "not determined by the final model (no std is given for them): " + ", ".join(undetermined)
            )
        lines += [
            f"not determined, not even in combination: {' + '.join(c['combination'])}"
            for c in disc.get("combinations_not_quadratic") or []
        ]
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(
            path,
            "parameters",
            "records as `calbench discover --json` writes them",
            f"{type(e).__name__}: {e}",
        ) from None
    return [ln.strip() for ln in lines]


def discovery_section(disc: dict, path: str | os.PathLike = "--discover") -> dict:
    named = [n for n in disc["named_effects"]]
    steps = disc.get("steps") or []
    if not named:
        verdict = "The model explains the measurements to the noise level: no missing effect is named."
    elif "unexplained" in named:
        verdict = (
            "A disagreement remains that no candidate of the library explains. No parameter is "
            "reported as determined: every std would assume a model the readings reject."
        )
    else:
        verdict = (
            "Named: "
            + ", ".join(
                f"{s['effect']}" + (f" ({s['detail']})" if s.get("detail") else "")
                for s in steps
                if s.get("effect") != "unexplained"
            )
            + "."
        )
    step_rows = []
    for s in steps:
        params = []
        for p in s.get("parameters") or []:
            label, f = unit_display(str(p.get("unit") or ""))
            e, sd = _finite(p.get("estimate")), _finite(p.get("std"))
            d = decimals(sd * f if sd else None)
            params.append(
                f"{p['name']} = {num(None if e is None else e * f, d)}"
                + (f" ± {num(sd * f, d)} {label}" if sd is not None else f" {label} (not determined)")
            )
        step_rows.append(
            {
                "effect": s.get("effect"),
                "detail": s.get("detail") or "",
                "before": um(s.get("rms_before")),
                "after": um(s.get("rms_after")),
                "parameters": params,
            }
        )
    pp = disc.get("per_pose") or []
    chart = None
    nb, na = _finite(disc.get("noise_rms_before")), _finite(disc.get("noise_rms_after"))
    if pp and nb is not None:
        chart = htmlplots.before_after(
            [int(p["pose"]) for p in pp],
            [p["rms_before"] * 1e6 for p in pp],
            [p["rms_after"] * 1e6 for p in pp] if named else None,
            nb * 1e6,
            (na if na is not None else nb) * 1e6,
        )
    cands = []
    for c in disc.get("candidates") or []:
        sc, p_lr = _finite(c.get("score")), _finite(c.get("p_lr"))
        cands.append(
            {
                "effect": c.get("effect"),
                "detail": c.get("detail") or "",
                "score": "–" if sc is None else f"{sc:.1f}",
                "lr": "–" if _finite(c.get("lr")) is None else f"{c['lr']:.1f}",
                "k": c.get("k", "–"),
                "p": "–" if p_lr is None else f"{p_lr:.2g}",
                "accepted": bool(c.get("accepted")),
                "error": c.get("error"),
            }
        )

    try:
        ambiguous = ambiguous_rows(disc.get("ambiguous") or [])
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(
            path,
            "ambiguous",
            "rounds of {round, candidates: [{candidate, lr, k, "
            "bic_gain}]} as `calbench discover --json` writes them",
            f"{type(e).__name__}: {e}",
        ) from None
    try:
        aliasing = aliasing_rows(disc.get("aliasing") or [])
    except (KeyError, TypeError, ValueError, IndexError) as e:
        raise InputError(
            path,
            "aliasing",
            "entries as `calbench discover --json` writes them (docs/contract.md)",
            f"{type(e).__name__}: {e}",
        ) from None

    def stat(k):
        v = _finite(disc.get(k))
        return "–" if v is None else (f"{v:.3g}" if k.startswith("p_") else f"{v:.1f}")

    return {
        "verdict": verdict,
        "named": named,
        "steps": step_rows,
        "chart": chart,
        "rms_before": um(disc.get("rms_before")),
        "rms_after": um(disc.get("rms_after")),
        "noise_before": um(nb),
        "noise_after": um(na),
        "chi2_before": stat("chi2_before"),
        "chi2_after": stat("chi2_after"),
        "dof_before": disc.get("dof_before", "–"),
        "dof_after": disc.get("dof_after", "–"),
        "p_before": stat("p_before"),
        "p_after": stat("p_after"),
        "where_before": (disc.get("where_before") or {}).get("words") or [],
        "where_after": (disc.get("where_after") or {}).get("words") or [],
        "candidates": cands,
        "ambiguous": ambiguous,
        "aliasing": aliasing,
        "honesty": honesty_lines(disc, path),
        "hints": _generic_rows(disc["hints"]) if disc.get("hints") else [],
        "augmented_model": disc.get("augmented_model"),
    }


def _fixed(x, fmt: str) -> str | None:
    v = _finite(x)
    return None if v is None else format(v, fmt)


def design_section(design: dict) -> dict:
    m = design.get("measures") or {}
    cert = design.get("certificate")
    c = None
    if isinstance(cert, dict) and _finite(cert.get("efficiency")) is not None:
        eff = float(cert["efficiency"])
        crit = cert.get("criterion", design["criterion"])
        if "plan_logdet" in cert:  # D: log det of the information, bounded from above
            labels = (
                "log det of the plan's information",
                "certified upper bound (no plan from these candidates has more)",
            )
            plan_v, bound_v = _fixed(cert.get("plan_logdet"), ".4f"), _fixed(cert.get("bound_logdet"), ".4f")
        else:  # A, AD, pose: the criterion, smaller is better
            labels = (
                f"{crit} of the plan (smaller is better)",
                "certified lower bound (no plan from these candidates does better)",
            )
            plan_v, bound_v = _fixed(cert.get("plan_value"), ".4g"), _fixed(cert.get("bound_value"), ".4g")
        c = {
            "criterion": crit,
            "plan_label": labels[0],
            "bound_label": labels[1],
            "plan": plan_v or "–",
            "bound": bound_v or "–",
            "efficiency": f"{eff * 100:.2f}",
            "gap": f"{(1 - eff) * 100:.2f}",
            "refined": _fixed(cert.get("refined_plan"), ".4f" if "plan_logdet" in cert else ".4g"),
        }
    rel = m.get("relative_std") or {}
    rows = [
        {
            "pose": i,
            "q": ", ".join(f"{x:.1f}" for x in p.get("q_deg", [])),
            "load": p.get("load", ""),
            "repeats": p.get("repeats", 1),
        }
        for i, p in enumerate(design["poses"])
    ]
    own = (design.get("input_plan") or {}).get("measures") or {}

    def measures(src: dict) -> list[tuple[str, str]]:
        return [(k, _fixed(src.get(k), ".4g")) for k in ("A", "D", "AD") if _finite(src.get(k)) is not None]

    meas = measures(m)
    if _finite(m.get("pose_rms_um")) is not None:
        meas.append(("pose (µm rms at [work])", f"{m['pose_rms_um']:.2f}"))
    return {
        "criterion": design["criterion"],
        "configs": design.get("configs", len(rows)),
        "candidates": (design.get("candidates") or {}).get("count"),
        "certificate": c,
        "measures": meas,
        "own": measures(own),
        "relative_std": [
            (k, _fixed(v * 100 if _finite(v) is not None else None, ".2g"))
            for k, v in rel.items()
            if _finite(v) is not None
        ],
        "rows": rows,
    }


def reproduce_section(log_path: Path, log: CampaignLog, simulated: bool, inputs: dict, out: Path) -> dict:
    q = shlex.quote
    cmds = []
    if simulated:
        cmds.append(
            (
                "the campaign log (the scenario with its [truth], seed of the log)",
                f"calbench simulate {q(str(log.header.get('scenario_name', 'SCENARIO')) + '.toml')} "
                f"--out {q(str(log_path))} --seed {log.header.get('seed')}",
            )
        )

    def model_flag(model: str | None) -> str:  # identify and discover name the log's own
        model = str(model or "")  # MJCF so: "... (from the log)", "MJCF from
        return "" if not model or "from the log" in model else f" --model {q(model)}"  # the log"

    if "identify" in inputs:
        path, rep = inputs["identify"]
        cmds.append(
            (
                "parameters, correlation, residuals",
                f"calbench identify {q(str(log_path))}{model_flag(rep.model)} --method "
                f"{q(str(rep.method))} --json {q(str(path))}",
            )
        )
    if "discover" in inputs:
        path, doc = inputs["discover"]
        cmds.append(
            (
                "discovery",
                f"calbench discover {q(str(log_path))}{model_flag(doc.get('model'))} --json {q(str(path))}",
            )
        )
    if "design" in inputs:
        path, doc = inputs["design"]
        n = (doc.get("candidates") or {}).get("count")
        cmds.append(
            (
                "design",
                f"calbench design {q(str(doc.get('scenario', 'SCENARIO.toml')))} "
                f"--configs {doc.get('configs')} --criterion {q(str(doc['criterion']))}"
                + (f" --candidates {n}" if n else "")
                + (" --no-refine" if doc.get("refinement") == {} else "")
                + f" --json {q(str(path))}",
            )
        )
    flags = "".join(
        f" --{'identified' if k == 'identify' else k} {q(str(p))}" for k, (p, _) in inputs.items()
    )
    cmds.append(("this report", f"calbench report {q(str(log_path))}{flags} --out {q(str(out))}"))
    files_ = [
        {
            "role": "campaign log",
            "path": str(log_path),
            "size": log_path.stat().st_size,
            "sha256": _sha256(log_path),
        }
    ]
    for k, (p, _) in inputs.items():
        files_.append({"role": KINDS[k][0], "path": str(p), "size": p.stat().st_size, "sha256": _sha256(p)})
    return {"commands": cmds, "files": files_, "version": log.header.get("calbench_version", "?")}


# ---------------------------------------------------------------------------------------------
# the page
# ---------------------------------------------------------------------------------------------


def render(context: dict) -> str:
    import jinja2

    env = jinja2.Environment(
        loader=jinja2.FileSystemLoader(str(files("calbench.identify.report").joinpath("templates"))),
        autoescape=True,
        trim_blocks=True,
        lstrip_blocks=True,
        undefined=jinja2.StrictUndefined,
    )
    return env.get_template("report.html.j2").render(**context)


def html_report(
    log_path, identified=None, discover=None, design=None, out: str | os.PathLike = "REPORT.html"
) -> str:
    """The report's HTML text. ``out`` only names the report in its reproduce section."""
    log_path = Path(log_path)
    log = read_log(log_path)  # what identification had: no truth
    simulated = has_truth(log_path)
    inputs: dict[str, tuple[Path, dict]] = {}
    for kind, path in (("identify", identified), ("discover", discover), ("design", design)):
        if path is not None:
            inputs[kind] = (
                Path(path),
                read_identify_report(path) if kind == "identify" else read_json_report(path, kind),
            )
    notes = provenance(log_path, log, inputs)  # refuses inputs that do not belong together
    ident = inputs.get("identify", (None, None))[1]
    disc = inputs.get("discover", (None, None))[1]
    plan = inputs.get("design", (None, None))[1]
    camp = campaign_section(log, simulated)
    ctx = {
        "title": f"Calibration report: {camp['scenario']}",
        "log_name": log_path.name,
        "campaign": camp,
        "parameters": parameters_section(ident) if ident else None,
        "correlation": correlation_section(ident) if ident else None,
        "residuals": residuals_section(ident, camp["reflectors"]) if ident else None,
        "discovery": discovery_section(disc, inputs["discover"][0]) if disc else None,
        "design": design_section(plan) if plan else None,
        "reproduce": reproduce_section(log_path, log, simulated, inputs, Path(out)),
        "log_path": str(log_path),
        "provenance": notes,
    }
    return render(ctx)


def write_report(log_path, out, identified=None, discover=None, design=None) -> Path:
    """Write the report to ``out`` (atomically, bench/core/outputs.py) and return its path.
    Raises InputError before writing anything on bad input."""
    out = check_outputs(
        {"--out": out},
        {"LOG.mcap": log_path, "--identified": identified, "--discover": discover, "--design": design},
    )["--out"]
    return write_text(out, html_report(log_path, identified, discover, design, out))


__all__ = [
    "write_report",
    "profile_interval",
    "html_report",
    "read_json_report",
    "read_identify_report",
    "campaign_section",
    "parameters_section",
    "correlation_section",
    "residuals_section",
    "discovery_section",
    "design_section",
    "aliasing_rows",
    "ambiguous_rows",
]
