"""A study's campaigns in memory (identify/study/campaign.py): the same rows as through the log.

Two proofs. (1) What the in-memory identify and discover see is what a reader of the log sees
without its truth: the Observations equal ``from_log(read_log(log))`` (read without truth) in
every field and bit, and the robot is the log's MJCF text; the truth enters only the report's
error columns, after the estimate, equal to the log's. (2) Small studies run both ways (the log
path forced through ``needs_log``) give bit-identical Parquet rows, timing columns aside, for
the cell kinds the shipped studies use: isotropic, spec and iso10360 trackers, one-step and
two-step, a hidden tracker drift, and discover (a model without the compensator).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pyarrow.parquet as pq
import pytest
from conftest import PAPER

from calbench.bench.campaign import run_campaign
from calbench.bench.log import read_log
from calbench.bench.model import Robot
from calbench.bench.scenario import load_scenario, scenario_variant
from calbench.bench.tracker import TrackerSpec
from calbench.identify.core import from_log
from calbench.identify.report import truth_vector
from calbench.identify.study import (
    TIMING_COLUMNS,
    load_study,
    needs_log,
    prepare,
    run_study,
    simulate_in_memory,
)
from calbench.identify.study import campaign as campaign_mod

SPEC = 'model = "spec"\ndistance = [1.0e-5, 2.0e-6]\ntransverse = [2.0e-5, 3.0e-6]\n'
DRIFT = "[truth.effects.tracker_drift]\noffset = [30e-6, -20e-6, 25e-6]\n"


def differences(u, v, where="obs") -> list[str]:
    """Every place where u and v differ: type, shape, dtype or any bit (NaN equals NaN)."""
    if type(u) is not type(v):
        return [f"{where}: {type(u).__name__} vs {type(v).__name__}"]
    if isinstance(u, np.ndarray):
        same = u.shape == v.shape and u.dtype == v.dtype and u.tobytes() == v.tobytes()
        return [] if same else [f"{where}: differs"]
    if dataclasses.is_dataclass(u):
        return [
            d
            for f in dataclasses.fields(u)
            for d in differences(getattr(u, f.name), getattr(v, f.name), f"{where}.{f.name}")
        ]
    if isinstance(u, (list, tuple)):
        if len(u) != len(v):
            return [f"{where}: length {len(u)} vs {len(v)}"]
        return [d for i, (a, b) in enumerate(zip(u, v)) for d in differences(a, b, f"{where}[{i}]")]
    if isinstance(u, float):
        return [] if np.float64(u).tobytes() == np.float64(v).tobytes() else [f"{where}: {u!r} vs {v!r}"]
    return [] if u == v else [f"{where}: {u!r} vs {v!r}"]


def _scenario(tmp_path, tracker: str = "", extra: str = ""):
    path = scenario_variant(PAPER, tmp_path / "s.toml", extra=extra)
    if tracker:
        path.write_text(path.read_text().replace("[tracker]\n", "[tracker]\n" + tracker, 1))
    return load_scenario(path)


@pytest.mark.parametrize(
    "tracker, extra", [("", ""), (SPEC, ""), ("", DRIFT)], ids=["isotropic", "spec", "tracker drift"]
)
def test_the_in_memory_campaign_is_what_a_reader_of_its_log_without_truth_gets(tmp_path, tracker, extra):
    scn = _scenario(tmp_path, tracker, extra)
    assert not needs_log(scn)
    sim = simulate_in_memory(scn)
    run_campaign(scn, tmp_path / "s.mcap")
    log = read_log(tmp_path / "s.mcap")  # without truth, as identify reads it
    logged = from_log(log)
    # every field to the last bit; the source only names where they came from (nothing reads it)
    assert differences(dataclasses.replace(sim.obs, source=logged.source), logged) == []
    assert sim.mjcf == log.mjcf_text
    # the truth, kept apart for the error columns, is the log's truth record
    robot = Robot.from_xml(log.mjcf_text)
    truth = truth_vector(read_log(tmp_path / "s.mcap", include_truth=True).truth, robot)
    assert differences(sim.truth, truth) == []


def test_the_iso10360_tracker_goes_through_the_log():
    """Its covariances depend on the readings' times as the log stamps them (module docstring
    of identify/study/campaign.py): such a campaign is simulated into a log and read back."""

    scn = load_scenario(PAPER)
    iso = dataclasses.replace(scn, tracker=TrackerSpec(scn.tracker.position, model="iso10360"))
    assert needs_log(iso) and not needs_log(scn)


IDENTIFY = f'''scenario = "{PAPER.as_posix()}"
seeds = 2
[[axis]]
name = "kind"
cases = [
  {{ label = "isotropic" }},
  {{ label = "spec two-step", set = {{ "tracker.model" = "spec", "tracker.distance" = [1.0e-5, 2.0e-6], "tracker.transverse" = [2.0e-5, 3.0e-6], "campaign.method" = "two-step" }} }},
  {{ label = "iso10360", set = {{ "tracker.model" = "iso10360" }} }},
  {{ label = "drift two-step", set = {{ "truth.effects.tracker_drift" = {{ offset = [3.0e-5, -3.0e-5, 3.0e-5] }}, "campaign.method" = "two-step" }} }},
]
'''

DISCOVER = f'''scenario = "{PAPER.as_posix()}"
seeds = 1
[campaign]
discover = true
[[axis]]
name = "effect"
cases = [
  {{ label = "compensator", set = {{ "truth.compensator.stiffness" = 6.0e6, "campaign.discover_without" = ["compensator"] }} }},
]
'''


def _rows(path) -> dict[str, list]:
    t = pq.read_table(path)
    return {n: t.column(n).to_pylist() for n in t.column_names if n not in TIMING_COLUMNS}


def _bits(v):
    return np.float64(v).tobytes() if isinstance(v, float) else v


def _run_both_ways(tmp_path, monkeypatch, text: str):
    """The study's rows in memory and through logs, and how many logs each way wrote."""
    study = tmp_path / "study.toml"
    study.write_text(text)
    written = []
    real = campaign_mod.run_campaign
    monkeypatch.setattr(campaign_mod, "run_campaign", lambda scn, out: written.append(out) or real(scn, out))
    run_study(prepare(load_study(study), tmp_path / "memory.parquet"))
    in_memory = len(written)
    monkeypatch.setattr(campaign_mod, "needs_log", lambda scn: True)
    run_study(prepare(load_study(study), tmp_path / "logs.parquet"))
    return (
        _rows(tmp_path / "memory.parquet"),
        _rows(tmp_path / "logs.parquet"),
        in_memory,
        len(written) - in_memory,
    )


def _assert_identical(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for k in a:
        assert [_bits(x) for x in a[k]] == [_bits(x) for x in b[k]], k


def test_an_identify_study_in_memory_has_the_rows_of_the_study_through_logs(tmp_path, monkeypatch):
    mem, logs, n_mem, n_logs = _run_both_ways(tmp_path, monkeypatch, IDENTIFY)
    assert mem["error"] == [""] * 8 and logs["error"] == [""] * 8
    assert (n_mem, n_logs) == (2, 8)  # in memory: only the iso10360 cell's logs
    _assert_identical(mem, logs)


def test_a_discover_study_in_memory_has_the_rows_of_the_study_through_logs(tmp_path, monkeypatch):
    mem, logs, n_mem, n_logs = _run_both_ways(tmp_path, monkeypatch, DISCOVER)
    assert mem["error"] == [""] and logs["error"] == [""]
    assert (n_mem, n_logs) == (0, 1)
    assert all(mem["named_first"])  # discover ran and named something (or nothing)
    _assert_identical(mem, logs)
