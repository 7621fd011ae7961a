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


def test_models_with_their_own_parameters_stay_scalar(paper):
    """Discovery's augmented model writes effects the batch's copy of the model would not see."""
    scn, obs = paper
    robot = Robot.from_file(scn.robot)
    design = design_from_observations(robot, obs)
    assert _model(scn, obs, True)._stacked(False)
    assert not _model(scn, obs, True)._stacked(True)  # effects' springs changed: A_base re-taken
    assert not AugmentedForward(robot, design, [])._stacked(False)  # even with no effect yet
