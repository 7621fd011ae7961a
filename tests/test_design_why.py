"""Why design finds no feasible configuration (issue 21): it gives up after one batch of draws
and names, per rule, how many sampled commands each rejected and the pair or limit that did it;
`check-robot` prints the share of a sample that passes each rule."""

from __future__ import annotations

import re
import time

import mujoco
import numpy as np
import pytest
from conftest import MJCF, PAPER
from urdf_robots import arm_overlay, arm_urdf

from calbench.bench.model import Robot
from calbench.identify.cli import main
from calbench.identify.design import BATCH, BatchInfo, InfoEngine, hopeless, load_design_scenario, tally_rules


def test_hopeless_gives_up_after_one_batch_when_nothing_passes():
    assert hopeless(0, BATCH, 10000)  # 0 of 4096: the share is below 1/200 at 97.5 %
    assert not hopeless(0, BATCH // 2, 10000)  # not before a full batch
    assert not hopeless(40, BATCH, 10000)  # 1 % feasible: 10^4 within 10^6 draws
    assert hopeless(19, 200 * 20 + 1, 20)  # the old budget still holds for small sets


def test_design_names_the_rule_and_value_within_seconds(tmp_path, capsys):
    text = PAPER.read_text(encoding="utf-8") + "\n[design]\nmin_height = 10.0\n"
    scn = tmp_path / "tall.toml"
    scn.write_text(text.replace('robot = "', f'robot = "{PAPER.parent.as_posix()}/'), encoding="utf-8")
    t0 = time.perf_counter()
    rc = main(["design", str(scn), "--processes", "1", "--out", str(tmp_path / "plan.toml")])
    seconds = time.perf_counter() - t0
    err = [x for x in capsys.readouterr().err.strip().splitlines() if "error" in x]
    assert rc == 2 and not (tmp_path / "plan.toml").exists()
    assert len(err) == 1 and "Traceback" not in err[0], err
    assert f"only 0 of {BATCH} sampled commands feasible" in err[0]
    got = re.search(
        r"min_height rejects (\d+) of (\d+) \(wrist centre link5 below 10 m; highest ([\d.]+) m\)", err[0]
    )
    assert got and got[1] == got[2] == "256", err[0]
    assert float(got[3]) < 10.0
    assert seconds < 60  # was 2 x 10^6 draws (~25 s alone); one batch here, even on a loaded machine


def test_the_tally_counts_each_rule_on_its_own(tmp_path):
    """Independent counts: the wrist centre's height by MuJoCo kinematics on the plain model,
    the collisions by the batched collider design itself uses."""
    scn, st = load_design_scenario(PAPER)
    eng = InfoEngine(scn, st)
    q = np.random.default_rng(3).uniform(-1.5, 1.5, (64, 6)) + np.radians([0, 45, 0, 0, 0, 0])
    t = tally_rules(eng.feas, eng.solver, scn.load_mass, q, equilibria=4)
    robot = Robot.from_file(MJCF)
    d = mujoco.MjData(robot.model)
    low = loops_bad = 0
    wrist = mujoco.mj_name2id(robot.model, mujoco.mjtObj.mjOBJ_BODY, "link5")
    for qi in q:
        d.qpos[:] = robot.rigid_qpos(qi)
        mujoco.mj_kinematics(robot.model, d)
        low += d.xpos[wrist, 2] < eng.settings.min_height  # the default, scaled with the reach
        loops_bad += not robot.loop_ok(qi)
    assert t.failed["min_height"] == low and t.failed["degenerate_loop"] == loops_bad
    hits = BatchInfo(eng, nthread=1).collider.collides(np.array([robot.rigid_qpos(x) for x in q]))
    assert t.failed["self_collision"] >= int(hits.sum())  # plus any at the equilibria
    assert t.solved == min(4, t.passed_command) and 0 <= t.feasible <= t.solved


def test_check_robot_prints_the_share_each_rule_lets_pass(capsys):
    assert main(["check-robot", str(MJCF), "--grid", "1", "--sample", "64"]) == 0
    out = capsys.readouterr().out
    assert "design's feasibility rules on 64 sampled commands" in out
    for rule in (
        "joint_limits",
        "degenerate_loop",
        "min_height",
        "min_radius",
        "self_collision",
        "visibility",
    ):
        share = re.search(rf"^    {rule} +([\d.]+) % of (\d+) pass", out, flags=re.M)
        assert share and 0 <= float(share[1]) <= 100, rule
    assert main(["check-robot", str(MJCF), "--grid", "1", "--sample", "0"]) == 0
    assert "feasibility rules" not in capsys.readouterr().out
    assert main(["check-robot", str(MJCF), "--grid", "1", "--sample", "-1"]) == 2


ONE_POSE = "[[pose]]\nq = [0, 20, 10, 0, 30, 0]\n"


def _arm_design(tmp_path, capsys, overlay: str, poses: str, json_out: bool = False, urdf: str | None = None):
    """design on the tests' arm (tests/urdf_robots.py) converted with ``overlay``, its scenario's
    poses replaced by ``poses``: (exit status, stdout, stderr, the JSON or None)."""
    import json

    from urdf_robots import convert_arm, scenario

    rc, robot = convert_arm(tmp_path, urdf or arm_urdf(), overlay)
    assert rc == 0
    text = scenario(str(robot))
    (tmp_path / "s.toml").write_text(text[: text.index("[[pose]]")] + poses, encoding="utf-8")
    capsys.readouterr()
    args = ["design", str(tmp_path / "s.toml"), "--candidates", "150", "--processes", "1", "--no-refine"]
    rc = main([*args, "--out", str(tmp_path / "plan.toml"), "--json", str(tmp_path / "d.json")])
    out, err = capsys.readouterr()
    doc = json.loads((tmp_path / "d.json").read_text()) if json_out and rc == 0 else None
    return rc, out, err, doc


ON_J6 = (
    '[payload]\nlink = "tool0"\npos = [0.35, 0.0, -0.15]',
    '[payload]\nlink = "link_6"\npos = [0.35, 0.0, 0.0]',
)


def test_a_payload_on_the_j6_axis_is_named_with_its_fix(tmp_path, capsys):
    """The payload hung on link_6's x axis, J6's own axis: no load has a lever arm about J6 (its
    weight and every pull pass through the axis). k6 is seen only through link_6's own weight,
    which the load's sag turns a little: the A-optimal plan determines it to +-10^5 %, above
    identify's MAX_RELATIVE_STD (1). design names k6, the torque and the fix, in the summary and
    the JSON, instead of an A of 4e6."""
    assert ON_J6[0] in arm_overlay()
    rc, out, err, doc = _arm_design(tmp_path, capsys, arm_overlay().replace(*ON_J6), ONE_POSE, True)
    assert rc == 0, err
    assert list(doc["not_identifiable"]) == ["k6"]
    assert doc["not_identifiable"]["k6"].startswith("no pose's load puts a torque on motor 6")
    assert (
        doc["measures"]["relative_std"]["k6"]
        > 1.0
        > max(v for k, v in doc["measures"]["relative_std"].items() if k != "k6")
    )
    assert "the designed plan leaves k6 undetermined" in out
    assert "fix: hang the payload off motor 6's axis" in out


@pytest.mark.parametrize("com_z", ["0.0", "-1e-6"])
def test_a_parameter_no_candidate_sees_is_named_with_its_fix(tmp_path, capsys, com_z):
    """The same, with link_6's own centre of mass moved onto the axis: nothing turns J6 at all,
    k6's column is zero in every candidate, and design stops (exit 2) with identify's words and
    the fix, not a column number. With the centre of mass 1 um off the axis (a mesh's rounding:
    the M-710iC/50 from its ROS-Industrial URDF) k6's column is 3e-11 of the largest, below
    MIN_COLUMN: design once normalised it into unit noise and wrote a plan of A = inf that it
    said determined every parameter."""
    urdf = arm_urdf().replace(
        '<origin xyz="0.04 0.0 -0.02" rpy="0 0 0"/>', f'<origin xyz="0.04 0.0 {com_z}" rpy="0 0 0"/>'
    )
    assert urdf != arm_urdf()
    rc, _, err, _ = _arm_design(tmp_path, capsys, arm_overlay().replace(*ON_J6), ONE_POSE, urdf=urdf)
    lines = [x for x in err.strip().splitlines() if "error" in x]
    assert rc == 2 and len(lines) == 1 and not (tmp_path / "plan.toml").exists(), err
    assert "s.toml: design: expected candidates that identify every parameter" in lines[0]
    assert "k6: no pose's load puts a torque on motor 6" in lines[0]
    assert "fix: hang the payload off motor 6's axis" in lines[0] and "column" not in lines[0]
    assert "k1" not in lines[0] and "k5" not in lines[0]  # lateral pulls turn J1; J5 sees the weight


def test_the_scenarios_own_plan_names_what_it_leaves_undetermined(tmp_path, capsys):
    """One pose under its vertical weight: J1's axis is vertical, so no load turns it (paper
    §5.1), and one pose's nine readings cannot separate six compliances anyway. The summary and
    the JSON name k1 and why, with the fix, instead of a bare 'A inf'."""
    rc, out, err, doc = _arm_design(
        tmp_path, capsys, arm_overlay(), "[[pose]]\nq = [0, 20, 10, 0, 30, 0]\n", True
    )
    assert rc == 0, err
    line = next(x for x in out.splitlines() if "scenario's own plan" in x)
    assert "A inf" in line and "undetermined" in line and "k1" in line, out
    why = doc["input_plan"]["not_identifiable"]
    assert why["k1"].startswith("every load is vertical, so none turns the J1 axis")
    assert "k1: every load is vertical" in out and "fix: add lateral pulls" in out
    assert "D (det^1/6)" in out  # six parameters, not the FANUC's eight
