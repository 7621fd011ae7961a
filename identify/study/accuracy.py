"""Predicted accuracy of a campaign: the Cramer-Rao bound of its parameters under its tracker.

The bound is the inverse Fisher information (J^T Sigma^-1 J)^-1 at the scenario's true
parameters on the exact model (identify/core/forward.py), Sigma the deflections' covariance under the
scenario's tracker model, one block per pose (identify/core/whitening.py; for the iso10360 tracker
the field and the drift on the campaign's timeline, bench/tracker/models/iso10360.py). It is what the one-step
estimator's spread reaches (identify/study/montecarlo.py measures it), so it predicts a campaign's
accuracy before anyone measures: the same plan under isotropic, spec and iso10360 noise
(docs/performance.md, "Tracker models") differs only here.
"""

from __future__ import annotations

import numpy as np

from calbench.bench.campaign import simulate
from calbench.bench.model import Robot
from calbench.bench.scenario import Scenario
from calbench.identify.core import ForwardModel, Whitener, design_from_observations, from_campaign

from .montecarlo import true_theta


def cramer_rao(scn: Scenario) -> tuple[np.ndarray, tuple[str, ...]]:
    """(p, p) Cramer-Rao bound of theta (SI, the robot's parameter layout: k1..kN, then K_C and s0
    per compensator) for the scenario's campaign, and the parameters' names."""
    obs = from_campaign(simulate(scn, None, force=True))  # exact readings: no noise drawn, no size limit
    robot = Robot.from_file(scn.robot)
    theta = true_theta(scn, robot)
    _, jac = ForwardModel(robot, design_from_observations(robot, obs)).evaluate(theta)
    jw = Whitener.from_observations(obs).mat(jac) * theta  # scaled columns
    return np.linalg.pinv(jw.T @ jw) * np.outer(theta, theta), tuple(robot.layout.names)


def predicted_std(scn: Scenario) -> dict[str, float]:
    """Per parameter name, the Cramer-Rao standard deviation (SI)."""
    crb, names = cramer_rao(scn)
    return {n: float(v) for n, v in zip(names, np.sqrt(np.diag(crb)))}


__all__ = ["cramer_rao", "predicted_std"]
