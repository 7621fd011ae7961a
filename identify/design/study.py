"""The paper's §5.2 study on our model (`calbench design SCENARIO --study --out-dir DIR`).

Family of plans, as in the paper: the parallelogram angles only. For every q2 in a set and
q3 in {-30, 30} deg, two wrist configurations of Table 5 ([q4, q5, q6] = [-45, 30, 135] and
[45, -30, 45]) at q1 = 0 with the scenario's vertical load, plus the scenario's lateral-pull
poses (fixed: they carry k1, which the parallelogram study does not move). The paper's box
q2 in [0, 120], q3 in [-30, 30] is used as the paper states it; our wrist-centre rule would cut
the q2 = 0, q3 = -30 corner (0.84 m from axis 1), which the study reports but does not enforce.
Reflectors count where seen. In our model q3 - q2 = -120 deg is the degenerate parallelogram
(crank parallel to the upper arm), which lies INSIDE the paper's box (q2 = 90, q3 = -30): for
q2 in (80, 100) only q3 = +30 is used (``bench.robot.Robot.loop_ok``). Measures: the p-parameter
normalised covariance of the one-step estimator (the FANUC's 8: O1 = trace, O2 = det^(1/8),
O3 = (O1 + O2)/2). The paper's measures are over its
"aggregated parameters" of the two-step method with the linear model, so absolute values are not
comparable; shapes are. The study is the paper's, on a six-axis robot (q1..q6 as above);
another robot gets an InputError.

Outputs in DIR: study.json, table1 (3/4/5 distinct q2), fig7_measures_vs_middle_q2.png with the
10/20/50 % intervals (Table 2), fig8_std_vs_middle_q2.png (per-parameter relative std, Tables
3-4).
"""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np

from calbench.bench.core import InputError, write_text

from .engine import InfoEngine
from .optimal import measures
from .settings import load_design_scenario

WRISTS = ((-45.0, 30.0, 135.0), (45.0, -30.0, 45.0))
Q3 = (-30.0, 30.0)


def run_paper_study(scenario: Path, out_dir: Path, progress=None, step: float = 5.0) -> dict:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scn, st = load_design_scenario(scenario)
    eng = InfoEngine(scn, st)
    if eng.robot.n_act != 6:
        raise InputError(
            scn.robot, "calbench:actuated", "the six axes of the paper's robot for --study", eng.robot.n_act
        )
    names = eng.robot.layout.names
    npar = len(names)
    out_dir.mkdir(parents=True, exist_ok=True)
    weight = np.r_[eng.robot.weight(scn.load_mass), 0, 0, 0.0]
    F_lat = np.zeros((npar, npar))
    for p in scn.poses:
        if p.wrench is not None:
            b = eng.pose(p.q, p.wrench, require_all_visible=False, check=False).block
            F_lat += p.repeats * b.T @ b
    cache: dict[float, np.ndarray] = {}

    def info_q2(q2: float) -> np.ndarray:
        if q2 not in cache:
            F = np.zeros((npar, npar))
            for q3 in Q3:
                if not eng.feas.loop(np.radians([0.0, q2, q3, 0, 0, 0])):
                    continue  # q3 - q2 within 10 deg of -120: the loop degenerates (q2 ~ 90, q3 = -30)
                for w in WRISTS:
                    b = eng.pose(
                        np.radians([0.0, q2, q3, *w]), weight, require_all_visible=False, check=False
                    ).block
                    F += b.T @ b
            cache[q2] = F
        return cache[q2]

    def plan(q2s) -> dict:
        m = measures(F_lat + sum(info_q2(float(v)) for v in q2s))
        return {"O1": m["A"], "O2": m["D"], "O3": m["AD"], "std": m["std"]}

    grid = np.arange(0.0, 120.0 + 1e-9, step)
    # Table 1: best plans with 3, 4, 5 distinct q2 (ends 0 and 120 free too, on a 10 deg grid)
    coarse = np.arange(0.0, 121.0, 10.0)
    table1 = {}
    for n in (3, 4, 5):
        best = {}
        for combo in itertools.combinations(coarse, n):
            r = plan(combo)
            for k in ("O1", "O2", "O3"):
                if k not in best or r[k] < best[k][0]:
                    best[k] = (r[k], combo)
        configs = n * len(Q3) * len(WRISTS)
        table1[n] = {
            k: {"value": v, "per_configuration": v * configs, "q2": list(map(float, c))}
            for k, (v, c) in best.items()
        }
    # Fig 7 / Table 2: middle q2 with 0 and 120 fixed
    curves = {k: [] for k in ("O1", "O2", "O3")}
    stds = []
    for mid in grid:
        r = plan((0.0, mid, 120.0))
        for k in curves:
            curves[k].append(r[k])
        stds.append(r["std"])
    stds = np.array(stds)
    table2 = {}
    for k, v in curves.items():
        v = np.array(v)
        i = int(np.argmin(v))
        row = {"argmin_q2": float(grid[i]), "min": float(v[i])}
        for loss in (0.1, 0.2, 0.5):
            ok = grid[v <= v[i] * (1 + loss)]
            row[f"{int(loss * 100)}%"] = [float(ok.min()), float(ok.max())]
        table2[k] = row
    table3 = {
        n: {
            "argmin_q2": float(grid[int(np.argmin(stds[:, j]))]),
            "min_relative_std": float(stds[:, j].min()),
            "max_over_min": float(stds[:, j].max() / stds[:, j].min()),
        }
        for j, n in enumerate(names)
    }

    fig, ax = plt.subplots(1, 3, figsize=(13, 4))
    for a, (k, v) in zip(ax, curves.items()):
        a.plot(grid, v, "k-")
        for loss, c in ((0.1, "g"), (0.2, "orange"), (0.5, "r")):
            lo, hi = table2[k][f"{int(loss * 100)}%"]
            a.axvspan(lo, hi, color=c, alpha=0.12, label=f"{int(loss * 100)}% loss: {lo:g}..{hi:g}")
        a.set_xlabel("middle q2 (deg); q2 = 0 and 120 fixed")
        a.set_title(k)
        a.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out_dir / "fig7_measures_vs_middle_q2.png", dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for j, n in enumerate(names):
        ax.semilogy(grid, stds[:, j], label=n)
    ax.set_xlabel("middle q2 (deg)")
    ax.set_ylabel("relative std")
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(out_dir / "fig8_std_vs_middle_q2.png", dpi=110)
    plt.close(fig)
    res = {
        "table1": table1,
        "table2": table2,
        "table3_parameters": table3,
        "curves": {
            "middle_q2": grid.tolist(),
            **{k: list(map(float, v)) for k, v in curves.items()},
            "relative_std": {n: stds[:, j].tolist() for j, n in enumerate(names)},
        },
    }
    write_text(out_dir / "study.json", json.dumps(res, indent=1))
    return res


__all__ = ["run_paper_study"]
