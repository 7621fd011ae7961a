"""Robots nobody here wrote (issue 21): a base welded to the world, and the ABB IRB 6640 converted
from its ROS-Industrial URDF (``../shared/data/cases/irb6640/``; skipped where absent).

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
