"""A parallelogram drawn as mimic joints (ROS-Industrial's FANUC style) becomes a closed loop.

Held to independent computations:
* the test arm drawn both ways, its parallelogram as two mimic joints on a serial tree and as a
  hand-made loop (crank on the turret, ``[loops]`` in the overlay, tests/urdf_robots.py), gives
  the same campaign, reading for reading;
* on the FANUC M-900iB/700's own xacro (../shared/data, skipped where absent) the loaded
  equilibrium keeps the URDF's mimic relations (elbow = crank + joint_2 and rod = elbow, the
  parallelogram's rigid-body kinematics), and the total potential energy along the motors,
  with the passive joints from those relations, is stationary there (finite differences).
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
from shared_data import shared_data
from urdf_robots import FANUC_TOOL, LINKS, SERIAL, _joint, _link, arm_overlay, convert_arm, scenario

from calbench.bench.log import read_log
from calbench.bench.model import Params, Robot, Spring
from calbench.bench.statics import Load, StaticsSolver
from calbench.identify.cli import main

# the serial arm plus the parallelogram's crank (on link_2, coaxial with joint_2, turning with
# the forearm) and rod (on the forearm, turning with the upper arm), as ROS-Industrial draws it
MIMIC = """  <joint name="crank_joint" type="continuous"><parent link="link_2"/><child link="crank"/>
    <origin xyz="0 -0.35 0" rpy="0 0 0"/><axis xyz="0 {a} 0"/><mimic joint="joint_3" multiplier="{m_a}"/></joint>
  <joint name="rod_joint" type="continuous"><parent link="link_3"/><child link="rod"/>
    <origin xyz="-0.4 -0.35 0" rpy="0 0 0"/><axis xyz="0 1 0"/><mimic joint="joint_3" multiplier="-1"/></joint>
"""


def mimic_arm(axis: int = 1) -> str:
    """The loop arm of tests/urdf_robots.py drawn on the serial tree; its rod's frame sits at
    the forearm's end of the rod (the hand-made one's at the crank's), so its mass is moved."""
    names = ["base_link"] + [j[3] for j in SERIAL] + ["crank"]
    rod = _link("rod").replace('xyz="0.0 0.0 0.55"', 'xyz="0.0 0.0 -0.55"')
    assert rod.count("-0.55") == 3  # inertial, visual, collision
    body = "".join(_link(n) for n in names) + rod
    serial = [j if j[0] != "joint_3" else (*j[:7], (-90, 90)) for j in SERIAL]
    joints = "".join(_joint(j) for j in serial) + MIMIC.format(a=axis, m_a=axis)
    return f'<?xml version="1.0"?>\n<robot name="arm6_mimic">\n{body}{joints}</robot>\n'


def test_the_rod_mass_moved_is_the_same_rod():
    assert LINKS["rod"][1] == (0, 0, 0.55)  # the hand-made rod's centre, 0.55 m above the crank end


def test_a_mimic_parallelogram_gives_the_hand_made_loops_campaign(tmp_path, capsys):
    from urdf_robots import arm_urdf

    rc, loop = convert_arm(tmp_path / "loop", arm_urdf(loop=True), arm_overlay(loop=True))
    assert rc == 0
    rc, mimic = convert_arm(tmp_path / "mimic", mimic_arm(), arm_overlay())
    err = capsys.readouterr().err
    assert rc == 0, err
    assert (
        "note: parallelogram crank/rod (mimic joints crank_joint, rod_joint of joint_3) became the loop"
        in err
    )
    robot = Robot.from_file(mimic)
    m = robot.model
    assert robot.description.loops == ("parallelogram",)
    assert sorted(m.joint(j).name for j in robot.passive_joint) == ["joint_3_elbow", "rod_joint"]
    assert m.body(m.body("crank").parentid[0]).name == "link_1"  # motor 3 on the turret
    np.testing.assert_allclose(np.degrees(m.joint("joint_3").range), [-90, 90])
    assert m.body(m.body("rod").parentid[0]).name == "crank"  # the rod on the crank's end
    # the hand-made loop's points (tests/urdf_robots.py LOOP_OVERLAY), the rod's mass where it was
    np.testing.assert_allclose(m.site("parallelogram_site1").pos, [0.0, 0.0, 1.1], atol=1e-15)
    np.testing.assert_allclose(m.site("parallelogram_site2").pos, [-0.4, -0.35, 0.0], atol=1e-15)
    np.testing.assert_allclose(m.body("rod").ipos, [0.0, 0.0, 0.55], atol=1e-15)
    logs = []
    for name, robot_file in (("loop", loop), ("mimic", mimic)):
        (tmp_path / f"{name}.toml").write_text(scenario(str(robot_file), loop=True), encoding="utf-8")
        assert (
            main(["simulate", str(tmp_path / f"{name}.toml"), "--out", str(tmp_path / f"{name}.mcap")]) == 0
        )
        logs.append(read_log(tmp_path / f"{name}.mcap"))
    a, b = (np.array([x.position for x in log.measurements]) for log in logs)
    assert a.shape == b.shape == (36, 3, 3)  # 18 poses, unloaded and loaded
    # the same mechanism: equal to the statics' tolerance (1e-10 of a metre-scale solve)
    np.testing.assert_allclose(a, b, atol=1e-9, equal_nan=True)


def test_the_crank_counts_along_the_elbow_axis_whatever_its_own_axis(tmp_path, capsys):
    """A crank drawn with its axis reversed (and its multiplier with it) is the same crank."""
    rc, one = convert_arm(tmp_path / "a", mimic_arm(1), arm_overlay())
    assert rc == 0
    rc, two = convert_arm(tmp_path / "b", mimic_arm(-1), arm_overlay())
    assert rc == 0, capsys.readouterr().err
    ma, mb = (mujoco.MjModel.from_xml_path(str(p)) for p in (one, two))
    for m in (ma, mb):
        d = mujoco.MjData(m)
        d.qpos[m.joint("joint_3").qposadr[0]] = 0.3
        mujoco.mj_kinematics(m, d)
        # the crank turned by +0.3 rad about +y: its free end (crank frame -0.4, 0, 0) rises
        np.testing.assert_allclose(
            d.body("rod").xpos[2] - d.body("link_1").xpos[2], 0.55 + 0.4 * np.sin(0.3), atol=1e-12
        )


def test_a_crank_off_the_joint_2_axis_is_refused_naming_it(tmp_path, capsys):
    urdf = mimic_arm().replace(
        '<origin xyz="0 -0.35 0" rpy="0 0 0"/><axis xyz="0 1 0"/>',
        '<origin xyz="0.1 -0.35 0" rpy="0 0 0"/><axis xyz="0 1 0"/>',
    )
    rc, out = convert_arm(tmp_path, urdf, arm_overlay())
    err = capsys.readouterr().err
    assert rc == 2 and not out.exists()
    assert "arm.urdf: joint 'crank_joint': expected a parallelogram crank pivot on the axis of joint_2" in err
    assert "got '0.1 m off it'" in err


# --------------------------------------------------------------------------- the FANUC's own xacro

FANUC_MASSES = {  # kg, centre of mass in the link frame: ASSUMED (the URDF has none)
    "link_1": (800.0, (0.15, 0.0, -0.3)),
    "link_2": (500.0, (0.0, 0.0, 0.56)),
    "link_3": (400.0, (0.0, 0.0, 0.2)),
    "link_4": (150.0, (0.6, 0.0, 0.0)),
    "link_5": (40.0, (0.1, 0.0, 0.0)),
    "link_6": (40.0, (0.1, 0.0, 0.0)),
    "plink_1": (380.0, (-0.9, 0.0, 0.0)),
    "plink_2": (60.0, (0.0, 0.0, -0.56)),
}
FANUC_OVERLAY = FANUC_TOOL + (
    "".join(f"[inertials.{k}]\nmass = {m}\ncom = {list(c)}\n" for k, (m, c) in FANUC_MASSES.items())
)


def fanuc(tmp_path: Path, capsys) -> Path:
    xacro = shared_data("robots", "fanuc_m900ib_support", "urdf", "m900ib700.xacro")
    (tmp_path / "fanuc.toml").write_text(FANUC_OVERLAY, encoding="utf-8")
    out = tmp_path / "fanuc.xml"
    assert main(["from-urdf", str(xacro), "--overlay", str(tmp_path / "fanuc.toml"), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "became the loop 'parallelogram'" in err and "joint_3 - joint_2" in err
    assert "'balancer' stands for both" in err  # left and right cylinders on one pair of pivots
    return out


def test_the_fanuc_xacro_converts_with_its_loop_and_one_balancer(tmp_path, capsys):
    out = fanuc(tmp_path, capsys)
    robot = Robot.from_file(out)
    names = robot.layout.names
    assert len(names) == 8 and names[6:] == ("balancer_stiffness", "balancer_preload")
    m = robot.model
    assert m.body(m.body("plink_1").parentid[0]).name == "link_1"
    for b in ("balancer_left", "piston_left", "balancer_right", "piston_right"):
        assert mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, b) < 0
    assert main(["check-robot", str(out), "--grid", "1", "--sample", "0"]) == 0


def test_the_fanuc_loop_statics_against_its_mimic_relations_and_energy(tmp_path, capsys):
    """At a loaded equilibrium: the loop closed, the URDF's mimic relations hold (the bars stay
    parallel), and the potential energy (gravity, payload, joint and balancer springs) along
    each motor, the passive joints following those relations, is stationary: central
    differences of 1e-5 rad (error ~h^2 U''' ~1e-6 N*m) against torques of ~1e4 N*m."""
    robot = Robot.from_file(fanuc(tmp_path, capsys))
    m = robot.model
    k = np.array([2.5e-7, 1.6e-7, 3.0e-7, 1.6e-6, 1.4e-6, 2.0e-6])
    robot.set_params(Params(k, {"balancer": Spring(5e5, 0.80)}))
    q = np.radians([20.0, 25.0, -10.0, 30.0, -40.0, 60.0])
    e = StaticsSolver(robot).solve(q, Load.mass(robot, 700.0))
    assert e.acceptable and e.loop_violation < 1e-9
    adr = {n: m.joint(n).qposadr[0] for n in ("joint_2", "joint_3", "joint_3_elbow", "pjoint_2")}
    qp = e.qpos
    # the crank is the forearm's angle against the turret: elbow = crank + joint_2; rod = elbow
    np.testing.assert_allclose(qp[adr["joint_3_elbow"]], qp[adr["joint_3"]] + qp[adr["joint_2"]], atol=1e-9)
    np.testing.assert_allclose(qp[adr["pjoint_2"]], qp[adr["joint_3_elbow"]], atol=1e-9)
    assert np.abs(e.deflection).max() > 1e-5  # the load does bend it

    d = mujoco.MjData(m)
    payload, g = robot.payload_site, m.opt.gravity
    tendon = m.tendon("balancer").id

    def energy(motors: np.ndarray) -> float:
        d.qpos[:] = qp
        d.qpos[robot.act_qpos] = motors
        d.qpos[adr["joint_3_elbow"]] = motors[2] + motors[1]
        d.qpos[adr["pjoint_2"]] = motors[2] + motors[1]
        mujoco.mj_kinematics(m, d)
        mujoco.mj_tendon(m, d)
        u = -float(np.sum(m.body_mass[:, None] * d.xipos * g))
        u -= float(700.0 * g @ d.site_xpos[payload])
        u += float(np.sum((motors - q) ** 2 / k) / 2)
        u += 0.5 * 5e5 * (float(d.ten_length[tendon]) - 0.80) ** 2
        return u

    motors = qp[robot.act_qpos].copy()
    h = 1e-5
    grad = np.array(
        [(energy(motors + h * np.eye(6)[i]) - energy(motors - h * np.eye(6)[i])) / (2 * h) for i in range(6)]
    )
    torques = np.abs(e.deflection / k)  # each motor's spring torque, N*m (J1: none, a vertical load)
    assert torques.max() > 5e3 and torques[1] > 100.0
    np.testing.assert_allclose(grad, 0.0, atol=1e-6 * torques.max())
    # the same difference without the springs is the motors' torques: not a vanishing test
    assert np.abs(grad - (motors - q) / k).max() > 0.5 * torques.max()
