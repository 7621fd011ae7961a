"""A new estimator is one file (issue 20): a method defined and registered here, in the test
file alone, runs through `identify` (library and command line), its report and a Monte Carlo,
and every verb's list of methods is the registry's.

The toy reports the actuator compliances of the paper's two-step (identify/methods/twostep.py)
and declares its spring parameters not identified, with its own reason and its own details: a
method whose output differs from every built-in one, whose numbers can be checked exactly
against the two-step's on the same readings (the same solve of the same inputs: equal to the
last bit, checked to 1e-12).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import PAPER

from calbench.bench.core import InputError
from calbench.bench.model import Robot
from calbench.bench.scenario import load_scenario
from calbench.identify.cli import build_parser, main
from calbench.identify.methods import (
    Method,
    MethodResult,
    NotApplicable,
    method_names,
    montecarlo_choices,
    register_method,
    select_methods,
    two_step,
    unregister_method,
)
from calbench.identify.report import identification_report, identify
from calbench.identify.study import run_montecarlo, simulate_in_memory

TOY_REASON = "the toy estimates the actuator compliances only"


def toy_estimate(robot, obs, options) -> MethodResult:
    r = two_step(robot, obs)
    lay = robot.layout
    keep = np.zeros(lay.n, bool)
    keep[lay.compliance] = True
    theta = np.where(keep, r.theta, np.nan)
    cov = np.where(np.outer(keep, keep), r.cov, np.nan)
    reasons = {name: TOY_REASON for name, k in zip(lay.names, keep) if not k}
    return MethodResult(
        "toy",
        lay.names,
        lay.units,
        theta,
        cov,
        keep,
        reasons,
        r.residual,
        r.residual_w,
        r.chi2,
        r.dof,
        details={"toy": {"kept": int(keep.sum())}},
    )


def never(robot):
    raise NotApplicable("no robot is a toy robot")


TOY = Method("toy", toy_estimate, summary="the two-step's compliances alone")
PICKY = Method(
    "picky-toy", toy_estimate, summary="refuses every robot", applies=never, requirement="a toy robot"
)


@pytest.fixture
def toys():
    for m in (TOY, PICKY):
        register_method(m)
    yield
    for m in (TOY, PICKY):
        unregister_method(m.name)


@pytest.fixture(scope="module")
def campaign():
    scn = load_scenario(PAPER)
    sim = simulate_in_memory(scn)
    return scn, sim, Robot.from_xml(sim.mjcf)


def test_a_registered_method_is_in_every_list_and_leaves_with_its_registration(toys, campaign):
    scn, _, robot = campaign
    assert method_names()[:4] == ("one-step", "two-step", "two-step-weighted", "two-step-iterated")
    assert "toy" in method_names(offered_only=True) and "two-step-weighted" not in method_names(True)
    assert montecarlo_choices()["toy"] == ("toy",)
    assert montecarlo_choices()["two-step"] == ("two-step", "two-step-weighted")
    # `both` runs what applies; a method asked for by name that does not apply is bad input
    assert select_methods("both", robot, scn.robot)[-1] == "toy"
    assert "picky-toy" not in select_methods("both", robot, scn.robot)
    # the default leaves out the iterated two-step (~5x the one-step per run); all runs it
    assert "two-step-iterated" not in select_methods("both", robot, scn.robot)
    assert select_methods("all", robot, scn.robot) == method_names()[:4] + ("toy",)
    with pytest.raises(InputError, match="a toy robot"):
        select_methods("picky-toy", robot, scn.robot)
    sub = next(a for a in build_parser()._actions if a.dest == "command").choices
    for verb in ("identify", "montecarlo"):
        method = next(a for a in sub[verb]._actions if a.dest == "method")
        assert "toy" in method.choices
    with pytest.raises(ValueError, match="exists already"):
        register_method(TOY)
    unregister_method("toy")
    assert "toy" not in method_names() and "toy" not in montecarlo_choices()


def test_identify_runs_a_registered_method_and_reports_what_it_returns(toys, campaign, tmp_path, capsys):
    _, sim, robot = campaign
    res = identify(robot, sim.obs, "toy")
    rep = identification_report(res, sim.truth, "in memory", "MJCF", 0.0)
    two = two_step(robot, sim.obs)
    lay = robot.layout
    est = np.array([np.nan if p.estimate is None else p.estimate for p in rep.parameters])
    assert rep.method == "toy"
    np.testing.assert_allclose(est[lay.compliance], two.theta[lay.compliance], rtol=1e-12)
    np.testing.assert_allclose(
        [p.std for p in rep.parameters[lay.compliance]], np.sqrt(np.diag(two.cov))[lay.compliance], rtol=1e-12
    )
    assert rep.unidentifiable == {n: TOY_REASON for n in ("compensator_stiffness", "compensator_preload")}
    assert rep.details["toy"] == {"kept": 6} and rep.chi2 == pytest.approx(two.chi2, rel=1e-12)
    with pytest.raises(InputError, match="--method picky-toy"):
        identify(robot, sim.obs, "picky-toy")
    # and through the command line: the choice comes from the registry
    log, js = tmp_path / "p.mcap", tmp_path / "toy.json"
    assert main(["simulate", str(PAPER), "--out", str(log)]) == 0
    assert main(["identify", str(log), "--method", "toy", "--json", str(js)]) == 0
    assert "(toy; model" in capsys.readouterr().out
    out = json.loads(js.read_text())
    assert out["method"] == "toy" and out["toy"] == {"kept": 6}
    assert [p["estimate"] is None for p in out["parameters"]] == [False] * 6 + [True] * 2


def test_a_short_monte_carlo_runs_a_registered_method_on_the_same_noise(toys):
    """The toy has no Monte Carlo set-up of its own: every run is its full estimate (the
    family's default), on the same readings as the built-in two-step's."""
    mc = run_montecarlo(load_scenario(PAPER), 3, methods=("two-step", "toy"), progress=False)
    np.testing.assert_allclose(mc.estimates["toy"][:, :6], mc.estimates["two-step"][:, :6], rtol=1e-12)
    np.testing.assert_allclose(mc.stds["toy"][:, :6], mc.stds["two-step"][:, :6], rtol=1e-12)
    assert np.isnan(mc.estimates["toy"][:, 6:]).all() and mc.failed["toy"] == 0
    np.testing.assert_allclose(mc.noise_free["toy"][:6], mc.noise_free["two-step"][:6], rtol=1e-12)
    rows = {p["name"]: p for p in mc.summary()["methods"]["toy"]["parameters"]}
    assert rows["k1"]["identified_runs"] == 3 and rows["compensator_stiffness"]["identified_runs"] == 0


def test_a_result_of_the_wrong_shape_is_refused_naming_the_method_and_the_shape(campaign):
    _, sim, robot = campaign
    r = toy_estimate(robot, sim.obs, None)
    with pytest.raises(ValueError, match=r"toy: cov has shape \(8, 7\), expected \(8, 8\)"):
        MethodResult(
            "toy",
            r.names,
            r.units,
            r.theta,
            r.cov[:, :7],
            r.identifiable,
            {},
            r.residual,
            r.residual_w,
            0.0,
            1,
        )
