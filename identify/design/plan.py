"""`calbench design`: optimal measurement configurations (issue 4).

    calbench design SCENARIO.toml --configs M --criterion A|D|AD|pose --out PLAN.toml [--json OUT]
    calbench design SCENARIO.toml --export-candidates CANDS.npz
    calbench design SCENARIO.toml --study --out-dir logs/design_study

Pipeline: feasible candidates with their exact information blocks
(identify/design_candidates.py), multi-start exchange with low-rank updates
(identify/design_exchange.py), then a continuous refinement of the chosen configurations:
coordinate steps of 4, 2 and 1 degree on each joint of each chosen pose, accepted when the
pose stays feasible (every rule of design_candidates) and the criterion, recomputed from the
exact block of the moved pose, decreases. PLAN.toml is the input scenario (robot, truth, tracker,
load, work) with the chosen poses as its [[pose]] list: vertical-load poses use [load], lateral
pulls carry their wrench; a configuration chosen twice becomes ``repeats = 2``.

The prior guess of the parameters is the scenario's [truth] (see design_candidates).
"""
from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calbench.bench.campaign import GRAVITY
from calbench.bench.errors import InputError
from calbench.bench.progress import Progress
from calbench.bench.scenario import Scenario, scenario_as_dict, scenario_to_toml

from .candidates import (LOAD_KINDS, CandidateSet, DesignSettings, InfoEngine,
                                generate_candidates, lateral_wrench, load_design_scenario)
from .criteria import CRITERIA, criterion_value, information, measures
from .exchange import Exchanger
from ..forward import PARAM_NAMES

REFINE_STEPS_DEG = (4.0, 2.0, 1.0)


@dataclass
class PlanPose:
    q: np.ndarray          # rad
    wrench: np.ndarray     # (6,) world
    kind: int              # 0 vertical (the scenario's [load]), 1 lateral pull
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

    def information(self) -> np.ndarray:
        return sum(p.repeats * p.block.T @ p.block for p in self.poses)


def work_jacobian(engine: InfoEngine, scn: Scenario) -> np.ndarray | None:
    return None if scn.work is None else engine.work_jacobian(scn.work.q, scn.work.wrench)


def plan_measures(F: np.ndarray, theta0: np.ndarray, G: np.ndarray | None) -> dict:
    m = measures(F, G)
    out = {k: float(m[k]) for k in ("A", "D", "AD", "pose") if k in m}
    if "pose" in out and np.isfinite(out["pose"]):
        out["pose_rms_um"] = float(np.sqrt(out["pose"]) * 1e6)
    out["relative_std"] = {n: float(s) for n, s in zip(PARAM_NAMES, m["std"])}
    out["std"] = {n: float(s * t) for n, s, t in zip(PARAM_NAMES, m["std"], theta0)}
    return out


def scenario_plan_information(engine: InfoEngine, scn: Scenario) -> tuple[np.ndarray, list]:
    """Fisher information of the scenario's own [[pose]] plan (reflectors visible in both states
    only, as identification uses them) and each pose's violated design rules."""
    F = np.zeros((len(engine.theta0),) * 2)
    viol = []
    for i, p in enumerate(scn.poses):
        w = p.wrench if p.wrench is not None else np.array([0, 0, -scn.load_mass * GRAVITY, 0, 0, 0.0])
        info = engine.pose(p.q, w, require_all_visible=True)
        if info.violations:
            viol.append({"pose": i, "rules": info.violations})
        # information with what is actually seen
        info = engine.pose(p.q, w, require_all_visible=False, repeats=p.repeats)
        F += info.block.T @ info.block
    return F, viol


def _lateral_sign(q, w) -> float:
    return 1.0 if (-np.sin(q[0]) * w[0] + np.cos(q[0]) * w[1]) >= 0 else -1.0


def refine(engine: InfoEngine, poses: list[PlanPose], criterion: str, G, steps=REFINE_STEPS_DEG,
           budget_s: float = 20.0, progress: Progress | None = None) -> dict:
    """Coordinate descent in q on each chosen pose (see the module docstring). In place."""
    t0 = time.perf_counter()
    F = sum(p.repeats * p.block.T @ p.block for p in poses)
    cur = criterion_value(criterion, F, G)
    start = cur
    tried = accepted = 0
    force = engine.settings.lateral_force
    for step in steps:
        for k, p in enumerate(poses):
            for j in range(6):
                for sgn in (1.0, -1.0):
                    if time.perf_counter() - t0 > budget_s:
                        break
                    q2 = p.q.copy()
                    q2[j] += sgn * np.radians(step)
                    w2 = p.wrench if p.kind == 0 else lateral_wrench(q2[0], _lateral_sign(p.q, p.wrench), force)
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
    return {"before": start, "after": cur, "tried": tried, "accepted": accepted,
            "seconds": time.perf_counter() - t0, "steps_deg": list(steps)}


def design_plan(scn: Scenario, settings: DesignSettings, cands: CandidateSet, M: int, criterion: str,
                n_random: int = 8, seed: int = 0, do_refine: bool = True, engine: InfoEngine | None = None,
                progress: Progress | None = None) -> DesignResult:
    if criterion not in CRITERIA:
        raise InputError("--criterion", "criterion", "one of " + ", ".join(CRITERIA), criterion)
    engine = engine or InfoEngine(scn, settings)
    G = work_jacobian(engine, scn)
    if criterion == "pose" and G is None:
        raise InputError(scn.path, "work", "a [work] table (q in degrees, wrench in N and N*m) for "
                         "--criterion pose: the pose measure is the compliance error there", None)
    t0 = time.perf_counter()
    ex = Exchanger(cands.blocks, criterion, G)
    r = ex.optimise(M, n_random=n_random, seed=seed)
    t_ex = time.perf_counter() - t0
    if progress:
        progress.update("exchange done")
    poses = [PlanPose(cands.q[i].copy(), cands.wrench[i].copy(), int(cands.kind[i]), cands.blocks[i].copy())
             for i in r.idx]
    exch_meas = plan_measures(information(cands.blocks, r.idx), cands.theta0, G)
    ref = {}
    if do_refine:
        ref = refine(engine, poses, criterion, G, progress=progress)
    # merge identical configurations into repeats
    merged: list[PlanPose] = []
    for p in poses:
        for m in merged:
            if np.allclose(m.q, p.q, atol=1e-12) and np.allclose(m.wrench, p.wrench):
                m.repeats += p.repeats
                break
        else:
            merged.append(p)
    F = sum(p.repeats * p.block.T @ p.block for p in merged)
    return DesignResult(criterion, merged, plan_measures(F, cands.theta0, G), exch_meas,
                        {"exchange_s": t_ex, "refine_s": ref.get("seconds", 0.0)},
                        {"value": r.value, "start_values": r.start_values, "start_results": r.start_results,
                         "passes": r.passes, "swaps": r.swaps, "scans": ex.stats["scans"],
                         "exact_evaluations": ex.stats["exact_evaluations"], "indices": r.idx.tolist()},
                        ref)


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
        "scenario": str(scn.path), "criterion": res.criterion,
        "configs": int(sum(p.repeats for p in res.poses)),
        "measures": res.measures, "measures_before_refinement": res.exchange_measures,
        "poses": [{"q_deg": np.round(np.degrees(p.q), 6).tolist(), "load": LOAD_KINDS[p.kind],
                   "wrench": [float(x) for x in p.wrench], "repeats": p.repeats} for p in res.poses],
        "candidates": {"count": len(cands), "lateral": int(cands.kind.sum()), **cands.stats,
                       "settings": cands.settings.as_dict()},
        "exchange": res.exchange, "refinement": res.refine, "timings": res.timings,
        "prior_theta": {n: float(t) for n, t in zip(PARAM_NAMES, cands.theta0)},
    }
    if extra:
        out.update(extra)
    return out


def add_design(sub) -> None:
    p = sub.add_parser("design", help="optimal measurement configurations (design of experiments)")
    p.add_argument("scenario", type=Path, help="scenario TOML (robot, truth = prior guess, tracker, load, "
                   "optional [work] and [design])")
    p.add_argument("--configs", type=int, default=12, help="number of measurement configurations M")
    p.add_argument("--criterion", choices=CRITERIA, default="A")
    p.add_argument("--out", type=Path, default=None, help="write the plan as a runnable scenario")
    p.add_argument("--json", type=Path, default=None, help="write the criteria, stds and poses as JSON")
    p.add_argument("--export-candidates", type=Path, default=None, help="write the candidate set (NPZ)")
    p.add_argument("--candidates", type=int, default=None, help="override [design] candidates")
    p.add_argument("--starts", type=int, default=8, help="random starts besides the greedy one")
    p.add_argument("--no-refine", action="store_true", help="skip the continuous refinement")
    p.add_argument("--processes", type=int, default=None, help="worker processes for the candidates")
    p.add_argument("--study", action="store_true", help="reproduce the paper's §5 study (plots)")
    p.add_argument("--out-dir", type=Path, default=Path("logs/design_study"), help="--study output folder")
    p.set_defaults(func=cmd_design)


def cmd_design(args) -> int:
    if args.study:
        from .study import run_study
        run_study(args.scenario, args.out_dir, progress=sys.stderr.isatty())
        return 0
    if args.out is None and args.json is None and args.export_candidates is None:
        raise InputError("(command line)", "--out", "--out PLAN.toml, --json OUT.json or --export-candidates "
                         "CANDS.npz", None)
    if args.configs < 1:
        raise InputError("--configs", "configs", "an integer >= 1", args.configs)
    scn, settings = load_design_scenario(args.scenario)
    if args.criterion == "pose" and scn.work is None and (args.out or args.json):
        raise InputError(scn.path, "work", "a [work] table (q in degrees, wrench in N and N*m) for "
                         "--criterion pose", None)
    tty = sys.stderr.isatty()
    t0 = time.perf_counter()
    cands = generate_candidates(scn, settings, n=args.candidates, processes=args.processes, progress=tty)
    t_c = time.perf_counter() - t0
    print(f"{len(cands)} feasible candidates ({int(cands.kind.sum())} lateral pulls) in {t_c:.1f} s "
          f"from {cands.stats['raw_commands']} sampled commands", file=sys.stderr)
    if args.export_candidates:
        args.export_candidates.parent.mkdir(parents=True, exist_ok=True)
        cands.save_npz(args.export_candidates)
        print(f"wrote {args.export_candidates}", file=sys.stderr)
    if args.out is None and args.json is None:
        return 0
    bar = Progress(total=1 + 3 * args.configs, enabled=tty)
    engine = InfoEngine(scn, settings)
    res = design_plan(scn, settings, cands, args.configs, args.criterion, n_random=args.starts,
                      do_refine=not args.no_refine, engine=engine, progress=bar)
    bar.close()
    res.timings["candidates_s"] = t_c
    G = work_jacobian(engine, scn)
    F_in, viol = scenario_plan_information(engine, scn)
    input_plan = {"configs": int(sum(p.repeats for p in scn.poses)),
                  "measures": plan_measures(F_in, cands.theta0, G), "violations": viol}
    m = res.measures
    summary = (f"design: {args.criterion}-optimal plan of {args.configs} configurations "
               f"from {len(cands)} candidates\n"
               f"  A (trace cov) {m['A']:.4g}   D (det^1/8) {m['D']:.4g}   AD {m['AD']:.4g}"
               + (f"   pose {m['pose']:.4g} m^2 ({m['pose_rms_um']:.2f} um rms)" if "pose" in m else "")
               + f"\n  scenario's own plan ({input_plan['configs']} poses): A {input_plan['measures']['A']:.4g}"
               f"   D {input_plan['measures']['D']:.4g}"
               + (f"   pose {input_plan['measures']['pose']:.4g}" if "pose" in input_plan["measures"] else ""))
    print(summary)
    if args.out:
        comment = (f"Measurement plan by `calbench design {Path(args.scenario).name} --configs {args.configs} "
                   f"--criterion {args.criterion}`\n(prior guess = the scenario's [truth]). Predicted: "
                   f"A = {m['A']:.6g}, D = {m['D']:.6g}, AD = {m['AD']:.6g}"
                   + (f", pose = {m['pose']:.6g} m^2" if "pose" in m else ""))
        text = plan_scenario_text(scn, res.poses, args.out, comment)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text)
        print(f"wrote {args.out}", file=sys.stderr)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result_json(res, scn, cands, {"input_plan": input_plan}), indent=2))
    return 0


__all__ = ["add_design", "cmd_design", "design_plan", "plan_scenario_text", "scenario_plan_information",
           "plan_measures", "refine", "work_jacobian", "PlanPose", "DesignResult"]
