"""Robots nobody here wrote (issue 21): a base welded to the world, the ABB IRB 6640 converted
from its ROS-Industrial URDF (``../shared/data/cases/irb6640/``; skipped where absent), and the
robots of ``../shared/data/robots`` nobody had tried (the UR10 from its own xacro and from the
generic ur.xacro with [xacro] arguments, the IRB 6640's plain URDF with assumed_density) from
from-urdf to a small design, one of them to identify --check (skipped where absent).

MuJoCo filters contacts between a parent and a child body, but not when the parent is welded
to the world (a URDF's ``base_link`` has no joint): the base's mesh and link 1's touch across
joint 1 in every configuration, so design must exclude that pair itself.
"""

from __future__ import annotations

import re
from pathlib import Path

import mujoco
import numpy as np
import pytest
from robots import serial_mjcf
from shared_data import shared_data

from calbench.bench.model import Robot
from calbench.identify.cli import main
from calbench.identify.design import collision_model, excluded_pairs


def _all_collide(path: Path, margin: float) -> mujoco.MjModel:
    spec = mujoco.MjSpec.from_file(str(path))
    for g in spec.geoms:
        g.contype, g.conaffinity, g.margin = 1, 1, margin
    return spec.compile()


def _contacts(model: mujoco.MjModel, qpos) -> set[tuple[str, str]]:
    d = mujoco.MjData(model)
    d.qpos[:] = qpos
    mujoco.mj_kinematics(model, d)
    mujoco.mj_collision(model, d)
    return {
        tuple(
            sorted(
                (model.body(model.geom_bodyid[c.geom[0]]).name, model.body(model.geom_bodyid[c.geom[1]]).name)
            )
        )
        for c in d.contact[: d.ncon]
    }


@pytest.fixture(scope="module")
def welded(tmp_path_factory) -> Path:
    """The four-axis test arm: its pedestal (no joint: welded to the world) carries the column on
    the vertical base_yaw hinge; the cylinder's top and the column's box meet at z = 0.4 m."""
    path = tmp_path_factory.mktemp("welded") / "serial.xml"
    path.write_text(serial_mjcf(), encoding="utf-8")
    return path


def test_mujoco_does_not_filter_a_child_of_a_body_welded_to_the_world(welded):
    """The premise: with every geom collidable, MuJoCo reports pedestal-column at q = 0 and with
    the column turned (its filter drops column-arm, a jointed parent and its child)."""
    robot = Robot.from_file(welded)
    raw = _all_collide(welded, 0.01)
    for q1 in (0.0, 1.0):
        q = np.array([q1, 0.0, 0.0, 0.0])
        got = _contacts(raw, robot.rigid_qpos(q))
        assert ("column", "pedestal") in got
        assert ("arm", "column") not in got


def test_the_world_welded_parent_pair_is_excluded_and_other_contacts_still_count(welded):
    robot = Robot.from_file(welded)
    assert ("column", "pedestal") in excluded_pairs(robot, welded)
    cm = collision_model(robot, welded, clearance=0.01)
    for q1 in (0.0, 1.0, -2.5):
        assert _contacts(cm, robot.rigid_qpos(np.array([q1, 0.0, 0.0, 0.0]))) == set()
    # the arm swung down (shoulder +90 deg) runs into the pedestal: not parent and child, counted
    assert ("arm", "pedestal") in _contacts(cm, robot.rigid_qpos(np.radians([0.0, 90.0, 0.0, 0.0])))


def test_design_finds_a_distinct_certified_plan_on_the_irb6640(tmp_path, capsys):
    """Before the fix: 'only 0 of 2000384 sampled commands feasible' (base_link-link_1 counted)."""
    case = shared_data("cases", "irb6640")
    out = tmp_path / "plan.toml"
    args = ["design", str(case / "irb6640_hidden.toml"), "--distinct", "--candidates", "1500"]
    rc = main([*args, "--processes", "1", "--out", str(out), "--no-refine"])
    text = capsys.readouterr().out
    assert rc == 0
    poses = re.findall(r"^q = \[(.*)\]$", out.read_text(encoding="utf-8"), flags=re.M)
    assert len(poses) >= 12 and len(set(poses)) == len(poses)
    assert re.search(r"certificate \(A, every 12-pose distinct plan .*>= bound", text)
    xml = case / "irb6640.xml"
    assert ("base_link", "link_1") in excluded_pairs(Robot.from_file(xml), xml)


# Robots nobody here had tried (issue 21's robustness round), with overlays written from
# docs/your-robot.md alone: the URDF's own inertials or assumed_density, no masses typed.
def _tool0_overlay(actuated: list[str], payload, reflectors, top: str = "", extra: str = "") -> str:
    return (
        "actuated = [" + ", ".join(f'"{a}"' for a in actuated) + "]\n" + top
        + f'\n[payload]\nlink = "tool0"\npos = {payload}\n'
        + "".join(f'\n[reflectors.r{i}]\nlink = "tool0"\npos = {p}\n' for i, p in enumerate(reflectors, 1))
        + extra
    )  # fmt: skip


UR_JOINTS = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint"]
UR = _tool0_overlay(
    [*UR_JOINTS, "wrist_3_joint"],
    [0.1, 0.0, 0.1],
    ([0.08, 0.0, 0.05], [-0.08, 0.0, 0.05], [0.0, 0.1, 0.05]),
    extra='\n[packages]\nur_description = "{robots}/ur_description"\n',
)
UR10_ARGS = '\n[xacro]\nrobot_model = "ur10"\n' + "".join(
    f'{k} = "$(find ur_description)/config/ur10/{f}.yaml"\n'
    for k, f in (
        ("joint_limit_params", "joint_limits"),
        ("kinematics_params", "default_kinematics"),
        ("physical_params", "physical_parameters"),
        ("visual_params", "visual_parameters"),
    )
)
SIX = [f"joint_{i}" for i in range(1, 7)]
HEAVY_REFLECTORS = ([0.25, 0.15, 0.15], [-0.25, 0.15, 0.15], [0.0, -0.3, 0.15])
NEWCOMERS = {
    "ur10": ("ur_description/urdf/ur10.xacro", UR, 10.0, "[5e-6, 5e-6, 8e-6, 2e-5, 2e-5, 3e-5]", ""),
    "ur10 via ur.xacro": ("ur_description/urdf/ur.xacro", UR + UR10_ARGS, 10.0, "[5e-6, 5e-6, 8e-6, 2e-5, 2e-5, 3e-5]", ""),
    "irb6640 plain urdf": (
        "abb_irb6640_support/urdf/irb6640_185_280.urdf",
        _tool0_overlay(SIX, [0.0, 0.1, 0.25], HEAVY_REFLECTORS, top="assumed_density = 1000.0\n"),
        185.0,
        "[2.5e-7, 1.6e-7, 3.5e-7, 1.6e-6, 1.4e-6, 2.0e-6]",
        "[truth.compensators.balancer]\nstiffness = 5e5\npreload = 0.40\n",
    ),
}  # fmt: skip


def _newcomer(tmp_path: Path, which: str) -> tuple[Path, Path]:
    """from-urdf and check-robot of a newcomer robot: (its MJCF, a scenario for it)."""
    xacro, overlay, mass, compliance, springs = NEWCOMERS[which]
    path = shared_data("robots", *xacro.split("/"))
    robots = path.parents[2]
    (tmp_path / "ov.toml").write_text(overlay.replace("{robots}", robots.as_posix()), encoding="utf-8")
    out = tmp_path / "robot.xml"
    assert main(["from-urdf", str(path), "--overlay", str(tmp_path / "ov.toml"), "--out", str(out)]) == 0
    scn = tmp_path / "plan.toml"
    scn.write_text(
        f'name = "newcomer"\nrobot = "robot.xml"\nseed = 1\n[truth]\ncompliance = {compliance}\n{springs}'
        "[tracker]\nsigma = 20e-6\nposition = [2.5, -2.5, 2.0]\n"
        f"[load]\nmass = {mass}\n[[pose]]\nq = [0, -40, 40, 0, 45, 0]\n",
        encoding="utf-8",
    )
    return out, scn


@pytest.mark.parametrize("which", sorted(NEWCOMERS))
def test_a_robot_nobody_tried_converts_checks_and_designs(tmp_path, capsys, which):
    """from-urdf, check-robot (its design rules scaled to the robot's reach: a UR10's min_radius
    is about half a metre, a heavy robot's 1 m) and a small distinct design, certificate printed."""
    robot, scn = _newcomer(tmp_path, which)
    capsys.readouterr()
    assert main(["check-robot", str(robot), "--grid", "1", "--sample", "32"]) == 0
    out = capsys.readouterr().out
    radius = float(re.search(r"min_radius ([\d.]+) m; reach ([\d.]+) m", out)[1])
    assert (radius < 0.6) if which.startswith("ur10") else (radius == 1.0), out
    args = ["design", str(scn), "--distinct", "--configs", "8", "--candidates", "60", "--no-refine"]
    assert main([*args, "--processes", "1", "--out", str(tmp_path / "designed.toml")]) == 0
    out = capsys.readouterr().out
    assert "certificate (A, every 8-pose distinct plan" in out and "efficiency" in out
    assert (tmp_path / "designed.toml").read_text(encoding="utf-8").count("[[pose]]") == 8


def test_a_ur10_nobody_tried_identifies_from_its_designed_plan(tmp_path, capsys):
    """The whole way for one of them: design (12 distinct poses), simulate, identify --check."""
    robot, scn = _newcomer(tmp_path, "ur10")
    plan, log = tmp_path / "designed.toml", tmp_path / "c.mcap"
    args = ["design", str(scn), "--distinct", "--candidates", "300", "--processes", "1", "--out", str(plan)]
    assert main(args) == 0
    assert main(["simulate", str(plan), "--out", str(log)]) == 0
    capsys.readouterr()
    assert main(["identify", str(log), "--check"]) == 0
    assert "check passed" in capsys.readouterr().out


def test_a_ur_whose_files_are_absent_is_one_line_naming_the_file(tmp_path, capsys):
    """../shared/data holds only the UR10's config/ and meshes/ of ur_description: the UR5's
    xacro reads config/ur5/joint_limits.yaml, and from-urdf names that file, on one line."""
    xacro = shared_data("robots", "ur_description", "urdf", "ur5.xacro")
    if (xacro.parents[1] / "config" / "ur5").exists():
        pytest.skip("this ur_description has the UR5's files")
    (tmp_path / "ov.toml").write_text(UR.replace("{robots}", xacro.parents[2].as_posix()), encoding="utf-8")
    out = tmp_path / "ur5.xml"
    rc = main(["from-urdf", str(xacro), "--overlay", str(tmp_path / "ov.toml"), "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and not out.exists(), err
    assert (
        "expected every file the xacro reads" in err[0]
        and "config/ur5/joint_limits.yaml is missing" in err[0]
    )
