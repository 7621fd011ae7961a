"""The profile check (identify/core/profile.py) and identification's use of it (identify/methods/onestep.py).

Tolerances. A quadratic chi2 rises by exactly PROFILE_SIGMAS^2 = 4 at +-2 std (to the refit's
chi2 tolerance, here exact). The identification cases: the weak 7-pose KR 270 plan
(tests/kr270_weak7.toml) with its 20 um tracker, where the Monte Carlo finds the Fisher std
honest (tests/test_montecarlo.py), and with a 100 um tracker, where it does not: empirical over
reported std of balancer_stiffness 0.79 over 400 runs (sampling error 1/sqrt(2N) = 0.035) and
the preload's variance 1.26x the CRB. Over 100 campaigns the preload's profile failed on 68 %
of the 100 um ones and on none of the 20 um ones: over 12 campaigns, the chance that none of
the 100 um ones fails is 0.32^12 ~ 1e-6.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from calbench.bench.campaign import remeasure, simulate
from calbench.bench.model import Robot
from calbench.bench.scenario import load_scenario
from calbench.identify.core import PROFILE_SIGMAS, from_campaign, profile_check
from calbench.identify.methods import one_step
from calbench.identify.study import run_montecarlo

WEAK = Path(__file__).resolve().parent / "kr270_weak7.toml"
CAMPAIGNS = 12


def test_a_quadratic_profile_passes_and_a_flat_or_bounded_one_does_not():
    """chi2 = sum ((x - x0) / sd)^2 refitted over nothing: rises exactly 4; a quartic rises
    PROFILE_SIGMAS^4 = 16 (> 8) and fails; a point past a bound fails with None."""
    x0, sd = np.array([1.0, 2.0, 3.0]), np.array([0.1, 0.2, 0.3])
    quad = profile_check(lambda v, i: ((v[i] - x0[i]) / sd[i]) ** 2, x0, 0.0, sd, x0 - 1, x0 + 1, range(3))
    assert not quad.bad.any()
    assert np.allclose([quad.rises[i] for i in range(3)], PROFILE_SIGMAS**2)
    quart = profile_check(lambda v, i: ((v[i] - x0[i]) / sd[i]) ** 4, x0, 0.0, sd, x0 - 1, x0 + 1, [0])
    assert quart.bad[0] and np.allclose(quart.rises[0], PROFILE_SIGMAS**4)
    bounded = profile_check(lambda v, i: ((v[i] - x0[i]) / sd[i]) ** 2, x0, 0.0, sd, x0 - 0.1, x0 + 1, [1])
    assert bounded.bad[1] and np.isclose(bounded.rises[1][0], 4.0) and bounded.rises[1][1] is None


def _campaigns(scn, n):
    campaign = simulate(scn, None)
    robot = Robot.from_file(scn.robot)
    for r in range(n):
        obs = from_campaign(remeasure(campaign, np.random.default_rng([scn.seed, r])))
        yield one_step(robot, obs, check_profile=True)


def test_a_spring_is_checked_where_the_report_s_claim_ends_too():
    """FAR: a profile quadratic to +-2 std that flattens beyond (a spring's curved valley: chi2 =
    d^2 up to d = 2, then 4 + 0.1 (d^2 - 4)) passes the +-2 std check and fails at +-FAR_SIGMAS
    (rise 5.6 < PROFILE_LOW x 20.25) when named ``far``; a quadratic passes both (rise 20.25); a
    far point past a bound is skipped (the parameter cannot be there), not failed."""
    from calbench.identify.core import FAR_SIGMAS, PROFILE_LOW

    x0, sd = np.array([1.0, 2.0]), np.array([0.1, 0.2])

    def bent(v, i):
        d2 = ((v[i] - x0[i]) / sd[i]) ** 2
        return d2 if d2 <= 4 + 1e-9 else 4 + 0.1 * (d2 - 4)

    near = profile_check(bent, x0, 0.0, sd, x0 - 10, x0 + 10, [0])
    assert not near.bad[0] and not near.rises_far
    far = profile_check(bent, x0, 0.0, sd, x0 - 10, x0 + 10, [0], far=[0])
    assert far.bad[0] and all(r < PROFILE_LOW * FAR_SIGMAS**2 for r in far.rises_far[0])
    quad = profile_check(
        lambda v, i: ((v[i] - x0[i]) / sd[i]) ** 2, x0, 0.0, sd, x0 - 10, x0 + 10, [0, 1], far=[0, 1]
    )
    assert not quad.bad.any() and np.allclose(quad.rises_far[1], FAR_SIGMAS**2)
    edge = profile_check(
        lambda v, i: ((v[i] - x0[i]) / sd[i]) ** 2, x0, 0.0, sd, x0 - 0.3, x0 + 10, [0], far=[0]
    )
    assert not edge.bad[0] and edge.rises_far[0][1] is None


def test_identification_flags_the_profile_where_the_fisher_std_is_wrong(tmp_path):
    scn = load_scenario(WEAK)
    preload = Robot.from_file(scn.robot).layout.names.index("balancer_preload")
    honest = [f.extra["profile"] for f in _campaigns(scn, CAMPAIGNS)]
    assert all(preload in p.rises for p in honest)  # every determined one is checked
    assert not any(p.bad.any() for p in honest)
    mjcf = (WEAK.parent / ".." / "mjcf" / "kr270.xml").resolve()
    loud_file = tmp_path / "kr270_weak7_100um.toml"
    loud_file.write_text(
        WEAK.read_text()
        .replace("sigma = 2e-05", "sigma = 0.0001")
        .replace('robot = "../mjcf/kr270.xml"', f'robot = "{mjcf}"')
    )
    loud = load_scenario(loud_file)
    assert loud.tracker.sigma == 100e-6
    mc = run_montecarlo(loud, 400, methods=("one-step",), progress=False).summary()
    kc = next(p for p in mc["methods"]["one-step"]["parameters"] if p["name"] == "balancer_stiffness")
    assert abs(kc["empirical_over_reported_std"] - 1) > 4 * np.sqrt(1 / (2 * 399))  # the Fisher std is wrong
    assert any(f.extra["profile"].bad[preload] for f in _campaigns(loud, CAMPAIGNS))


def _banana(curvature: float, rise: float):
    """A determined x (std 1 at the estimate 0) and an undetermined u on a valley x = curvature
    u^2 along which chi2 rises by ``rise`` u^2: refit_values with u held returns the valley's
    point, with x held the parabola's minimum over u."""

    def refit_values(v: np.ndarray, i: int) -> tuple[float, np.ndarray]:
        if i != 1:
            raise ValueError("only u is walked")
        u = v[1]
        return rise * u**2, np.array([curvature * u**2, u])

    return refit_values


def test_a_walk_along_a_curved_valley_marks_what_it_carries_far_with_little_rise():
    """The VALLEY rule (identify/core/profile.py): along x = u^2 a point m std out rises by
    ``rise`` m, so with rise 0.1 the point at m = 2 rises 0.2 (a quadratic: 4, the check's
    floor 2) and x is marked; with rise 10 every point rises at least 0.5 min(m, 4.5)^2 (10 m >=
    10.1 from m = 2 on) and x stands; a valley that does not bend (curvature 0) never moves x."""
    from calbench.identify.core import valley_check

    x0, sd, det = np.zeros(2), np.array([1.0, np.nan]), np.array([True, False])
    lo, hi, size = np.full(2, -100.0), np.full(2, 100.0), np.ones(2)
    flat = valley_check(_banana(1.0, 0.1), x0, 0.0, sd, det, lo, hi, [1], size)
    assert flat.bad.tolist() == [True, False]
    m, rise = flat.walks[1]["broke"][0]
    assert m >= PROFILE_SIGMAS and rise == pytest.approx(0.1 * m)
    assert flat.walks[1]["moved"][0][1] >= m  # the range x took on the way
    steep = valley_check(_banana(1.0, 10.0), x0, 0.0, sd, det, lo, hi, [1], size)
    assert not steep.bad.any() and steep.walks[1]["points"] > 0
    straight = valley_check(_banana(0.0, 0.1), x0, 0.0, sd, det, lo, hi, [1], size)
    assert not straight.bad.any() and straight.walks[1]["moved"][0] == [0.0, 0.0]


def test_the_story_says_which_walk_left_a_parameter_undetermined():
    """discover's text (identify/discover/narrative.py) names the walked parameter, the distance,
    the rise against the quadratic's, and the range, for every record carrying ``valley``."""
    from calbench.identify.discover import valley_lines

    rec = {"walked": "compensator_preload", "distance_std": 10.0, "chi2_rise": 4.9, "range": [8.8e-8, 1.2e-7]}
    lines = valley_lines(
        [
            {"name": "k2", "unit": "rad/(N*m)", "valley": rec},
            {"name": "k3", "unit": "rad/(N*m)"},
        ]
    )
    assert len(lines) == 2 and "k3" not in "".join(lines)
    assert "compensator_preload" in lines[1] and "4.9" in lines[1] and "20.2" in lines[1]
    assert "8.8e-08 to 1.2e-07" in lines[1]
