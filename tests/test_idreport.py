"""The identification report type: JSON round trips, old and minimal reports, bad input."""

from __future__ import annotations

import json

import pytest

from calbench.bench.core import InputError
from calbench.bench.log import IdentificationReport, ObservationFit, Outlier, ParameterEstimate

# An `identify --json` report as calbench wrote it before the report had a type (trimmed to
# two parameters and one observation; every key of that version is here, in its order).
OLD_IDENTIFY = {
    "method": "one-step",
    "parameters": [
        {
            "name": "k1",
            "unit": "rad/(N*m)",
            "estimate": None,
            "std": None,
            "truth": 2.5e-07,
            "error": None,
            "z": None,
            "identifiable": False,
            "reason": "every load is vertical, so none turns the J1 axis",
        },
        {
            "name": "k2",
            "unit": "rad/(N*m)",
            "estimate": 1.1829e-07,
            "std": 1.12e-09,
            "truth": 1.2e-07,
            "error": -1.71e-09,
            "z": -1.5267857142857142,
            "identifiable": True,
            "reason": None,
        },
    ],
    "residual_rms": 1.91e-05,
    "noise_sigma": 2e-05,
    "chi2_per_dof": 0.92,
    "chi2": 73.6,
    "dof": 80,
    "expected_residual_rms": 1.95e-05,
    "whitened_residual_rms": 0.93,
    "covariance": [[None, None], [None, 1.2544e-18]],
    "log": "cut.mcap",
    "model": "m900ib700.xml (from the log)",
    "n_poses_planned": 16,
    "n_poses_used": 9,
    "lost_poses": [9, 10, 11, 12, 13, 14, 15],
    "n_lost_poses": 7,
    "truncated": True,
    "n_observations": 29,
    "identifiable": {"k1": False, "k2": True},
    "unidentifiable": {"k1": "every load is vertical, so none turns the J1 axis"},
    "outliers": [],
    "outlier_threshold_sigma": 5.0,
    "dropped_outliers": [],
    "seconds": 0.031,
    "observations": [
        {
            "pose": 0,
            "reflector": "refl_a",
            "measured": [1e-3, -2e-3, 3e-4],
            "predicted": [1.01e-3, -2e-3, 3e-4],
            "residual": [-1e-5, 0.0, 0.0],
        }
    ],
    "start": "two-step",
    "iterations": 3,
    "evaluations": 5,
    "converged": True,
}

# what `calbench discover` wrote for the viewer before it went through the report type
OLD_DISCOVER_VIEW = {
    "method": "discover: link_compliance",
    "parameters": [
        {"name": "k1", "unit": "rad/(N*m)", "estimate": 2.5e-07, "std": 6e-10, "truth": None},
        {"name": "forearm_rx", "unit": "rad/(N*m)", "estimate": 8e-08, "std": None, "truth": None},
    ],
    "observations": [{"pose": 3, "reflector": "refl_b", "predicted": [1e-3, 0.0, -2e-3]}],
    "residual_rms": 2.1e-05,
    "noise_sigma": 2e-05,
}


def full_report() -> IdentificationReport:
    return IdentificationReport(
        method="two-step",
        parameters=(
            ParameterEstimate("k1", "rad/(N*m)", 2.5e-7, 6e-10, 2.49e-7, 1e-9, 1.6667, True, None),
            ParameterEstimate(
                "compensator_preload",
                "m",
                None,
                None,
                0.83,
                identifiable=False,
                reason="K_C is not identified",
            ),
        ),
        residual_rms=2e-5,
        noise_sigma=2e-5,
        chi2_per_dof=1.01,
        chi2=125.2,
        dof=124,
        expected_residual_rms=1.98e-5,
        whitened_residual_rms=1.0,
        covariance=((3.6e-19, None), (None, None)),
        log="paper.mcap",
        model="m900ib700.xml",
        n_poses_planned=16,
        n_poses_used=15,
        lost_poses=(15,),
        truncated=True,
        n_observations=44,
        outliers=(Outlier(5, "refl_a", 9.8),),
        outlier_threshold_sigma=5.0,
        dropped_outliers=(Outlier(2, "refl_c", 6.1),),
        seconds=0.05,
        observations=(
            ObservationFit(0, "refl_a", (1e-3, 2e-3, -3e-3), (1.1e-3, 2e-3, -3e-3), (1e-4, 0.0, 0.0)),
            ObservationFit(1, "refl_b", (4e-4, 0.0, 1e-3)),
        ),
        details={
            "step1": {"names": ["k1", "k2@0deg"], "estimate": [1.0, None]},
            "step2": {"n_distinct_q2": 3},
        },
    )


def test_round_trip_to_json_from_json():
    rep = full_report()
    text = rep.to_json()
    back = IdentificationReport.from_json(text, "x.json")
    assert back == rep
    assert back.to_json() == text
    assert back.source == "x.json" and back.read_warnings == ()
    d = json.loads(text)
    # the CONTRACT keys and the derived ones are written
    for key in ("method", "parameters", "residual_rms", "noise_sigma", "chi2_per_dof"):
        assert key in d
    assert list(d["parameters"][0]) == [
        "name",
        "unit",
        "estimate",
        "std",
        "truth",
        "error",
        "z",
        "identifiable",
        "reason",
    ]
    assert d["n_lost_poses"] == 1
    assert d["identifiable"] == {"k1": True, "compensator_preload": False}
    assert d["unidentifiable"] == {"compensator_preload": "K_C is not identified"}
    # estimator-specific details go at the top level, after the observations
    assert list(d)[-2:] == ["step1", "step2"] and d["step2"] == {"n_distinct_q2": 3}
    assert d["observations"][1] == {
        "pose": 1,
        "reflector": "refl_b",
        "measured": None,
        "predicted": [4e-4, 0.0, 1e-3],
        "residual": None,
    }
    assert back.predictions() == {0: {"refl_a": (1e-3, 2e-3, -3e-3)}, 1: {"refl_b": (4e-4, 0.0, 1e-3)}}


def test_non_finite_values_are_written_as_null():
    rep = IdentificationReport(
        "one-step", (ParameterEstimate("k1", estimate=float("nan")),), residual_rms=float("inf")
    )
    d = json.loads(rep.to_json())
    assert d["parameters"][0]["estimate"] is None and d["residual_rms"] is None


def test_details_may_not_shadow_report_keys():
    rep = IdentificationReport("one-step", (), details={"chi2": 1.0})
    with pytest.raises(ValueError, match="chi2"):
        rep.to_json()


def test_a_report_of_the_previous_version_loads_and_is_written_back_unchanged():
    text = json.dumps(OLD_IDENTIFY, indent=2)
    rep = IdentificationReport.from_json(text)
    assert rep.parameters[0].estimate is None and rep.parameters[0].identifiable is False
    assert rep.parameters[0].reason.startswith("every load is vertical")
    assert rep.lost_poses == tuple(range(9, 16)) and rep.truncated is True
    assert rep.covariance == ((None, None), (None, 1.2544e-18))
    assert rep.details == {"start": "two-step", "iterations": 3, "evaluations": 5, "converged": True}
    assert rep.observations[0].residual == (-1e-5, 0.0, 0.0)
    assert json.loads(rep.to_json()) == OLD_IDENTIFY
    assert rep.to_json() == text  # same keys, same order


def test_an_old_discover_view_report_and_a_minimal_one_load():
    rep = IdentificationReport.from_json(json.dumps(OLD_DISCOVER_VIEW))
    assert rep.method == "discover: link_compliance"
    assert [p.identifiable for p in rep.parameters] == [True, True]  # an estimate: identified
    assert rep.predictions() == {3: {"refl_b": (1e-3, 0.0, -2e-3)}}
    assert rep.observations[0].measured is None and rep.chi2_per_dof is None
    assert rep.lost_poses == () and rep.outliers == () and rep.details == {}
    assert IdentificationReport.from_json(rep.to_json()) == rep
    minimal = IdentificationReport.from_json('{"parameters": [{"name": "k2", "estimate": 1e-7}]}')
    assert minimal.method is None and minimal.parameters[0] == ParameterEstimate("k2", estimate=1e-7)


def test_unfit_observations_are_skipped_with_a_note():
    doc = dict(
        OLD_DISCOVER_VIEW,
        observations=[
            {"pose": 3, "reflector": "refl_b", "predicted": [1e-3, 0.0, -2e-3]},
            {"pose": 0, "reflector": "refl_a"},  # no prediction
            {"pose": True, "reflector": "refl_a", "predicted": [0, 0, 0]},  # a bool pose
            {"pose": 1, "reflector": "refl_a", "predicted": [0, 0]},  # two numbers
            {"pose": 1, "reflector": "refl_a", "predicted": [0, 0, 0], "measured": "far"},
        ],
    )
    rep = IdentificationReport.from_json(json.dumps(doc))
    assert len(rep.observations) == 1
    assert rep.read_warnings == (
        "observations: 4 entries without pose, reflector and a predicted [dx, dy, dz] were skipped",
    )


@pytest.mark.parametrize(
    "text, key",
    [
        ("{not json", "file"),
        (json.dumps({"method": "x"}), "parameters"),
        (json.dumps({"parameters": [{"name": "k1"}]}), "parameters[0]"),
        (json.dumps({"parameters": [{"estimate": 1.0}]}), "parameters[0]"),
        (json.dumps({"parameters": [{"name": "k1", "estimate": "big"}]}), "parameters[0].estimate"),
        (json.dumps({"parameters": [], "dof": 1.5}), "dof"),
        (json.dumps({"parameters": [], "covariance": [[1.0], [2.0]]}), "covariance"),
        (json.dumps({"parameters": [], "outliers": [{"pose": 1}]}), "outliers[0]"),
        (json.dumps({"parameters": [], "lost_poses": ["3"]}), "lost_poses"),
    ],
)
def test_bad_reports_name_the_file_and_key(text, key):
    with pytest.raises(InputError) as e:
        IdentificationReport.from_json(text, "bad.json")
    assert e.value.file == "bad.json" and e.value.key == key


def test_read_names_a_missing_file(tmp_path):
    with pytest.raises(InputError, match="readable JSON file"):
        IdentificationReport.read(tmp_path / "none.json")
    p = tmp_path / "r.json"
    p.write_text(full_report().to_json())
    rep = IdentificationReport.read(p)
    assert rep == full_report() and rep.source == str(p)
