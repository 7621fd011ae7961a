"""The task of a study: whole campaigns of one cell, exactly as a user would run them.

For each replicate: ``simulate`` the cell's scenario with the campaign's seed into a log in a
private temporary folder, ``identify`` it (the log without its truth; the truth is read only
afterwards, for the error and z columns, as in identify/report.py), and, where the study asks,
``discover`` on the log with the user's model (the log's MJCF, or it without the effects of
``discover_without``). The record of a campaign is one flat dict of :func:`result_columns`: per
parameter the estimate, reported std, truth, error and z; the fit's chi2; what discover named;
the timings; and the error, if the campaign failed (then the numbers are NaN).

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

import pyarrow as pa

from calbench.bench.campaign import run_campaign
from calbench.bench.effects import without_compensator
from calbench.bench.outputs import write_text

from ..portable import PortableScenario

# effects discover's starting model can lack (campaign.discover_without): MJCF text -> MJCF text
REMOVABLE = {"compensator": without_compensator}
PARAM_FIELDS = ("estimate", "std", "truth", "error", "z")
NOTHING = "nothing"

_F, _I, _S, _B = pa.float64(), pa.int64(), pa.string(), pa.bool_()


def result_columns(param_names) -> dict[str, pa.DataType]:
    """The measured columns of a study's rows, for a robot whose parameters are ``param_names``
    (its layout: k1..kN, then each compensator's stiffness and preload)."""
    return {
        "cell": _I, "replicate": _I, "seed": _I, "cell_id": _S,
        **{f"{p}_{f}": _F for p in param_names for f in PARAM_FIELDS},
        "chi2": _F, "dof": _I, "chi2_per_dof": _F, "residual_rms": _F, "noise_sigma": _F,
        "n_poses_planned": _I, "n_poses_used": _I, "converged": _B,
        "expected": _S, "named_first": _S, "named_effects": _S, "detected": _B,
        "rms_before": _F, "rms_after": _F, "noise_rms_before": _F, "noise_rms_after": _F,
        "simulate_s": _F, "identify_s": _F, "discover_s": _F, "campaign_s": _F,
        "worker": _S, "error": _S,
    }


TIMING_COLUMNS = ("simulate_s", "identify_s", "discover_s", "campaign_s", "worker")


@dataclass(frozen=True)
class CampaignJob:
    """Campaigns of one cell: its scenario (seed replaced per campaign; the MJCF texts travel
    apart, once per cluster: :func:`run_campaigns`), what to run after the simulation, and the
    (replicate, seed) pairs."""

    scenario: PortableScenario          # its mjcf is empty here
    method: str
    discover: bool
    without: tuple[str, ...]            # effects discover's model lacks (its MJCF is shared)
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


def one_campaign(job: CampaignJob, replicate: int, seed: int, folder: Path,
                 discover_model: str | None = None) -> dict:
    """Simulate, identify (and discover) one campaign; its record (without the cell's columns).
    Discovery is imported only where a campaign runs it: its import (scipy.stats, ~0.9 s once
    per worker) was most of the per-task overhead of identify-only studies."""
    from ..report import run_identify
    rec: dict = {"replicate": replicate, "seed": seed, "expected": job.expected,
                 "worker": f"{socket.gethostname()}:{os.getpid()}", "error": ""}
    t0 = time.perf_counter()
    log = folder / f"campaign{replicate}.mcap"
    try:
        run_campaign(job.scenario.scenario(seed), log)
        t1 = time.perf_counter()
        rep = run_identify(log, None, job.method)
        t2 = time.perf_counter()
        rec.update(simulate_s=t1 - t0, identify_s=t2 - t1)
        for p in rep.parameters:
            for f in PARAM_FIELDS:
                rec[f"{p.name}_{f}"] = _num(getattr(p, f))
        rec.update(chi2=_num(rep.chi2), dof=rep.dof, chi2_per_dof=_num(rep.chi2_per_dof),
                   residual_rms=_num(rep.residual_rms), noise_sigma=_num(rep.noise_sigma),
                   n_poses_planned=rep.n_poses_planned, n_poses_used=rep.n_poses_used,
                   converged=rep.details.get("converged"))
        if job.discover:
            from ..discover.workflow import discover
            model = None
            if discover_model is not None:
                model = folder / "model.xml"
                if not model.is_file():
                    write_text(model, discover_model)
            d = discover(log, model, out_model=folder / "augmented.xml")
            first = _named_first(d)
            rec.update(named_first=first, named_effects=",".join(d["named_effects"]),
                       detected=None if job.expected is None else first == job.expected,
                       rms_before=d["rms_before"], rms_after=d["rms_after"],
                       noise_rms_before=d["noise_rms_before"], noise_rms_after=d["noise_rms_after"],
                       discover_s=time.perf_counter() - t2)
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


__all__ = ["CampaignJob", "run_campaigns", "one_campaign", "discover_model_text", "result_columns",
           "TIMING_COLUMNS", "REMOVABLE", "empty_record"]
