"""The robot description read from the MJCF (bench/model/description.py), the parameter layout it
gives (bench/model/params.py), and a robot built from scratch with no loop and no compensator.

The serial arm's statics are held to paper eq. (1) with gravity off: dq = K^-1 J^T W at the
rigid pose. The load (20 N, ~2 m lever) deflects the springs (1e6 N*m/rad) by ~4e-5 rad, so
the geometric nonlinearity left out of eq. (1) is ~4e-5 relative: allowed 1e-3 (0.1 %).
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from conftest import MJCF, PAPER
from robots import fourbar_mjcf, serial_mjcf

from calbench.bench.core import InputError
from calbench.bench.model import (
    LEGACY_COMPENSATOR,
    DescriptionError,
    ParamLayout,
    Params,
    Robot,
    Spring,
    read_description,
    springs_from_message,
)
from calbench.bench.scenario import load_scenario, scenario_params
from calbench.bench.statics import Load, StaticsSolver


def test_the_fanuc_model_carries_its_description():
    d = Robot.from_file(MJCF).description
    assert d.actuated == ("j1", "j2", "j3", "j4", "j5", "j6")
    assert d.loops == ("parallelogram",) and d.compensators == ("compensator",)
    assert d.reflectors == ("refl_a", "refl_b", "refl_c")
    assert (d.payload, d.flange) == ("payload", "flange")


def test_the_fanuc_passive_joints_and_layout_are_derived():
    robot = Robot.from_file(MJCF)
    m = robot.model
    # the loop's passive hinges follow from the loop: the unsprung joints between its sites
    assert [m.joint(j).name for j in robot.passive_joint] == ["elbow", "rod"]
    assert robot.layout.names == (
        "k1",
        "k2",
        "k3",
        "k4",
        "k5",
        "k6",
        "compensator_stiffness",
        "compensator_preload",
    )
    assert robot.layout.units == ("rad/(N*m)",) * 6 + ("N/m", "m")
    # the compensator's joint is derived: the one hinge between its two sites' bodies
    assert robot.compensator_joint(0) == 1


BAD = {
    "actuated missing": ({"actuated": None}, "calbench:actuated: required"),
    "actuated unknown joint": ({"actuated": "base_yaw shoulder wrist"}, "no joint named 'wrist'"),
    "actuated twice": ({"actuated": "base_yaw base_yaw"}, "listed twice"),
    "reflectors too few": ({"reflectors": "t1 t2"}, "calbench:reflectors: at least 3"),
    "reflector unknown site": ({"reflectors": "t1 t2 t9"}, "no site named 't9'"),
    "payload missing": ({"payload": None}, "calbench:payload: required"),
    "payload two sites": ({"payload": "hook t1"}, "calbench:payload: one site name"),
    "flange unknown site": ({"flange": "nowhere"}, "no site named 'nowhere'"),
    "a misspelt key": ({"reflector": "t1 t2 t3"}, "custom text calbench:reflector: unknown"),
    "loop unknown": ({"loops": "closure"}, "no equality named 'closure'"),
    "compensator unknown": ({"compensators": "spring"}, "no tendon named 'spring'"),
}


@pytest.mark.parametrize("case", list(BAD), ids=list(BAD))
def test_a_bad_description_names_the_element(case):
    texts, message = BAD[case]
    with pytest.raises(DescriptionError) as info:
        Robot.from_xml(serial_mjcf(texts))
    assert message in str(info.value)


def test_element_types_are_checked():
    weld = '<equality><weld name="clamp" body1="hand" body2="lever"/></equality>'
    with pytest.raises(DescriptionError, match="equality 'clamp' must be a <connect> between two sites"):
        Robot.from_xml(serial_mjcf({"loops": "clamp"}, extra=weld))
    slide = serial_mjcf().replace('name="tool_roll" type="hinge"', 'name="tool_roll" type="slide"')
    with pytest.raises(DescriptionError, match="joint 'tool_roll' must be a hinge"):
        Robot.from_xml(slide)
    three = serial_mjcf(balancer=True).replace(
        '<site site="bal_high"/>', '<site site="bal_high"/><site site="t1"/>'
    )
    with pytest.raises(
        DescriptionError, match="tendon 'balancer' must be a <spatial> tendon between exactly two"
    ):
        Robot.from_xml(three)
    # a connect between two sites on one body closes nothing: no passive joint on its path
    same = '<equality><connect name="nothing" site1="t1" site2="t2"/></equality>'
    with pytest.raises(DescriptionError, match="loop 'nothing' has no passive"):
        Robot.from_xml(serial_mjcf({"loops": "nothing"}, extra=same))


def test_a_serial_robot_without_loops_or_compensators():
    robot = Robot.from_xml(serial_mjcf())
    assert robot.n_act == 4 and robot.loops == () and len(robot.passive_joint) == 0
    assert robot.layout.names == ("k1", "k2", "k3", "k4") and robot.flange_site == -1
    assert robot.loop_ok(np.zeros(4)) and robot.loop_conditioning(np.zeros(4)).size == 0
    q = np.radians([10.0, 20.0, -30.0, 40.0])
    np.testing.assert_array_equal(robot.rigid_qpos(q), q)


def test_serial_statics_hold_to_eq_1_with_gravity_off():
    robot = Robot.from_xml(serial_mjcf())
    k = np.array([2.0, 1.0, 3.0, 5.0]) * 1e-6
    robot.set_params(Params(k))
    solver = StaticsSolver(robot, tol=1e-12)
    m, d = robot.model, robot.data
    force, moment = np.array([12.0, -9.0, -20.0]), np.array([7.0, -3.0, 4.5])
    for qdeg in ([0, 20, -30, 40], [60, -10, 70, -90], [-120, 45, 10, 170]):
        q = np.radians(qdeg)
        e = solver.solve(q, Load(force, moment, robot.payload_site), gravity=False)
        d.qpos[:] = robot.rigid_qpos(q)
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        jp, jr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
        mujoco.mj_jacSite(m, d, jp, jr, robot.payload_site)
        tau = (jp.T @ force + jr.T @ moment)[robot.act_dof]
        expected = k * tau  # eq. (1): dq = K^-1 J^T W
        assert np.abs(tau).min() > 0.5  # every spring loaded
        np.testing.assert_allclose(e.deflection, expected, rtol=1e-3, atol=0)


def test_a_compensator_of_another_name_gets_its_own_parameter_names():
    robot = Robot.from_xml(serial_mjcf(balancer=True))
    lay = robot.layout
    assert lay.names == ("k1", "k2", "k3", "k4", "balancer_stiffness", "balancer_preload")
    assert robot.compensator_joint(0) == 1  # across the shoulder
    theta = np.array([1e-6, 2e-6, 3e-6, 4e-6, 2.5e6, 0.6])
    p = lay.params(theta)
    assert p.springs == {"balancer": Spring(2.5e6, 0.6)}
    np.testing.assert_array_equal(lay.theta(p), theta)
    robot.set_params(p)
    assert robot.params().springs == p.springs
    # the log spells it under "compensators"; the tendon named "compensator" stays "compensator"
    assert p.as_dict() == {
        "compliance": theta[:4].tolist(),
        "compensators": {"balancer": {"stiffness": 2.5e6, "preload": 0.6}},
    }
    assert springs_from_message(p.as_dict()) == p.springs
    legacy = Params(np.ones(2), {LEGACY_COMPENSATOR: Spring(1.0, 2.0), "b": Spring(3.0, 4.0)})
    assert list(legacy.as_dict()) == ["compliance", "compensator", "compensators"]
    assert springs_from_message(legacy.as_dict()) == legacy.springs


def test_layout_rejects_params_of_another_robot():
    lay = ParamLayout(4, ("balancer",))
    with pytest.raises(ValueError, match="expected 4 compliances"):
        lay.theta(Params(np.ones(6), {"balancer": Spring(1.0, 1.0)}))
    with pytest.raises(ValueError, match="compensator springs"):
        lay.theta(Params(np.ones(4), {"compensator": Spring(1.0, 1.0)}))


def test_scenario_truth_is_matched_against_the_robot(tmp_path):
    """[truth.compensators.T] for a tendon of another name; keys that do not fit the robot are
    InputErrors naming them."""
    xml = tmp_path / "arm.xml"
    xml.write_text(serial_mjcf(balancer=True))
    base = (
        'robot = "arm.xml"\nseed = 1\n[truth]\ncompliance = [1e-6, 2e-6, 3e-6, 4e-6]\n'
        "{comp}\n[tracker]\nposition = [3.0, 0.0, 1.0]\n[load]\nmass = 50.0\n"
        "[[pose]]\nq = [0, 20, -30, 40]\n"
    )
    robot = Robot.from_file(xml)
    good = tmp_path / "good.toml"
    good.write_text(base.format(comp="[truth.compensators.balancer]\nstiffness = 2e6\npreload = 0.5"))
    p = scenario_params(load_scenario(good), robot.n_act, robot.description.compensators)
    assert p.springs == {"balancer": Spring(2e6, 0.5)}
    balancer = "[truth.compensators.balancer]\nstiffness = 2e6\npreload = 0.5\n"
    cases = {
        "": "truth.compensators.balancer",  # missing
        balancer + "[truth.compensator]\nstiffness = 2e6\npreload = 0.5": "truth.compensator",
    }  # extra
    for comp, key in cases.items():
        bad = tmp_path / "bad.toml"
        bad.write_text(base.format(comp=comp))
        with pytest.raises(InputError) as info:
            scenario_params(load_scenario(bad), robot.n_act, robot.description.compensators)
        assert info.value.key == key
    # the FANUC's scenarios: six compliances and [truth.compensator]
    fanuc = Robot.from_file(MJCF)
    with pytest.raises(InputError) as info:
        scenario_params(load_scenario(good), fanuc.n_act, fanuc.description.compensators)
    assert info.value.key == "truth.compliance"
    assert read_description(fanuc.model) == fanuc.description
    assert scenario_params(load_scenario(PAPER), 6, ("compensator",)).springs["compensator"].preload > 0


def test_a_non_parallel_loop_closes_by_newton_and_its_rule_is_its_angle():
    """A four-bar with unequal links: the passive angles are no linear map of the motors', so
    the rigid pose comes from Gauss-Newton on the gap (closed to bench.loop.LOOP_TOL = 1e-12 m);
    the derived loop rule is still tan(alpha / 2), alpha the acute angle between the two
    passive hinges' levers in the loop's plane (knee -> anchor, coupler -> its end), from the
    geometry. The statics
    converge with the loop closed."""
    robot = Robot.from_xml(fourbar_mjcf())
    m, d = robot.model, mujoco.MjData(robot.model)
    assert [m.joint(j).name for j in robot.passive_joint] == ["knee", "coupler"]
    assert not robot.linear_loops
    robot.set_params(Params(np.array([1.0, 2.0, 3.0]) * 1e-7))
    solver = StaticsSolver(robot)
    rng = np.random.default_rng(3)
    anchor = lambda name: d.xanchor[m.joint(name).id]  # noqa: E731
    site = lambda name: d.site_xpos[m.site(name).id]  # noqa: E731
    for q in np.radians(rng.uniform([-90, -20, -30], [90, 40, 30], (6, 3))):
        qpos = robot.rigid_qpos(q)
        np.testing.assert_array_equal(qpos[robot.act_qpos], q)
        d.qpos[:] = qpos
        mujoco.mj_kinematics(m, d)
        assert np.abs(site("link_end") - site("anchor")).max() <= 1e-12
        # the levers in the loop's plane (perpendicular to the hinges' common axis)
        ax = d.xaxis[m.joint("knee").id]
        u, v = site("anchor") - anchor("knee"), site("link_end") - anchor("coupler")
        u, v = u - ax * (u @ ax), v - ax * (v @ ax)
        alpha = np.arctan2(np.linalg.norm(np.cross(u, v)), abs(u @ v))
        assert robot.loop_conditioning(q)[0] == pytest.approx(np.tan(alpha / 2), abs=1e-12)
        e = solver.solve(q, Load.mass(robot, 30.0))
        assert e.acceptable and e.loop_violation < 1e-9
