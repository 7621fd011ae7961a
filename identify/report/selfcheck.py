"""`calbench identify --self-check`: does the reported std hold on this very campaign? (issue 22)

A parametric bootstrap at the estimate (identify/discover/uncertainty.py's ``bootstrap``, the one
discover runs on every model it reports): the deflections the identified model predicts on the
campaign's own poses and reflectors (the exact statics at theta_hat) plus REPLICAS draws of the
tracker noise the estimator assumes (each pose's covariance), each refitted by the same method as
the Monte Carlo refits a campaign (its ``repeats``: identify/methods/, for the one-step one
evaluation of the exact model on the batched statics per replica, from the noise-free
estimate). Then, for every determined parameter, the replicas' spread must lie within STD_FACTOR
(1.5) of the reported std and their mean within BIAS_SIGMA (0.5) std of the estimate (the
probabilities that a right std or estimator fails: that function's docstring).

A parameter that fails is flagged and `identify --check` fails. What it checks is the estimator
at this plan and noise (its linearisation, the model's curvature over a std, the stopping
rule), under the model as identified; what no bootstrap of that model can see -- an effect the
model lacks -- is discovery's exposure (identify/discover/exposure.py).
"""

from __future__ import annotations

import numpy as np

from calbench.identify.core import Observations, Whitener
from calbench.identify.discover import (
    BIAS_SIGMA,
    REPLICAS,
    STD_FACTOR,
    bootstrap,
    self_check_failures,
    unit_checks,
    with_deflections,
)
from calbench.identify.methods import method_named


def self_check(robot, obs: Observations, method: str, theta: np.ndarray, std: np.ndarray, predicted) -> dict:
    """The bootstrap of the module docstring around the estimate ``theta`` (std: its reported
    std, NaN where not determined; ``predicted``: (M, 3) the model's deflections at theta)."""
    obs0 = with_deflections(obs, predicted)
    # every replica has the campaign's covariance (only its deflections differ): one whitening
    white = Whitener.from_observations(obs0)
    reps = method_named(method).repeats(robot, obs0, white)

    def refit(o: Observations) -> np.ndarray:
        return reps.run(o, white).theta

    return bootstrap(obs, predicted, theta, unit_checks(reps.noise_free.names, std), refit)


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
    return [head + ": FAILED for " + ", ".join(check["failed"])] + [
        "    " + line for line in self_check_failures(check)
    ]


__all__ = ["REPLICAS", "STD_FACTOR", "BIAS_SIGMA", "self_check", "self_check_lines"]
