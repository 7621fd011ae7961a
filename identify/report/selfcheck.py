"""`calbench identify --self-check`: does the reported std hold on this very campaign? (issue 22)

A parametric bootstrap at the estimate: the deflections the identified model predicts on the
campaign's own poses and reflectors (the exact statics at theta_hat) plus REPLICAS draws of the
tracker noise the estimator assumes (each pose's covariance, identify/core/observations.py),
each refitted by the same method as the Monte Carlo refits a campaign (its ``repeats``:
identify/methods/, for the one-step one evaluation of the exact model per replica from the
noise-free estimate). Then, for every determined parameter:

* the replicas' spread over the reported std must lie within a factor STD_FACTOR (1.5) either
  way: with 30 replicas the sample std has a relative standard error of 1/sqrt(2 * 29) = 0.13,
  so a right std fails with probability < 0.5 %;
* the replicas' mean must lie within BIAS_SIGMA (0.5) reported std of the estimate: the mean's
  standard error is 1/sqrt(30) = 0.18 std, a right estimator fails with probability 0.6 %.

A parameter that fails is flagged and `identify --check` fails. What it checks is the estimator
at this plan and noise (its linearisation, the model's curvature over a std, the stopping
rule), under the model as identified; what no bootstrap of that model can see -- an effect the
model lacks -- is discovery's exposure (identify/discover/exposure.py).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from calbench.identify.core import Observations, Whitener
from calbench.identify.methods import method_named

REPLICAS = 30
STD_FACTOR = 1.5
BIAS_SIGMA = 0.5
SEED = 22  # the replicas' noise: fixed, so the check is reproducible


def with_deflections(obs: Observations, dp: np.ndarray) -> Observations:
    """A copy of ``obs`` whose deflections are ``dp`` (M, 3), in its row order."""
    poses, i = [], 0
    for p in obs.poses:
        n = len(p.reflectors)
        poses.append(replace(p, dp=np.array(dp[i : i + n], dtype=float)))
        i += n
    return Observations(
        poses, obs.tracker, obs.noise_sigma, obs.n_planned, list(obs.lost_poses), obs.truncated, obs.source
    )


def noise(obs: Observations, rng: np.random.Generator) -> np.ndarray:
    """(M, 3) one draw of the tracker noise the estimator assumes: each pose's covariance."""
    out = []
    for p in obs.poses:
        chol = np.linalg.cholesky(p.block())
        out.append((chol @ rng.standard_normal(chol.shape[0])).reshape(-1, 3))
    return np.concatenate(out) if out else np.zeros((0, 3))


def self_check(robot, obs: Observations, method: str, theta: np.ndarray, std: np.ndarray, predicted) -> dict:
    """The bootstrap of the module docstring around the estimate ``theta`` (std: its reported
    std, NaN where not determined; ``predicted``: (M, 3) the model's deflections at theta)."""
    obs0 = with_deflections(obs, predicted)
    white = Whitener.from_observations(obs0)
    reps = method_named(method).repeats(robot, obs0, white)
    rng = np.random.default_rng(SEED)
    est = np.full((REPLICAS, theta.size), np.nan)
    for r in range(REPLICAS):
        o = with_deflections(obs0, obs0.dp + noise(obs0, rng))
        est[r] = reps.run(o, Whitener.from_observations(o)).theta
    out, failed = {}, []
    names = reps.noise_free.names
    for i, name in enumerate(names):
        if not (np.isfinite(std[i]) and std[i] > 0):
            continue
        col = est[:, i][np.isfinite(est[:, i])]
        if col.size < 3:
            out[name] = {"std_ratio": None, "bias_sigma": None, "ok": False, "replicas": int(col.size)}
            failed.append(name)
            continue
        ratio = float(np.std(col, ddof=1) / std[i])
        bias = float((np.mean(col) - theta[i]) / std[i])
        ok = 1 / STD_FACTOR <= ratio <= STD_FACTOR and abs(bias) <= BIAS_SIGMA
        out[name] = {"std_ratio": ratio, "bias_sigma": bias, "ok": bool(ok), "replicas": int(col.size)}
        if not ok:
            failed.append(name)
    return {
        "replicas": REPLICAS,
        "seed": SEED,
        "std_factor": STD_FACTOR,
        "bias_sigma_max": BIAS_SIGMA,
        "parameters": out,
        "failed": failed,
        "passed": not failed,
    }


def self_check_lines(check: dict | None) -> list[str]:
    """The identify table's lines of a self-check (empty: none was run)."""
    if not check:
        return []
    head = (
        f"  self-check ({check['replicas']} replicas at the estimate): every reported std within "
        f"{check['std_factor']:g}x of the replicas' spread and their mean within "
        f"{check['bias_sigma_max']:g} std"
    )
    if check["passed"]:
        return [head + ": passed"]
    lines = [head + ": FAILED for " + ", ".join(check["failed"])]
    for n in check["failed"]:
        p = check["parameters"][n]
        if p["std_ratio"] is None:
            lines.append(f"    {n}: only {p['replicas']} of the replicas determined it")
        else:
            lines.append(
                f"    {n}: spread / reported std {p['std_ratio']:.2f}, mean - estimate {p['bias_sigma']:+.2f} std"
            )
    return lines


__all__ = [
    "REPLICAS",
    "STD_FACTOR",
    "BIAS_SIGMA",
    "self_check",
    "self_check_lines",
    "with_deflections",
    "noise",
]
