"""The task of a study: whole campaigns of one cell, exactly as a user would run them.

For each replicate: ``simulate`` the cell's scenario with the campaign's seed, ``identify`` it
(what the log without its truth holds; the truth is read only afterwards, for the error and z
columns, as in identify/report/identification.py), and, where the study asks, ``discover`` with the user's model (the log's MJCF, or it without the effects of
``discover_without``). The record of a campaign is one flat dict of :func:`result_columns`: per
parameter the estimate, reported std, truth, error and z; the fit's chi2; what discover named;
the timings; and the error, if the campaign failed (then the numbers are NaN).

No log is written where nothing needs one (:func:`needs_log`): the campaign is simulated in
memory (bench.campaign.simulate with the campaign's own generator, the one code path the log
writer reads too) and identify/core's ``from_campaign`` gives identify and discover the same
Observations, to the last bit, that ``from_log`` reads from the log without its truth
(the robot from the same MJCF text, the truth afterwards for the error columns): the same rows,
without writing the log and reading it back twice. A tracker whose covariance depends on the
readings' times (TrackerModel.uses_times: iso10360) still goes through the log: identify takes
the times as the log stamps them (whole nanoseconds, kept strictly increasing over every message
written, Foxglove's too), which only the log writer knows. tests/test_study_memory.py runs studies both ways and compares their rows.

The function depends on nothing but its arguments (texts, seeds): it runs the same in-process
and on any Dask worker that has calbench installed.
"""

from __future__ import annotations

import math
import os
import socket
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pyarrow as pa

from calbench.bench.campaign import run_campaign, simulate, truth_params
from calbench.bench.core import write_text
from calbench.bench.model import LOG_KEY, Robot, load_robot
from calbench.bench.model.effects import without_compensator
from calbench.bench.scenario import Scenario
from calbench.bench.tracker import tracker_models
from calbench.identify.core import Observations, from_campaign
from calbench.identify.runtime import PortableScenario

# effects discover's starting model can lack (campaign.discover_without): MJCF text -> MJCF text
REMOVABLE = {"compensator": without_compensator}
PARAM_FIELDS = ("estimate", "std", "truth", "error", "z")
NOTHING = "nothing"

_F, _I, _S, _B = pa.float64(), pa.int64(), pa.string(), pa.bool_()


def result_columns(param_names) -> dict[str, pa.DataType]:
    """The measured columns of a study's rows, for a robot whose parameters are ``param_names``
    (its layout: k1..kN, then each compensator's stiffness and preload)."""
    return {
        "cell": _I,
        "replicate": _I,
        "seed": _I,
        "cell_id": _S,
        **{f"{p}_{f}": _F for p in param_names for f in PARAM_FIELDS},
        "chi2": _F,
        "dof": _I,
        "chi2_per_dof": _F,
        "residual_rms": _F,
        "noise_sigma": _F,
        "n_poses_planned": _I,
        "n_poses_used": _I,
        "converged": _B,
        "expected": _S,
        "named_first": _S,
        "named_effects": _S,
        "detected": _B,
        "rms_before": _F,
        "rms_after": _F,
        "noise_rms_before": _F,
        "noise_rms_after": _F,
        "simulate_s": _F,
        "identify_s": _F,
        "discover_s": _F,
        "campaign_s": _F,
        "worker": _S,
        "error": _S,
    }


TIMING_COLUMNS = ("simulate_s", "identify_s", "discover_s", "campaign_s", "worker")


@dataclass(frozen=True)
class CampaignJob:
    """Campaigns of one cell: its scenario (seed replaced per campaign; the MJCF texts travel
    apart, once per cluster: :func:`run_campaigns`), what to run after the simulation, and the
    (replicate, seed) pairs."""

    scenario: PortableScenario  # its mjcf is empty here
    method: str
    discover: bool
    without: tuple[str, ...]  # effects discover's model lacks (its MJCF is shared)
    expected: str | None
    replicates: tuple[tuple[int, int], ...]


def _num(x) -> float:
    return float("nan") if x is None else float(x)


def _named_first(rep: dict) -> str:
    if not rep["steps"]:
        return NOTHING
    s = rep["steps"][0]
    if s["effect"] == "unexplained" or not s["detail"]:
        return s["effect"]
    return f"{s['effect']}[{s['detail']}]"


def tracker_needs_log(model: str) -> bool:
    """Whether a campaign with the tracker model named ``model`` must go through its log to give
    identify exactly what a log gives (module docstring): when the model's covariances depend on
    the readings' times (TrackerModel.uses_times, iso10360's drift), which identify takes from
    the log's stamps. False for a name no model has (the scenario's check refuses it)."""
    found = tracker_models().get(model)
    return found is not None and found.uses_times


def needs_log(scn: Scenario) -> bool:
    """:func:`tracker_needs_log` of the scenario's tracker."""
    return tracker_needs_log(scn.tracker.model)


@dataclass(frozen=True)
class Simulated:
    """A campaign simulated in memory: what a reader of its log without truth gets (the
    observations, the MJCF text of its header) and, apart, the truth's parameter vector in the
    robot's layout (None when the layouts differ), read only after the estimate, as
    identify/report/identification.py reads the log's truth."""

    obs: Observations
    mjcf: str
    truth: np.ndarray | None


def simulate_in_memory(scn: Scenario) -> Simulated:
    """The campaign `calbench simulate` would log (bench.campaign.simulate with the scenario's
    seed, the same size check), as a reader of that log without its truth gets it: the
    observations (identify/core's from_campaign, InputError when no pose can be used, as
    ``from_log``) and the header's MJCF text; the truth's parameter vector apart."""
    campaign = simulate(scn, np.random.default_rng(scn.seed))
    obs = from_campaign(campaign)
    mjcf = campaign.header.mjcf_text
    rb = Robot.from_xml(mjcf)
    try:
        truth = rb.layout.theta(truth_params(scn, campaign.robot))
    except ValueError:  # as report.truth_vector
        truth = None
    return Simulated(obs, mjcf, truth)


def identify_in_memory(sim: Simulated, method: str):
    """report.run_identify on the in-memory campaign: the log's robot (its MJCF text), the sites
    checked, the estimate, then the truth for the report's error columns."""
    from calbench.identify.core import check_sites
    from calbench.identify.report import identification_report, identify

    t0 = time.perf_counter()
    robot = load_robot(sim.obs.source, LOG_KEY, text=sim.mjcf)  # as from the log
    check_sites(robot, sim.obs, sim.obs.source)
    res = identify(robot, sim.obs, method)
    return identification_report(res, sim.truth, sim.obs.source, "MJCF (in memory)", time.perf_counter() - t0)


def discover_in_memory(sim: Simulated, discover_model: str | None) -> dict:
    """discover.workflow.discover on the in-memory campaign: the user's model (the log's MJCF or
    the one without ``discover_without``'s effects), the search, and the augmented MJCF built
    and loaded (discover's check that it loads), not written."""
    from calbench.identify.core import check_sites
    from calbench.identify.discover import augmented_mjcf, discover_observations

    src = sim.mjcf if discover_model is None else discover_model
    check_sites(Robot.from_xml(src), sim.obs, sim.obs.source)
    rep, final = discover_observations(sim.obs, src)
    if final.effects:
        Robot.from_xml(augmented_mjcf(src, final))  # must load
    return rep


def one_campaign(
    job: CampaignJob, replicate: int, seed: int, folder: Path, discover_model: str | None = None
) -> dict:
    """Simulate, identify (and discover) one campaign; its record (without the cell's columns).
    In memory unless :func:`needs_log` (module docstring). Discovery is imported only where a
    campaign runs it: its import (scipy.stats, ~0.9 s once per worker) was most of the per-task
    overhead of identify-only studies."""
    from calbench.identify.report import run_identify

    rec: dict = {
        "replicate": replicate,
        "seed": seed,
        "expected": job.expected,
        "worker": f"{socket.gethostname()}:{os.getpid()}",
        "error": "",
    }
    t0 = time.perf_counter()
    log = folder / f"campaign{replicate}.mcap"
    try:
        scn = job.scenario.scenario(seed)
        sim = None
        if needs_log(scn):
            run_campaign(scn, log)
            t1 = time.perf_counter()
            rep = run_identify(log, None, job.method, check_profile=False)  # as in memory
        else:
            sim = simulate_in_memory(scn)
            t1 = time.perf_counter()
            rep = identify_in_memory(sim, job.method)
        t2 = time.perf_counter()
        rec.update(simulate_s=t1 - t0, identify_s=t2 - t1)
        for p in rep.parameters:
            for f in PARAM_FIELDS:
                rec[f"{p.name}_{f}"] = _num(getattr(p, f))
        rec.update(
            chi2=_num(rep.chi2),
            dof=rep.dof,
            chi2_per_dof=_num(rep.chi2_per_dof),
            residual_rms=_num(rep.residual_rms),
            noise_sigma=_num(rep.noise_sigma),
            n_poses_planned=rep.n_poses_planned,
            n_poses_used=rep.n_poses_used,
            converged=rep.details.get("converged"),
        )
        if job.discover:
            if sim is not None:
                d = discover_in_memory(sim, discover_model)
            else:
                from calbench.identify.discover import discover

                model = None
                if discover_model is not None:
                    model = folder / "model.xml"
                    if not model.is_file():
                        write_text(model, discover_model)
                d = discover(log, model, out_model=folder / "augmented.xml")
            first = _named_first(d)
            rec.update(
                named_first=first,
                named_effects=",".join(d["named_effects"]),
                detected=None if job.expected is None else first == job.expected,
                rms_before=d["rms_before"],
                rms_after=d["rms_after"],
                noise_rms_before=d["noise_rms_before"],
                noise_rms_after=d["noise_rms_after"],
                discover_s=time.perf_counter() - t2,
            )
    except Exception as exc:  # noqa: BLE001 - a failed campaign is a row of the study, not its end
        rec["error"] = f"{type(exc).__name__}: {exc}".splitlines()[0][:500]
    finally:
        log.unlink(missing_ok=True)
    rec["campaign_s"] = time.perf_counter() - t0
    return rec


def run_campaigns(mjcf: str, models: dict, job: CampaignJob) -> list[dict]:
    """The task: every (replicate, seed) of the job, in order; one record each. ``mjcf``: the
    robot's text; ``models``: discover's starting MJCF per ``without`` tuple (shared by all tasks)."""
    job = replace(job, scenario=replace(job.scenario, mjcf=mjcf))
    with tempfile.TemporaryDirectory(prefix="calbench-study-") as d:
        return [one_campaign(job, r, s, Path(d), models.get(job.without)) for r, s in job.replicates]


def discover_model_text(mjcf: str, without: tuple[str, ...]) -> str | None:
    """The MJCF discover starts from: the robot without the named effects (None: the log's own)."""
    if not without:
        return None
    for name in without:
        mjcf = REMOVABLE[name](mjcf)
    return mjcf


def empty_record(columns: dict[str, pa.DataType]) -> dict:
    """A record with every result column missing (NaN numbers, None elsewhere)."""
    return {k: (math.nan if t == _F else None) for k, t in columns.items()}


__all__ = [
    "CampaignJob",
    "run_campaigns",
    "one_campaign",
    "needs_log",
    "tracker_needs_log",
    "simulate_in_memory",
    "Simulated",
    "identify_in_memory",
    "discover_in_memory",
    "discover_model_text",
    "result_columns",
    "TIMING_COLUMNS",
    "REMOVABLE",
    "empty_record",
]
