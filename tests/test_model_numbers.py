"""The physical numbers of docs/model.md, recomputed from the model (and the page checked to say them).

Each figure is computed independently of the code that uses it: gravity torques from MuJoCo's
bias forces mapped to the motors by virtual work (bench/model/loop.py's motor_forces), the
compensator's torque from eq. (9) (itself held to MuJoCo's tendon in tests/test_statics.py),
the best balancer by least squares over the bench's q2 range. The tolerances are the page's
own rounding.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from conftest import K_TRUE, MJCF, ROOT, TABLE5, fanuc_params
from scipy.optimize import least_squares

from calbench.bench.model import Robot, motor_forces, motor_jacobian

MODEL_PAGE = " ".join((ROOT / "docs" / "model.md").read_text().split())  # line breaks as spaces
SCENARIO = " ".join((ROOT / "scenarios" / "paper_table5.toml").read_text().split())
Q2 = np.radians(np.linspace(0.0, 120.0, 121))  # the bench's (the paper's) q2 range


@pytest.fixture(scope="module")
def robot() -> Robot:
    r = Robot.from_file(MJCF)
    r.set_params(fanuc_params(K_TRUE, 2.6e6, 0.83))
    return r


def motor2_gravity_torque(robot: Robot, q: np.ndarray, payload: float = 0.0) -> float:
    m, d = robot.model, robot.data
    d.qpos[:] = robot.rigid_qpos(q)
    d.qvel[:] = 0.0
    mujoco.mj_fwdPosition(m, d)
    mujoco.mj_fwdVelocity(m, d)
    tau = motor_forces(robot, d, -d.qfrc_bias.copy())  # gravity's generalised force
    if payload:
        tau = tau + motor_jacobian(robot, d, robot.payload_site)[:3].T @ robot.weight(payload)
    return float(tau[1])


def amplitude(robot, q_rest, payload) -> tuple[float, float, float]:
    """Fit tau2(q2) = A sin(q2 + phi) + c over the q2 range where the loop is well conditioned:
    (A, phi in degrees, relative rms of the fit)."""
    q2 = np.array([x for x in Q2 if robot.loop_ok(np.r_[q_rest[0], x, q_rest[1:]])])
    tau = np.array([motor2_gravity_torque(robot, np.r_[q_rest[0], x, q_rest[1:]], payload) for x in q2])
    x = np.column_stack([np.sin(q2), np.cos(q2), np.ones_like(q2)])
    (a, b, c), *_ = np.linalg.lstsq(x, tau, rcond=None)
    return (
        float(np.hypot(a, b)),
        float(np.degrees(np.arctan2(b, a))),
        float(np.std(tau - x @ [a, b, c]) / np.hypot(a, b)),
    )


def test_motor2_gravity_torque_amplitude(robot):
    """Motor 2's gravity torque is A sin(q2 - 30 deg): A = 10.1 kN*m unloaded, 17.8 kN*m with
    the 700 kg payload, the same at every crank angle q3 and every wrist pose of Table 5 (the
    parallelogram carries the forearm's moment to motor 3)."""
    for payload, a_readme in ((0.0, 10.1e3), (700.0, 17.8e3)):
        for q in TABLE5[[0, 2, 6, 9]]:
            a, phi, rel = amplitude(robot, np.delete(q, 1), payload)
            assert a == pytest.approx(a_readme, abs=0.05e3) and phi == pytest.approx(-30.0, abs=0.01)
            assert rel < 1e-9  # exactly a sinusoid
    assert "A = 10.1 kN·m" in MODEL_PAGE and "17.8 kN·m with the 700 kg payload" in MODEL_PAGE


def compensator_torque(robot: Robot, q2, k_c: float, s0: float):
    """Eq. (9) as the generalised force on q2 (q2 a number or an array)."""
    g = robot.compensator_geometry()
    q2 = np.atleast_1d(q2)
    psi = np.array([g.angle(x) for x in q2])
    s = np.array([g.length(x) for x in q2])
    return -k_c * g.l_c * g.l_2 * (1 - s0 / s) * np.sin(psi)


def test_default_spring_is_not_a_gravity_compensator(robot):
    """The shipped spring (K_C = 2.6e6 N/m, s0 = 0.83 m) pushes 2.7e5 N*m at q2 = 120 deg: 26x
    the unloaded gravity amplitude, 15x the loaded one, and it adds to gravity's torque at most
    of the range instead of cancelling it."""
    t120 = abs(float(compensator_torque(robot, np.radians(120.0), 2.6e6, 0.83)[0]))
    assert t120 == pytest.approx(2.7e5, rel=0.02)
    a0 = amplitude(robot, np.delete(TABLE5[2], 1), 0.0)[0]
    a1 = amplitude(robot, np.delete(TABLE5[2], 1), 700.0)[0]
    assert t120 / a0 == pytest.approx(26.3, abs=0.1) and t120 / a1 == pytest.approx(14.9, abs=0.1)
    assert "2.7e5 N·m at q2 = 120°" in MODEL_PAGE and "15–26×" in MODEL_PAGE
    assert "not a gravity compensator" in MODEL_PAGE and "not a gravity compensator" in SCENARIO


def test_best_balancer_cancels_87_percent(robot):
    """The unconstrained least-squares best spring (K_C, s0 free) for this geometry leaves 13 %
    of motor 2's gravity torque (rms over q2 in [0, 120] deg), loaded or not (the torque only
    scales)."""
    tg = amplitude(robot, np.delete(TABLE5[2], 1), 0.0)[0] * np.sin(Q2 - np.radians(30.0))

    def rest(x):
        return tg + compensator_torque(robot, Q2, x[0] * 1e5, x[1])

    best = min(
        (
            least_squares(rest, [k, s], bounds=([0.0, 0.05], [1e3, 5.0]))
            for k in (0.3, 1.0, 3.0)
            for s in (0.5, 0.8, 1.1)
        ),
        key=lambda r: r.cost,
    )
    cancelled = 1 - np.sqrt(np.mean(rest(best.x) ** 2)) / np.sqrt(np.mean(tg**2))
    assert cancelled == pytest.approx(0.868, abs=0.002)
    assert best.x[0] * 1e5 == pytest.approx(6.0e4, rel=0.02) and best.x[1] == pytest.approx(0.66, abs=0.01)
    assert "cancels 87 %" in MODEL_PAGE


def test_q2_mapping_is_an_assumption(robot):
    """The paper gives q2 in [0, 120] deg and no zero; q2 = FANUC J2 + 30 deg puts it on J2's
    [-30, 90] deg, and so does the reverse, J2 = 90 deg - q2: the limits cannot tell them apart."""
    lo, hi = np.degrees(robot.limits()[1])  # the model's q2 = J2 + 30
    j2_lo, j2_hi = lo - 30.0, hi - 30.0  # FANUC J2's own limits
    assert (j2_lo, j2_hi) == (pytest.approx(-64.0, abs=0.1), pytest.approx(90.0, abs=0.1))
    for to_j2 in (lambda q2: q2 - 30.0, lambda q2: 90.0 - q2):
        image = sorted(to_j2(np.array([0.0, 120.0])))
        assert image == [pytest.approx(-30.0), pytest.approx(90.0)]
        assert j2_lo <= image[0] and image[1] <= j2_hi + 1e-6
    assert "an assumption" in MODEL_PAGE and "J2 = 90° − q2" in MODEL_PAGE
