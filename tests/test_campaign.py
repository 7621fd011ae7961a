"""`calbench simulate` end to end: determinism, crash safety, bad input, independent readers."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import MJCF, PAPER
from rerun_cli import rerun_env, rerun_exe

from calbench.bench.log import read_log
from calbench.bench.scenario import load_scenario
from calbench.identify.cli import main


def simulate(tmp_path: Path, scenario: Path = PAPER, name: str = "log.mcap", *extra: str) -> tuple[int, Path]:
    out = tmp_path / name
    return main(["simulate", str(scenario), "--out", str(out), *extra]), out


@pytest.fixture(scope="module")
def paper_log(tmp_path_factory) -> Path:
    rc, out = simulate(tmp_path_factory.mktemp("paper"))
    assert rc == 0
    return out


def test_log_holds_every_pose_both_states(paper_log):
    scn = load_scenario(PAPER)
    log = read_log(paper_log)
    assert log.complete_poses == list(range(len(scn.poses)))
    assert not log.truncated
    states = {(m.pose, m.state) for m in log.measurements}
    assert states == {(i, s) for i in range(len(scn.poses)) for s in ("unloaded", "loaded")}
    # loaded minus unloaded is millimetres, far above the 20 um noise: the physics is in the log
    truth = read_log(paper_log, include_truth=True).truth
    assert truth is not None
    assert log.mjcf_text and "compensator" in log.mjcf_text


def test_same_seed_same_bytes_other_seed_other_noise(tmp_path, paper_log):
    _, again = simulate(tmp_path, PAPER, "again.mcap")
    assert again.read_bytes() == paper_log.read_bytes()
    _, other = simulate(tmp_path, PAPER, "other.mcap", "--seed", "7")
    a = np.concatenate([m.position[m.visible] for m in read_log(paper_log).measurements])
    b = np.concatenate([m.position[m.visible] for m in read_log(other).measurements])
    diff = a - b
    # two independent draws: the difference has std sigma*sqrt(2) per axis (20 um)
    assert 0.5 * 20e-6 * np.sqrt(2) < diff.std() < 1.5 * 20e-6 * np.sqrt(2)


def test_noise_matches_truth_statistics(paper_log):
    """Measured minus true reflector positions: zero mean, sigma 20 um, within sampling error."""
    from calbench.bench.tracker import to_world_frame

    full = read_log(paper_log, include_truth=True)
    scn = load_scenario(PAPER)
    errs = []
    for m in full.measurements:
        true = full.truth.reflectors[m.pose].get(m.state).position_world
        meas = to_world_frame(scn.tracker, np.nan_to_num(m.position))
        errs.append((meas - true)[m.visible])
    e = np.concatenate(errs).ravel()
    n = e.size
    assert abs(e.mean()) < 4 * 20e-6 / np.sqrt(n)
    assert abs(e.std(ddof=1) / 20e-6 - 1) < 4 * np.sqrt(1 / (2 * (n - 1)))


def test_rerun_reads_the_log(paper_log, tmp_path):
    res = subprocess.run(
        [rerun_exe(), "mcap", "info", str(paper_log)],
        capture_output=True,
        text=True,
        env=rerun_env(tmp_path),
        timeout=120,
    )
    assert res.returncode == 0, res.stderr
    assert "Channels" in res.stdout or "channels" in res.stdout.lower()


KILLER = r"""
import os, signal, sys
import calbench.bench.campaign.run as c
orig = c.LogWriter.pose_done
count = {"n": 0}
def pose_done(self, pose):
    orig(self, pose)
    count["n"] += 1
    if count["n"] == int(sys.argv[3]):
        # start the next pose, then die hard in the middle of it
        self.pose(pose + 1, "unloaded", [0.0] * 6)
        os.kill(os.getpid(), signal.SIGKILL)
c.LogWriter.pose_done = pose_done
from calbench.identify.cli import main
main(["simulate", sys.argv[1], "--out", sys.argv[2]])
"""


def test_killed_campaign_keeps_finished_poses(tmp_path):
    out = tmp_path / "killed.mcap"
    res = subprocess.run(
        [sys.executable, "-c", KILLER, str(PAPER), str(out), "5"], capture_output=True, timeout=120
    )
    assert res.returncode == -9
    log = read_log(out)
    assert log.truncated
    assert log.complete_poses == [0, 1, 2, 3, 4]
    assert {m.pose for m in log.measurements} == {0, 1, 2, 3, 4}


def bad_scenario(tmp_path: Path, edit) -> Path:
    text = PAPER.read_text()
    text = text.replace('robot = "../mjcf/m900ib700.xml"', f'robot = "{MJCF}"')
    p = tmp_path / "bad.toml"
    p.write_text(edit(text))
    return p


CASES = {
    "unknown key": (lambda t: t.replace("seed = 1", "seed = 1\ncolour = 3"), "colour"),
    "wrong length": (
        lambda t: t.replace("q = [0, 0, -30, -45, 30, 135]", "q = [0, 0, -30, -45, 30]", 1),
        "pose[0].q",
    ),
    "beyond limit": (
        lambda t: t.replace("q = [0, 0, -30, -45, 30, 135]", "q = [0, 0, 45, -45, 30, 135]", 1),
        "pose[0].q",
    ),
    "non-positive mass": (lambda t: t.replace("mass = 700.0", "mass = 0.0"), "load.mass"),
    "degenerate parallelogram": (
        lambda t: t.replace("q = [0, 0, -30, -45, 30, 135]", "q = [0, 90, -30, -45, 30, 135]", 1),
        "pose[0].q",
    ),
    "unseeable": (
        lambda t: t.replace("position = [3.5, -3.5, 3.2]", "position = [0.0, 0.0, 0.45]"),
        "pose[0].q",
    ),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_input_exit_2_no_output(tmp_path, capsys, case):
    edit, key = CASES[case]
    scn = bad_scenario(tmp_path, edit)
    out = tmp_path / "never.mcap"
    rc = main(["simulate", str(scn), "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2
    assert "bad.toml" in err and key in err and "expected" in err
    assert not out.exists()


def test_cli_exit_status_from_a_real_process(tmp_path):
    exe = Path(sys.executable).parent / "calbench"
    res = subprocess.run(
        [str(exe), "simulate", str(tmp_path / "missing.toml"), "--out", str(tmp_path / "x.mcap")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == 2
    assert "missing.toml" in res.stderr
