"""`calbench design`: optimal measurement configurations (issue 4).

    calbench design SCENARIO.toml --configs M --criterion A|D|AD|pose --out PLAN.toml [--json OUT] [--distinct]
    calbench design SCENARIO.toml --export-candidates CANDS.npz [--normalise]
    calbench design [SCENARIO.toml] --from-candidates CANDS.npz --configs M [--distinct] [--json OUT]
    calbench design SCENARIO.toml --study --out-dir logs/design_study

Pipeline: feasible candidates with their exact information blocks (candidates.py), multi-start
exchange with low-rank updates (exchange.py) and the certificate of its rows against every
M-pose plan from the candidates (selection.py, certificate.py), then a continuous refinement of the chosen configurations:
coordinate steps of 4, 2 and 1 degree on each joint of each chosen pose, accepted when the
pose stays feasible (every rule of design_candidates) and the criterion, recomputed from the
exact block of the moved pose, decreases. PLAN.toml is the input scenario (robot, truth, tracker,
load, work) with the chosen poses as its [[pose]] list: vertical-load poses use [load], lateral
pulls carry their wrench; a configuration chosen twice becomes ``repeats = 2``.

The prior guess of the parameters is the scenario's [truth] (see design_candidates).
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calbench.bench.core import InputError, ProgressSink
from calbench.bench.scenario import Scenario, scenario_as_dict, scenario_to_toml

from .candidates import CandidateSet
from .engine import InfoEngine, unseen_parameters
from .feasibility import LOAD_KINDS, lateral_wrench
from .optimal import (
    CRITERIA,
    Selection,
    SingularCandidates,
    criterion_value,
    information,
    measures,
    select_rows,
    selection_text,
)
from .settings import DesignSettings

REFINE_STEPS_DEG = (4.0, 2.0, 1.0)


@dataclass
class PlanPose:
    q: np.ndarray  # rad
    wrench: np.ndarray  # (6,) world
    kind: int  # 0 vertical (the scenario's [load]), 1 lateral pull
    block: np.ndarray
    repeats: int = 1


@dataclass
class DesignResult:
    criterion: str
    poses: list[PlanPose]
    measures: dict
    exchange_measures: dict
    timings: dict
    exchange: dict
    refine: dict = field(default_factory=dict)
    selection: Selection | None = None  # the exchange's rows and their certificate
    unseen: dict = field(default_factory=dict)  # parameter -> why the plan leaves it undetermined

    def information(self) -> np.ndarray:
        return sum(p.repeats * p.block.T @ p.block for p in self.poses)


def work_jacobian(engine: InfoEngine, scn: Scenario) -> np.ndarray | None:
    """G of the pose criterion: the compensation job's (``engine.job_jacobian``, design --job),
    else the [work] pose's, else None."""
    if engine.job_jacobian is not None:
        return engine.job_jacobian
    return None if scn.work is None else engine.work_jacobian(scn.work.q, scn.work.wrench)


def plan_measures(F: np.ndarray, theta0: np.ndarray, G: np.ndarray | None, names) -> dict:
    """The criteria of information F and each parameter's (``names``) std at the prior theta0."""
    m = measures(F, G)
    out = {k: float(m[k]) for k in ("A", "D", "AD", "pose") if k in m}
    if "pose" in out and np.isfinite(out["pose"]):
        out["pose_rms_um"] = float(np.sqrt(out["pose"]) * 1e6)
    out["relative_std"] = {n: float(s) for n, s in zip(names, m["std"])}
    out["std"] = {n: float(s * t) for n, s, t in zip(names, m["std"], theta0)}
    return out


def _fix(reason: str, every_pose: bool = False) -> str:
    """What to change so that a plan sees a parameter ``reason`` (identify's words) says it lacks;
    ``every_pose``: the reason holds for every candidate, so other poses will not do."""
    if m := re.match(r"no pose's load puts a torque on motor (\d+)", reason):
        return f"hang the payload off motor {m[1]}'s axis (calbench:payload, the overlay's [payload] pos)" + (
            "" if every_pose else ", or add poses whose load has a lever arm about it"
        )
    if m := re.match(r"every load is vertical, so none turns the J(\d+)", reason):
        return "add lateral pulls ([design] lateral_force > 0) or a [[pose]] with a horizontal wrench"
    if m := re.match(r"no reflector seen moves when motor (\d+)", reason):
        return f"place a reflector off motor {m[1]}'s axis, seen by the tracker"
    if m := re.match(r"only \d+ distinct (q\d+)", reason):
        return f"poses at three or more {m[1]}"
    if every_pose:
        return "a robot description whose parameters each move a reflector (check-robot), or fewer parameters"
    return "more poses, or other ones (calbench design chooses them)"


def unseen_lines(reasons: dict[str, str], indent: str = "    ", every_pose: bool = False) -> list[str]:
    """One line per distinct reason: the parameters, why the plan cannot determine them, and the
    fix (the reasons of :func:`engine.unseen_parameters`; ``every_pose``: of all the candidates)."""
    groups: dict[str, list[str]] = {}
    for name, why in reasons.items():
        groups.setdefault(why, []).append(name)
    return [
        f"{indent}{', '.join(names)}: {why}; fix: {_fix(why, every_pose)}" for why, names in groups.items()
    ]


def scenario_plan_information(engine: InfoEngine, scn: Scenario) -> tuple[np.ndarray, list]:
    """Fisher information of the scenario's own [[pose]] plan (reflectors visible in both states
    only, as identification uses them) and each pose's violated design rules."""
    F = np.zeros((len(engine.theta0),) * 2)
    viol = []
    for i, p in enumerate(scn.poses):
        w = p.wrench if p.wrench is not None else np.r_[engine.robot.weight(scn.load_mass), 0, 0, 0.0]
        info = engine.pose(p.q, w, require_all_visible=True)
        if info.violations:
            viol.append({"pose": i, "rules": info.violations})
        # information with what is actually seen
        info = engine.pose(p.q, w, require_all_visible=False, repeats=p.repeats)
        F += info.block.T @ info.block
    return F, viol


def _lateral_sign(q, w) -> float:
    return 1.0 if (-np.sin(q[0]) * w[0] + np.cos(q[0]) * w[1]) >= 0 else -1.0


def refine(
    engine: InfoEngine,
    poses: list[PlanPose],
    criterion: str,
    G,
    steps=REFINE_STEPS_DEG,
    budget_s: float = 20.0,
    progress: ProgressSink | None = None,
) -> dict:
    """Coordinate descent in q on each chosen pose (see the module docstring). In place."""
    t0 = time.perf_counter()
    F = sum(p.repeats * p.block.T @ p.block for p in poses)
    cur = criterion_value(criterion, F, G)
    start = cur
    tried = accepted = 0
    force = engine.settings.lateral_force
    for step in steps:
        for k, p in enumerate(poses):
            for j in range(len(p.q)):
                for sgn in (1.0, -1.0):
                    if time.perf_counter() - t0 > budget_s:
                        break
                    q2 = p.q.copy()
                    q2[j] += sgn * np.radians(step)
                    w2 = (
                        p.wrench
                        if p.kind == 0
                        else lateral_wrench(q2[0], _lateral_sign(p.q, p.wrench), force)
                    )
                    tried += 1
                    try:
                        info = engine.pose(q2, w2, LOAD_KINDS[p.kind])
                    except (np.linalg.LinAlgError, RuntimeError):
                        continue
                    if info.violations:
                        continue
                    F2 = F - p.repeats * p.block.T @ p.block + p.repeats * info.block.T @ info.block
                    v = criterion_value(criterion, F2, G)
                    if v < cur * (1 - 1e-9):
                        poses[k] = p = PlanPose(q2, w2, p.kind, info.block, p.repeats)
                        F, cur = F2, v
                        accepted += 1
            if progress:
                progress.update(f"refining ({step:g} deg) pose {k + 1}/{len(poses)}")
    return {
        "before": start,
        "after": cur,
        "tried": tried,
        "accepted": accepted,
        "seconds": time.perf_counter() - t0,
        "steps_deg": list(steps),
    }


def poses_of_rows(q, wrench, kind, blocks, rows) -> list[PlanPose]:
    """The plan's poses from candidate rows (q in rad), one per row (repeats not merged)."""
    return [PlanPose(q[i].copy(), wrench[i].copy(), int(kind[i]), blocks[i].copy()) for i in rows]


def merge_repeats(poses: list[PlanPose]) -> list[PlanPose]:
    """Identical configurations (q and wrench) merged into one pose with repeats."""
    merged: list[PlanPose] = []
    for p in poses:
        for m in merged:
            if np.allclose(m.q, p.q, atol=1e-12) and np.allclose(m.wrench, p.wrench):
                m.repeats += p.repeats
                break
        else:
            merged.append(p)
    return merged


def design_plan(
    scn: Scenario,
    settings: DesignSettings,
    cands: CandidateSet,
    M: int,
    criterion: str,
    n_random: int = 8,
    seed: int = 0,
    do_refine: bool = True,
    engine: InfoEngine | None = None,
    progress: ProgressSink | None = None,
    distinct: bool = False,
) -> DesignResult:
    """The plan of M configurations: exchange on the candidates, certificate of its rows
    (selection.py), then the continuous refinement (which leaves the candidate set: the
    certificate is of the plan before it). ``distinct``: no candidate twice."""
    if criterion not in CRITERIA:
        raise InputError("--criterion", "criterion", "one of " + ", ".join(CRITERIA), criterion)
    if distinct and M > len(cands):
        raise InputError("--configs", "configs", f"at most {len(cands)} (the candidates) with --distinct", M)
    engine = engine or InfoEngine(scn, settings)
    G = work_jacobian(engine, scn)
    if criterion == "pose" and G is None:
        raise InputError(
            scn.path,
            "work",
            "a [work] table (q in degrees, wrench in N and N*m) for "
            "--criterion pose: the pose measure is the compliance error there",
            None,
        )
    try:
        sel = select_rows(cands.blocks, M, criterion, G, distinct=distinct, n_random=n_random, seed=seed)
    except SingularCandidates as exc:
        F = information(cands.blocks)
        why = unseen_parameters(engine, F, cands.q, cands.wrench)
        got = "; ".join(line.strip() for line in unseen_lines(why, every_pose=True)) or str(exc)
        raise InputError(
            scn.path,
            "design",
            "candidates that identify every parameter",
            f"from none of {len(cands)}: {got}",
        ) from None
    r = sel.exchange
    if progress:
        progress.update("exchange done")
    poses = poses_of_rows(cands.q, cands.wrench, cands.kind, cands.blocks, r.idx)
    exch_meas = plan_measures(information(cands.blocks, r.idx), cands.theta0, G, cands.param_names)
    ref = {}
    if do_refine:
        ref = refine(engine, poses, criterion, G, progress=progress)
    merged = merge_repeats(poses)
    F = sum(p.repeats * p.block.T @ p.block for p in merged)
    unseen = unseen_parameters(
        engine, F, np.array([p.q for p in merged]), np.array([p.wrench for p in merged])
    )
    return DesignResult(
        criterion,
        merged,
        plan_measures(F, cands.theta0, G, cands.param_names),
        exch_meas,
        {**sel.seconds, "refine_s": ref.get("seconds", 0.0)},
        {
            "value": r.value,
            "start_values": r.start_values,
            "start_results": r.start_results,
            "passes": r.passes,
            "swaps": r.swaps,
            "scans": sel.exchanger_stats["scans"],
            "exact_evaluations": sel.exchanger_stats["exact_evaluations"],
            "indices": r.idx.tolist(),
        },
        ref,
        sel,
        unseen,
    )


def plan_scenario_text(scn: Scenario, poses: list[PlanPose], out: Path, comment: str = "") -> str:
    """The runnable scenario: scn with its [[pose]] list replaced by ``poses``."""
    doc = scenario_as_dict(scn, out.parent)
    doc.pop("design", None)
    entries = []
    for p in poses:
        e = {"q": np.round(np.degrees(p.q), 10).tolist()}
        if p.kind != 0:
            e["wrench"] = [float(x) for x in p.wrench]
        e["repeats"] = int(p.repeats)
        entries.append(e)
    doc["pose"] = entries
    head = "".join(f"# {line}\n" for line in comment.splitlines())
    return head + scenario_to_toml(doc)


def result_json(res: DesignResult, scn: Scenario, cands: CandidateSet, extra: dict | None = None) -> dict:
    out = {
        "scenario": str(scn.path),
        "criterion": res.criterion,
        "configs": int(sum(p.repeats for p in res.poses)),
        "measures": res.measures,
        "not_identifiable": res.unseen,
        "measures_before_refinement": res.exchange_measures,
        "poses": [
            {
                "q_deg": np.round(np.degrees(p.q), 6).tolist(),
                "load": LOAD_KINDS[p.kind],
                "wrench": [float(x) for x in p.wrench],
                "repeats": p.repeats,
            }
            for p in res.poses
        ],
        "candidates": {
            "count": len(cands),
            "lateral": int(cands.kind.sum()),
            **cands.stats,
            "settings": cands.settings.as_dict(),
        },
        "exchange": res.exchange,
        "refinement": res.refine,
        "timings": res.timings,
        "prior_theta": {n: float(t) for n, t in zip(cands.param_names, cands.theta0)},
    }
    if res.selection is not None:
        out.update(res.selection.as_json(cands.q, [LOAD_KINDS[k] for k in cands.kind]))
        if res.refine:
            F = res.information()
            out["certificate"]["refined_plan"] = (
                float(np.linalg.slogdet(F)[1]) if res.criterion == "D" else float(res.measures[res.criterion])
            )
    if extra:
        out.update(extra)
    return out


def input_plan_measures(engine: InfoEngine, scn: Scenario, theta0: np.ndarray) -> dict:
    """The scenario's own [[pose]] plan, measured like a designed one, with its rule violations."""
    F_in, viol = scenario_plan_information(engine, scn)
    q = np.array([p.q for p in scn.poses])
    w = np.array(
        [
            p.wrench if p.wrench is not None else np.r_[engine.robot.weight(scn.load_mass), 0, 0, 0.0]
            for p in scn.poses
        ]
    )
    return {
        "configs": int(sum(p.repeats for p in scn.poses)),
        "measures": plan_measures(F_in, theta0, work_jacobian(engine, scn), engine.robot.layout.names),
        "violations": viol,
        "not_identifiable": unseen_parameters(engine, F_in, q, w),
    }


def summary_text(res: DesignResult, cands: CandidateSet, input_plan: dict) -> str:
    """What `calbench design` prints: the plan's measures beside the scenario's own plan's, and
    the certificate with the continuous design (selection_text)."""
    m, mi = res.measures, input_plan["measures"]
    configs = int(sum(p.repeats for p in res.poses))
    text = (
        f"design: {res.criterion}-optimal plan of {configs} configurations from {len(cands)} candidates\n"
        f"  A (trace cov) {m['A']:.4g}   D (det^1/{len(m['std'])}) {m['D']:.4g}   AD {m['AD']:.4g}"
        + (f"   pose {m['pose']:.4g} m^2 ({m['pose_rms_um']:.2f} um rms)" if "pose" in m else "")
        + f"\n  scenario's own plan ({input_plan['configs']} poses): A {mi['A']:.4g}   D {mi['D']:.4g}"
        + (f"   pose {mi['pose']:.4g}" if "pose" in mi else "")
    )
    unseen = input_plan.get("not_identifiable") or {}
    if unseen:
        text += f"; it leaves {', '.join(unseen)} undetermined:\n" + "\n".join(unseen_lines(unseen))
    if res.unseen:
        text += f"\n  the designed plan leaves {', '.join(res.unseen)} undetermined:\n" + "\n".join(
            unseen_lines(res.unseen, every_pose=True)
        )
    if res.selection is not None:
        text += "\n" + selection_text(res.selection, len(cands), cands.q, [LOAD_KINDS[k] for k in cands.kind])
        if res.refine:
            text += (
                "\n  (the certificate is of the exchange's plan on the candidates; the refinement then "
                f"moved poses off them: {res.criterion} {res.refine['before']:.6g} -> {res.refine['after']:.6g})"
            )
    return text


def plan_comment(scenario: Path, res: DesignResult, job: Path | None = None) -> str:
    """The header comment of a written PLAN.toml: how it was made and what it predicts."""
    m = res.measures
    configs = int(sum(p.repeats for p in res.poses))
    return (
        f"Measurement plan by `calbench design {Path(scenario).name} --configs {configs} "
        f"--criterion {res.criterion}" + (f" --job {Path(job).name}" if job is not None else "") + "`"
        "\n(prior guess = the scenario's [truth]). Predicted: "
        f"A = {m['A']:.6g}, D = {m['D']:.6g}, AD = {m['AD']:.6g}"
        + (f", pose = {m['pose']:.6g} m^2" if "pose" in m else "")
        + (
            ""
            if res.selection is None
            else f"\nCertified efficiency of the exchange's plan (before refinement): "
            f"{100 * res.selection.certificate.efficiency:.2f} % of the best {configs}-pose "
            f"{'distinct ' if res.selection.distinct else ''}plan from the candidates ({res.criterion})"
        )
    )


__all__ = [
    "poses_of_rows",
    "merge_repeats",
    "input_plan_measures",
    "summary_text",
    "plan_comment",
    "design_plan",
    "plan_scenario_text",
    "scenario_plan_information",
    "plan_measures",
    "refine",
    "work_jacobian",
    "PlanPose",
    "DesignResult",
]
