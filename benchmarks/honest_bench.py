"""Never confidently wrong, measured (issue 22): `calbench discover` over robots x every library
effect x two magnitudes x seeds, plus null campaigns.

    nice -n 10 python benchmarks/honest_bench.py [--seeds 10] [--nulls 20] [--processes 2]
        [--robots fanuc,kr270,irb6640,kr210] [--out logs/honest] [--quick] [--report-only]

ROBOTS. The FANUC (scenarios/paper_table5.toml), the KUKA KR 270 (scenarios/kr270_paper.toml)
and two converted third-party robots: the ABB IRB 6640 case (../shared/data/cases/irb6640, its
Table 5-style plan with the hidden effect removed) and the KUKA KR 210 R2700-2, converted here
with `calbench from-urdf` from ../shared/data/robots/kuka_quantec_support with the overlay and
first plan of docs/your-robot.md, the plan designed by `calbench design --distinct` (all of it in
a temporary folder: nothing made from the shared data is kept).

CELLS. Each robot's study (identify/study/spec.py: a base scenario, an ``effect`` axis of cases,
``seeds`` campaigns per cell with the study's common random numbers) hides every effect of the
discovery library (bench/model/effects/: link_compliance on each link the robot names,
joint_nonlinearity on each axis, base_compliance, tracker_drift; the compensator on the FANUC,
removed from the model discover starts from, as studies/discovery_power.toml does) at two
magnitudes, JUST DETECTABLE and 3x that. Just detectable is computed on a pilot campaign (no
effect, a seed no replicate uses) at the user's model fitted as identify fits it: the effect's
excited parameters each at the size whose signature is sqrt(T_1) (the aliasing report's
reference magnitude), the vector scaled so that what the user's model cannot absorb of it, |P d|^2
to first order, is the candidate's likelihood-ratio threshold T_k (identify/discover/decide.py):
about half the campaigns should name it, 3x (|P d|^2 = 9 T_k) nearly all. An effect the plan
absorbs exactly (no visible part: no size of it is ever named) is hidden at its reference
magnitude and 3x, and marked ``absorbed``. A joint cubic's deflection is not linear in its size
(its stiffening saturates, its softening nears a loss of equilibrium), so its sizes are solved on
the exact statics instead (:func:`exact_sizes`: lambda = T_1 and 9 T_1, the noncentrality of
identify/discover/aliasing.py's EXACT); a cubic no size of which is named is labelled ``never``
(1x) or ``saturates`` (3x) and hidden at its first-order sizes. Before stop 31 the cubics were
hidden at their first-order sizes: on the KR 270 a J6 cubic "at 3x" left lambda 2.1, not 138.
The IRB 6640 also runs the issue's own case (link_2 bending [0, 3e-7, 3e-7] rad/(N*m)). NULL campaigns: the base scenario, ``--nulls`` seeds.

PER CAMPAIGN. Simulate in memory (identify/study's simulate_in_memory, the observations a log
reader gets), then discover_observations with the user's model; the truth is read only
afterwards. Outcome (by the first step): the right effect named; ambiguous including it; nothing
named; unexplained; a wrong effect (or an ambiguous verdict without it). CONFIDENTLY WRONG: a
parameter reported as determined (after the profile check, the valley walks and the self-check) with
|estimate - truth| > 4.5 std, unless the hidden effect was not named and the exposure report
predicted it (the hidden effect among the parameter's ``unbounded_by``, or the gap within
4.5 std plus its exposure to that effect), and any determined combination beyond 4.5 std. The
truth of a named effect's parameter is the hidden one's where it is that effect, else 0.

PER CELL: the shares with one-sided 95 % Clopper-Pearson upper bounds; on the nulls the
false-alarm rate (anything named, ambiguous or unexplained) with its bound; ``valley_flags``:
the campaigns where a walk along an undetermined parameter left another one undetermined
(identify/discover/uncertainty.py's along_valleys; the record's ``valley`` names them). Writes
OUT/campaigns.jsonl (one line per campaign; a rerun skips what is there), OUT/honest.json,
OUT/honest_table.md and OUT/honest.png (docs/discovery.md shows them). Progress: one line per
campaign on stderr with the counts so far and the expected remaining time.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy import stats

ROOT = Path(__file__).resolve().parent.parent
Z_DETERMINED = 4.5
SHARED = Path(__file__).resolve().parents[3] / "shared" / "data"
OUTCOMES = ("right", "ambiguous_with", "nothing", "unexplained", "wrong")
ISSUE_CASE = {"link": "link_2", "compliance": [0.0, 3e-7, 3e-7]}

# ----------------------------------------------------------------------------- robots


def shared_data() -> Path:
    import os

    return Path(os.environ.get("CALBENCH_SHARED_DATA", SHARED))


def doc_block(name: str) -> str:
    """The TOML code block of docs/your-robot.md whose first line is ``# name``."""
    text = (ROOT / "docs" / "your-robot.md").read_text()
    for block in re.findall(r"```toml\n(.*?)```", text, re.S):
        if block.startswith(f"# {name}"):
            return block
    raise KeyError(name)


def kr210_scenario(tmp: Path, log) -> Path:
    """The KR 210 of docs/your-robot.md: from-urdf with its overlay, design --distinct on its first
    plan (2000 candidates). Returns the designed scenario."""
    from calbench.identify.cli import main as identify_main

    pkg = shared_data() / "robots" / "kuka_quantec_support"
    overlay = doc_block("kr210.toml").replace('"robots/kuka_quantec_support"', f'"{pkg}"')
    (tmp / "kr210.toml").write_text(overlay)
    (tmp / "kr210_plan.toml").write_text(doc_block("kr210_plan.toml"))
    xacro = pkg / "urdf" / "kr210_r2700_2.urdf.xacro"
    log("kr210: calbench from-urdf (KUKA KR 210 R2700-2, docs/your-robot.md)")
    argv = ["from-urdf", str(xacro), "--overlay", str(tmp / "kr210.toml"), "--out", str(tmp / "kr210.xml")]
    if identify_main(argv) != 0:
        raise RuntimeError("from-urdf failed")
    log("kr210: calbench design --distinct --candidates 2000")
    out = tmp / "kr210_designed.toml"
    argv = ["design", str(tmp / "kr210_plan.toml"), "--distinct", "--candidates", "2000", "--out", str(out)]
    if identify_main(argv) != 0:
        raise RuntimeError("design failed")
    return out


def irb_scenario(tmp: Path) -> Path:
    """The IRB 6640 case's plan with its hidden effect removed (the robot by absolute path)."""
    case = shared_data() / "cases" / "irb6640"
    text = (case / "irb6640_hidden.toml").read_text()
    text = text.replace('robot = "irb6640.xml"', f'robot = "{case / "irb6640.xml"}"')
    text = re.sub(r"\[truth\.effects\.link_compliance\]\n(?:(?!\[).*\n)*", "", text)
    path = tmp / "irb6640_null.toml"
    path.write_text(text)
    return path


def robot_scenarios(names: list[str], tmp: Path, log) -> dict[str, Path]:
    out = {}
    for n in names:
        if n == "fanuc":
            out[n] = ROOT / "scenarios" / "paper_table5.toml"
        elif n == "kr270":
            out[n] = ROOT / "scenarios" / "kr270_paper.toml"
        elif n == "irb6640":
            out[n] = irb_scenario(tmp)
        elif n == "kr210":
            out[n] = kr210_scenario(tmp, log)
        else:
            raise SystemExit(f"unknown robot {n!r}")
    return out


# ----------------------------------------------------------------------------- magnitudes


def truth_table(effect, d: np.ndarray) -> tuple[str, dict] | None:
    """(scenario key, value) that hides the library ``effect`` with parameters d (SI); None for
    an effect the bench cannot hide this way."""
    if effect.name == "link_compliance":
        return "truth.effects.link_compliance", {"link": effect.detail, "compliance": [float(x) for x in d]}
    if effect.name == "joint_nonlinearity":
        return "truth.effects.joint_nonlinearity", {"joint": int(effect.detail[1:]), "cubic": float(d[0])}
    if effect.name == "base_compliance":
        return "truth.effects.base_compliance", {"compliance": [float(x) for x in d]}
    if effect.name == "tracker_drift":
        return "truth.effects.tracker_drift", {"offset": [float(x) for x in d]}
    return None


def hidden_size(jw_base: np.ndarray, est: np.ndarray, block: np.ndarray, size: np.ndarray, k_thr, thr1):
    """(d (k,) SI at 'just detectable', absorbed?) for an effect with whitened columns ``block``
    (module docstring); None when the plan does not excite it at all."""
    from calbench.identify.discover import UNEXCITED, regress

    full = np.linalg.norm(block, axis=0)
    excited = full * size > UNEXCITED
    if not excited.any():
        return None
    d = np.zeros(block.shape[1])
    d[excited] = math.sqrt(thr1) / full[excited]
    _, perp = regress(jw_base[:, est], block[:, excited])
    lam = float(np.sum((perp @ d[excited]) ** 2))
    if lam <= 1e-6 * thr1:  # absorbed exactly: its reference magnitude
        return d, True
    return d * math.sqrt(k_thr / lam), False


def exact_sizes(pilot, white, base, eff, first: float, thr1: float) -> dict:
    """A joint cubic's just-detectable and 3x sizes on the exact statics (module docstring): the
    size whose noise-free signature leaves lambda = T_1 and 9 T_1 (identify/discover/aliasing.py's
    exact_detection). A size not reached is marked: the first-order size is kept, the cell
    labelled ``never`` (1x) or ``saturates`` (3x).
    Stiffening (+) only: a softening cubic's statics lose their equilibrium close to the size it
    is named from (KR 270 J4: LR 3.3 at 6.3e11, none from 8.9e11).
    Returns {"d": (1,), "d3": (1,), "tags": (1x tag, 3x tag), "lambda": {...}}."""
    from calbench.identify.discover import build, effect_priors, exact_detection

    start = effect_priors(eff)[0]
    fm = build(pilot.mjcf, [(eff, start)], pilot.obs)[1]
    est = base.free | base.at_bound
    out, lam = {}, {}
    for key, size, thr in (("d", first, thr1), ("d3", 3 * first, 9 * thr1)):
        recs = exact_detection(eff, fm, white, base, base.extra["jw"], est, 0, size, thr)
        lam[key] = [
            {k: r[k] for k in ("sign", "magnitude", "lambda_first_order", "lambda_max")} for r in recs
        ]
        # stiffening only: its statics have one equilibrium at every size; a softening cubic's
        # lose it close to where it is named, and which branch a solve finds there is the solver's
        named = [r for r in recs if r["magnitude"] is not None and r["sign"] > 0]
        if named:
            out[key] = np.array([named[0]["magnitude"]])
        else:
            out[key] = np.array([size])
            out[f"{key}_tag"] = "never" if key == "d" else "saturates"
    return {
        "d": out["d"],
        "d3": out["d3"],
        "first_order": first,
        "tags": (out.get("d_tag", "exact"), out.get("d3_tag", "exact")),
        "lambda": lam,
    }


def magnitudes(scn_path: Path, robot: str) -> list[dict]:
    """Each library effect's hidden value at just detectable (module docstring), on a pilot
    campaign; the FANUC's compensator (K_C at the scenario's s0) from the model without it."""
    from calbench.bench.model.effects import without_compensator
    from calbench.bench.scenario import load_scenario
    from calbench.identify.core import Whitener
    from calbench.identify.discover import (
        alias_columns,
        base_fit,
        build,
        effect_priors,
        label,
        library,
        lr_threshold,
        whitened,
    )
    from calbench.identify.study import simulate_in_memory

    scn = load_scenario(scn_path)
    pilot = simulate_in_memory(scn)  # the scenario's own seed: no replicate uses it
    white = Whitener.from_observations(pilot.obs)
    base = base_fit(pilot.mjcf, pilot.obs, white)
    lib = library(base.robot)
    est = base.free | base.at_bound
    thr1 = lr_threshold(1, len(lib))
    out = []
    for eff, block in alias_columns(pilot.mjcf, pilot.obs, white, base, lib):
        if truth_table(eff, np.zeros(len(eff.param_names))) is None:
            continue
        got = hidden_size(
            base.extra["jw"],
            est,
            block,
            effect_priors(eff)[3],
            lr_threshold(len(eff.param_names), len(lib)),
            thr1,
        )
        if got is not None:
            out.append({"label": label(eff), "effect": eff, "d": got[0], "absorbed": got[1]})
            if eff.name == "joint_nonlinearity" and not got[1]:
                out[-1].update(exact_sizes(pilot, white, base, eff, float(got[0][0]), thr1))
    if robot == "fanuc":  # the compensator the user's model lacks (studies/discovery_power.toml)
        src = without_compensator(pilot.mjcf)
        nb = base_fit(src, pilot.obs, white)
        comp = next(e for e in library(nb.robot) if e.name == "compensator")
        start = effect_priors(comp)[0].copy()
        start[1] = scn.compensators["compensator"].preload
        _, fm = build(src, [(comp, start)], pilot.obs)
        _, jw = whitened(fm, white, np.r_[nb.values, start])
        got = hidden_size(
            jw[:, :-2],
            nb.free | nb.at_bound,
            jw[:, -2:-1],
            np.array([1e6]),
            lr_threshold(2, len(library(nb.robot))),
            thr1,
        )
        if got is not None:
            out.append({"label": "compensator", "effect": comp, "d": got[0], "absorbed": got[1]})
    return out


def study_text(scn_path: Path, seeds: int, cases: list[dict], seed: int) -> str:
    """A study file (identify/study/spec.py) with one ``effect`` axis of ``cases``."""
    lines = [
        f'scenario = "{scn_path}"',
        f"seeds = {seeds}",
        f"seed = {seed}",
        "[campaign]",
        "discover = true",
        "[[axis]]",
        'name = "effect"',
        "cases = [",
    ]
    for c in cases:
        sets = ", ".join(f'"{k}" = {toml_value(v)}' for k, v in c.get("set", {}).items())
        lines.append(f'  {{ label = "{c["label"]}"' + (f", set = {{ {sets} }}" if sets else "") + " },")
    lines.append("]")
    return "\n".join(lines) + "\n"


def toml_value(v) -> str:
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {toml_value(x)}" for k, x in v.items()) + " }"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, str):
        return json.dumps(v)
    return repr(float(v)) if isinstance(v, float) else str(v)


def cases_for(robot: str, mags: list[dict]) -> list[dict]:
    cases = []
    for m in mags:
        for factor, tag in ((1.0, "1x"), (3.0, "3x")):
            d = m["d"] * factor
            if "d3" in m:  # a cubic sized on the exact statics (exact_sizes)
                d = m["d"] if factor == 1.0 else m["d3"]
                tag = f"{tag}|{m['tags'][0 if factor == 1.0 else 1]}"
            if m["label"] == "compensator":
                sets = {
                    "truth.compensator.stiffness": float(d[0]),
                    "campaign.discover_without": ["compensator"],
                }
            else:
                key, val = truth_table(m["effect"], d)
                sets = {key: val}
            cases.append(
                {"label": f"{m['label']}|{tag}" + ("|absorbed" if m["absorbed"] else ""), "set": sets}
            )
    if robot == "irb6640":
        cases.append(
            {"label": "link_compliance[link_2]|issue", "set": {"truth.effects.link_compliance": ISSUE_CASE}}
        )
    return cases


# ----------------------------------------------------------------------------- one campaign

_STUDIES: dict = {}


def _study(path: str):
    from calbench.identify.study import load_study

    if path not in _STUDIES:
        _STUDIES[path] = load_study(path)
    return _STUDIES[path]


def hidden_truth(scn, cell) -> tuple[dict, str | None]:
    """{effect label: {parameter: true value}} of the hidden effects, and the compensator's."""
    from calbench.bench.model.effects import effect_from_truth

    out = {}
    for name, table in scn.effects.items():
        e, p = effect_from_truth(name, table)
        lab = f"{e.name}[{e.detail}]" if e.detail else e.name
        out[lab] = dict(zip(e.param_names, p))
    return out


def judge(rep: dict, truth_base: dict, hidden: dict, expected: str | None) -> dict:
    """Outcome and confidently-wrong parameters of one discovery (module docstring)."""
    steps = rep["steps"]
    labels = [
        s["effect"]
        + (f"[{s['detail']}]" if s.get("detail") and s["effect"] not in ("ambiguous", "unexplained") else "")
        for s in steps
    ]
    named = [lab for lab in labels if lab not in ("ambiguous", "unexplained")]
    if not steps:
        outcome = "nothing"
    elif steps[0]["effect"] == "unexplained":
        outcome = "unexplained"
    elif steps[0]["effect"] == "ambiguous":
        tied = {t["candidate"] for t in steps[0]["candidates"]}
        outcome = "ambiguous_with" if expected in tied else "wrong"
    else:
        outcome = "right" if labels[0] == expected else "wrong"
    bad = []

    def truth(name: str) -> float:
        if name in truth_base:
            return truth_base[name]
        lab, _, pn = name.rpartition(".")
        return hidden.get(lab, {}).get(pn, 0.0)

    for p in rep["parameters"]:
        if not p["determined"]:
            continue
        name = p["name"]
        t = truth(name)
        gap = abs(p["estimate"] - t)
        allowed = Z_DETERMINED * p["std"]
        excused = False
        ex = p.get("exposure") or {}
        for lab in hidden:
            if lab not in named and ex:
                if lab in ex.get("unbounded_by", []):
                    excused = True
                allowed += ex.get("by_effect", {}).get(lab, 0.0)
        if gap > allowed and not excused:
            bad.append(
                {
                    "name": name,
                    "estimate": p["estimate"],
                    "truth": t,
                    "std": p["std"],
                    "z": (p["estimate"] - t) / p["std"],
                }
            )
    for c in rep.get("combinations", []):
        t = sum(v * truth(n) for n, v in c["combination"].items())  # an effect's: the hidden one's
        if abs(c["estimate"] - t) > Z_DETERMINED * c["std"]:
            bad.append(
                {
                    "name": " + ".join(c["combination"]),
                    "estimate": c["estimate"],
                    "truth": t,
                    "std": c["std"],
                    "z": (c["estimate"] - t) / c["std"],
                }
            )
    return {"outcome": outcome, "named": labels, "confidently_wrong": bad}


def one_campaign(study_path: str, cell_index: int, replicate: int, without: tuple, kind: str) -> dict:
    """Simulate, discover, judge one campaign of a study cell."""
    from calbench.bench.model.effects import without_compensator
    from calbench.identify.discover import discover_observations
    from calbench.identify.study import simulate_in_memory

    study = _study(study_path)
    cell = study.cells[cell_index]
    seed = study.campaign_seed(replicate)
    t0 = time.perf_counter()
    scn = study.portable(cell).scenario(seed)
    sim = simulate_in_memory(scn)
    src = without_compensator(sim.mjcf) if "compensator" in without else sim.mjcf
    rec = {"cell": cell.values.get("effect"), "replicate": replicate, "seed": seed, "kind": kind}
    try:
        rep, _ = discover_observations(sim.obs, src)
    except Exception as exc:  # noqa: BLE001 - a failed campaign is a row, not the end
        rec.update(error=f"{type(exc).__name__}: {exc}"[:300], seconds=time.perf_counter() - t0)
        return rec
    from calbench.bench.model import Robot

    names = Robot.from_xml(sim.mjcf).layout.names
    truth_base = dict(zip(names, sim.truth)) if sim.truth is not None else {}
    hidden = hidden_truth(scn, cell)
    if "compensator" in without:  # the model lacks it: its truth is the named effect's
        hidden["compensator"] = {
            "K_C": truth_base.pop("compensator_stiffness"),
            "s0": truth_base.pop("compensator_preload"),
        }
    expected = cell.expected
    rec.update(judge(rep, truth_base, hidden, expected))
    rec.update(
        expected=expected,
        self_check_failed=rep["self_check"]["failed"],
        valley=[p["name"] for p in rep["parameters"] if p.get("valley")],
        exposure_growth=exposure_growth(rep),
        nonlinear_growth=exposure_growth(rep, "bias_first_order"),
        unconfirmed={
            p["name"]: (p.get("exposure") or {}).get("unconfirmed_by", [])
            for p in rep["parameters"]
            if p["determined"] and (p.get("exposure") or {}).get("unconfirmed_by")
        },
        seconds=time.perf_counter() - t0,
    )
    return rec


def exposure_growth(rep: dict, against: str = "bias_at_estimate") -> list[float]:
    """Per determined parameter: its exposure over the region (identify/discover/exposure.py)
    over its exposure at the estimate alone (``against="bias_first_order"``: over the region's
    first-order exposure, what the nonlinear SIZE check adds): what it costs in words."""
    out = []
    for p in rep["parameters"]:
        ex = p.get("exposure") or {}
        if p["determined"] and ex.get(against):
            out.append(ex["bias"] / ex[against])
    return out


# ----------------------------------------------------------------------------- summary


def cp_upper(k: int, n: int, conf: float = 0.95) -> float:
    """One-sided Clopper-Pearson upper bound of a binomial rate, k of n."""
    if n == 0:
        return 1.0
    return 1.0 if k >= n else float(stats.beta.ppf(conf, k + 1, n - k))


def summarise(rows: list[dict]) -> dict:
    by: dict = {}
    for r in rows:
        by.setdefault((r["robot"], r["cell"]), []).append(r)
    cells = []
    for (robot, cell), rs in sorted(by.items()):
        ok = [r for r in rs if "error" not in r]
        n = len(ok)
        row = {"robot": robot, "cell": cell, "n": n, "errors": len(rs) - n}
        for o in OUTCOMES:
            k = sum(r["outcome"] == o for r in ok)
            row[o] = k
            row[o + "_upper"] = cp_upper(k, n)
        k = sum(bool(r["confidently_wrong"]) for r in ok)
        row["confidently_wrong"] = k
        row["confidently_wrong_upper"] = cp_upper(k, n)
        row["wrong_parameters"] = sorted({b["name"] for r in ok for b in r["confidently_wrong"]})
        row["self_check_flags"] = sum(bool(r["self_check_failed"]) for r in ok)
        row["valley_flags"] = sum(bool(r.get("valley")) for r in ok)  # uncertainty.along_valleys fired
        growth = [g for r in ok for g in r.get("exposure_growth", [])]
        row["exposure_growth_median"] = float(np.median(growth)) if growth else None
        row["exposure_growth_p90"] = float(np.percentile(growth, 90)) if growth else None
        growth = [g for r in ok for g in r.get("nonlinear_growth", [])]
        row["nonlinear_growth_median"] = float(np.median(growth)) if growth else None
        row["nonlinear_growth_p90"] = float(np.percentile(growth, 90)) if growth else None
        row["seconds_median"] = float(np.median([r["seconds"] for r in rs])) if rs else 0.0
        cells.append(row)
    hidden = [r for r in rows if r["kind"] == "hidden" and "error" not in r]
    nulls = [r for r in rows if r["kind"] == "null" and "error" not in r]
    alarms = sum(r["outcome"] != "nothing" for r in nulls)
    cw = sum(bool(r["confidently_wrong"]) for r in hidden + nulls)
    return {
        "cells": cells,
        "hidden_campaigns": len(hidden),
        "null_campaigns": len(nulls),
        "false_alarms": alarms,
        "false_alarm_upper": cp_upper(alarms, len(nulls)),
        "confidently_wrong": cw,
        "confidently_wrong_upper": cp_upper(cw, len(hidden) + len(nulls)),
        "errors": sum("error" in r for r in rows),
    }


def table(summary: dict) -> str:
    head = (
        "| robot | effect | size | n | right | ambiguous with it | nothing | unexplained | wrong | "
        "confidently wrong (95 % bound) |\n|---|---|---|---|---|---|---|---|---|---|"
    )
    out = [head]
    for c in summary["cells"]:
        eff, _, size = c["cell"].partition("|")

        def pct(k: str, c=c) -> str:
            return f"{100 * c[k] / c['n']:.0f} %" if c["n"] else "-"

        out.append(
            f"| {c['robot']} | {eff} | {size or '-'} | {c['n']} | {pct('right')} | {pct('ambiguous_with')} | "
            f"{pct('nothing')} | {pct('unexplained')} | {pct('wrong')} | {c['confidently_wrong']} "
            f"(≤ {100 * c['confidently_wrong_upper']:.0f} %)"
            + (f" {', '.join(c['wrong_parameters'])}" if c["wrong_parameters"] else "")
            + " |"
        )
    return "\n".join(out) + "\n"


def plot(summary: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    robots = sorted({c["robot"] for c in summary["cells"]})
    colors = {
        "right": "#2a9d8f",
        "ambiguous_with": "#8ab17d",
        "nothing": "#bbbbbb",
        "unexplained": "#e9c46a",
        "wrong": "#e76f51",
    }
    fig, axes = plt.subplots(len(robots), 1, figsize=(12, 2.6 * len(robots) + 0.8), squeeze=False)
    for ax, robot in zip(axes[:, 0], robots):
        cs = [c for c in summary["cells"] if c["robot"] == robot and c["n"]]
        x = np.arange(len(cs))
        bottom = np.zeros(len(cs))
        for o in OUTCOMES:
            v = np.array([c[o] / c["n"] for c in cs])
            ax.bar(x, v, bottom=bottom, color=colors[o], label=o.replace("_", " "), width=0.8)
            bottom += v
        for i, c in enumerate(cs):
            if c["confidently_wrong"]:
                ax.text(i, 1.02, f"✗{c['confidently_wrong']}", ha="center", color="red", fontsize=8)
        ax.set_xticks(
            x,
            [c["cell"].replace("|absorbed", "*").replace("|", " ") for c in cs],
            rotation=60,
            ha="right",
            fontsize=7,
        )
        ax.set_ylim(0, 1.12)
        ax.set_ylabel(robot)
    axes[0, 0].legend(ncol=5, fontsize=8, loc="upper left", bbox_to_anchor=(0, 1.35))
    fig.suptitle(
        f"discover on {summary['hidden_campaigns']} hidden-effect and {summary['null_campaigns']} null campaigns: "
        f"confidently wrong {summary['confidently_wrong']} (95 % bound {100 * summary['confidently_wrong_upper']:.1f} %), "
        f"false alarms {summary['false_alarms']} (bound {100 * summary['false_alarm_upper']:.1f} %)",
        fontsize=9,
        y=0.995,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ----------------------------------------------------------------------------- main


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10, help="campaigns per hidden-effect cell (default 10)")
    ap.add_argument("--nulls", type=int, default=20, help="null campaigns per robot (default 20)")
    ap.add_argument("--robots", default="fanuc,kr270,irb6640,kr210", help="default: all four")
    ap.add_argument(
        "--effects", default="", help="only cells whose effect label contains one of these (comma-separated)"
    )
    ap.add_argument("--processes", type=int, default=2, help="local workers (default 2)")
    ap.add_argument("--out", default="logs/honest", help="output folder (default logs/honest)")
    ap.add_argument("--quick", action="store_true", help="smoke: FANUC, 2 effects, 2 seeds, 2 nulls")
    ap.add_argument("--report-only", action="store_true", help="summarise OUT/campaigns.jsonl only")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    jsonl = out / "campaigns.jsonl"
    t0 = time.perf_counter()

    def log(msg: str) -> None:
        print(f"[{time.perf_counter() - t0:7.0f} s] {msg}", file=sys.stderr, flush=True)

    if args.quick:
        args.robots, args.seeds, args.nulls, args.effects = "fanuc", 2, 2, "forearm,j2"
    if not args.report_only:
        run(args, jsonl, log)
    rows = [json.loads(x) for x in jsonl.read_text().splitlines() if x.strip()]
    summary = summarise(rows)
    summary["seconds"] = time.perf_counter() - t0
    (out / "honest.json").write_text(json.dumps(summary, indent=1))
    (out / "honest_table.md").write_text(table(summary))
    plot(summary, out / "honest.png")
    print(table(summary))
    print(json.dumps({k: v for k, v in summary.items() if k != "cells"}, indent=1))
    return 0


def run(args, jsonl: Path, log) -> None:
    from calbench.identify.runtime import choose, open_executor

    done = set()
    if jsonl.exists():
        for x in jsonl.read_text().splitlines():
            if x.strip():
                r = json.loads(x)
                done.add((r["robot"], r["cell"], r["replicate"]))
    tmp = Path(tempfile.mkdtemp(prefix="honest-bench-"))
    robots = [r for r in args.robots.split(",") if r]
    scns = robot_scenarios(robots, tmp, log)
    tasks, meta = [], []
    for robot in robots:
        log(f"{robot}: just-detectable magnitudes on a pilot campaign")
        mags = magnitudes(scns[robot], robot)
        for m in mags:
            log(
                f"  {m['label']}: {np.array2string(m['d'], precision=3)}"
                + (" (absorbed exactly)" if m["absorbed"] else "")
                + (
                    f" on the exact statics ({m['tags'][0]}), 3x: {np.array2string(m['d3'], precision=3)} "
                    f"({m['tags'][1]}); first order said {m['first_order']:.3g}"
                    if "d3" in m
                    else ""
                )
            )
        cases = cases_for(robot, mags)
        if args.effects:
            keys = [k.partition(":") for k in args.effects.split(",")]
            keys = [(r, k) if sep else ("", r) for r, sep, k in keys]
            cases = [c for c in cases if any(r in ("", robot) and k in c["label"] for r, k in keys)]
        for kind, cs, seeds in (("hidden", cases, args.seeds), ("null", [{"label": "none"}], args.nulls)):
            if not cs or seeds < 1:
                continue
            path = tmp / f"{robot}_{kind}_study.toml"
            path.write_text(study_text(scns[robot], seeds, cs, 22))
            study = _study(str(path))
            for cell in study.cells:
                without = tuple(cell.campaign.discover_without)
                for r in range(seeds):
                    if (robot, cell.values["effect"], r) in done:
                        continue
                    tasks.append((str(path), cell.index, r, without, kind))
                    meta.append(robot)
    log(f"{len(tasks)} campaigns to run ({len(done)} already in {jsonl})")
    where = "local" if args.processes > 1 else "in-process"
    n_done, cw, t1 = 0, 0, time.perf_counter()
    with open_executor(choose(where, 0.0, len(tasks), workers=args.processes)) as ex, jsonl.open("a") as fh:
        for i, rec in ex.run(one_campaign, tasks):
            rec["robot"] = meta[i]
            fh.write(json.dumps(rec, default=float) + "\n")
            fh.flush()
            n_done += 1
            cw += bool(rec.get("confidently_wrong"))
            left = (time.perf_counter() - t1) / n_done * (len(tasks) - n_done)
            log(
                f"{n_done}/{len(tasks)} {meta[i]} {rec['cell']} #{rec['replicate']}: "
                f"{rec.get('outcome', rec.get('error'))} {rec.get('named', '')} "
                f"({rec['seconds']:.1f} s; confidently wrong so far {cw}; ~{left / 60:.0f} min left)"
            )


if __name__ == "__main__":
    sys.exit(main())
