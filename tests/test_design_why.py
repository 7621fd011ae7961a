"""Why design finds no feasible configuration (issue 21): it gives up after one batch of draws
and names, per rule, how many sampled commands each rejected and the pair or limit that did it;
`check-robot` prints the share of a sample that passes each rule."""

from __future__ import annotations

import re
import time

import mujoco
import numpy as np
from conftest import MJCF, PAPER

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
        low += d.xpos[wrist, 2] < st.min_height
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
