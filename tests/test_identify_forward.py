"""The exact forward model of identification: same physics as the simulator, exact Jacobian.

Tolerances. The statics are solved to a residual of tol x (gravity scale ~1e5 N*m): with the
default tol = 1e-10 that is ~1e-11 rad, ~3e-11 m at the reflectors; the Jacobian test uses
tol = 1e-12 (~2e-13 m). Central differences with a relative step h = 1e-3 carry an O(h^2)
truncation error of ~1e-6 x (curvature ratio, < 10 here) and a round-off of 2 x 2e-13 m over
the change they measure, 2 h theta |J| >= 7e-8 m for the weakest column (K_C: 34 um at 100 %),
i.e. < 1e-5; the stale part of the KKT matrix costs < 1e-6. Allowed: 1e-4 of the column.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest
from conftest import MJCF, PAPER, fanuc_params

from calbench.bench.campaign import simulate, truth_robot
from calbench.bench.model import Robot
from calbench.bench.scenario import load_scenario
from calbench.identify.core import ForwardModel, design_from_observations, from_campaign
from calbench.identify.methods import step2_rows
from calbench.identify.study import true_theta


@pytest.fixture(scope="module")
def paper():
    scn = load_scenario(PAPER)
    campaign = simulate(scn, None)
    return scn, campaign.plans, from_campaign(campaign)


def test_forward_model_reproduces_the_simulator(paper):
    """dp(theta_true) on the nominal MJCF equals the simulated true reflector motion."""
    scn, plans, obs = paper
    robot = Robot.from_file(scn.robot)
    fm = ForwardModel(robot, design_from_observations(robot, obs))
    dp, _ = fm.evaluate(true_theta(scn, Robot.from_file(scn.robot)), jacobian=False)
    assert np.abs(dp - obs.dp).max() < 1e-10  # both at ~3e-11 m solver precision
    # a second, warm-started evaluation (the fast path) gives the same
    dp2, _ = fm.evaluate(true_theta(scn, Robot.from_file(scn.robot)) * 1.0, jacobian=False)
    assert np.abs(dp2 - obs.dp).max() < 1e-10


def test_ift_jacobian_matches_finite_differences(paper):
    scn, _, obs = paper
    robot = Robot.from_file(scn.robot)
    fm = ForwardModel(robot, design_from_observations(robot, obs), tol=1e-12)
    th = true_theta(scn, Robot.from_file(scn.robot)) * np.array(
        [1.1, 0.9, 1.05, 1.2, 0.95, 1.1, 0.8, 1.05]
    )  # off the truth
    _, jac = fm.evaluate(th)
    assert_jacobian_matches_differences(fm, th, jac, 1e-4)


def assert_jacobian_matches_differences(
    fm: ForwardModel, th: np.ndarray, jac: np.ndarray, rel: float
) -> None:
    """Every column of ``jac`` within ``rel`` of its largest entry of fm's central differences
    (relative step 1e-3) at ``th``."""
    for j in range(th.size):
        h = 1e-3 * th[j]
        tp, tm = th.copy(), th.copy()
        tp[j] += h
        tm[j] -= h
        fd = (fm.evaluate(tp, False)[0] - fm.evaluate(tm, False)[0]) / (2 * h)
        col = jac[:, :, j]
        assert np.abs(fd - col).max() <= rel * np.abs(col).max(), f"column {j}"


def test_compensator_stiffness_has_sin_squared_and_the_model_angle():
    """Eqs. (10)-(11) with sin^2 (PHYSICS.md) and psi = q2 + offset: the step-2 row C_i times
    [0, K_C, s0 K_C] equals -d(tendon torque on J2)/dq2 by central differences (h = 1e-6 rad:
    O(h^2) ~ 1e-12 relative; round-off 1e-16 * 1e5 N*m / 1e-6 ~ 1e-5 N*m/rad)."""
    robot = Robot.from_file(MJCF)
    k_c, s0 = 2.6e6, 0.83
    robot.set_params(fanuc_params(np.full(6, 1e-7), k_c, s0))
    geom = robot.compensator_geometry()
    m, d = robot.model, robot.data
    j2 = robot.act_dof[1]

    def torque(q2):
        d.qpos[:] = robot.rigid_qpos(np.array([0.0, q2, 0, 0, 0, 0]))
        mujoco.mj_fwdPosition(m, d)
        return -k_c * (d.ten_length[robot.tendons[0]] - s0) * robot.tendon_moment()[j2]

    q2s = np.radians([0.0, 35.0, 77.0, 120.0])
    rows = step2_rows(geom, q2s)
    for q2, row in zip(q2s, rows):
        h = 1e-6
        k_fd = -(torque(q2 + h) - torque(q2 - h)) / (2 * h)
        k_model = row @ np.array([0.0, k_c, s0 * k_c])
        assert abs(k_fd - k_model) < 1e-6 * abs(k_model) + 1e-3


def test_effect_columns_and_overridden_base_columns(paper):
    """Discovery's augmented model extends Robot.dforce_dtheta: the compensator effect on the
    MJCF that already has one owns K_C and s0, so their base columns are exactly zero, and its
    own columns (central differences of MuJoCo's passive force) equal the plain model's
    analytic ones. Both models solve the same statics to the same tolerance, so dp agrees to
    the solver's ~3e-11 m; the difference columns' round-off (eps x |qfrc_passive| / h, ~1e-10 of
    d g / d theta) grows through the KKT solve to ~1e-7 of a dp column: allowed 1e-6."""
    from calbench.bench.model.effects import compensator
    from calbench.identify.discover import build

    scn, _, obs = paper
    theta = true_theta(scn, Robot.from_file(scn.robot))
    robot = Robot.from_file(scn.robot)
    dp, jac = ForwardModel(robot, design_from_observations(robot, obs)).evaluate(theta)
    _, aug = build(scn.robot, [(compensator(), theta[6:8])], obs)
    dp_a, jac_a = aug.evaluate(np.r_[theta, theta[6:8]])
    assert np.abs(dp_a - dp).max() < 1e-10
    assert np.all(jac_a[..., 6:8] == 0.0)
    np.testing.assert_allclose(jac_a[..., :6], jac[..., :6], rtol=0, atol=1e-6 * np.abs(jac[..., :6]).max())
    for i in (6, 7):
        assert np.abs(jac_a[..., 2 + i] - jac[..., i]).max() <= 1e-6 * np.abs(jac[..., i]).max()


KR270_PAPER = Path(__file__).resolve().parents[1] / "scenarios" / "kr270_paper.toml"


def test_jacobian_exact_after_a_far_excursion():
    """A fit that wanders far (a far-off start) leaves the cached A_base taken there; the
    Jacobian back near the optimum must still be the exact one (identify/core/forward.py, KKT_QTOL).
    Before A_base was re-taken at the solution, the KR 270's balancer columns were wrong by
    20-40 % after this excursion, and Monte Carlo runs converged ~1 sigma off the estimate.
    Tolerance: A_base re-taken within KKT_QTOL = 1e-3 rad of the solution leaves a relative
    error of up to ~1.1 x KKT_QTOL (measured), the central differences < 1e-5 (module
    docstring): 2e-3 of the column."""
    scn = load_scenario(KR270_PAPER)
    tr = truth_robot(scn)
    obs = from_campaign(simulate(scn, None, robot=tr))
    robot = Robot.from_file(scn.robot)
    th = true_theta(scn, Robot.from_file(scn.robot))
    fm = ForwardModel(robot, design_from_observations(robot, obs), tol=1e-12)
    fm.evaluate(th)
    # the far two-step start of identify/methods/onestep.py's docstring: K_C 20x, s0 0.2x; its equilibria
    # are cold solves (fallbacks), their A_base taken there
    fm.evaluate(th * np.array([1.0] * 6 + [20.0, 0.2]))
    assert fm.stats["fallbacks"] > 0
    _, jac = fm.evaluate(th)
    fresh = ForwardModel(Robot.from_file(scn.robot), design_from_observations(robot, obs), tol=1e-12)
    fresh.evaluate(th, False)
    assert_jacobian_matches_differences(fresh, th, jac, 2e-3)
