"""The estimator's forward model evaluated stacked (identify/core/forward.py, bench/statics/batched.py)
against its scalar loop, along a sequence of parameters such as a fit visits.

Both solve the same equilibria to the same criterion (forward.py's docstring: ~3e-11 m at a
reflector), so the deflections agree within 1e-10 m (the bound tests/test_identify_forward.py
uses against the simulator). While the warm path converges, both take their Jacobian from the
same cached A_base plus the analytic springs at solutions that agree that closely, so the
Jacobians agree to 1e-8 of each column's largest entry (the configuration difference, ~1e-11
rad, times the matrix's relative variation per radian, O(1), leaves far less; 1e-8 is the
linear algebra's rounding at the KKT matrix's condition ~1e7). After a move the warm chord
cannot follow, both re-take A_base by forward differences at their own solutions: that matrix's
rounding noise (~1e-10 relative per entry) reaches ~1e-6 in the weakest columns, so there the
bound is the forward model's stated Jacobian accuracy, 1e-5 (forward.py's docstring).
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import PAPER

from calbench.bench.campaign import simulate, truth_robot
from calbench.bench.model import Robot
from calbench.bench.scenario import load_scenario
from calbench.identify.core import ForwardModel, design_from_observations, from_campaign
from calbench.identify.discover import AugmentedForward
from calbench.identify.study import true_theta


@pytest.fixture(scope="module")
def paper():
    scn = load_scenario(PAPER)
    tr = truth_robot(scn)
    obs = from_campaign(simulate(scn, None, robot=tr))
    return scn, obs


def _model(scn, obs, batched):
    robot = Robot.from_file(scn.robot)
    return ForwardModel(robot, design_from_observations(robot, obs), batched=batched)


def test_stacked_evaluations_equal_the_scalar_loop(paper):
    scn, obs = paper
    fast, slow = _model(scn, obs, True), _model(scn, obs, False)
    th = true_theta(scn, fast.robot)
    p = len(th)
    rng = np.random.default_rng(7)
    moves = [
        np.ones(p),
        1 + 0.02 * rng.standard_normal(p),
        1 + 0.3 * rng.standard_normal(p),
        np.full(p, 2.5),
        np.ones(p),
    ]
    for k, mv in enumerate(moves):
        theta = th * np.abs(mv)
        retaken = slow.stats["refreshes"], slow.stats["retakes"]
        dp_f, jac_f = fast.evaluate(theta, jacobian=k != 1)
        dp_s, jac_s = slow.evaluate(theta, jacobian=k != 1)
        assert np.abs(dp_f - dp_s).max() <= 1e-10, k
        if jac_s is not None:
            scale = np.abs(jac_s).max(axis=(0, 1))
            # A_base re-taken (a refresh, or at a solution > KKT_QTOL away): by differences at
            # solutions equal to 1e-10, not bit-equal
            rel = 1e-8 if (slow.stats["refreshes"], slow.stats["retakes"]) == retaken else 1e-5
            assert (np.abs(jac_f - jac_s).max(axis=(0, 1)) <= rel * scale).all(), k
    # the same work: a 2.5x move from the last solution is beyond the warm chord, and the same
    # fallbacks ran in both
    assert fast.stats == slow.stats and slow.stats["refreshes"] > 0 and slow.stats["fallbacks"] > 0


def test_which_models_run_stacked(paper):
    """The base model runs stacked unless its A_base must be re-taken (``refresh``); discovery's
    augmented model runs stacked whenever its springs' part S is analytic (its A_base never
    depends on a parameter, and every spring value is synced into the batch: tested against its
    scalar loop in tests/test_discover.py), and pose by pose where a spring is outside the
    analytic S (a dead band, an elasto-plastic spring) or the batch is switched off."""
    scn, obs = paper
    robot = Robot.from_file(scn.robot)
    design = design_from_observations(robot, obs)
    assert _model(scn, obs, True)._stacked(False)
    assert not _model(scn, obs, True)._stacked(True)
    assert not _model(scn, obs, False)._stacked(False)
    assert AugmentedForward(robot, design, [])._stacked(False)
    assert AugmentedForward(robot, design, [])._stacked(True)
    assert not AugmentedForward(robot, design, [], batched=False)._stacked(False)
    band = Robot.from_file(scn.robot)
    band.model.tendon_lengthspring[band.tendons[0], 1] += 0.01  # a dead band of 1 cm
    assert not AugmentedForward(band, design, [])._stacked(False)
    yielding = Robot.from_file(scn.robot)
    yielding.model.jnt_springyield[yielding.act_joint[0]] = 1e3  # an elasto-plastic joint spring
    assert not AugmentedForward(yielding, design, [])._stacked(False)


@pytest.mark.parametrize("batched", [True, False])
def test_a_warm_evaluation_that_finds_no_equilibrium_is_retried_from_cold(paper, batched):
    """Cached equilibria far from the parameters asked (a profile or a soft-spring fit took the
    model there) can fail Newton where an equilibrium exists: the evaluation is retried once
    from cold, and gives what a fresh model gives (within the solver's 1e-10 m above). A cold
    evaluation's NoEquilibrium is final."""
    from calbench.identify.core import NoEquilibrium

    scn, obs = paper
    model, fresh = _model(scn, obs, batched), _model(scn, obs, batched)
    th = true_theta(scn, model.robot)
    model.evaluate(th * 1.5)
    real, calls = type(model)._solve, []

    def fails_once(self, des, load, eq, theta, refresh):
        if not calls:
            calls.append(1)
            raise NoEquilibrium(self.robot, des, theta)
        return real(self, des, load, eq, theta, refresh)

    model._solve = fails_once.__get__(model)
    dp, jac = model.evaluate(th)
    assert model.stats["cold_retries"] == 1 and calls
    dp0, jac0 = fresh.evaluate(th)
    assert np.abs(dp - dp0).max() < 1e-10
    assert np.allclose(jac, jac0, rtol=0, atol=1e-5 * np.abs(jac0).max())

    def never(theta, jacobian=True):
        raise NoEquilibrium(model.robot, model.design[0], theta)

    model._evaluate = never  # no equilibrium warm, nor cold
    with pytest.raises(NoEquilibrium):
        model.evaluate(th * 1.2)
    assert model.stats["cold_retries"] == 2
