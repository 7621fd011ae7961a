"""`calbench identify`: read a campaign log, identify, report (table and docs/contract.md JSON).

The estimation reads the log WITHOUT truth (``read_log(path)``: /truth/ messages are skipped
before decoding, the ground_truth record ignored) and the MJCF for geometry only (every elastic
value in it is overwritten by the estimator's own parameters). Only after the estimate is made
is the log read a second time with ``include_truth=True`` to fill the truth, error and z
columns; the estimate cannot depend on it (tests/test_identify_cli.py strips the truth and
scales every MJCF stiffness by 10 and checks the estimates do not move).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from calbench.bench.core import DISPLAY, InputError
from calbench.bench.log import (
    CampaignTruth,
    IdentificationReport,
    ObservationFit,
    Outlier,
    ParameterEstimate,
    read_log,
)
from calbench.bench.model import Robot, display_name, free_length_note, log_robot
from calbench.bench.tracker import DEFAULT_MODEL, tracker_models
from calbench.identify.compensate import robot_sha256
from calbench.identify.core import (
    MAX_RELATIVE_STD,
    OUTLIER_SIGMA,
    Observations,
    check_sites,
    from_log,
    outliers,
)
from calbench.identify.methods import IdentifyOptions, MethodResult, check_method, method_named, method_names

from .selfcheck import self_check as bootstrap
from .selfcheck import self_check_lines

Z_CHECK = 4.0


@dataclass
class Identified:
    """An identification: the method's result on the observations it used, the readings off by
    more than OUTLIER_SIGMA, and those dropped before the refit (``drop_outliers``)."""

    result: MethodResult
    obs: Observations
    outliers: list
    dropped: list

    @property
    def method(self) -> str:
        return self.result.method


def identify(
    robot: Robot,
    obs: Observations,
    method: str = "one-step",
    drop_outliers: bool = False,
    check_profile: bool = False,
) -> Identified:
    """Estimate with the method named ``method`` (one that `calbench identify --method` offers:
    identify/methods/registry.py), flag outliers (> 5 sigma), optionally refit without them;
    ``check_profile``: the one-step's profile check too (identify/methods/onestep.py; ~0.1-0.25
    s, which the studies' ~0.1 s campaigns do not pay)."""
    offered = method_names(offered_only=True)
    if method not in offered:
        raise InputError("--method", "method", " or ".join(offered), method)
    m = method_named(method)
    check_method(m, robot, robot.source or "robot model", f"--method {method}")
    options = IdentifyOptions(check_profile=check_profile)
    r = m.estimate(robot, obs, options)
    found = outliers(r.residual_w, obs.labels, OUTLIER_SIGMA)
    dropped: list = []
    if drop_outliers and found:
        bad = {(o["pose"], o["reflector"]) for o in found}
        keep = [lab for lab in obs.labels if lab not in bad]
        obs = obs.subset(keep)
        dropped = found
        r = m.estimate(robot, obs, options)
        found = outliers(r.residual_w, obs.labels, OUTLIER_SIGMA)
    return Identified(r, obs, found, dropped)


def truth_vector(truth: CampaignTruth | None, robot: Robot) -> np.ndarray | None:
    """The true theta (the robot's layout) of a log read with truth; None without truth, or
    when the truth is of another robot than the model identified (a --model of another family)."""
    if truth is None or truth.parameters is None:
        return None
    try:
        return robot.layout.theta(truth.parameters.params())
    except ValueError:
        return None


def _num(x) -> float | None:
    return None if x is None or not np.isfinite(x) else float(x)


def identification_report(
    res: Identified, truth: np.ndarray | None, log_path, model_name: str, seconds: float
) -> IdentificationReport:
    """The report of an identification; ``truth`` (from the log, after the estimate) fills the
    truth, error and z columns."""
    obs, r = res.obs, res.result
    sd = np.sqrt(np.where(np.isfinite(np.diag(r.cov)), np.diag(r.cov), np.nan))
    params = []
    names, units = r.names, r.units
    for i, name in enumerate(names):
        est = _num(r.theta[i]) if r.identifiable[i] else None
        std = _num(sd[i]) if r.identifiable[i] else None
        t = None if truth is None else float(truth[i])
        err = None if (est is None or t is None) else est - t
        z = None if (err is None or not std) else err / std
        params.append(
            ParameterEstimate(
                name, units[i], est, std, t, err, z, bool(r.identifiable[i]), r.reasons.get(name)
            )
        )
    n = r.residual.size
    cov_diag = np.concatenate([np.diagonal(c) for c in obs.cov]) if obs.poses else np.zeros(0)
    return IdentificationReport(
        method=r.method,
        parameters=tuple(params),
        residual_rms=float(np.sqrt(np.mean(r.residual**2))) if n else None,
        noise_sigma=float(obs.noise_sigma),
        chi2_per_dof=r.chi2 / r.dof if r.dof > 0 else None,
        chi2=r.chi2,
        dof=r.dof,
        expected_residual_rms=float(np.sqrt(np.mean(cov_diag) * r.dof / max(n, 1))) if n else None,
        whitened_residual_rms=float(np.sqrt(np.mean(r.residual_w**2))) if n else None,
        covariance=tuple(tuple(_num(r.cov[i, j]) for j in range(len(names))) for i in range(len(names))),
        log=str(log_path),
        model=model_name,
        n_poses_planned=obs.n_planned,
        n_poses_used=len(obs.poses),
        lost_poses=tuple(obs.lost_poses),
        truncated=bool(obs.truncated),
        n_observations=obs.n_obs(),
        outliers=tuple(Outlier(**o) for o in res.outliers),
        outlier_threshold_sigma=OUTLIER_SIGMA,
        dropped_outliers=tuple(Outlier(**o) for o in res.dropped),
        seconds=seconds,
        # per observation, world frame, m: what `calbench view --identified` draws
        observations=tuple(
            ObservationFit(
                int(pose),
                refl,
                predicted=tuple(float(x) for x in dp - e),
                measured=tuple(float(x) for x in dp),
                residual=tuple(float(x) for x in e),
            )
            for (pose, refl), dp, e in zip(obs.labels, obs.dp, r.residual.reshape(-1, 3))
        ),
        details={**r.details, "tracker_noise_model": obs.tracker.model},
    )


def noise_source(rep: IdentificationReport) -> str:
    """Where the expected residual comes from, in words: the tracker's sigma when its model
    gives every reading that sigma per axis (TrackerModel.sigma_per_axis: isotropic), else the
    model's name and summary (its ``noise_sigma`` is not used)."""
    noise = rep.details.get("tracker_noise_model", DEFAULT_MODEL)
    model = tracker_models().get(noise)  # None: a model this installation does not know
    if model is not None and model.sigma_per_axis and rep.noise_sigma is not None:
        return f"σ = {rep.noise_sigma * 1e6:.3g} µm per reading"
    return f"its {noise} error model" + (f", {model.summary}" if model is not None else "")


def format_table(rep: IdentificationReport) -> str:
    has_truth = rep.has_truth()
    lines = [
        f"calbench identify: {rep.log} ({rep.method}; model {rep.model})",
        f"  poses used {rep.n_poses_used} of {rep.n_poses_planned} planned, "
        f"{rep.n_lost_poses} lost"
        + (f" {list(rep.lost_poses)}" if rep.lost_poses else "")
        + (" (log truncated)" if rep.truncated else "")
        + f"; {rep.n_observations} reflector deflections",
    ]
    head = f"  {'parameter':<24}{'unit':<12}{'estimate':>12} {'± std':>10}"
    if has_truth:
        head += f"{'truth':>12}{'error':>11}{'z':>7}"
    lines.append(head)
    for p in rep.parameters:
        label, f = DISPLAY[p.unit]
        if p.estimate is None:
            row = f"  {display_name(p.name):<24}{label:<12}{'not identifiable':>23}"
            if has_truth and p.truth is not None:
                row += f"{p.truth * f:>12.5g}"
            lines.append(row)
            continue
        sd = p.std * f
        dec = max(0, 1 - math.floor(math.log10(sd))) if sd > 0 else 3  # std to 2 digits
        row = f"  {display_name(p.name):<24}{label:<12}{p.estimate * f:>12.{dec}f} {sd:>10.{dec}f}"
        if has_truth and p.truth is not None:
            row += f"{p.truth * f:>12.{dec}f}{p.error * f:>+11.{dec}f}{p.z:>+7.2f}"
        lines.append(row)
    if rep.residual_rms is not None:
        lines.append(
            f"  residual RMS {rep.residual_rms * 1e6:.2f} µm per axis (expected "
            f"{rep.expected_residual_rms * 1e6:.2f} µm from the tracker: {noise_source(rep)}, a "
            f"deflection is the difference of two); χ²/dof = {rep.chi2_per_dof:.3f} ({rep.dof} dof)"
        )
    note = free_length_note([p.name for p in rep.parameters])
    if note:
        lines.append(f"  {note}")
    for name, why in rep.unidentifiable.items():
        lines.append(f"  not identifiable: {name}: {why}")
    for name, p in rep.details.get("profile", {}).items():
        if not p["quadratic"]:
            rise = ", ".join(
                "none (past its bound or no fit)" if r is None else f"{r:.2f}"
                for r in (p["rise_plus"], p["rise_minus"])
            )
            lines.append(
                f"  chi2 not quadratic: {name}: rises {rise} at +2/-2 std (4 if quadratic); "
                "its std is the Fisher std, its error is not Gaussian"
            )
    for o in rep.outliers:
        lines.append(
            f"  outlier (> {rep.outlier_threshold_sigma:g}σ): pose {o.pose} reflector "
            f"{o.reflector}: {o.sigma:.1f}σ"
            + ("" if rep.dropped_outliers else " (refit without: --drop-outliers)")
        )
    if rep.dropped_outliers:
        lines.append(
            "  dropped and refitted without: "
            + ", ".join(f"pose {o.pose} {o.reflector} ({o.sigma:.1f}σ)" for o in rep.dropped_outliers)
        )
    if rep.details.get("converged") is False:
        lines.append("  WARNING: the estimator did not converge")
    lines += self_check_lines(rep.details.get("self_check"))
    for e in rep.details.get("exposure", []):
        label, f = DISPLAY[e["unit"]]
        line = f"  exposure: {e['parameter']}: "
        if e["effect"] and e["bias"] > 0:
            line += (
                f"an undetected {e['effect']} could move it by up to {e['bias'] * f:.3g} {label} "
                f"({e['sigma']:.2g} std, {e['percent']:.2g} %)"
            )
        if e["unbounded_by"]:
            line += (
                ("; " if e["bias"] > 0 else "")
                + "by any amount, along a direction this plan cannot see: "
                + ", ".join(e["unbounded_by"])
            )
        lines.append(line)
    return "\n".join(lines)


def run_identify(
    log_path,
    model=None,
    method: str = "one-step",
    drop_outliers: bool = False,
    check_profile: bool = True,
    self_check: bool = False,
    exposure: bool = False,
) -> IdentificationReport:
    """Everything `calbench identify` does except printing; returns the report. ``self_check``:
    the parametric bootstrap at the estimate too (identify/report/selfcheck.py); ``exposure``:
    each parameter's exposure to the discovery library's effects (the one-step only)."""
    t0 = time.perf_counter()
    log = read_log(log_path)  # no truth: nothing below can see it
    obs = from_log(log)
    robot = log_robot(log, model)
    check_sites(robot, obs, model or log.path)
    res = identify(robot, obs, method, drop_outliers, check_profile)
    if self_check:
        r = res.result
        r.details["self_check"] = bootstrap(robot, res.obs, method, r.theta, r.std, res.obs.dp - r.residual)
    if exposure:
        from calbench.identify.discover import base_exposure

        src = Path(model) if model is not None else log.mjcf_text
        r = res.result
        r.details["exposure"] = [e for e in base_exposure(src, res.obs, r.std) if e["sigma"] is not None]
    seconds = time.perf_counter() - t0
    truth = truth_vector(read_log(log_path, include_truth=True).truth, robot)  # for the report only
    model_name = str(model) if model is not None else f"{log.header.get('robot', 'MJCF')} (from the log)"
    rep = identification_report(res, truth, log_path, model_name, seconds)
    # which robot this is (compensate refuses an identification of another one)
    return replace(rep, details={**rep.details, "robot_sha256": robot_sha256(robot)})


def check_failed(rep: IdentificationReport, z_max: float = Z_CHECK) -> list[str]:
    """Why ``identify --check`` fails, one phrase each (empty: it passes). Always: the fit did
    not converge; a parameter is reported as a number although the data do not determine it
    (no finite std, or a std above MAX_RELATIVE_STD of the estimate: identify/core/identifiability.py).
    With the log's truth: a parameter with |z| > z_max."""
    bad = []
    if rep.details.get("converged") is False:
        bad.append("the estimator did not converge")
    sc = rep.details.get("self_check")
    if sc and not sc["passed"]:
        bad.append("the self-check flags " + ", ".join(sc["failed"]))
    for p in rep.parameters:
        if p.estimate is None:
            continue
        if not p.identifiable or p.std is None or not p.std > 0 or p.std > MAX_RELATIVE_STD * abs(p.estimate):
            bad.append(f"{p.name} is reported as a number the plan does not determine")
        elif p.z is not None and abs(p.z) > z_max:
            bad.append(f"{p.name}: |z| = {abs(p.z):.2f} > {z_max:g}")
    return bad


__all__ = [
    "Identified",
    "run_identify",
    "identify",
    "format_table",
    "identification_report",
    "check_failed",
    "Z_CHECK",
]
