"""Design of experiments (issue 4): feasibility rules, information blocks, exchange, CLI, and the
predicted covariance against Monte Carlo.

Sampling bound of the Monte Carlo test: for Gaussian estimates with covariance C, the trace of
the sample covariance of N runs has standard deviation sqrt(2 tr(C^2) / (N - 1)); we allow 4 of
them (plus the CRB's asymptotic approximation, which the one-step estimator meets to a few %
on these plans: tests/test_montecarlo.py).
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import numpy as np
import pytest
from conftest import MJCF, PAPER, ROOT

from calbench.bench.campaign import simulate, truth_robot
from calbench.bench.model import Robot
from calbench.bench.scenario import load_scenario
from calbench.identify.cli import main
from calbench.identify.core import ForwardModel, design_from_observations, from_campaign, whiten_factors
from calbench.identify.design import (
    DesignSettings,
    InfoEngine,
    PlanPose,
    generate_candidates,
    load_design_scenario,
    plan_scenario_text,
    read_design_settings,
    robot_reach,
    wrist_body,
)
from calbench.identify.design.optimal import Exchanger, criterion_value, information, measures
from calbench.identify.study import run_montecarlo

WEIGHT = np.r_[Robot.from_file(MJCF).weight(700.0), 0, 0, 0.0]  # the model's own gravity


@pytest.fixture(scope="module")
def paper():
    return load_design_scenario(PAPER)


@pytest.fixture(scope="module")
def engine(paper):
    return InfoEngine(*paper)


@pytest.fixture(scope="module")
def cands(paper):
    scn, st = paper
    return generate_candidates(scn, st, n=400, processes=1, progress=False)


def _scenario_with_poses(scn, poses, tmp: Path, name="plan.toml") -> Path:
    path = tmp / name
    path.write_text(plan_scenario_text(scn, poses, path))
    return path


# ------------------------------------------------------------------------------ feasibility


@pytest.mark.parametrize(
    "q, rule",
    [
        ([0, 125, 0, 0, 0, 0], "joint_limits"),  # j2 range ends at 120 deg
        ([0, 60, 0, 0, 122, 0], "self_collision"),  # wrist folded down: the tool hits the forearm
        ([90, 0, 30, 45, -30, 45], "visibility"),  # Table 5 pose 4: refl_c hidden from the tracker
        ([0, 0, -30, -45, 30, 135], "min_radius"),  # Table 5 pose 1: wrist centre 0.84 m from axis 1
        ([0, 60, -65, 0, 0, 0], "degenerate_loop"),  # q3 - q2 = -125: 5 deg from the degenerate -120
    ],
)
def test_a_pose_violating_a_rule_is_rejected_with_the_rule_named(engine, q, rule):
    info = engine.pose(np.radians(q), WEIGHT)
    assert rule in info.violations, info.violations


def test_a_feasible_pose_passes_every_rule(engine):
    assert engine.pose(np.radians([90, 120, 30, 0, 0, 0]), WEIGHT).violations == []


def _wrist_radii(robot: Robot, n: int, seed: int = 0) -> np.ndarray:
    """The wrist centre's distance from axis 1 at n commands sampled in the joint ranges, by
    MuJoCo's kinematics on the plain model (not the design's Feasibility)."""
    import mujoco

    m, d = robot.model, mujoco.MjData(robot.model)
    lim = robot.limits()
    q = np.random.default_rng(seed).uniform(lim[:, 0], lim[:, 1], (n, robot.n_act))
    out = []
    for qi in q:
        d.qpos[:] = robot.rigid_qpos(qi)
        mujoco.mj_kinematics(m, d)
        j = robot.act_joint[0]
        v = d.xpos[wrist_body(robot)] - d.xanchor[j]
        out.append(np.linalg.norm(v - (v @ d.xaxis[j]) * d.xaxis[j]))
    return np.array(out)


@pytest.mark.parametrize("mjcf", [MJCF, ROOT / "mjcf" / "kr270.xml"])
def test_a_heavy_robot_keeps_the_papers_wrist_rules(mjcf):
    """The reach bounds the wrist centre's distance from axis 1 (sampled commands stay below it
    and come within 10 %: these arms stretch out straight), and a robot of 2.5 m reach or more
    keeps the paper's 0.5 m and 1 m exactly (the shipped plans are those of before)."""
    robot = Robot.from_file(mjcf)
    reach, radii = robot_reach(robot), _wrist_radii(robot, 1500)
    assert radii.max() <= reach + 1e-9 and radii.max() >= 0.9 * reach, (radii.max(), reach)
    st = DesignSettings().for_reach(reach)
    assert reach >= 2.5 and (st.min_height, st.min_radius) == (0.5, 1.0)


def test_the_wrist_rules_scale_with_a_smaller_robot(tmp_path, paper):
    """The FANUC shrunk to 40 % (bodies, joints, sites; a UR10's size): its reach is 40 % of the
    FANUC's (a length: exactly), and design's defaults 0.5 m x and 1 m x min(1, reach / 2.5 m);
    a value the scenario gives is kept as given."""
    import mujoco

    spec = mujoco.MjSpec.from_file(str(MJCF))
    for el in (*spec.bodies, *spec.joints, *spec.sites):
        el.pos = [0.4 * x for x in el.pos]
    for eq in spec.equalities:  # the loop's connect anchors, when given as points
        eq.data = [0.4 * x for x in eq.data[:6]] + list(eq.data[6:])
    small = tmp_path / "small.xml"
    small.write_text(spec.to_xml(), encoding="utf-8")
    big = robot_reach(Robot.from_file(MJCF))
    reach = robot_reach(Robot.from_file(small))
    assert reach == pytest.approx(0.4 * big, rel=1e-9)
    st = DesignSettings().for_reach(reach)
    assert st.min_height == pytest.approx(0.5 * reach / 2.5) and st.min_radius == pytest.approx(reach / 2.5)
    given = DesignSettings(min_radius=0.2).for_reach(reach)
    assert given.min_radius == 0.2 and given.min_height == st.min_height
    assert InfoEngine(*paper).settings.min_radius == 1.0  # the engine applies them


def test_min_height_is_a_scenario_setting(tmp_path, paper):
    """[design] min_height = 1.0 rejects Table 5's q2 = 120, q3 = 30 pose (wrist at z = 0.51 m),
    which the default 0.5 m accepts."""
    text = PAPER.read_text() + "\n[design]\nmin_height = 1.0\ncandidates = 50\n"
    path = tmp_path / "high.toml"
    path.write_text(text.replace('robot = "../mjcf/', f'robot = "{ROOT}/mjcf/'))
    scn, st = load_design_scenario(path)
    assert st.min_height == 1.0 and st.candidates == 50
    q = np.radians([180, 120, 30, -135, 30, -135])
    assert "min_height" in InfoEngine(scn, st).pose(q, WEIGHT).violations
    assert "min_height" not in InfoEngine(*paper).pose(q, WEIGHT).violations
    bad = tmp_path / "bad.toml"
    bad.write_text(path.read_text() + "min_heigth = 2\n")
    from calbench.bench.core import InputError

    with pytest.raises(InputError, match="design.min_heigth"):
        read_design_settings(bad)


def test_candidates_are_all_feasible(engine, cands):
    for i in range(0, len(cands), 97):
        info = engine.pose(cands.q[i], cands.wrench[i])
        assert info.violations == []
        # the candidates are computed batched: the same blocks up to the finite-difference noise both
        # carry (tests/test_design_batch.py)
        np.testing.assert_allclose(info.block, cands.blocks[i], rtol=0, atol=1e-6 * np.abs(info.block).max())
    assert 0 < cands.kind.sum() < len(cands)  # both vertical loads and lateral pulls


# ------------------------------------------------------------------------------ information


def test_exported_blocks_reproduce_the_fisher_information_of_a_plan(tmp_path, paper):
    """NPZ from the CLI; information of 6 of its candidates against identify/core/forward.py's IFT
    Jacobian on the campaign of those 6 poses (an independent code path)."""
    scn, _ = paper
    npz = tmp_path / "c.npz"
    assert (
        main(
            ["design", str(PAPER), "--export-candidates", str(npz), "--candidates", "60", "--processes", "1"]
        )
        == 0
    )
    z = np.load(npz)
    assert z["q"].shape == (60, 6) and z["blocks"].shape[0] == 60 and z["blocks"].shape[2] == 8
    pick = [0, 7, 13, 21, 34, 55]
    if not (z["load_kind"][pick] == "lateral").any():
        pick[-1] = int(np.flatnonzero(z["load_kind"] == "lateral")[0])
    F = information(z["blocks"], pick)
    poses = [
        PlanPose(np.radians(z["q"][i]), z["wrench"][i], int(z["load_kind"][i] == "lateral"), None)
        for i in pick
    ]
    path = _scenario_with_poses(scn, poses, tmp_path)
    s2 = load_scenario(path)
    rb = truth_robot(s2)
    obs = from_campaign(simulate(s2, None, robot=rb))
    model_rb = Robot.from_file(s2.robot)
    _, J = ForwardModel(model_rb, design_from_observations(model_rb, obs)).evaluate(z["theta0"])
    jw = np.einsum("mij,mjk->mik", whiten_factors(obs.cov), J).reshape(-1, 8) * z["theta0"]
    np.testing.assert_allclose(F, jw.T @ jw, rtol=1e-6, atol=1e-6 * np.abs(F).max())


def test_measures_definitions():
    rng = np.random.default_rng(0)
    R = rng.standard_normal((20, 8))
    F = R.T @ R
    C = np.linalg.inv(F)
    G = rng.standard_normal((3, 8))
    m = measures(F, G)
    assert m["A"] == pytest.approx(np.trace(C))
    assert m["D"] == pytest.approx(np.linalg.det(C) ** (1 / 8))
    assert m["AD"] == pytest.approx(0.5 * m["A"] + 0.5 * m["D"])
    assert m["pose"] == pytest.approx(np.trace(G @ C @ G.T))
    assert measures(F[:7, :7].copy() * 0 + np.eye(7) * 0, None)["A"] == np.inf


# ------------------------------------------------------------------------------ exchange


@pytest.mark.parametrize("crit", ["A", "D", "AD", "pose"])
def test_exchange_beats_its_starts_and_updates_equal_recomputation(cands, engine, paper, crit):
    scn, _ = paper
    G = engine.work_jacobian(np.radians([30, 60, 0, 0, -60, 0]), [-1600, 800, 900, 0, 0, 0])
    ex = Exchanger(cands.blocks, crit, G)
    r = ex.optimise(12, n_random=3, seed=2)
    assert r.value <= min(r.start_values) * (1 + 1e-9)
    assert r.value == pytest.approx(criterion_value(crit, information(cands.blocks, r.idx), G), rel=1e-9)
    assert r.updated_value == pytest.approx(r.value, rel=1e-6)  # ridge 1e-9 of the mean information
    # one low-rank step from a plan equals the recomputation; the bounded scan equals the full one
    idx = r.idx[:11]
    P, ld, tr = ex.state(idx)
    j, v = ex.scan(P, ld, tr)
    full = ex.scan(P, ld, tr, full=True)
    assert j == int(np.argmin(full)) and v == pytest.approx(full.min(), rel=1e-12)
    for k in (0, 5, j):
        plan = np.append(idx, k)
        F = information(cands.blocks, plan) + ex.ridge * np.eye(8)
        scratch = criterion_value(crit, F, G)
        assert full[k] == pytest.approx(scratch, rel=1e-7)  # F is conditioned ~1e6-1e8
    # removal (downdate) then re-adding the same block restores the inverse
    P2, ld2 = ex._update(P, ld, ex.T[idx[3]], -1)
    P3, ld3 = ex._update(P2, ld2, ex.T[idx[3]], +1)
    np.testing.assert_allclose(P3, P, rtol=1e-8, atol=1e-10 * np.abs(P).max())
    assert ld3 == pytest.approx(ld, rel=1e-10)


def test_exchange_is_better_than_random_plans(cands):
    ex = Exchanger(cands.blocks, "A")
    r = ex.optimise(12, n_random=2)
    rng = np.random.default_rng(5)
    rand = [
        criterion_value("A", information(cands.blocks, rng.choice(len(cands), 12, replace=False)))
        for _ in range(50)
    ]
    assert r.value < 0.5 * np.median(rand)


# ------------------------------------------------------------------------------ CLI and Monte Carlo


def test_design_out_writes_a_scenario_that_simulate_accepts(tmp_path):
    plan, js, log = tmp_path / "plan.toml", tmp_path / "plan.json", tmp_path / "plan.mcap"
    rc = main(
        [
            "design",
            str(PAPER),
            "--configs",
            "8",
            "--criterion",
            "D",
            "--out",
            str(plan),
            "--json",
            str(js),
            "--candidates",
            "150",
            "--starts",
            "1",
            "--processes",
            "1",
        ]
    )
    assert rc == 0
    doc = tomllib.loads(plan.read_text())
    assert sum(p.get("repeats", 1) for p in doc["pose"]) == 8
    out = json.loads(js.read_text())
    assert out["configs"] == 8 and set(out["measures"]["relative_std"]) >= {"k1", "compensator_preload"}
    assert main(["simulate", str(plan), "--out", str(log)]) == 0
    assert log.stat().st_size > 0


def test_pose_criterion_without_work_is_bad_input(tmp_path, capsys):
    import re

    text = PAPER.read_text().replace('"../mjcf/', f'"{PAPER.parent.parent / "mjcf"}/')
    no_work = re.sub(r"\n\[work\]\n(?:[^\[\n][^\n]*\n|\n)*", "\n", text)
    assert "[work]" in text and "[work]" not in no_work
    scn = tmp_path / "no_work.toml"
    scn.write_text(no_work)
    rc = main(
        [
            "design",
            str(scn),
            "--configs",
            "4",
            "--criterion",
            "pose",
            "--out",
            str(tmp_path / "x.toml"),
            "--candidates",
            "20",
            "--processes",
            "1",
        ]
    )
    assert rc == 2
    assert "work" in capsys.readouterr().err
    assert not (tmp_path / "x.toml").exists()


def test_predicted_trace_matches_monte_carlo(tmp_path, paper, cands, engine):
    """O1 (trace of the normalised covariance) of an A-optimal plan of 12 against the trace of the
    one-step estimator's empirical covariance over N = 150 noise seeds."""
    scn, _ = paper
    N = 150
    r = Exchanger(cands.blocks, "A").optimise(12, n_random=1)
    poses = [PlanPose(cands.q[i], cands.wrench[i], int(cands.kind[i]), cands.blocks[i]) for i in r.idx]
    path = _scenario_with_poses(scn, poses, tmp_path)
    C = np.linalg.inv(information(cands.blocks, r.idx))
    mc = run_montecarlo(load_scenario(path), N, methods=("one-step",), progress=False)
    est = mc.estimates["one-step"] / mc.truth
    emp = np.cov(est.T, ddof=1)
    se = np.sqrt(2 * np.trace(C @ C) / (N - 1))
    assert abs(np.trace(emp) - np.trace(C)) < 4 * se, (np.trace(emp), np.trace(C), se)
    # and per parameter, against the variance's own sampling error
    ratio = np.diag(emp) / np.diag(C)
    assert np.all(np.abs(ratio - 1) < 4 * np.sqrt(2 / (N - 1))), ratio


def test_a_small_candidate_set_is_not_mistaken_for_an_infeasible_setup(tmp_path):
    """Candidates come in batches of sampled commands; asking for few must not trip the
    'settings leave no feasible configurations' guard once enough have been found."""
    rc = main(
        [
            "design",
            str(PAPER),
            "--configs",
            "4",
            "--criterion",
            "A",
            "--out",
            str(tmp_path / "x.toml"),
            "--candidates",
            "20",
            "--processes",
            "1",
        ]
    )
    assert rc == 0
    assert (tmp_path / "x.toml").exists()
