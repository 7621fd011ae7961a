"""What a plan can identify, and exactness on noise-free data.

Noise-free observations come from the simulated campaign's true reflector positions (with the
tracker's covariances as weights), built by the same code as a log's observations.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from conftest import MJCF, PAPER

from calbench.bench.campaign import simulate, truth_robot
from calbench.bench.model import Robot
from calbench.bench.scenario import parse_scenario
from calbench.identify.core import ForwardModel, design_from_observations, from_campaign, whiten_factors
from calbench.identify.methods import linear_plan, one_step, two_step
from calbench.identify.study import true_theta

TEXT = PAPER.read_text()
HEAD, *POSES = TEXT.split("[[pose]]")
COMPENSATOR = ("k2", "compensator_stiffness", "compensator_preload")


def observations(poses, tmp="/tmp/plan.toml"):
    head = HEAD.replace('robot = "../mjcf/m900ib700.xml"', f'robot = "{(MJCF).as_posix()}"')
    scn = parse_scenario(head + "".join("[[pose]]" + POSES[i] for i in poses), Path(tmp))
    return scn, Robot.from_file(scn.robot), from_campaign(simulate(scn, None))


@pytest.fixture(scope="module")
def paper():
    return observations(range(16))


def crb_std(robot, obs, theta):
    fm = ForwardModel(robot, design_from_observations(robot, obs))
    _, j = fm.evaluate(theta)
    jw = np.einsum("mij,mjk->mik", whiten_factors(obs.cov), j).reshape(-1, 8) * theta
    return np.sqrt(np.diag(np.linalg.inv(jw.T @ jw))) * theta


def test_one_step_recovers_the_truth_from_noise_free_data(paper):
    """Exact model, exact data: the error is set by the solver (~1e-6 sigma per residual, see
    identify/core/forward.py) and the stopping rule (1e-6 sigma): allow 1e-4 of the CRB's sigma.

    This tests the OPTIMISER, not the physics: the data come from the same statics as the
    model. The physics is held to independent computations elsewhere: the equilibrium against
    mj_step relaxation and the paper's equations (tests/test_statics.py), the Jacobian against
    finite differences of solved equilibria (tests/test_identify_forward.py)."""
    scn, robot, obs = paper
    res = one_step(robot, obs)
    assert res.converged and res.chi2 < 1e-6
    truth = true_theta(scn, Robot.from_file(scn.robot))
    sd = crb_std(robot, obs, truth)
    assert np.all(np.abs(res.theta - truth) < 1e-4 * sd), (res.theta - truth) / sd


def test_two_step_is_exact_on_its_own_linear_model(paper):
    """Steps 1 and 2 (eqs. 19-22 with sin^2) invert the linear model exactly."""
    scn, robot, obs = paper
    truth = true_theta(scn, Robot.from_file(scn.robot))
    lp = linear_plan(robot, obs)
    geom = robot.compensator_geometry()
    ll = geom.l_c * geom.l_2
    k = truth[:6].copy()
    synth = []
    for i, row in enumerate(lp.cols):
        q2 = obs.poses[lp.rows_pose[i]].q[1]
        psi, s = geom.angle(q2), geom.length(q2)
        eta = (1 - truth[7] / s) * np.cos(psi) + truth[7] * ll * np.sin(psi) ** 2 / s**3
        kk = k.copy()
        kk[1] = 1 / (1 / truth[1] + truth[6] * ll * eta)  # eq. (10)
        synth.append(row @ kk)
    synth = np.array(synth)
    poses, row = [], 0
    for p in obs.poses:  # the linear model's prediction replaces dp
        n = len(p.reflectors)
        poses.append(dataclasses.replace(p, dp=synth[row : row + n]))
        row += n
    lin_obs = dataclasses.replace(obs, poses=poses)
    exact = two_step(robot, lin_obs)
    assert np.allclose(exact.theta, truth, rtol=1e-9, atol=0)


def test_two_step_is_unbiased_where_its_linear_model_holds(tmp_path):
    """Gravity and the compensator off, the payload as an explicit force (tests/linear_case.py):
    the linear model of eqs. (19)-(22) then lacks only the load's own geometric stiffness, so
    the two-step estimates on exact data are the truth within a small fraction of their standard
    deviations: k1, k3..k6 within 0.05 (the geometric stiffness is ~1e-4 of their deflections);
    k2 within 0.25, because the load's geometric stiffness about J2, |W| x lever ~ 1.4e4 N*m/rad
    = 0.17 % of K2, differs between the three q2 and step 2 (exactly determined by them) turns
    that into a K_C and passes it to k2 (measured 0.15); the compensator it finds is nothing
    within 0.25 of its standard deviation. tests/test_montecarlo.py checks the same with noise:
    unbiased within the sampling error."""
    from linear_case import linear_world

    scn = parse_scenario(linear_world(tmp_path).read_text(), tmp_path / "linear_world.toml")
    tr = truth_robot(scn)
    obs = from_campaign(simulate(scn, None, robot=tr))
    robot = Robot.from_file(scn.robot)
    truth = true_theta(scn, robot)
    res = two_step(robot, obs)
    sd = np.sqrt(np.diag(res.cov))[:6]  # the linear model's CRB: the exact one here to ~1e-4
    z = (res.theta[:6] - truth[:6]) / sd
    assert np.all(np.abs(np.delete(z, 1)) < 0.05), z
    assert abs(z[1]) < 0.25, z
    assert abs(res.theta[6]) < 0.25 * np.sqrt(res.cov[6, 6])  # no compensator, within 0.25 sigma


def test_two_step_on_the_exact_statics_and_iterated_at_its_sagged_pose(paper):
    """The paper's two-step on exact data of the paper campaign (docs/performance.md, "Identification"): a
    NEGATIVE spring, K_C = -3.16e6 N/m against +2.6e6 (the stiff compensator sags J2 by
    1.0-1.8 deg; its Jacobians are taken at the commanded pose), k2 +6.8 sigma, k1 and k4 about
    -0.2 sigma (CRB sigma). Re-taking its Jacobians at the pose its own estimate sags to
    (identify/methods/twostep_iterated.py, the fixed point by Newton) brings K_C to +2.1 sigma, k2 to
    -0.7 sigma, s0 to -0.8 sigma; at the TRUE sag the linear model would give K_C +0.8 sigma:
    the rest is the linear model's own error (H00 of eq. 18) feeding the estimated sag."""
    from calbench.identify.methods import two_step_iterated

    scn, robot, obs = paper
    truth = true_theta(scn, Robot.from_file(scn.robot))
    sd = crb_std(robot, obs, truth)
    plain = two_step(robot, obs)
    assert plain.theta[6] == pytest.approx(-3.16e6, rel=0.005)
    err = (plain.theta - truth) / sd
    assert err[1] == pytest.approx(6.8, abs=0.1) and err[0] == pytest.approx(-0.2, abs=0.01)
    assert err[3] == pytest.approx(-0.21, abs=0.01)
    it = two_step_iterated(robot, obs)
    assert it.step2["converged"]
    e = (it.theta - truth) / sd
    np.testing.assert_allclose(e[[1, 6, 7]], [-0.69, 2.06, -0.85], atol=0.03)
    assert np.all(np.abs(e) < 2.1)


def test_iterated_covariance_carries_the_sags_share(paper):
    """The iterated two-step's covariance is A C A^T (identify/methods/twostep_iterated.py,
    Uncertainty), A = dtheta*/dtheta at the fixed sag. Checked against re-solving the whole fixed
    point on perturbed readings: the iterated estimate moves by A times the move of the linear
    solve at the old sag, up to a second-order remainder -- which halves when the perturbation
    halves (a wrong A would leave a first-order error that does not). The sag's share is not
    small: k1's std grows by a third and s0's shrinks (the sag and s0 are anti-correlated)."""
    from calbench.identify.methods import SagMap, sensitivity, two_step_iterated

    scn, robot, obs = paper
    it = two_step_iterated(robot, obs)
    fixed_pose = two_step_iterated(robot, obs, uncertainty=False)
    assert "sag's share" in it.step2["covariance"]
    np.testing.assert_array_equal(it.theta, fixed_pose.theta)
    sd = np.sqrt(np.diag(it.cov))
    ratio = sd / np.sqrt(np.diag(fixed_pose.cov))
    assert ratio[0] > 1.2 and ratio[7] < 0.9, ratio
    d = np.array(it.step2["sag_rad"])
    a = sensitivity(SagMap(robot, obs, False), d, it.theta)
    u = [np.random.default_rng(3).normal(size=p.dp.shape) for p in obs.poses]
    errors = []
    for delta in (0.02, 0.01):  # of the deflection noise sigma
        pert = dataclasses.replace(
            obs,
            poses=[
                dataclasses.replace(p, dp=p.dp + delta * np.sqrt(2) * obs.noise_sigma * v)
                for p, v in zip(obs.poses, u)
            ],
        )
        moved = two_step_iterated(robot, pert, start=d, uncertainty=False)
        assert moved.step2["converged"]
        linear = SagMap(robot, pert, False).estimate(d).theta
        move, pred = (moved.theta - it.theta) / sd, a @ (linear - it.theta) / sd
        errors.append(np.linalg.norm(move - pred) / np.linalg.norm(move))
    assert errors[0] < 0.1, errors
    assert errors[0] / errors[1] == pytest.approx(2.0, abs=0.3), errors


def test_iterated_sag_tangent_matches_finite_differences(paper):
    """S = dD/dtheta of the iterated two-step (identify/methods/twostep_iterated.py) comes from
    the statics' implicit-function tangent at each pose's unloaded equilibrium; checked against
    central differences of re-solved equilibria (REL_STEP = 1e-5 of each parameter), the way it
    was computed before. The differences' own error bounds the tolerance: the equilibria are
    solved to ~1e-11 rad, over a sag change of REL_STEP x (the sag's share, ~0.02 rad) ~ 2e-7 rad,
    i.e. ~5e-5 relative (their truncation error, ~REL_STEP^2, is far below). Columns are compared
    as S_j theta_j (the sag's response to a relative change), scaled by the largest; the
    covariance A C A^T it gives, with G shared, agrees with the finite-difference one as closely."""
    from calbench.identify.methods import REL_STEP, SagMap, sensitivity, sensitivity_fd, two_step_iterated

    scn, robot, obs = paper
    it = two_step_iterated(robot, obs)
    fixed = two_step_iterated(robot, obs, uncertainty=False)
    d, th = np.array(it.step2["sag_rad"]), it.theta
    sm = SagMap(robot, obs, False)
    s = sm.sag_tangent(th)
    fd = np.zeros_like(s)
    for j in range(len(th)):
        h = REL_STEP * abs(th[j])
        up, down = th.copy(), th.copy()
        up[j] += h
        down[j] -= h
        fd[:, j] = (sm.sag(up) - sm.sag(down)) / (2 * h)
    scaled = np.abs(fd * th)
    assert scaled[:, [1, 6, 7]].min(axis=0).max() > 0.1 * scaled.max()  # k2, K_C, s0 move the sag
    np.testing.assert_allclose(s * th, fd * th, rtol=0, atol=5e-5 * scaled.max())
    c = fixed.cov
    a, a_fd = sensitivity(sm, d, th), sensitivity_fd(SagMap(robot, obs, False), d, th)
    sd, sd_fd = np.sqrt(np.diag(a @ c @ a.T)), np.sqrt(np.diag(a_fd @ c @ a_fd.T))
    np.testing.assert_allclose(sd, sd_fd, rtol=5e-5)
    # what two_step_iterated reports: the same A, its equilibria warm-started (equal to the
    # statics' tolerance, 1e-10 of the forces, not bit for bit)
    np.testing.assert_allclose(np.sqrt(np.diag(it.cov)), sd, rtol=1e-8)


def test_vertical_loads_only_name_k1(paper):
    scn, robot, obs = observations(range(12))  # Table 5 without the lateral pulls
    for res in (one_step(robot, obs), two_step(robot, obs)):
        assert not res.identifiable[0] and np.isnan(res.theta[0])
        assert "vertical" in res.reasons["k1"] and "5.1" in res.reasons["k1"]
        assert res.identifiable[1:].all()


def test_two_distinct_q2_the_two_step_cannot_separate_the_compensator():
    scn, robot, obs = observations([0, 1, 2, 3, 8, 9, 10, 11, 12, 13, 14, 15])  # q2 = 0, 120
    two = two_step(robot, obs)
    for name, i in zip(COMPENSATOR, (1, 6, 7)):
        assert not two.identifiable[i] and np.isnan(two.theta[i])
        assert "2 distinct q2" in two.reasons[name]
    # The exact model also sees the compensator's static torque (eq. 9) through the J2 sag it
    # causes (1-2 degrees on this bench): two q2 suffice for the one-step estimator.
    one = one_step(robot, obs)
    assert one.identifiable.all()


def test_one_distinct_q2_names_the_compensator_for_both_methods():
    scn, robot, obs = observations([8, 9, 10, 11, 12, 13, 14, 15])  # q2 = 120
    for res in (one_step(robot, obs), two_step(robot, obs)):
        for name, i in zip(COMPENSATOR, (1, 6, 7)):
            assert not res.identifiable[i] and np.isnan(res.theta[i]), name
            assert "1 distinct q2" in res.reasons[name]
        assert res.identifiable[[0, 2, 3, 4, 5]].all()
