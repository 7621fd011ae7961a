"""Discovery: residual diagnostics. Where the model and the measurements disagree.

Everything here works on whitened residuals r_w = L^-1 (dp - f), L L^T = Cov (the tracker's own
covariance of each measured deflection), so that for a model that is right r_w is standard
normal and chi2 = |r_w|^2 follows a chi-square law with n - p degrees of freedom (n scalar
residuals, p parameters the data determine). The tracker's sigma is known, so the likelihood
ratio of two nested models is the chi2 difference itself (identify/discover/decide.py decides
between models). Nothing here knows about any particular effect.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

ALPHA_FIT = 1e-3  # p-value below which the residual is not noise (the model is rejected)
DIRECTIONS = ("x", "y", "z")


def chi2_p(chi2: float, dof: float) -> float:
    """P(chi2_dof >= chi2): small when the residual is larger than noise would make it."""
    return float(stats.chi2.sf(chi2, dof)) if dof > 0 else float("nan")


def expected_rms(cov: np.ndarray, dof: int, n_res: int) -> float:
    """RMS per coordinate that noise alone leaves after fitting (n_res - dof) parameters:
    sqrt(mean(diag Cov) * dof / n_res)."""
    diag = np.concatenate([np.diagonal(c) for c in cov]) if len(cov) else np.zeros(1)
    return float(math.sqrt(float(np.mean(diag)) * dof / max(n_res, 1)))


def rms(residual: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.asarray(residual) ** 2)))


# --------------------------------------------------------------------------- where


def _group_chi2(rw2: np.ndarray, groups: list, dof_share: float) -> list[dict]:
    """chi2 per group of residual entries; expected dof = count * dof_share."""
    out = []
    for key, idx in groups:
        c = float(rw2[idx].sum())
        d = float(np.size(rw2[idx]) * dof_share)
        out.append(
            {"key": key, "chi2": c, "dof": d, "chi2_per_dof": c / d if d > 0 else None, "p": chi2_p(c, d)}
        )
    return out


def pose_features(fit, obs) -> dict[str, np.ndarray]:
    """What varies across the plan, per pose, from the known inputs and the fitted model only:
    q2 (deg), the load's torque on each motor (N*m: the fitted spring's extra deflection times
    its stiffness, loop included), the load's angle from vertical (deg), arm extension (m:
    horizontal distance of the load point from the J1 axis)."""
    import mujoco

    robot = fit.robot
    m, d = robot.model, robot.data
    eqs = fit.model.equilibria()
    k = fit.values[: robot.n_act]
    q2, ext, ang = [], [], []
    tau = []
    for p, (q0, q1) in zip(obs.poses, eqs):
        q2.append(math.degrees(p.q[1]) if len(p.q) > 1 else 0.0)
        dq = q1[robot.act_qpos] - q0[robot.act_qpos]
        tau.append(np.abs(dq / k))
        d.qpos[:] = q0
        mujoco.mj_kinematics(m, d)
        site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, p.site)
        x = d.site_xpos[site]
        ext.append(float(np.hypot(x[0], x[1])))
        f = np.asarray(p.force, float)
        nf = np.linalg.norm(f)
        ang.append(math.degrees(math.acos(min(1.0, abs(f[2]) / nf))) if nf > 0 else 0.0)
    tau = np.array(tau)
    feats = {
        "q2 (deg)": np.array(q2),
        "load angle from vertical (deg)": np.array(ang),
        "arm extension (m)": np.array(ext),
    }
    for i in range(robot.n_act):
        feats[f"load torque on motor {i + 1} (N*m)"] = tau[:, i]
    return feats


def diagnose(fit, obs, noise_sigma: float) -> dict:
    """Where the model and the measurements disagree: chi2 overall, per pose, per reflector,
    per world direction, and correlations of per-pose residual size with the plan's features.
    Returns a dict with numbers and a list of sentences ("words")."""
    rw = fit.residual_w
    rw2 = rw**2
    n_res = rw.size
    share = fit.dof / n_res  # each residual's share of the dof
    labels = obs.labels
    exp_rms = expected_rms(obs.cov, fit.dof, n_res)
    total = {
        "chi2": fit.chi2,
        "dof": fit.dof,
        "chi2_per_dof": fit.chi2 / fit.dof,
        "p": chi2_p(fit.chi2, fit.dof),
        "rms": rms(fit.residual),
        "expected_rms": exp_rms,
        "ratio": rms(fit.residual) / exp_rms,
    }
    # per pose / reflector
    pose_idx: dict[int, list[int]] = {}
    refl_idx: dict[str, list[int]] = {}
    for i, (pose, refl) in enumerate(labels):
        pose_idx.setdefault(pose, []).append(i)
        refl_idx.setdefault(refl, []).append(i)
    per_pose = _group_chi2(rw2, [(p, idx) for p, idx in pose_idx.items()], share)
    for e, (_pose, idx) in zip(per_pose, pose_idx.items()):
        e["pose"] = e.pop("key")
        e["rms"] = rms(fit.residual[idx])
    per_refl = _group_chi2(rw2, [(r, idx) for r, idx in refl_idx.items()], share)
    for e, (_refl, idx) in zip(per_refl, refl_idx.items()):
        e["reflector"] = e.pop("key")
        e["rms"] = rms(fit.residual[idx])
    # per world direction: residual over that axis' own sigma
    sd = np.sqrt(np.stack([np.diagonal(c) for c in obs.cov]))
    z2 = (fit.residual / sd) ** 2
    per_dir = []
    for a, name in enumerate(DIRECTIONS):
        c = float(z2[:, a].sum())
        dd = z2.shape[0] * share
        per_dir.append(
            {
                "direction": name,
                "chi2": c,
                "dof": dd,
                "chi2_per_dof": c / dd,
                "p": chi2_p(c, dd),
                "rms": rms(fit.residual[:, a]),
            }
        )
    # correlations with what varies across the plan
    size = np.array([e["rms"] for e in per_pose])
    corr = []
    try:
        feats = pose_features(fit, obs)
    except Exception:  # noqa: BLE001  (diagnostics must not stop the workflow)
        feats = {}
    for name, v in feats.items():
        if np.ptp(v) <= 1e-9 * max(1.0, np.abs(v).max()) or len(v) < 4:
            continue
        r, p = stats.pearsonr(v, size)
        corr.append({"feature": name, "r": float(r), "p": float(p)})
    corr.sort(key=lambda c: c["p"])
    return {
        "total": total,
        "per_pose": per_pose,
        "per_reflector": per_refl,
        "per_direction": per_dir,
        "correlations": corr,
        "words": _words(total, per_pose, per_refl, per_dir, corr, noise_sigma),
    }


def _words(total, per_pose, per_refl, per_dir, corr, noise_sigma) -> list[str]:
    um = 1e6
    w = []
    if total["p"] >= ALPHA_FIT:
        w.append(
            f"The model explains the measurements to the noise level: chi2 = {total['chi2']:.1f} for "
            f"{total['dof']} degrees of freedom (p = {total['p']:.2g}); residual RMS "
            f"{total['rms'] * um:.1f} um per coordinate against {total['expected_rms'] * um:.1f} um "
            f"expected from the tracker (sigma {noise_sigma * um:.3g} um per reading)."
        )
        return w
    w.append(
        f"The model does not fit: chi2 = {total['chi2']:.1f} for {total['dof']} degrees of freedom "
        f"(p = {total['p']:.2g}); residual RMS {total['rms'] * um:.1f} um per coordinate, "
        f"{total['ratio']:.2f}x the {total['expected_rms'] * um:.1f} um that tracker noise alone leaves."
    )
    bad = sorted([e for e in per_pose if e["p"] < ALPHA_FIT / len(per_pose)], key=lambda e: -e["chi2"])
    if bad:
        w.append(
            f"{len(bad)} of {len(per_pose)} poses disagree beyond noise (p < {ALPHA_FIT / len(per_pose):.1g} "
            "each): "
            + ", ".join(
                f"pose {e['pose']} ({e['rms'] * um:.0f} um, chi2/dof {e['chi2_per_dof']:.1f})"
                for e in bad[:6]
            )
            + ("..." if len(bad) > 6 else "")
            + "."
        )
    else:
        worst = max(per_pose, key=lambda e: e["chi2"])
        w.append(
            f"No single pose stands out (worst: pose {worst['pose']}, chi2/dof {worst['chi2_per_dof']:.1f}): "
            "the misfit is spread over the plan."
        )
    excess = sum(max(e["chi2"] - e["dof"], 0.0) for e in per_dir) or 1.0
    dirs = ", ".join(
        f"{e['direction']} {e['rms'] * um:.0f} um ({100 * max(e['chi2'] - e['dof'], 0) / excess:.0f} % "
        "of the excess)"
        for e in per_dir
    )
    w.append(f"By world direction: {dirs}.")
    refl = ", ".join(f"{e['reflector']} {e['rms'] * um:.0f} um" for e in per_refl)
    w.append(f"By reflector: {refl}.")
    sig = [c for c in corr if c["p"] < 0.01]
    if sig:
        w.append(
            "The per-pose misfit grows with "
            + "; ".join(f"{c['feature']} (r = {c['r']:+.2f}, p = {c['p']:.1g})" for c in sig[:4])
            + "."
        )
    else:
        w.append(
            "The per-pose misfit correlates with none of q2, the motor load torques, the load "
            "direction or the arm extension at p < 0.01."
        )
    return w


__all__ = ["ALPHA_FIT", "chi2_p", "expected_rms", "rms", "diagnose", "pose_features"]
