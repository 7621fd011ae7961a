"""Tests of bench/view/recording.py (`calbench view`) and the discover view: the .rrd verifies, holds the
expected entities, its arrows are the magnified deflections of the log, its ghosts the magnified
joint deflections, the truth appears only under truth/, and the blueprint opens where a
first-time user needs it.

The rerun CLI runs with a scratch HOME / XDG dirs, CI=1 and analytics off (tests/rerun_cli.py),
so it never touches the user's settings. Recordings store float32: positions of a few metres
read back to ~1e-6 m, which bounds the tolerances below.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import mujoco
import numpy as np
import pytest
import rerun as rr
from conftest import K_TRUE, MJCF, PAPER
from rerun.chunk import RrdReader
from rerun_cli import rerun_env, rerun_exe

from calbench.bench.campaign import run_campaign
from calbench.bench.core import InputError
from calbench.bench.log import IdentificationReport, read_log, strip_truth
from calbench.bench.model import Robot, geom_shapes, reflector_posts
from calbench.bench.scenario import load_scenario
from calbench.bench.tracker import TrackerSpec, to_world_frame
from calbench.bench.view import (
    HALF_FOV_TAN,
    WIDTH,
    Discovery,
    build_blueprint,
    framing,
    geom_archetype,
    measured_deflections,
    plan_view,
    write_discovery_recording,
    write_recording,
)
from calbench.identify.cli import main as calbench_main

F32 = 2e-6  # m: float32 resolution of world coordinates of a few metres, with margin
TRUE = [*K_TRUE, 2.6e6, 0.83]  # the paper scenario's truth, SI
BASE = ["k1", "k2", "k3", "k4", "k5", "k6", "compensator_stiffness", "compensator_preload"]


@pytest.fixture(autouse=True)
def scratch_home(tmp_path, monkeypatch):
    """Also the in-process SDK: scratch HOME, CI=1 (no viewer is ever spawned), no analytics."""
    for k, v in rerun_env(tmp_path).items():
        if k in ("HOME", "XDG_CONFIG_HOME", "XDG_DATA_HOME", "XDG_CACHE_HOME", "CI", "RERUN_ANALYTICS"):
            monkeypatch.setenv(k, v)


@pytest.fixture(scope="module")
def paper_log(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("view") / "paper_table5.mcap"
    run_campaign(load_scenario(PAPER), out)
    return out


@pytest.fixture(scope="module")
def stripped_log(paper_log) -> Path:
    out = paper_log.with_name("real.mcap")
    strip_truth(paper_log, out)
    return out


@pytest.fixture(scope="module")
def paper_rrd(paper_log) -> Path:
    rrd = paper_log.with_name("paper.rrd")
    write_recording(paper_log, rrd)
    return rrd


def chunks(rrd: Path) -> list:
    return list(RrdReader(rrd).stream())


def entity_paths(rrd: Path) -> set[str]:
    return {c.entity_path for c in chunks(rrd)}


def column(chunk, name: str) -> list:
    b = chunk.to_record_batch()
    return b.column(b.schema.names.index(name)).to_pylist()


def rows_at(rrd: Path, entity: str, component: str) -> dict[int, list]:
    """pose -> value of `component` logged on `entity` at that pose."""
    out: dict[int, list] = {}
    for c in chunks(rrd):
        if c.entity_path == entity and not c.is_static:
            names = c.to_record_batch().schema.names
            if component in names:
                for p, v in zip(column(c, "pose"), column(c, component)):
                    out[p] = v
    return out


def page_at(rrd: Path, pose: int) -> str:
    """The markdown of the pose page."""
    return text(rows_at(rrd, "/info/pose", "TextDocument:text")[pose])


def text(v) -> str:
    """A TextDocument's text as read back (a one-element list)."""
    return v[0] if isinstance(v, list) else v


def static(rrd: Path, entity: str, component: str):
    for c in chunks(rrd):
        if c.entity_path == entity and c.is_static and component in c.to_record_batch().schema.names:
            return column(c, component)[0]
    raise KeyError((entity, component))


def expected_deflection(log_path: Path, pose: int, reflector: str) -> np.ndarray:
    """Mean loaded minus mean unloaded world position of one reflector, straight from the log."""
    log = read_log(log_path)
    t = log.header["tracker"]
    spec = TrackerSpec(position=np.asarray(t["position"], float), yaw=float(t["yaw"]))
    mean = {}
    for state in ("unloaded", "loaded"):
        pts = [
            m.position[m.reflectors.index(reflector)]
            for m in log.measurements
            if m.pose == pose and m.state == state and m.visible[m.reflectors.index(reflector)]
        ]
        mean[state] = to_world_frame(spec, np.mean(pts, axis=0)[None])[0]
    return mean["loaded"] - mean["unloaded"]


def body_pose(rrd: Path, entity: str, pose: int) -> tuple[np.ndarray, np.ndarray]:
    """World translation and rotation matrix of a body entity's Transform3D at a pose."""
    t = rows_at(rrd, entity, "Transform3D:translation")[pose]
    q = rows_at(rrd, entity, "Transform3D:quaternion")[pose]
    q = q[0] if np.ndim(q) == 2 else q
    m = np.empty(9)
    mujoco.mju_quat2Mat(m, np.array([q[3], q[0], q[1], q[2]], float))
    return np.ravel(t), m.reshape(3, 3)


def kinematics(log_path: Path, qpos: np.ndarray, body: str) -> tuple[np.ndarray, np.ndarray]:
    """MuJoCo's world pose of `body` at `qpos` of the log's own MJCF."""
    model = mujoco.MjModel.from_xml_string(read_log(log_path).mjcf_text)
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_kinematics(model, data)
    b = model.body(body).id
    return data.xpos[b].copy(), data.xmat[b].reshape(3, 3).copy()


def write_identified(
    path: Path,
    log_path: Path,
    predictions: bool,
    full: bool = True,
    factor: float = 1.01,
    truth: bool = True,
    extra: dict | None = None,
) -> Path:
    """A report of the paper's parameters at `factor` times the truth (std 2 %); predictions
    0.9 times the log's measured deflections."""
    params = []
    for n, t in zip(BASE, TRUE):
        p = {"name": n, "estimate": t * factor}
        if full:
            p.update(
                unit={"compensator_stiffness": "N/m", "compensator_preload": "m"}.get(n, "rad/(N*m)"),
                std=abs(t) * 0.02,
                truth=t if truth else None,
            )
        params.append(p)
    if extra:
        params.append(extra)
    doc: dict = {"method": "one-step", "parameters": params}
    if predictions:
        d = measured_deflections(read_log(log_path))
        doc["observations"] = [
            {"pose": p, "reflector": r, "predicted": (0.9 * v).tolist()}
            for p, refl in d.items()
            for r, v in refl.items()
        ]
        doc["observations"].append({"pose": 0, "reflector": "refl_a"})  # malformed: skipped
    path.write_text(json.dumps(doc))
    return path


# --------------------------------------------------------------------------- the recording


def test_rrd_verifies_and_has_the_expected_entities(paper_rrd, tmp_path):
    exe = rerun_exe()
    r = subprocess.run(
        [exe, "rrd", "verify", str(paper_rrd)],
        env=rerun_env(tmp_path),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    r = subprocess.run(
        [exe, "rrd", "print", str(paper_rrd)],
        env=rerun_env(tmp_path),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    printed = r.stdout
    for e in (
        "/robot/forearm",
        "/robot/link6/tool_plate",
        "/robot/link6/reflectors/refl_a",
        "/robot/upper_arm/upper_arm_geom",
        "/robot/tendon/compensator",
        "/robot/payload",
        "/tracker",
        "/tracker/line_of_sight",
        "/measured/loaded",
        "/measured/unloaded",
        "/deflection/x200/measured",
        "/deflection/x200/uncertainty_3sigma",
        "/truth/reflectors/loaded",
        "/truth/deflection/x200",
        "/truth/deformed_x200/forearm",
        "/plots/deflection_mm/refl_a",
        "/info/pose",
        "/viewport",
        "/time_panel",
    ):
        assert f"- {e} -" in printed, e
    # loaded back through the SDK: the same entities, and geometry for every drawn body
    paths = entity_paths(paper_rrd)
    model = mujoco.MjModel.from_xml_string(read_log(paper_rrd.with_name("paper_table5.mcap")).mjcf_text)
    for b in range(1, model.nbody):
        assert f"/robot/{model.body(b).name}" in paths
    assert not any(p.startswith(("/parameters", "/model", "/residual")) for p in paths)


def test_arrow_is_the_magnified_deflection_of_the_log(paper_log, paper_rrd):
    vectors = rows_at(paper_rrd, "/deflection/x200/measured", "Arrows3D:vectors")
    origins = rows_at(paper_rrd, "/deflection/x200/measured", "Arrows3D:origins")
    labels = rows_at(paper_rrd, "/deflection/x200/measured", "Arrows3D:labels")
    log = read_log(paper_log)
    assert sorted(vectors) == log.complete_poses
    pose = 3
    names = [lab.split()[0] for lab in labels[pose]]
    j = names.index("refl_b")
    expected = 200.0 * expected_deflection(paper_log, pose, "refl_b")
    np.testing.assert_allclose(vectors[pose][j], expected.astype(np.float32), rtol=2e-7, atol=1e-9)
    # the (hover) label gives the true-scale size; the 3D view shows no text on arrows
    assert labels[pose][j] == f"refl_b measured {np.linalg.norm(expected) / 200 * 1e3:.3f} mm"
    shown = rows_at(paper_rrd, "/deflection/x200/measured", "Arrows3D:show_labels")[pose]
    assert np.ravel(shown).tolist() == [False]
    # every arrow matches measured_deflections() and starts at the measured unloaded reflector
    d = measured_deflections(log)
    unloaded = rows_at(paper_rrd, "/measured/unloaded", "Points3D:positions")
    for p, vec in vectors.items():
        for lab, v, o in zip(labels[p], vec, origins[p]):
            np.testing.assert_allclose(v, 200 * d[p][lab.split()[0]], rtol=1e-6, atol=1e-8)
            assert min(np.linalg.norm(np.array(unloaded[p]) - o, axis=1)) < F32


def test_robot_is_drawn_at_the_command(paper_log, paper_rrd):
    """The robot (outside truth/) stands at the rigid closed loop of the commanded angles, not
    at the true equilibrium; the measured reflectors sit by the sag from its posts."""
    log = read_log(paper_log, include_truth=True)
    robot = Robot.from_xml(log.mjcf_text)
    pose = 5
    q = log.poses[pose].unloaded
    t, R = body_pose(paper_rrd, "/robot/link6", pose)
    x, M = kinematics(paper_log, robot.rigid_qpos(q), "link6")
    np.testing.assert_allclose(t, x, atol=F32)
    np.testing.assert_allclose(R, M, atol=1e-6)
    x_true, _ = kinematics(paper_log, log.truth.joints[pose].unloaded.qpos, "link6")
    assert np.linalg.norm(x_true - x) > 1e-3  # the sag: the two differ by centimetres


def test_truth_ghost_is_the_magnified_joint_deflection(paper_log, paper_rrd, tmp_path):
    """truth/deformed_x200: motor angles q + d_u + 200 (d_l - d_u) from /truth/joints, passive
    joints by the loop; at x1 it is the true loaded equilibrium itself (the parallelogram's
    closure holds at any motor angles, so nothing is lost by rebuilding the passive joints)."""
    log = read_log(paper_log, include_truth=True)
    robot = Robot.from_xml(log.mjcf_text)
    pose = 8
    q = np.asarray(log.poses[pose].unloaded)
    du, dl = log.truth.joints[pose].unloaded.deflection, log.truth.joints[pose].loaded.deflection
    x, M = kinematics(paper_log, robot.rigid_qpos(q + du + 200.0 * (dl - du)), "link6")
    t, R = body_pose(paper_rrd, "/truth/deformed_x200/link6", pose)
    np.testing.assert_allclose(t, x, atol=F32)
    np.testing.assert_allclose(R, M, atol=1e-6)
    # the magnified deformation is large: the ghost's tool is tens of cm off the robot's
    assert np.linalg.norm(t - body_pose(paper_rrd, "/robot/link6", pose)[0]) > 0.1
    one = tmp_path / "x1.rrd"
    write_recording(paper_log, one, magnify=1.0)
    x, M = kinematics(paper_log, log.truth.joints[pose].loaded.qpos, "link6")
    t, R = body_pose(one, "/truth/deformed_x1/link6", pose)
    np.testing.assert_allclose(t, x, atol=F32)
    np.testing.assert_allclose(R, M, atol=1e-6)


def test_no_truth_outside_the_truth_tree(paper_log, stripped_log, tmp_path):
    """Hiding truth/ leaves exactly what a real campaign shows: every entity outside truth/ has
    the same data whether the log (and the report) carry truth or not. Only the pose page's
    legend differs, since it names what is drawn."""

    def content(rrd: Path) -> dict:
        out = {}
        for c in chunks(rrd):
            if c.entity_path.startswith(("/truth", "/__properties")):
                continue
            b = c.to_record_batch()
            for name in b.schema.names:
                if name.startswith("rerun.") or name in ("pose", "log_time", "log_tick"):
                    continue
                vals = column(c, name)
                if name == "TextDocument:text":
                    vals = [text(v).split("**In the 3D view**")[0] for v in vals]
                key = (c.entity_path, name, c.is_static)
                out.setdefault(key, []).extend(
                    zip(column(c, "pose") if not c.is_static else [None] * len(vals), vals)
                )
        return {k: sorted(v, key=lambda t: -1 if t[0] is None else t[0]) for k, v in out.items()}

    full, real = tmp_path / "full.rrd", tmp_path / "real.rrd"
    (tmp_path / "t").mkdir()
    (tmp_path / "r").mkdir()
    write_recording(paper_log, full, write_identified(tmp_path / "t/id.json", paper_log, True))
    write_recording(
        stripped_log, real, write_identified(tmp_path / "r/id.json", paper_log, True, truth=False)
    )
    a, b = content(full), content(real)
    assert a.keys() == b.keys()
    for k in a:
        assert a[k] == b[k], k
    paths = entity_paths(full)
    assert {"/truth/parameters/table", "/truth/deformed_x200/forearm"} <= paths
    assert not any(p.startswith("/truth") for p in entity_paths(real))


def test_magnify_and_truth_free_log(paper_log, stripped_log, paper_rrd, tmp_path):
    """A stripped (real-campaign) log: no truth tree, no ghost; --magnify scales the arrows."""
    rrd = tmp_path / "real.rrd"
    s = write_recording(stripped_log, rrd, magnify=50)
    assert not s.truth and s.ghost == "none"
    paths = entity_paths(rrd)
    assert not any(p.startswith(("/truth", "/model")) for p in paths)
    assert "/deflection/x50/measured" in paths
    vec = rows_at(rrd, "/deflection/x50/measured", "Arrows3D:vectors")
    full = rows_at(paper_rrd, "/deflection/x200/measured", "Arrows3D:vectors")
    np.testing.assert_allclose(np.array(vec[0]) * 4, full[0], rtol=1e-6)
    page = page_at(rrd, 0)
    assert "no ghost" in page and "--identified" in page


# --------------------------------------------------------------------------- --identified


def test_model_ghost_from_the_truth_values_is_the_truth_ghost(paper_log, stripped_log, tmp_path):
    """The model's ghost comes from the statics with the report's estimates. With estimates
    equal to the truth it must coincide with the true ghost (the same statics made the log);
    it is drawn for a real campaign too, where no true ghost exists."""
    ident = write_identified(tmp_path / "id.json", paper_log, False, factor=1.0)
    rrd = tmp_path / "m.rrd"
    s = write_recording(paper_log, rrd, ident)
    assert "identified model" in s.ghost and "truth" in s.ghost
    for pose in (0, 8, 12):
        t, R = body_pose(rrd, "/model/deformed_x200/link6", pose)
        tt, RR = body_pose(rrd, "/truth/deformed_x200/link6", pose)
        # statics solved to 1e-10 relative: the joint deflections agree to ~1e-12 rad, x200
        np.testing.assert_allclose(t, tt, atol=F32)
        np.testing.assert_allclose(R, RR, atol=1e-6)
    real = tmp_path / "real.rrd"
    assert write_recording(stripped_log, real, ident).ghost == "the identified model"
    t, _ = body_pose(real, "/model/deformed_x200/link6", 8)
    np.testing.assert_allclose(t, body_pose(rrd, "/model/deformed_x200/link6", 8)[0], atol=F32)
    # the blueprint hides the true ghost beside the model's (it would sit on top of it)
    bp = build_blueprint(plan_view(read_log(paper_log, include_truth=True), IdentificationReport.read(ident)))
    scene = bp.root_container.contents[0]
    assert "/truth/deformed_x200" in scene.visualizer_overrides


def test_no_model_ghost_for_parameters_it_cannot_pose(stripped_log, paper_log, tmp_path):
    extra = {"name": "forearm_cx", "unit": "rad/(N*m)", "estimate": 1e-7, "std": 1e-8}
    ident = write_identified(tmp_path / "id.json", paper_log, False, extra=extra)
    rrd = tmp_path / "x.rrd"
    assert write_recording(stripped_log, rrd, ident).ghost == "none"
    assert not any(p.startswith("/model") for p in entity_paths(rrd))
    page = page_at(rrd, 0)
    assert "model ghost: none" in page and "forearm_cx" in page


def test_identified_with_predictions(paper_log, tmp_path):
    ident = write_identified(tmp_path / "id.json", paper_log, predictions=True)
    rrd = tmp_path / "id.rrd"
    s = write_recording(paper_log, rrd, identified=ident)
    assert s.predicted == s.arrows
    assert any("1 entries" in w for w in s.warnings)  # the command line prints these
    paths = entity_paths(rrd)
    for e in (
        "/deflection/x200/model",
        "/residual/x2000/model",
        "/residual/x2000/noise_3sigma",
        "/plots/residual_um/model",
        "/plots/residual_um/noise",
        "/parameters/table",
        "/parameters/chart/0_µrad__N_m/estimate",
        "/truth/parameters/table",
    ):
        assert e in paths, e
    meas = rows_at(rrd, "/deflection/x200/measured", "Arrows3D:vectors")
    start = rows_at(rrd, "/deflection/x200/measured", "Arrows3D:origins")
    res = rows_at(rrd, "/residual/x2000/model", "Arrows3D:vectors")
    res_o = rows_at(rrd, "/residual/x2000/model", "Arrows3D:origins")
    pose = 2
    # residual = measured - 0.9 measured, magnified 2000 = 10 x the arrows' 200
    np.testing.assert_allclose(res[pose], 10 * 0.1 * np.array(meas[pose]), rtol=1e-5, atol=1e-6)
    # and it ends at the measured arrow's tip
    np.testing.assert_allclose(
        np.array(res_o[pose]) + res[pose], np.array(start[pose]) + meas[pose], atol=F32
    )
    # the residual plot: RMS per axis of the pose's residuals, in um
    rms = rows_at(rrd, "/plots/residual_um/model", "Scalars:scalars")[pose]
    d = measured_deflections(read_log(paper_log))[pose]
    expect = 1e6 * np.sqrt(np.mean([(0.1 * v) ** 2 for v in d.values()]))
    assert np.ravel(rms)[0] == pytest.approx(expect, rel=1e-9)
    # the pose page carries the numbers: residual of refl_a in um
    page = page_at(rrd, pose)
    assert f"{np.linalg.norm(0.1 * d['refl_a']) * 1e6:.0f} µm" in page


def test_parameter_chart_names_every_parameter_and_reads_back(paper_log, tmp_path):
    """Each parameter is named in the chart, and its dot sits where the block's tick labels
    say its estimate is (in display units: µrad/(N·m), kN/m, mm)."""
    ident = write_identified(tmp_path / "id.json", paper_log, predictions=False)
    rrd = tmp_path / "id.rrd"
    write_recording(paper_log, rrd, identified=ident)
    shown = {"k1": 0.25 * 1.01, "compensator_stiffness": 2600 * 1.01, "compensator_preload": 830 * 1.01}
    texts = []
    for c in chunks(rrd):
        if (
            c.entity_path.startswith("/parameters/chart")
            and "Points2D:labels" in c.to_record_batch().schema.names
        ):
            texts += column(c, "Points2D:labels")[0]
    for n in BASE[:6]:
        assert n in texts
    assert "compensator_stiffness (kN/m)" in texts and "compensator_preload (mm)" in texts
    for block, name in (
        ("0_µrad__N_m", "k1"),
        ("1_kN_m", "compensator_stiffness"),
        ("2_mm", "compensator_preload"),
    ):
        base = f"/parameters/chart/{block}"
        ticks = [float(t) for t in static(rrd, f"{base}/ticks", "Points2D:labels")]
        labels = static(rrd, f"{base}/estimate", "Points2D:labels")
        dots = static(rrd, f"{base}/estimate", "Points2D:positions")
        x = dots[[lab.split(" = ")[0] for lab in labels].index(name)][0]
        value = ticks[0] + x / WIDTH * (ticks[-1] - ticks[0])
        assert value == pytest.approx(shown[name], rel=1e-5)
    table = text(static(rrd, "/parameters/table", "TextDocument:text"))
    assert "µrad/(N·m)" in table and "kN/m" in table and "truth" not in table.lower()
    # against the truth: z = (1.01 t - t) / (0.02 t) = +0.50 for every parameter
    assert "+0.50" in text(static(rrd, "/truth/parameters/table", "TextDocument:text"))


def test_identified_minimal_report(paper_log, tmp_path):
    """Only name and estimate per parameter (no std, truth, unit, observations)."""
    ident = write_identified(tmp_path / "id.json", paper_log, predictions=False, full=False)
    rrd = tmp_path / "id.rrd"
    s = write_recording(paper_log, rrd, identified=ident)
    assert s.predicted == 0
    paths = entity_paths(rrd)
    assert "/parameters/table" in paths and "/parameters/chart/0_unitless/estimate" in paths
    assert "/truth/parameters/table" not in paths and "/deflection/x200/model" not in paths


def test_identified_report_with_an_unidentifiable_parameter(paper_log, tmp_path):
    """identify writes estimate null for a parameter the campaign cannot identify (k1 without
    the lateral pulls); the chart says so, and the model ghost takes it as rigid."""
    ident = write_identified(tmp_path / "id.json", paper_log, predictions=False)
    doc = json.loads(ident.read_text())
    doc["parameters"][0].update(estimate=None, std=None, identifiable=False, reason="vertical")
    ident.write_text(json.dumps(doc))
    rrd = tmp_path / "id.rrd"
    s = write_recording(paper_log, rrd, identified=ident)
    assert s.poses == 16 and "identified model" in s.ghost
    assert static(rrd, "/parameters/chart/0_µrad__N_m/not_identifiable", "Points2D:labels") == [
        "not identifiable"
    ]
    page = page_at(rrd, 0)
    assert "k1 not identified: taken as rigid" in page


# --------------------------------------------------------------------------- first open


def test_blueprint_opens_at_pose_0_framing_robot_tool_and_tracker(paper_log, tmp_path):
    log = read_log(paper_log, include_truth=True)
    plan = plan_view(log)
    bp = build_blueprint(plan)
    assert bp.time_panel.timeline == "pose" and bp.time_panel.play_state == "paused"
    assert bp.blueprint_panel.state == "collapsed" and bp.selection_panel.state == "collapsed"
    scene = bp.root_container.contents[0]
    assert "×200" in scene.name
    eye = scene.properties["EyeControls3D"]
    # the camera: every body, arrow tip and the tracker inside its field of view
    e, target = framing(plan.scenes, log.tracker_spec().position, 200.0)
    np.testing.assert_allclose(np.ravel(eye.position.as_arrow_array().to_pylist()), e, rtol=1e-6)
    # every pose: stepping through them never takes the tool out of view
    pts = [log.tracker_spec().position[None]]
    for s in plan.scenes:
        d, _, ok = s.deflection()
        pts += [s.robot.xpos[1:], s.measured["unloaded"][ok] + 200 * d[ok]]
    pts = np.vstack(pts)
    fwd = (target - e) / np.linalg.norm(target - e)
    right = np.cross(fwd, [0, 0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    rel = pts - e
    depth = rel @ fwd
    assert np.all(depth > 0)
    assert np.all(np.abs(rel @ right) <= HALF_FOV_TAN * depth + 1e-9)
    assert np.all(np.abs(rel @ up) <= HALF_FOV_TAN * depth + 1e-9)
    # and it is tight: some point touches the edge
    assert np.max(np.maximum(np.abs(rel @ right), np.abs(rel @ up)) / depth) == pytest.approx(
        HALF_FOV_TAN, rel=1e-6
    )


def _screen_x(eye, target, p):
    """Screen x of p in half-widths of the view, and its depth, for a camera at eye on target."""
    fwd = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(fwd, [0, 0, 1.0])
    right /= np.linalg.norm(right)
    depth = (p - eye) @ fwd
    return (p - eye) @ right / depth / HALF_FOV_TAN, depth


@pytest.mark.parametrize("scenario", ["paper_table5.toml", "kr270_paper.toml"])
def test_the_tracker_stands_beyond_the_tool_and_apart_from_it(scenario, tmp_path):
    """On first open the tracker's tripod does not stand across the tool's arrows: at least
    TRACKER_APART half-widths to the side of the tool on screen, and farther from the eye. The
    FANUC's profile view already does that (the camera looks across the arm's plane: unchanged);
    on the KR 270 the profile put the tracker 0.05 half-widths behind the tool, and the camera
    turns by the least 5-degree step that sets them apart."""
    from calbench.bench.view import TRACKER_APART

    log_path = tmp_path / "c.mcap"
    run_campaign(load_scenario(PAPER.parent / scenario), log_path)
    log = read_log(log_path, include_truth=True)
    plan = plan_view(log)
    tracker = log.tracker_spec().position
    eye, target = framing(plan.scenes, tracker, 200.0)
    tool = np.nanmean(plan.scenes[0].reflector_sites, axis=0)
    (xt, dt), (xk, dk) = _screen_x(eye, target, tool), _screen_x(eye, target, tracker)
    assert abs(xk - xt) >= TRACKER_APART and dk > dt
    if scenario == "paper_table5.toml":  # in profile: across the arm's plane
        arm = tool[:2] - plan.scenes[0].robot.xpos[1][:2]
        assert abs((eye - target)[:2] @ arm) < 1e-9 * np.linalg.norm(arm) * np.linalg.norm(eye - target)


def test_reflector_posts_and_payload_are_drawn(paper_log, paper_rrd):
    model = mujoco.MjModel.from_xml_string(read_log(paper_log).mjcf_text)
    shapes = geom_shapes(model)
    sites = [model.site(n).id for n in ("refl_a", "refl_b", "refl_c")]
    plate = next(s for s in shapes if s.name == "tool_plate")
    for post in reflector_posts(model, shapes, sites):
        np.testing.assert_allclose(post.end, model.site_pos[post.site])
        # it leaves the tool plate (a box) from its surface, at the point nearest the reflector
        local = post.start - plate.pos
        assert np.all(np.abs(local) <= plate.size + 1e-12)
        assert np.any(np.isclose(np.abs(local), plate.size))
        strip = static(paper_rrd, f"/robot/link6/reflectors/{post.name}", "LineStrips3D:strips")
        np.testing.assert_allclose(strip[0], [post.start, post.end], atol=1e-6)
    # the payload of pose 0 (700 kg): a steel block of that mass below the payload site
    half = rows_at(paper_rrd, "/robot/payload", "Boxes3D:half_sizes")[0]
    assert (2 * half[0][0]) ** 3 * 7850.0 == pytest.approx(700.0, rel=1e-5)
    # the lateral pull of pose 12 (1.2 kN in y): an arrow along it
    pull = rows_at(paper_rrd, "/robot/payload", "Arrows3D:vectors")[12]
    np.testing.assert_allclose(np.ravel(pull), [0, 1200 * 4e-4, 0], atol=1e-6)


# --------------------------------------------------------------------------- discover


def test_discovery_view(paper_log, tmp_path):
    """Residuals before (user's model) and after (with the effects), both ending at the
    measured tips; the verdict on every pose's page names the worst (pose, reflector)."""
    d = measured_deflections(read_log(paper_log))

    def report(frac: float, rms: float) -> IdentificationReport:
        obs = [
            {"pose": p, "reflector": r, "predicted": (frac * v).tolist()}
            for p, refl in d.items()
            for r, v in refl.items()
        ]
        doc = {
            "method": "discover",
            "residual_rms": rms,
            "expected_residual_rms": 27e-6,
            "parameters": [{"name": n, "estimate": t, "unit": ""} for n, t in zip(BASE, TRUE)],
            "observations": obs,
        }
        return IdentificationReport.from_json(json.dumps(doc))

    disc = Discovery(report(0.8, 300e-6), report(0.99, 25e-6), ("link_compliance (forearm)",))
    rrd = tmp_path / "d.rrd"
    s = write_discovery_recording(paper_log, rrd, disc)
    assert s.poses == 16
    before = rows_at(rrd, "/residual/x2000/before", "Arrows3D:vectors")
    after = rows_at(rrd, "/residual/x2000/after", "Arrows3D:vectors")
    meas = rows_at(rrd, "/deflection/x200/measured", "Arrows3D:vectors")
    np.testing.assert_allclose(before[4], 2000 * 0.2 * np.array(meas[4]) / 200, rtol=1e-5)
    np.testing.assert_allclose(after[4], 2000 * 0.01 * np.array(meas[4]) / 200, rtol=1e-4, atol=1e-6)
    page = page_at(rrd, 4)
    assert "named link_compliance (forearm)" in page and "300.0 µm → 25.0 µm" in page
    # the worst residual of the user's model, found independently: largest 0.2 |d| / sigma
    plan = plan_view(read_log(paper_log, include_truth=True))
    worst = max(
        (
            (np.sqrt(0.2 * v @ np.linalg.solve(sc.deflection()[1][i], 0.2 * v)), p, r)
            for sc in plan.scenes
            for p, refl in d.items()
            if p == sc.index
            for i, (r, v) in enumerate((nm, refl[nm]) for nm in plan.names if nm in refl)
        ),
        key=lambda t: t[0],
    )
    assert f"pose {worst[1]} {worst[2]} ({worst[0]:.1f}σ)" in page
    assert {"/plots/residual_um/before", "/plots/residual_um/after"} <= entity_paths(rrd)


def test_cli_discover_writes_its_view(paper_log, tmp_path, capsys):
    log = tmp_path / "p.mcap"
    shutil.copy(paper_log, log)
    js = tmp_path / "d.json"
    assert calbench_main(["discover", str(log), "--json", str(js)]) == 0
    out = capsys.readouterr().out
    rrd = tmp_path / "d.rrd"
    assert rrd.exists() and f"rerun {rrd}" in out
    assert json.loads(js.read_text())["view_rrd"] == str(rrd)
    assert {"/residual/x2000/before", "/residual/x2000/after", "/parameters/table"} <= entity_paths(rrd)
    # an existing output is refused (exit 2) before any work
    assert calbench_main(["discover", str(log), "--rrd", str(log)]) == 2


# --------------------------------------------------------------------------- command line


def test_cli_writes_next_to_the_log_without_display(paper_log, tmp_path, capsys, monkeypatch):
    log = tmp_path / "logs" / "demo.mcap"
    log.parent.mkdir()
    shutil.copy(paper_log, log)
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert calbench_main(["view", str(log)]) == 0
    out = capsys.readouterr().out
    assert (tmp_path / "logs" / "demo.rrd").exists()
    # without a display: Rerun's web viewer, port forwarding, the Vulkan note and the telemetry
    assert "no display" in out and f"rerun --web-viewer {tmp_path / 'logs' / 'demo.rrd'}" in out
    assert "ssh -L 9090:localhost:9090" in out and "lavapipe" in out and "rerun analytics disable" in out
    rrd = tmp_path / "x" / "out.rrd"
    assert calbench_main(["view", str(log), "--rrd", str(rrd), "--magnify", "500"]) == 0
    assert "/deflection/x500/measured" in entity_paths(rrd)


def test_bad_input_exits_2(paper_log, tmp_path, capsys):
    not_mcap = tmp_path / "x.mcap"
    not_mcap.write_text("hello")
    out = tmp_path / "o.rrd"
    assert calbench_main(["view", str(not_mcap), "--rrd", str(out)]) == 2
    assert "MCAP" in capsys.readouterr().err and not out.exists()
    assert calbench_main(["view", str(tmp_path / "missing.mcap"), "--rrd", str(out)]) == 2
    # an MCAP without the tracker channel
    from mcap.writer import Writer

    bare = tmp_path / "bare.mcap"
    with open(bare, "wb") as f:
        w = Writer(f)
        w.start()
        w.register_channel("/campaign/info", "json", 0)
        w.finish()
    with pytest.raises(InputError, match="/campaign/pose|/tracker/measurement"):
        write_recording(bare, out)
    assert calbench_main(["view", str(bare), "--rrd", str(out)]) == 2
    bad = tmp_path / "bad.json"
    for text in ("{not json", json.dumps({"method": "x"}), json.dumps({"parameters": [{"name": "k1"}]})):
        bad.write_text(text)
        assert calbench_main(["view", str(paper_log), "--rrd", str(out), "--identified", str(bad)]) == 2
        assert str(bad) in capsys.readouterr().err
    assert not out.exists()
    assert calbench_main(["view", str(paper_log), "--rrd", str(out), "--magnify", "0"]) == 2


def test_every_geom_type_is_drawn():
    xml = """<mujoco><asset><mesh name="tet" vertex="0 0 0 1 0 0 0 1 0 0 0 1"/></asset>
      <worldbody><body name="b" pos="1 2 3">
        <geom name="box" type="box" size="0.1 0.2 0.3"/>
        <geom name="cap" type="capsule" fromto="0 0 0 1 0 0" size="0.1"/>
        <geom name="cyl" type="cylinder" size="0.1 0.5"/>
        <geom name="sph" type="sphere" size="0.2"/>
        <geom name="ell" type="ellipsoid" size="0.1 0.2 0.3"/>
        <geom name="msh" type="mesh" mesh="tet"/>
        <geom name="pln" type="plane" size="1 1 1"/>
      </body></worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    shapes = {s.name: s for s in geom_shapes(model)}
    kinds = {name: type(geom_archetype(rr, shape)).__name__ for name, shape in shapes.items()}
    assert kinds == {
        "box": "Boxes3D",
        "cap": "Capsules3D",
        "cyl": "Cylinders3D",
        "sph": "Ellipsoids3D",
        "ell": "Ellipsoids3D",
        "msh": "Mesh3D",
    }
    ghost = geom_archetype(rr, shapes["box"], (1, 2, 3, 80))
    assert ghost.colors.as_arrow_array().to_pylist() == [0x01020350]
    # the capsule starts at one end of its segment (rerun capsules grow along +z)
    cap = geom_archetype(rr, shapes["cap"])
    start = np.asarray(cap.translations.as_arrow_array().to_pylist()[0])
    ends = [np.zeros(3), np.array([1.0, 0, 0])]
    assert min(np.linalg.norm(start - e) for e in ends) < 1e-6


def test_report_tolerates_optional_fields(tmp_path):
    p = tmp_path / "id.json"
    p.write_text(
        json.dumps(
            {
                "parameters": [{"name": "k2", "estimate": 1e-7, "std": None, "truth": None}],
                "observations": "not a list",
            }
        )
    )
    ident = IdentificationReport.read(p)
    assert ident.parameters[0].std is None and ident.predictions() == {}
    assert ident.read_warnings


def test_logged_body_pose_places_geoms_where_mujoco_does(paper_log, paper_rrd):
    """Body Transform3D (world from body) composed with the geom's pose in the body frame
    gives MuJoCo's geom pose at the command (checks the wxyz -> xyzw handling)."""
    log = read_log(paper_log)
    model = mujoco.MjModel.from_xml_string(log.mjcf_text)
    data = mujoco.MjData(model)
    pose = 5
    data.qpos[:] = Robot(model).rigid_qpos(log.poses[pose].unloaded)
    mujoco.mj_kinematics(model, data)
    t, R = body_pose(paper_rrd, "/robot/link6", pose)
    (box,) = [c for c in chunks(paper_rrd) if c.entity_path == "/robot/link6/tool_plate"]
    center = np.asarray(column(box, "Boxes3D:centers")[0][0])
    gq = column(box, "Boxes3D:quaternions")[0][0]
    m = np.empty(9)
    mujoco.mju_quat2Mat(m, np.array([gq[3], gq[0], gq[1], gq[2]], float))
    g = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "tool_plate")
    np.testing.assert_allclose(t + R @ center, data.geom_xpos[g], atol=1e-5)
    np.testing.assert_allclose(R @ m.reshape(3, 3), data.geom_xmat[g].reshape(3, 3), atol=1e-5)


def test_spawn_failure_falls_back_to_a_file(paper_log, tmp_path, capsys, monkeypatch):
    import calbench.bench.cli as cli

    log = tmp_path / "c.mcap"
    shutil.copy(paper_log, log)
    monkeypatch.setattr(cli, "has_display", lambda: True)

    def no_viewer(self, **kw):
        raise RuntimeError("no viewer here")

    monkeypatch.setattr(rr.RecordingStream, "spawn", no_viewer)
    assert calbench_main(["view", str(log)]) == 0
    assert "could not spawn" in capsys.readouterr().err
    assert (tmp_path / "c.rrd").exists()


def test_the_payload_weight_on_the_page_is_under_the_models_gravity(tmp_path):
    """The pose page states a payload's weight m |g| with g from the MJCF's <option gravity>
    (issue 9: no GRAVITY = 9.81 constant). On the Moon, 700 kg weigh 700 x 1.62 = 1.134 kN."""
    xml = MJCF.read_text()
    assert 'gravity="0 0 -9.81"' in xml
    (tmp_path / "moon.xml").write_text(xml.replace('gravity="0 0 -9.81"', 'gravity="0 0 -1.62"'))
    scn = PAPER.read_text()
    assert 'robot = "../mjcf/m900ib700.xml"' in scn
    (tmp_path / "moon.toml").write_text(scn.replace('robot = "../mjcf/m900ib700.xml"', 'robot = "moon.xml"'))
    log, rrd = tmp_path / "moon.mcap", tmp_path / "moon.rrd"
    run_campaign(load_scenario(tmp_path / "moon.toml"), log)
    write_recording(log, rrd)
    assert "700 kg payload at the tool (1.13 kN)" in page_at(rrd, 0)


def test_the_payload_weight_on_earth(paper_rrd):
    assert "700 kg payload at the tool (6.87 kN)" in page_at(paper_rrd, 0)
