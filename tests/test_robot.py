"""The robot's own rules held to independent computations: the derived loop rule against the
parallelogram's crank-to-arm angle from the MJCF's kinematics, d g / d theta against MuJoCo's
passive force, the weight against the model's gravity.

Tolerances: the kinematic angle is exact up to rounding (~1e-15 rad per operation); the loop
rule's inverse condition number comes from an SVD of the normalised 3 x 2 Jacobian (relative
error ~1e-15), allowed 1e-12; central differences of a force linear in K_C and s0 and in 1/k_i with a relative step
h = 1e-6 carry O(h^2) = 1e-12 truncation and eps |g| / (h |dg/dtheta_i| theta_i) ~ 1e-7
round-off at worst here, allowed 1e-6 of each column.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from conftest import K_TRUE, MJCF, PAPER

from calbench.bench.campaign import pose_load
from calbench.bench.model import LOOP_MARGIN, LOOP_MARGIN_ANGLE, Params, Robot, Spring
from calbench.bench.scenario import load_scenario


def make_robot() -> Robot:
    robot = Robot.from_file(MJCF)
    robot.set_params(Params(K_TRUE, {"compensator": Spring(2.6e6, 0.83)}))
    return robot


def crank_arm_angle(robot: Robot, q: np.ndarray) -> float:
    """Angle (0..pi/2) between the crank (j3 hinge to rod hinge) and the upper arm (j2 hinge to
    elbow hinge) at the rigid pose, from MuJoCo's kinematics of the MJCF."""
    m, d = robot.model, robot.data
    d.qpos[:] = robot.rigid_qpos(q)
    mujoco.mj_kinematics(m, d)
    anchor = lambda name: d.xanchor[m.joint(name).id]  # noqa: E731
    u = anchor("elbow") - anchor("j2")
    c = anchor("rod") - anchor("j3")
    return float(np.arctan2(np.linalg.norm(np.cross(u, c)), abs(u @ c)))


def test_derived_loop_rule_is_the_crank_to_arm_angle_on_the_fanuc():
    """The loop rule derived from the loop Jacobian's conditioning (no table of angles) is, on
    the parallelogram, tan(alpha / 2) of the crank-to-arm angle alpha: LOOP_MARGIN = tan(5 deg)
    rejects exactly the 10 deg band around both degenerate configurations that the FANUC's
    old table rule (q3 - q2 at least 10 deg from -120 and 60 deg) rejected."""
    robot = make_robot()
    rng = np.random.default_rng(11)
    lim = robot.limits()
    for q in lim[:, 0] + (lim[:, 1] - lim[:, 0]) * rng.random((40, robot.n_act)):
        (cond,) = robot.loop_conditioning(q)
        assert cond == pytest.approx(np.tan(crank_arm_angle(robot, q) / 2), abs=1e-12)
        old = np.mod(q[2] - q[1] + np.radians(120.0), np.pi)  # the old table's angle
        assert robot.loop_ok(q) is bool(min(old, np.pi - old) >= np.radians(10.0))
    assert LOOP_MARGIN == pytest.approx(np.tan(LOOP_MARGIN_ANGLE / 2), rel=1e-15)
    # the margin's two sides, at both degenerate configurations (q3 - q2 = -120 and 60 deg)
    for degenerate in (-120.0, 60.0):
        for off, ok in ((9.99, False), (10.01, True), (-9.99, False), (-10.01, True)):
            q = np.radians([0.0, 40.0, 40.0 + degenerate + off, 0.0, 0.0, 0.0])
            assert robot.loop_ok(q) is ok
            assert bool(crank_arm_angle(robot, q) >= LOOP_MARGIN_ANGLE) is ok
        # at the degenerate configuration itself the conditioning is 0 (to rounding)
        assert robot.loop_conditioning(np.radians([0.0, 40.0, 40.0 + degenerate, 0, 0, 0]))[0] < 1e-7


def passive_force(robot: Robot, qpos: np.ndarray, params: Params) -> np.ndarray:
    robot.set_params(params)
    d = robot.data
    d.qpos[:] = qpos
    d.qvel[:] = 0.0
    mujoco.mj_fwdPosition(robot.model, d)
    mujoco.mj_fwdVelocity(robot.model, d)
    return d.qfrc_passive.copy()


def test_dforce_dtheta_is_the_derivative_of_the_passive_force():
    robot = make_robot()
    rng = np.random.default_rng(5)
    q = np.radians([20.0, 35.0, -30.0, 45.0, -30.0, 60.0])
    robot.set_command(q)
    qpos = robot.rigid_qpos(q)
    qpos[robot.act_qpos] += rng.normal(scale=2e-3, size=robot.n_act)  # deflected springs
    theta = np.r_[K_TRUE, 2.6e6, 0.83]
    to_params = robot.layout.params
    passive_force(robot, qpos, to_params(theta))
    got = robot.dforce_dtheta(to_params(theta))
    assert got.shape == (robot.model.nv, 8)
    for i in range(8):
        h = 1e-6 * theta[i]
        tp, tm = theta.copy(), theta.copy()
        tp[i] += h
        tm[i] -= h
        fd = (passive_force(robot, qpos, to_params(tp)) - passive_force(robot, qpos, to_params(tm))) / (2 * h)
        assert np.abs(fd - got[:, i]).max() <= 1e-6 * np.abs(fd).max(), f"column {i}"


def test_weight_is_the_model_gravity():
    """A mass's weight follows <option gravity>: the campaign's load has no gravity constant."""
    scn = load_scenario(PAPER)
    robot = make_robot()
    np.testing.assert_array_equal(robot.weight(700.0), [0.0, 0.0, -700.0 * 9.81])
    robot.model.opt.gravity[:] = [0.0, 0.0, -9.7]
    pose = next(p for p in scn.poses if p.wrench is None)
    load, mass = pose_load(robot, scn, pose)
    np.testing.assert_array_equal(load.force, [0.0, 0.0, -9.7 * mass])
