"""`calbench check-robot`: the shipped FANUC and a robot built from scratch pass; every broken
description is exit 2 with one line naming the element."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import MJCF
from robots import fourbar_mjcf, serial_mjcf

from calbench.bench.model import Robot
from calbench.bench.robots import check_robot, default_tracker, grid
from calbench.identify.cli import main


def test_the_fanuc_passes_with_its_derived_margin(capsys):
    assert main(["check-robot", str(MJCF)]) == 0
    out = capsys.readouterr().out
    assert "6 actuated joints: j1 j2 j3 j4 j5 j6" in out
    assert "loop parallelogram: passive joints elbow rod" in out
    assert "commands need >= 0.0875" in out  # tan 5 deg
    assert "compensator compensator: across j2" in out
    assert "statics converge at 729 grid poses" in out  # 3^6
    # the default tracker stands beside the FANUC's scenarios' (3.5, -3.5, 3.2)
    np.testing.assert_allclose(default_tracker(Robot.from_file(MJCF)), [3.5355, -3.5355, 3.0], atol=1e-3)


def test_robots_built_from_scratch_pass(tmp_path):
    for name, xml, n in (
        ("arm", serial_mjcf(), 81),
        ("bal", serial_mjcf(balancer=True), 81),
        ("fourbar", fourbar_mjcf(), 27),
    ):
        path = tmp_path / f"{name}.xml"
        path.write_text(xml)
        res = check_robot(path)
        assert res.poses + res.skipped == n == len(grid(Robot.from_file(path), 3))
        assert res.max_gap <= 1e-9
    assert res.loops == {"closure": ["knee", "coupler"]}


def _broken(tmp_path: Path, xml: str) -> tuple[int, str]:
    path = tmp_path / "broken.xml"
    path.write_text(xml)
    rc = main(["check-robot", str(path)])
    return rc, str(path)


BROKEN = {
    "not an MJCF": ("<mujoco><worldbody><body><joint name='a'/></body></mujoco>", "MJCF: expected a model"),
    "no actuated text": (serial_mjcf({"actuated": None}), "custom text calbench:actuated"),
    "a reflector missing": (serial_mjcf({"reflectors": "t1 t2 ghost"}), "no site named 'ghost'"),
    "a loop that cannot close": (
        fourbar_mjcf()
        .replace('fromto="0 0 0 0.95 0 0"', 'fromto="0 0 0 3 0 0"')
        .replace('name="link_end" pos="0.95 0 0"', 'name="link_end" pos="3 0 0"'),
        "calbench:loops",
    ),
    "collinear reflectors": (
        serial_mjcf().replace('name="t3" pos="0.15 0 -0.3"', 'name="t3" pos="0.15 0.5 0.2"'),
        "calbench:reflectors: expected reflectors not on one line",
    ),
    "a reflector inside the hand": (
        serial_mjcf().replace('name="t3" pos="0.15 0 -0.3"', 'name="t3" pos="0.1 0 0"'),
        "hidden: t3",
    ),
    "an actuated joint without spring": (
        serial_mjcf().replace('range="-150 150" stiffness="1e6"', 'range="-150 150"'),
        "calbench:actuated: joint 'elbow_pitch': expected a stiffness > 0",
    ),
    "a free joint": (
        serial_mjcf().replace('<site name="hook"', '<joint name="wobble" axis="0 0 1"/><site name="hook"'),
        "joint 'wobble': expected an actuated joint",
    ),
}


@pytest.mark.parametrize("case", list(BROKEN), ids=list(BROKEN))
def test_a_broken_robot_is_exit_2_naming_the_element(tmp_path, capsys, case):
    xml, fragment = BROKEN[case]
    rc, path = _broken(tmp_path, xml)
    err = capsys.readouterr().err
    assert rc == 2, err
    assert err.count("\n") == 1 and path in err and fragment in err, err
    assert "Traceback" not in err


def test_bad_options_are_exit_2(capsys):
    assert main(["check-robot", str(MJCF), "--grid", "0"]) == 2
    assert main(["check-robot", str(MJCF), "--mass", "-1"]) == 2
    assert main(["check-robot", "no_such.xml"]) == 2
    err = capsys.readouterr().err
    assert "--grid" in err and "--mass" in err and "no such file" in err


def test_the_readme_robot_passes(tmp_path):
    """The minimal MJCF of docs/your-robot.md is a robot check-robot accepts."""
    section = (Path(__file__).resolve().parent.parent / "docs" / "your-robot.md").read_text(encoding="utf-8")
    xml = section[section.index("```xml\n") + 7 : section.index("```\n", section.index("```xml\n"))]
    (tmp_path / "my_arm.xml").write_text(xml)
    res = check_robot(tmp_path / "my_arm.xml")
    assert res.parameters == ("k1", "k2", "k3") and res.poses == 27


def test_a_payload_on_the_last_axis_is_warned_about(tmp_path):
    """A payload hung on J6's own axis (the tests' arm, link_6's x axis) has no lever arm about
    it at any pose: check-robot says so, names the joint and the fix, before design refuses. The
    arm as shipped, with its payload 0.15 m off the axis, gets no warning, nor does any joint
    whose axis the payload only crosses at some poses."""
    from urdf_robots import arm_overlay, arm_urdf, convert_arm

    on_axis = (
        '[payload]\nlink = "tool0"\npos = [0.35, 0.0, -0.15]',
        '[payload]\nlink = "link_6"\npos = [0.35, 0.0, 0.0]',
    )
    assert on_axis[0] in arm_overlay()
    _, off = convert_arm(tmp_path / "off", arm_urdf(), arm_overlay())
    _, on = convert_arm(tmp_path / "on", arm_urdf(), arm_overlay().replace(*on_axis))
    assert check_robot(off).payload_on_axis == ()
    res = check_robot(on)
    assert res.payload_on_axis == ("joint_6",)
    line = next(x for x in res.lines() if "WARNING" in x)
    assert "on joint_6's axis at every grid pose" in line and "[payload] pos" in line
