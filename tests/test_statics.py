"""The statics held to theory: paper eqs. (1), (9)-(11), (16), loop closure and the residual.

Tolerances come from the physics: the linear VJM formula (1) differs from the exact nonlinear
equilibrium by terms of order |W| * lever * k (the load's own geometric stiffness), ~1e-4 here,
well inside the 0.1 % the issue asks for; finite differences carry O(h^2) error.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from conftest import K_TRUE, MJCF, TABLE5, fanuc_params

from calbench.bench.model import Robot, loop_gap, motor_jacobian
from calbench.bench.statics import (
    LOOP_TOL,
    Load,
    NewtonPoint,
    StaticsError,
    StaticsSolver,
    statics_options,
)


def make_robot(k_c: float = 2.6e6, s0: float = 0.83) -> Robot:
    robot = Robot.from_file(MJCF)
    robot.set_params(fanuc_params(K_TRUE, k_c, s0))
    return robot


def site_pose(robot: Robot, qpos: np.ndarray, site: int) -> tuple[np.ndarray, np.ndarray]:
    robot.data.qpos[:] = qpos
    mujoco.mj_kinematics(robot.model, robot.data)
    return robot.data.site_xpos[site].copy(), robot.data.site_xmat[site].reshape(3, 3).copy()


def rotation_vector(r: np.ndarray) -> np.ndarray:
    """Small-angle rotation vector of a rotation matrix close to identity."""
    return 0.5 * np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])


def small_load_response(robot: Robot, q: np.ndarray, w: np.ndarray):
    """Gravity off: the equilibria without and with wrench w at the flange, and the motor-space
    Jacobian of the flange at the unloaded one (where eq. 1 linearises)."""
    solver = StaticsSolver(robot)
    load = Load(w[:3], w[3:], robot.flange_site)
    e0 = solver.solve(q, gravity=False)
    e1 = solver.solve(q, load, qpos0=e0.qpos, gravity=False)
    robot.data.qpos[:] = e0.qpos
    mujoco.mj_kinematics(robot.model, robot.data)
    mujoco.mj_comPos(robot.model, robot.data)
    return e0, e1, motor_jacobian(robot, robot.data, robot.flange_site)


def deflection_twist(robot, e0, e1, site) -> np.ndarray:
    p0, r0 = site_pose(robot, e0.qpos, site)
    p1, r1 = site_pose(robot, e1.qpos, site)
    return np.concatenate([p1 - p0, rotation_vector(r1 @ r0.T)])


@pytest.mark.parametrize("q", TABLE5[[0, 5, 9]])
def test_eq1_gravity_off_small_load(q):
    """Eq. (1): dt = sum_i J_i k_i J_i^T W with motor-space (crank) Jacobians, no compensator."""
    robot = make_robot(k_c=0.0)
    w = np.array([120.0, -80.0, -200.0, 30.0, -25.0, 40.0])
    e0, e1, j = small_load_response(robot, q, w)
    predicted = j @ np.diag(K_TRUE) @ j.T @ w
    measured = deflection_twist(robot, e0, e1, robot.flange_site)
    assert np.linalg.norm(measured - predicted) < 1e-3 * np.linalg.norm(predicted)


def compensator_torque_and_stiffness(robot: Robot, q2: float) -> tuple[float, float]:
    """Paper eq. (9) as a generalized force on q2 (sign: it acts to shorten a stretched spring)
    and its derivative with the sin^2 correction of eq. (11)."""
    g = robot.compensator_geometry()
    spring = robot.params().springs["compensator"]
    k_c, s0 = spring.stiffness, spring.preload
    psi, s = g.angle(q2), g.length(q2)
    lcl2 = g.l_c * g.l_2
    torque = -k_c * lcl2 * (1 - s0 / s) * np.sin(psi)
    eta = (1 - s0 / s) * np.cos(psi) + s0 * lcl2 * np.sin(psi) ** 2 / s**3
    return torque, k_c * lcl2 * eta


def tendon_torque_j2(robot: Robot, q2: float) -> float:
    """The compensator's generalized force on j2 as MuJoCo computes it (tendon spring only)."""
    m, d = robot.model, robot.data
    d.qpos[:] = robot.rigid_qpos(np.array([0.0, q2, 0.0, 0.0, 0.0, 0.0]))
    mujoco.mj_fwdPosition(m, d)
    t = robot.tendons[0]
    force = -m.tendon_stiffness[t] * (d.ten_length[t] - m.tendon_lengthspring[t][0])
    return float(robot.tendon_moment(d)[robot.act_dof[1]] * force)


@pytest.mark.parametrize("q2_deg", [0.0, 20.0, 35.0, 60.0, 90.0, 120.0])
def test_compensator_eqs_9_to_11(q2_deg):
    """Eq. (9) equals MuJoCo's tendon torque; eq. (10)-(11) with sin^2 equals its derivative."""
    robot = make_robot()
    q2 = np.radians(q2_deg)
    torque, stiffness = compensator_torque_and_stiffness(robot, q2)
    assert tendon_torque_j2(robot, q2) == pytest.approx(torque, rel=1e-9, abs=1e-6)
    h = 1e-5
    fd = -(tendon_torque_j2(robot, q2 + h) - tendon_torque_j2(robot, q2 - h)) / (2 * h)
    # central difference error ~ h^2 * third derivative ~ 1e-10 * K_C l_c l_2: far below 1e-6
    assert fd == pytest.approx(stiffness, rel=1e-6)


def eta_printed_and_true(robot: Robot, q2: float) -> tuple[float, float]:
    """eta of eq. (10) as eq. (11) prints it (sin psi) and MuJoCo's: the finite-difference
    derivative of the tendon's torque, divided by K_C l_c l_2 (independent of eqs. 9-11)."""
    g = robot.compensator_geometry()
    spring = robot.params().springs["compensator"]
    psi, s = g.angle(q2), g.length(q2)
    s0, lcl2 = spring.preload, g.l_c * g.l_2
    printed = np.cos(psi) + s0 * lcl2 * np.sin(psi) / s**3 - s0 / s * np.cos(psi)
    h = 1e-5
    fd = -(tendon_torque_j2(robot, q2 + h) - tendon_torque_j2(robot, q2 - h)) / (2 * h)
    return printed, fd / (spring.stiffness * lcl2)


def test_printed_eq11_is_a_misprint():
    """Eq. (11) as printed (sin psi where the derivative of eq. 9 has sin^2 psi) against MuJoCo's
    own tendon, over the bench's q2 range [0, 120] deg (psi = q2 + 10 deg): off by up to 89 % of
    the term's largest value and of the WRONG SIGN between q2 = 3.4 and 18.1 deg (a relative
    error of -198 % at q2 = 10 deg; docs/model.md, "Statics"). The sin^2 form matches to 1e-6 over the
    same range (test_compensator_eqs_9_to_11)."""
    robot = make_robot()
    q2 = np.radians(np.linspace(0.0, 120.0, 1201))
    printed, true = np.array([eta_printed_and_true(robot, q) for q in q2]).T
    assert np.abs(printed - true).max() / np.abs(true).max() == pytest.approx(0.89, abs=0.005)
    wrong = np.degrees(q2[np.sign(printed) != np.sign(true)])
    first = wrong[wrong < 60]
    assert first.min() == pytest.approx(3.4, abs=0.1) and first.max() == pytest.approx(18.1, abs=0.1)
    i10 = int(np.argmin(np.abs(q2 - np.radians(10.0))))
    assert (printed[i10] - true[i10]) / true[i10] == pytest.approx(-1.98, abs=0.01)


def test_compensator_angle_offset_from_geometry():
    robot = make_robot()
    g = robot.compensator_geometry()
    assert g.offset == pytest.approx(np.radians(10.0), abs=1e-4)
    m, d = robot.model, robot.data
    for q2 in np.radians([0.0, 47.0, 120.0]):
        d.qpos[:] = robot.rigid_qpos(np.array([0.3, q2, -0.2, 0.0, 0.0, 0.0]))
        mujoco.mj_fwdPosition(m, d)
        assert d.ten_length[robot.tendons[0]] == pytest.approx(g.length(q2), rel=1e-6)


def test_motor2_spring_keeps_forearm_orientation():
    """Paper §3.4: deflecting motor 2 alone translates the forearm without turning it."""
    robot = make_robot(k_c=0.0)
    solver = StaticsSolver(robot)
    q = TABLE5[4]
    forearm = robot.model.body("forearm").id
    upper = robot.model.body("upper_arm").id
    e0 = solver.solve(q, gravity=False)
    # a torque on motor 2 only: move its spring reference and re-solve (gravity off, no load)
    q_shift = q.copy()
    q_shift[1] += 1e-3
    e1 = solver.solve(q_shift, gravity=False)
    e1_cmd = e1.qpos.copy()
    # the same physical state seen with motor 2 deflected from the original command
    robot.data.qpos[:] = e0.qpos
    mujoco.mj_kinematics(robot.model, robot.data)
    r_fore0 = robot.data.xmat[forearm].reshape(3, 3).copy()
    r_up0 = robot.data.xmat[upper].reshape(3, 3).copy()
    robot.data.qpos[:] = e1_cmd
    mujoco.mj_kinematics(robot.model, robot.data)
    r_fore1 = robot.data.xmat[forearm].reshape(3, 3)
    r_up1 = robot.data.xmat[upper].reshape(3, 3)
    assert np.linalg.norm(rotation_vector(r_up1 @ r_up0.T)) == pytest.approx(1e-3, rel=1e-6)
    assert np.linalg.norm(rotation_vector(r_fore1 @ r_fore0.T)) < 1e-12


def test_eq16_equivalent_serial_compliance_is_not_diagonal():
    """Eq. (15)-(16) through the STATICS: the serial (q2, elbow) compliance of the parallelogram
    with motor springs k2 (q2) and k3 (the crank; elbow = crank - q2) is [[k2, -k2], [-k2, k2 +
    k3]], not the printed [[k2, -k3], [-k3, k3]] (not even positive definite when k3 > k2).

    Solved equilibria, gravity and compensator off, under small pure moments M about the J2
    axis: on the forearm (generalised forces (M, M) on (q2, elbow)) q2 does not move and the
    elbow turns by k3 M (motor 3 holds the forearm's absolute angle, §3.4); on the upper arm
    ((M, 0)) q2 turns by k2 M and the elbow by -k2 M. Their difference is an elbow torque
    (0, M): q2 turns by -k2 M, the elbow by (k2 + k3) M. Tolerance 1e-4 relative: the moments'
    own geometric stiffness, |M| k ~ 1e-5 rad."""
    robot = make_robot(k_c=0.0)
    solver = StaticsSolver(robot)
    m = robot.model
    q = TABLE5[6]
    elbow = m.jnt_qposadr[robot.passive_joint[0]]
    j2 = robot.act_qpos[1]
    e0 = solver.solve(q, gravity=False)
    robot.data.qpos[:] = e0.qpos
    mujoco.mj_kinematics(m, robot.data)
    axis = robot.data.xaxis[robot.act_joint[1]].copy()  # J2's axis in the world
    moment = 50.0

    def turn(body: str) -> np.ndarray:
        site = [i for i in range(m.nsite) if m.site_bodyid[i] == m.body(body).id][0]
        e = solver.solve(q, Load(np.zeros(3), moment * axis, site), qpos0=e0.qpos, gravity=False)
        return np.array([e.qpos[j2] - e0.qpos[j2], e.qpos[elbow] - e0.qpos[elbow]]) / moment

    k2, k3 = K_TRUE[1], K_TRUE[2]
    on_forearm, on_upper = turn("forearm"), turn("upper_arm")
    np.testing.assert_allclose(on_forearm, [0.0, k3], atol=1e-4 * k3)
    np.testing.assert_allclose(on_upper, [k2, -k2], rtol=1e-4)
    np.testing.assert_allclose(on_forearm - on_upper, [-k2, k2 + k3], rtol=1e-4)  # the elbow torque
    printed = np.array([[k2, -k3], [-k3, k3]]) @ [0.0, 1.0]  # what eq. (16) as printed says
    assert np.abs(printed - (on_forearm - on_upper)).max() > 0.5 * k3


@pytest.mark.parametrize("idx", range(len(TABLE5)))
def test_residual_and_loop_at_full_load(idx):
    robot = make_robot()
    solver = StaticsSolver(robot)
    q = TABLE5[idx]
    e0 = solver.solve(q)
    e1 = solver.solve(q, Load.mass(robot, 700.0), qpos0=e0.qpos)
    for e in (e0, e1):
        assert e.residual < 1e-9 * e.gravity_scale
        assert e.loop_violation < 1e-7  # 0.1 um
    # the loaded flange moves by millimetres: the default truth is in the 0.5-3 mm band
    d = deflection_twist(robot, e0, e1, robot.flange_site)[:3]
    assert 0.5e-3 <= np.linalg.norm(d) <= 3e-3


def test_eq1_with_compensator_uses_aggregated_k2():
    """Eq. (10): with the compensator, J2's spring is K2 + K_C l_c l_2 eta at the deflected q2."""
    robot = make_robot()
    q = TABLE5[9]
    w = np.array([0.0, 0.0, -300.0, 0.0, 0.0, 0.0])
    e0, e1, j = small_load_response(robot, q, w)
    q2 = e0.qpos[robot.act_qpos[1]]
    _, s_c = compensator_torque_and_stiffness(robot, q2)
    k_eff = K_TRUE.copy()
    k_eff[1] = 1.0 / (1.0 / K_TRUE[1] + s_c)
    predicted = j @ np.diag(k_eff) @ j.T @ w
    measured = deflection_twist(robot, e0, e1, robot.flange_site)
    assert np.linalg.norm(measured - predicted) < 1e-3 * np.linalg.norm(predicted)
    # in joint space: motor 2 turns by k2_eff * tau2; the compensator changes it by > 1 %
    tau = j.T @ w  # the wrench acts at the flange
    dtheta = e1.deflection - e0.deflection
    assert dtheta[1] == pytest.approx(k_eff[1] * tau[1], rel=1e-3)
    assert abs(dtheta[1] - K_TRUE[1] * tau[1]) > 1e-2 * abs(dtheta[1])


def test_apparent_j2_stiffness_varies_over_plan_q2_range():
    """The shipped truth (scenarios/paper_table5.toml) through the STATICS: the J2 stiffness a
    small moment about the J2 axis meets at the unloaded equilibrium (gravity off: the
    compensator's and the drive's springs only) equals eq. (10) with sin^2,
    K2 + K_C l_c l_2 eta(psi) at the equilibrium's q2, to 1e-4 (the moment's own geometric
    stiffness); over q2 in [0, 120] deg it varies by 16.3 % (docs/model.md, "Default truth values")."""
    from conftest import PAPER, fanuc_truth

    from calbench.bench.scenario import load_scenario

    robot = Robot.from_file(MJCF)
    truth = fanuc_truth(load_scenario(PAPER))
    robot.set_params(truth)
    solver = StaticsSolver(robot)
    m = robot.model
    j2 = robot.act_qpos[1]
    site = [i for i in range(m.nsite) if m.site_bodyid[i] == m.body("upper_arm").id][0]
    k_statics, k_eq10 = [], []
    for q2 in np.radians(np.linspace(0.0, 120.0, 13)):
        q = np.array([0.0, q2, np.radians(30.0), 0.0, 0.0, 0.0])
        e0 = solver.solve(q, gravity=False)
        robot.data.qpos[:] = e0.qpos
        mujoco.mj_kinematics(m, robot.data)
        axis = robot.data.xaxis[robot.act_joint[1]].copy()
        e1 = solver.solve(q, Load(np.zeros(3), 20.0 * axis, site), qpos0=e0.qpos, gravity=False)
        k_statics.append(20.0 / (e1.qpos[j2] - e0.qpos[j2]))
        k_eq10.append(1.0 / truth.compliance[1] + compensator_torque_and_stiffness(robot, e0.qpos[j2])[1])
    np.testing.assert_allclose(k_statics, k_eq10, rtol=1e-4)
    # so eq. (10), checked at the (spring-sagged) equilibria, gives the variation over the range
    k = [
        1.0 / truth.compliance[1] + compensator_torque_and_stiffness(robot, q2)[1]
        for q2 in np.radians(np.linspace(0.0, 120.0, 1201))
    ]
    assert max(k) / min(k) - 1.0 == pytest.approx(0.163, abs=0.0005)


def relaxed_flange(robot: Robot, q: np.ndarray, load: Load, damping: float, max_steps: int) -> np.ndarray:
    """Where MuJoCo's own dynamics bring the flange to rest: mj_step from the rigid pose with
    heavy joint damping (statics ignore it), the load by mj_applyFT and the joint ranges off
    (they are controller limits), until every joint speed is below 1e-9 rad/s."""
    m, d = robot.model, robot.data
    m.dof_damping[:] = damping
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_LIMIT)
    d.qpos[:] = robot.rigid_qpos(q)
    d.qvel[:] = 0.0
    mujoco.mj_forward(m, d)
    for step in range(max_steps):
        d.qfrc_applied[:] = 0.0
        mujoco.mj_applyFT(
            m, d, load.force, load.moment, d.site_xpos[load.site], m.site_bodyid[load.site], d.qfrc_applied
        )
        mujoco.mj_step(m, d)
        if step > 100 and np.abs(d.qvel).max() < 1e-9:
            break
    return d.site_xpos[robot.flange_site].copy()


def test_second_solver_time_stepping_relaxation_agrees():
    """An independent solution: MuJoCo's own soft loop closure relaxed with mj_step.

    With solref -1e6 -2e3 the soft loop opens by < 0.1 um (PHYSICS.md), so the relaxed flange
    must agree with the Newton solution to a few micrometres once motion has died out.
    """
    robot = make_robot()
    solver = StaticsSolver(robot)
    q = TABLE5[2]  # q3 = 30 deg sits on j3's range: limits must not act
    load = Load.mass(robot, 700.0)
    e = solver.solve(q, load)
    relaxed = relaxed_flange(robot, q, load, damping=4.0e5, max_steps=4000)
    newton, _ = site_pose(robot, e.qpos, robot.flange_site)
    assert np.linalg.norm(relaxed - newton) < 5e-6


def test_degenerate_parallelogram_is_a_clear_error():
    """Crank parallel to the upper arm (q3 = q2 - 120 deg): no unique equilibrium exists."""
    robot = make_robot()
    with pytest.raises(StaticsError, match="degenerate"):
        StaticsSolver(robot).solve(np.radians([0.0, 90.0, -30.0, 0.0, 0.0, 0.0]))


# --------------------------------------------------------------------------- building blocks
# bench/statics/equilibrium.py's public pieces, each against an independent computation (mink-style:
# every Jacobian against finite differences).


def solved(q=TABLE5[9], tol=1e-10, wrench=None):
    robot = make_robot()
    solver = StaticsSolver(robot, tol=tol)
    load = Load.mass(robot, 700.0) if wrench is None else Load.wrench(robot, wrench)
    e0 = solver.solve(q)
    return robot, solver, load, e0, solver.solve(q, load, warm=e0)


def test_loop_gap_jacobian_matches_finite_differences():
    """J_c of bench.loop.loop_gap against central differences of the gap (h = 1e-6 rad:
    truncation ~h^2 x 1 m = 1e-12 m/rad, round-off 1e-16 x 3 m / 1e-6 ~ 3e-10 m/rad)."""
    robot = make_robot()
    m, d = robot.model, robot.data
    qpos = robot.rigid_qpos(TABLE5[6])
    d.qpos[:] = qpos
    mujoco.mj_kinematics(m, d)
    mujoco.mj_comPos(m, d)
    _, jc = loop_gap(robot, d)
    assert jc.shape == (3 * len(robot.loops), m.nv)
    h = 1e-6
    for j in range(m.nv):
        gaps = []
        for s in (1, -1):
            d.qpos[:] = qpos
            d.qpos[j] += s * h
            mujoco.mj_kinematics(m, d)
            gaps.append(loop_gap(robot, d)[0])
        np.testing.assert_allclose(jc[:, j], (gaps[0] - gaps[1]) / (2 * h), atol=1e-9)


def test_residual_is_the_force_balance_at_a_solution():
    """At a solved loaded equilibrium the residual is within the solver's tolerance, and the
    load's share of it is the wrench's generalized force as MuJoCo's mj_applyFT maps it."""
    robot, solver, load, _, e1 = solved()
    with statics_options(robot):
        res = solver.residual(e1.qpos, load, e1.lam, e1.basis)
        assert np.abs(res.r).max() <= solver.tol * e1.gravity_scale * 1.01  # scale moves ~1e-3
        assert np.abs(res.c_r).max() <= LOOP_TOL
        unloaded = solver.residual(e1.qpos, None, e1.lam, e1.basis)
        m, d = robot.model, robot.data
        qfrc = np.zeros(m.nv)
        mujoco.mj_applyFT(
            m, d, load.force, load.moment, d.site_xpos[load.site], m.site_bodyid[load.site], qfrc
        )
    # both sides are sums of ~1e4 N*m terms: agreement to round-off (1e-16 x 1e4 x a few)
    np.testing.assert_allclose(res.r - unloaded.r, qfrc, atol=1e-9)


def test_inverse_dynamics_matrix_is_the_exact_one_but_for_the_loop_force():
    """MuJoCo's mjd_inverseFD matrix equals our finite-difference d r / d q with no load and
    lam = 0 (both difference passive - bias with the same step: round-off only,
    eps x max|g| / fd_step ~ 1e-5 N*m/rad); with the loop force the two differ by its
    curvature, which the chord iteration absorbs (the docstring's ~1e-3 of the stiffness)."""
    robot, solver, _, e0, _ = solved()
    with statics_options(robot):
        robot.set_command(e0.command)
        a_id = solver.stiffness_inverse_dynamics(e0.qpos)
        a_fd = solver.stiffness_fd(e0.qpos, None, np.zeros_like(e0.lam), e0.basis)
        a_loop = solver.stiffness_fd(e0.qpos, None, e0.lam, e0.basis)
    assert np.abs(a_id - a_fd).max() <= 1e-5
    share = np.abs(a_loop - a_id).max() / np.abs(a_fd).max()
    assert 0.0 < share < 1e-2


def test_pluggable_matrix_gives_the_same_equilibrium():
    """Full Newton (the exact matrix every step) from the rigid pose reaches solve()'s chord
    equilibrium: both residuals within tol x scale (1e-5 N*m) over the softest spring
    (~1.7e6 N*m/rad) put them within ~1e-11 rad of each other; allowed 1e-10."""
    robot, solver, load, _, e1 = solved()
    with statics_options(robot):
        robot.set_command(e1.command)
        qpos = robot.rigid_qpos(e1.command)
        basis = solver.basis(qpos)

        def exact(p: NewtonPoint) -> np.ndarray:
            return solver.stiffness_fd(p.qpos, load, p.lam, basis, p.residual.r)

        full = solver.newton(qpos, np.zeros(basis.shape[1]), basis, load, exact, refresh=solver.max_iter)
        gave_up = solver.newton(qpos, np.zeros(basis.shape[1]), basis, load, lambda p: None)
    assert full.converged and full.stalls == 0
    np.testing.assert_allclose(full.qpos, e1.qpos, rtol=0, atol=1e-10)
    assert not gave_up.converged and gave_up.iterations == 0


def test_tangent_matches_finite_differences_of_solved_equilibria():
    """dq/dtheta by the implicit function theorem (StaticsSolver.tangent with
    Robot.dforce_dtheta) against central differences of equilibria solved to tol = 1e-12
    (~1e-13 rad) with theta moved by h = 1e-3 relative: truncation O(h^2) ~ 1e-6 of the column,
    round-off 1e-13 / (2 h theta |dq/dtheta|) < 1e-5; allowed 1e-4 of each column. A general
    wrench loads every motor, so every column is large against that round-off."""
    wrench = np.array([1200.0, -900.0, -6000.0, 300.0, -150.0, 200.0])
    robot, solver, load, _, e1 = solved(TABLE5[6], tol=1e-12, wrench=wrench)
    params = robot.params()
    theta = robot.layout.theta(params)
    to_params = robot.layout.params
    robot.set_command(e1.command)
    robot.data.qpos[:] = e1.qpos
    mujoco.mj_fwdPosition(robot.model, robot.data)
    tan = solver.tangent(e1, load, robot.dforce_dtheta(params))
    for i in range(8):
        h = 1e-3 * theta[i]
        qs = []
        for s in (1, -1):
            t = theta.copy()
            t[i] += s * h
            robot.set_params(to_params(t))
            qs.append(solver.solve(e1.command, load, qpos0=e1.qpos).qpos)
        fd = (qs[0] - qs[1]) / (2 * h)
        assert np.abs(fd - tan[:, i]).max() <= 1e-4 * np.abs(tan[:, i]).max(), f"column {i}"
    robot.set_params(params)


def test_statics_options_restore_the_model_after_a_failed_solve():
    robot = make_robot()
    m = robot.model
    flags, gravity = m.opt.disableflags, m.opt.gravity.copy()
    with pytest.raises(StaticsError):
        StaticsSolver(robot).solve(np.radians([0.0, 90.0, -30.0, 0.0, 0.0, 0.0]), gravity=False)
    assert m.opt.disableflags == flags
    np.testing.assert_array_equal(m.opt.gravity, gravity)
