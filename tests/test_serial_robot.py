"""A robot built from scratch (tests/robots.py: four axes, no loop, no FANUC name) through
every verb: simulate, identify --check, the two-step where it applies, design, and a variant
with a balancer tendon of another name ([truth.compensators.balancer], parameters
balancer_stiffness / balancer_preload).

The plan: ten poses, three with a horizontal pull (a vertical load cannot turn the vertical
base axis, paper §5.1), the tool rolled so that the hook's offset loads the roll axis. The
--check criterion is identify's own (|z| <= 4 for every parameter; with the fixed seed the
largest |z| is 1.3).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from robots import serial_mjcf

from calbench.bench.log import read_log
from calbench.identify.cli import main

POSES = [
    ([0, 0, 0, 0], None),
    ([0, 30, -60, 90], None),
    ([0, -30, 45, -90], None),
    ([45, 60, -90, 45], None),
    ([-45, 10, 30, -45], None),
    ([90, 45, -30, 135], None),
    ([120, 40, -80, -60], None),
    ([0, 0, 0, 0], [0.0, 1000.0, 0.0, 0.0, 0.0, 0.0]),
    ([30, 20, -20, 0], [-500.0, 866.0, 0.0, 0.0, 0.0, 0.0]),
    ([-60, 0, 10, 90], [866.0, 500.0, 0.0, 0.0, 0.0, 0.0]),
]


def scenario(tmp: Path, name: str, xml: str, truth_extra: str = "") -> Path:
    (tmp / f"{name}.xml").write_text(xml)
    poses = "".join(f"\n[[pose]]\nq = {q}\n" + (f"wrench = {w}\n" if w else "") for q, w in POSES)
    text = (
        f'robot = "{name}.xml"\nseed = 3\n[truth]\ncompliance = [3e-7, 2e-7, 4e-7, 1.5e-6]\n'
        f"{truth_extra}\n[tracker]\nsigma = 20e-6\nposition = [3.5, -3.5, 3.0]\n[load]\nmass = 150.0\n"
        + poses
    )
    path = tmp / f"{name}.toml"
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def arm(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("serial")
    scn = scenario(tmp, "arm", serial_mjcf())
    assert main(["simulate", str(scn), "--out", str(tmp / "arm.mcap")]) == 0
    return tmp, scn


def test_a_serial_robot_simulates_and_identifies(arm, capsys):
    tmp, _ = arm
    out = tmp / "id.json"
    assert main(["identify", str(tmp / "arm.mcap"), "--check", "--json", str(out)]) == 0
    assert "check passed" in capsys.readouterr().out
    rep = json.loads(out.read_text())
    assert [p["name"] for p in rep["parameters"]] == ["k1", "k2", "k3", "k4"]
    assert all(p["identifiable"] and abs(p["z"]) <= 4 for p in rep["parameters"])
    log = read_log(tmp / "arm.mcap", include_truth=True)
    assert all(len(q) == 4 for per in log.poses.values() for q in (per.unloaded, per.loaded))
    assert set(log.truth.parameters.springs) == set()  # no compensator


def test_the_two_step_applies_to_a_serial_robot_without_compensator(arm, tmp_path):
    """Step 1 alone (eqs. 19-20): no compensator, so no joint is split per angle."""
    tmp, _ = arm
    out = tmp_path / "two.json"
    assert main(["identify", str(tmp / "arm.mcap"), "--method", "two-step", "--json", str(out)]) == 0
    rep = json.loads(out.read_text())
    assert rep["step1"]["names"] == ["k1", "k2", "k3", "k4"]
    assert all(p["identifiable"] for p in rep["parameters"])


def test_a_serial_robot_designs_a_plan(arm, tmp_path):
    """Design's rules are derived from the model: no loop (no loop rule, no exclusions), the
    wrist centre at the elbow's body, no counterweights (§3.3 void)."""
    _, scn = arm
    js, plan = tmp_path / "d.json", tmp_path / "plan.toml"
    assert (
        main(
            [
                "design",
                str(scn),
                "--configs",
                "4",
                "--candidates",
                "40",
                "--starts",
                "1",
                "--no-refine",
                "--json",
                str(js),
                "--out",
                str(plan),
            ]
        )
        == 0
    )
    d = json.loads(js.read_text())
    assert set(d["prior_theta"]) == {"k1", "k2", "k3", "k4"}
    assert d["candidates"]["rejected_first_rule"]["degenerate_loop"] == 0
    assert main(["simulate", str(plan), "--out", str(tmp_path / "plan.mcap")]) == 0


def test_a_balancer_of_another_name(tmp_path, capsys):
    scn = scenario(
        tmp_path,
        "bal",
        serial_mjcf(balancer=True),
        "[truth.compensators.balancer]\nstiffness = 3e6\npreload = 0.68",
    )
    log, out = tmp_path / "bal.mcap", tmp_path / "id.json"
    assert main(["simulate", str(scn), "--out", str(log)]) == 0
    truth = read_log(log, include_truth=True).truth.parameters
    assert truth.springs["balancer"].stiffness == 3e6
    assert main(["identify", str(log), "--check", "--json", str(out)]) == 0
    rep = json.loads(out.read_text())
    assert [p["name"] for p in rep["parameters"]][4:] == ["balancer_stiffness", "balancer_preload"]
    # a scenario that calls it [truth.compensator] does not fit this robot: exit 2, key named
    bad = scenario(
        tmp_path, "bad", serial_mjcf(balancer=True), "[truth.compensator]\nstiffness = 3e6\npreload = 0.68"
    )
    capsys.readouterr()
    assert main(["simulate", str(bad), "--out", str(tmp_path / "bad.mcap")]) == 2
    assert "truth.compensators.balancer" in capsys.readouterr().err
    assert not (tmp_path / "bad.mcap").exists()


TWO_SPRINGS = """<tendon>
    <spatial name="helper" stiffness="1e5" springlength="0.7">
      <site site="bal_low"/>
      <site site="t1"/>
    </spatial>
  </tendon>"""


def test_the_two_step_refuses_a_robot_outside_eqs_19_to_22(tmp_path, capsys):
    """Two compensator springs: the two-step separates one. identify and montecarlo exit 2
    with the reason; the one-step runs (and montecarlo's default runs it alone)."""
    xml = serial_mjcf({"compensators": "balancer helper"}, balancer=True, extra=TWO_SPRINGS)
    scn = scenario(
        tmp_path,
        "two",
        xml,
        "[truth.compensators.balancer]\nstiffness = 3e6\npreload = 0.68\n"
        "[truth.compensators.helper]\nstiffness = 1e5\npreload = 0.7",
    )
    log = tmp_path / "two.mcap"
    assert main(["simulate", str(scn), "--out", str(log)]) == 0
    capsys.readouterr()
    assert main(["identify", str(log), "--method", "two-step"]) == 2
    err = capsys.readouterr().err
    assert "--method two-step" in err and "this robot has 2 (balancer, helper)" in err
    assert "Traceback" not in err
    assert main(["montecarlo", str(scn), "--runs", "2", "--method", "two-step"]) == 2
    assert "--method two-step" in capsys.readouterr().err
    js = tmp_path / "mc.json"
    assert main(["montecarlo", str(scn), "--runs", "2", "--json", str(js)]) == 0
    assert list(json.loads(js.read_text())["methods"]) == ["one-step"]


def test_candidates_of_one_robot_do_not_fit_another(arm, tmp_path, capsys):
    """--from-candidates with a scenario: q must have one column per actuated joint of its robot."""
    from conftest import PAPER

    _, scn = arm
    npz = tmp_path / "c.npz"
    assert main(["design", str(scn), "--candidates", "20", "--export-candidates", str(npz)]) == 0
    capsys.readouterr()
    assert (
        main(
            [
                "design",
                str(PAPER),
                "--from-candidates",
                str(npz),
                "--configs",
                "4",
                "--out",
                str(tmp_path / "p.toml"),
            ]
        )
        == 2
    )
    err = capsys.readouterr().err
    assert f"{npz}: q: expected N x 6 joint angles" in err and "got 'N x 4'" in err


def test_the_wrist_centre_is_derived_or_named():
    """Design's wrist centre: the body of the last-but-one actuated joint, unless calbench:wrist
    names another body."""
    from calbench.bench.model import Robot
    from calbench.identify.design import wrist_body

    plain = Robot.from_xml(serial_mjcf())
    assert plain.model.body(wrist_body(plain)).name == "lever"  # elbow_pitch's body
    named = Robot.from_xml(serial_mjcf({"wrist": "hand"}))
    assert named.model.body(wrist_body(named)).name == "hand"
