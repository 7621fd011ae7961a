"""Compliances from the paper's FANUC plan with a hidden geometric error, three ways (docs/geometry.md).

The paper's plan (scenarios/paper_table5.toml: 16 poses, each unloaded and under 700 kg or a
1.2 kN pull, three reflectors, 20 um tracker, its stiff balancer) with the truth's geometry off:
joint offsets on joints 2-5 and link4's frame (1-3 mm at the reflectors, times --scales). Each
seed is one noise draw of the bench (`calbench simulate`, scenario seed = the seed), the same for
every scale (the noise does not depend on the truth), so a difference between two scales of one
seed is the geometry's effect alone. Per seed:

* (a) `identify --geometry`'s complete model on the unloaded readings only (the compliances from
  the robot's own weight across poses);
* (b) the complete model on the loaded and unloaded readings (what `identify --geometry` does);
* (d) the same readings as (b) with the geometry held at the truth's, only the registration, the
  compliances and the balancer fitted: the reference of (b)'s sigma price (its std over (d)'s);
* (c) the classic loaded-minus-unloaded path (`calbench identify LOG`, one-step, the nominal
  geometry), at every scale: its bias from the uncalibrated geometry is the paired difference
  est(scale) - est(scale 0), over its reported std.

(a), (b) and (d) run at scale 1 (--complete-scale).

``--ur10 N``: instead, N seeds of a serial arm (model.py): a UR10 MJCF from its DH table
(write_chain_mjcf) with hidden joint offsets, 60 random poses each unloaded and under --mass kg at
the probe, simulated by the bench's statics; the compliances' z over the seeds for the loaded and
unloaded readings with the torques at the command (the nominal model), with the torques at the
model's own deflected pose (fit.py refresh_torques, what identify --geometry does), and for the
unloaded readings alone. Identification reads the logs without their truth
(include_truth=False, as the CLI); the truth (the scenario's) is read here only to score. Prints
JSON (per parameter: mean error, RMS error, mean reported std, mean and std of z) and progress on
stderr. The geometric error's size is the scale's unloaded readings against scale 0's, after a
rigid registration (3-D RMS and max, m).

Usage: nice -n 10 python benchmarks/geometry_loaded_bench.py [--seeds N] [--scales 0,1,2] [--complete-scale 1] [--quick]
       nice -n 10 python benchmarks/geometry_loaded_bench.py --ur10 N [--mass KG]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

import numpy as np

from calbench.bench.log import read_log
from calbench.identify.core import fit_rigid
from calbench.identify.geometry import (
    MODELS,
    base_set,
    calibrate,
    campaign_readings,
    complete_model,
    kind,
    rank_rule,
    refresh_torques,
    ur10,
    write_chain_mjcf,
)

ROOT = Path(__file__).resolve().parent.parent
SCENARIO = ROOT / "scenarios" / "paper_table5.toml"
OFFSETS = np.array([0.0, 1.0e-3, -0.8e-3, 1.5e-3, -1.2e-3, 0.0])  # rad: 1-3 mm at the reflectors
FRAME = np.array([1.5e-3, -1e-3, 2e-3, 1e-3, -0.5e-3, 0.8e-3])  # m and rad: link4's frame
CALBENCH = Path(sys.executable).parent / "calbench"


def scenario(seed: int, scale: float) -> str:
    text = SCENARIO.read_text().replace('robot = "../mjcf/', f'robot = "{ROOT / "mjcf"}/')
    text = text.replace("\nseed = 1\n", f"\nseed = {seed}\n")
    if scale:
        text += f"[truth.effects.joint_offset]\noffset = {(scale * OFFSETS).tolist()}\n"
        text += f'[truth.effects.link_geometry]\nlink = "link4"\noffset = {(scale * FRAME).tolist()}\n'
    return text


def truth() -> dict[str, float]:
    t = tomllib.loads(SCENARIO.read_text())["truth"]
    out = {f"k{i + 1}": float(c) for i, c in enumerate(t["compliance"])}
    out["K_C"] = float(t["compensator"]["stiffness"])
    return out


def classic(log: Path, work: Path) -> dict[str, tuple[float, float]]:
    out = work / (log.stem + "_classic.json")
    subprocess.run([CALBENCH, "identify", str(log), "--json", str(out)], check=True, capture_output=True)
    rep = json.loads(out.read_text())
    names = {"compensator_stiffness": "K_C"}
    return {names.get(p["name"], p["name"]): (p["estimate"], p["std"]) for p in rep["parameters"]}


def complete(
    log: Path, states: tuple[str, ...], known: float | None = None
) -> tuple[dict[str, tuple[float, float]], float, float]:
    """(estimates and stds, fit RMS (m), seconds) of identify --geometry's complete model;
    ``known``: the geometry held at the truth's (this scale), only the registration, the
    compliances and the balancer fitted (the reference of the sigma price)."""
    lg = read_log(log, include_truth=False)
    data = campaign_readings(lg, states=states)
    robot = complete_model(None, lg.mjcf_text, str(log), data.points, data.rows, data.y)
    m = robot.model
    t0 = time.perf_counter()
    if known is None:
        fit = calibrate(m, data.rows, data.y, MODELS["geometry+compliance"])
    else:
        start = np.zeros(m.size)
        start[m.lay.offset] = known * OFFSETS
        k = m.bodies.index("link4")
        start[m.lay.link.start + 6 * k : m.lay.link.start + 6 * k + 6] = known * FRAME
        _, jac = m.jacobian(data.rows, start)
        free = base_set(jac, m.names, ("base_frame", "joint_compliance", "compensator"), rank_rule(m))
        fit = calibrate(m, data.rows, data.y, free=free, theta0=start)
    seconds = time.perf_counter() - t0
    out = {}
    for nm, i, sd in zip(fit.names, fit.free, fit.std, strict=True):
        if kind(nm) == "joint_compliance":
            out["k" + nm.split(".")[0].lstrip("j")] = (m.value(i, fit.theta), float(sd))
        elif nm.endswith("spring_stiffness"):
            out["K_C"] = (float(fit.theta[i]), float(sd))
    return out, fit.rms, seconds


def unloaded(log: Path) -> np.ndarray:
    lg = read_log(log, include_truth=False)
    return campaign_readings(lg, states=("unloaded",)).y


def geometric_error(y: np.ndarray, y0: np.ndarray) -> tuple[float, float]:
    """y against y0 after the rigid motion that fits them best: (3-D RMS, max), m."""
    reg = fit_rigid(y, y0, np.broadcast_to(np.eye(3) * 1e-8, (len(y), 3, 3)))
    d = np.linalg.norm(y @ reg.rotation.T + reg.position - y0, axis=1)
    return float(np.sqrt(np.mean(d**2))), float(d.max())


def summary(runs: list[dict], true: dict[str, float], ref: list[dict] | None = None) -> dict:
    """Per parameter over the seeds: mean error, RMS error, mean std, z mean and std; with ``ref``
    (the scale-0 runs of the same seeds): the paired bias est - est_ref, mean and over std."""
    out = {}
    for p in true:
        have = [i for i, r in enumerate(runs) if p in r]
        if not have:
            continue
        est = np.array([runs[i][p][0] for i in have])
        sd = np.array([runs[i][p][1] for i in have])
        err = est - true[p]
        z = err / sd
        row = {
            "mean_error": float(err.mean()),
            "rms_error": float(np.sqrt(np.mean(err**2))),
            "mean_std": float(sd.mean()),
            "z_mean": float(z.mean()),
            "z_std": float(z.std(ddof=1)) if len(z) > 1 else None,
        }
        if ref is not None:
            shift = est - np.array([ref[i][p][0] for i in have])
            row["geometry_bias"] = float(shift.mean())
            row["geometry_bias_over_std"] = float(shift.mean() / sd.mean())
            row["geometry_bias_max_over_std"] = float(np.max(np.abs(shift / sd)))
        out[p] = row
    return out


UR10_K = [1e-6, 1.5e-5, 1e-5, 2e-5, 2e-5, 2e-5]  # rad/(N*m)


def ur10_seeds(n: int, mass: float) -> dict:
    """The serial arm's check over n seeds (module docstring): per fit and joint, z mean and std
    and the mean reported std."""
    joints = list(ur10().joints)
    z: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        write_chain_mjcf(work / "ur10.xml", ur10(), np.array([0.0, 0.0, 0.109]), name="ur10")
        for seed in range(n):
            lines = ['robot = "ur10.xml"', f"seed = {seed + 1}", "[truth]", f"compliance = {UR10_K}"]
            lines += ["[truth.effects.joint_offset]", "offset = [0.0, 0.0015, -0.002, 0.0012, -0.0018, 0.0]"]
            lines += ["[tracker]", "sigma = 2e-5", "position = [3.0, 1.0, 0.5]", "[load]", f"mass = {mass}"]
            for q in np.random.default_rng(100 + seed).uniform(-170, 170, (60, 6)):
                lines += ["[[pose]]", "q = [" + ", ".join(f"{v:.3f}" for v in q) + "]"]
            (work / "ur10.toml").write_text("\n".join(lines) + "\n")
            cmd = [CALBENCH, "simulate", str(work / "ur10.toml"), "--out", str(work / "ur10.mcap")]
            if subprocess.run(cmd, capture_output=True).returncode != 0:  # a pose hides every reflector
                print(f"ur10 seed {seed}: skipped (a pose the tracker cannot see)", file=sys.stderr)
                continue
            lg = read_log(work / "ur10.mcap", include_truth=False)
            for label, states, own in (
                ("loaded, torques at the command", ("unloaded", "loaded"), False),
                ("loaded, torques at the own pose", ("unloaded", "loaded"), True),
                ("unloaded only, own pose", ("unloaded",), True),
            ):
                data = campaign_readings(lg, states=states)
                robot = complete_model(work / "ur10.xml", None, "ur10", data.points, data.rows, data.y)
                fit = calibrate(robot.model, data.rows, data.y, MODELS["geometry+compliance"])
                if own:
                    fit, _ = refresh_torques(fit, data.rows, data.y)
                for nm, i, sd in zip(fit.names, fit.free, fit.std, strict=True):
                    if kind(nm) == "joint_compliance":
                        j = nm.split(".")[0]
                        z.setdefault(label, {}).setdefault(j, []).append(
                            ((fit.theta[i] - UR10_K[joints.index(j)]) / sd, sd)
                        )
            print(f"ur10 seed {seed} done", file=sys.stderr)
    return {
        label: {
            j: {
                "seeds": len(v),
                "z_mean": float(np.mean([a for a, _ in v])),
                "z_std": float(np.std([a for a, _ in v], ddof=1)),
                "mean_std": float(np.mean([b for _, b in v])),
            }
            for j, v in by.items()
        }
        for label, by in z.items()
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--scales", default="0,1,2")
    ap.add_argument("--complete-scale", type=float, default=1.0)
    ap.add_argument("--ur10", type=int, default=0, help="seeds of the serial-arm check instead")
    ap.add_argument("--mass", type=float, default=20.0, help="kg at the UR10's probe (--ur10)")
    ap.add_argument("--quick", action="store_true", help="one seed, geometry scales 0 and 1")
    a = ap.parse_args()
    if a.quick:
        a.seeds, a.scales = 1, "0,1"
    if a.ur10:
        print(
            json.dumps(
                {"ur10_seeds": a.ur10, "mass_kg": a.mass, "fits": ur10_seeds(a.ur10, a.mass)}, indent=1
            )
        )
        return
    scales = [float(s) for s in a.scales.split(",")]
    if 0.0 not in scales:
        scales.insert(0, 0.0)
    true = truth()
    runs: dict = {"a": [], "b": [], "d": [], **{f"c{s:g}": [] for s in scales}}
    sizes: dict = {f"{s:g}": [] for s in scales if s}
    seconds: dict = {"a": [], "b": [], "d": []}
    rms: dict = {"a": [], "b": [], "d": []}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for seed in range(a.seeds):
            y0 = None
            for s in scales:
                toml = work / f"s{seed}_{s:g}.toml"
                toml.write_text(scenario(seed + 1, s))
                log = work / f"s{seed}_{s:g}.mcap"
                cmd = [CALBENCH, "simulate", str(toml), "--out", str(log)]
                subprocess.run(cmd, check=True, capture_output=True)
                runs[f"c{s:g}"].append(classic(log, work))
                y = unloaded(log)
                if s == 0:
                    y0 = y
                else:
                    sizes[f"{s:g}"].append(geometric_error(y, y0))
                if s == a.complete_scale:
                    for key, states, known in (
                        ("a", ("unloaded",), None),
                        ("b", ("unloaded", "loaded"), None),
                        ("d", ("unloaded", "loaded"), s),
                    ):
                        est, r, sec = complete(log, states, known)
                        runs[key].append(est)
                        rms[key].append(r)
                        seconds[key].append(sec)
                        print(f"seed {seed}: ({key}) fit RMS {r * 1e6:.1f} um, {sec:.0f} s", file=sys.stderr)
            print(f"seed {seed} done", file=sys.stderr)
    report = {
        "scenario": str(SCENARIO.relative_to(ROOT)),
        "seeds": a.seeds,
        "complete_scale": a.complete_scale,
        "geometric_error_m": {
            s: {"rms": float(np.mean([v[0] for v in vs])), "max": float(np.max([v[1] for v in vs]))}
            for s, vs in sizes.items()
        },
        "a_unloaded_only": {
            "fit_rms_m": rms["a"],
            "seconds": seconds["a"],
            "params": summary(runs["a"], true),
        },
        "b_loaded_and_unloaded": {
            "fit_rms_m": rms["b"],
            "seconds": seconds["b"],
            "params": summary(runs["b"], true),
        },
        "d_geometry_known": {
            "fit_rms_m": rms["d"],
            "seconds": seconds["d"],
            "params": summary(runs["d"], true),
            "std_price": {
                p: float(np.mean([b[p][1] / d[p][1] for b, d in zip(runs["b"], runs["d"], strict=True)]))
                for p in true
                if all(p in b and p in d for b, d in zip(runs["b"], runs["d"], strict=True)) and runs["d"]
            },
        },
        "c_classic": {
            f"scale {s:g}": summary(runs[f"c{s:g}"], true, None if s == 0 else runs["c0"]) for s in scales
        },
    }
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
