"""Tests of bench/view.py (`calbench view`): the .rrd it writes is valid, holds the expected
entities, and its arrows are the magnified deflections of the log.

The rerun CLI runs with a scratch HOME / XDG dirs, CI=1 and analytics off (as in
tests/test_logformat.py), so it never touches the user's settings.
"""
from __future__ import annotations

import json
import shutil
import subprocess
import time
from pathlib import Path

import mujoco
import numpy as np
import pytest
import rerun as rr
from rerun.chunk import RrdReader

from calbench.bench.campaign import run_campaign
from calbench.bench.errors import InputError
from calbench.bench.geoms import geom_shapes
from calbench.bench.idreport import IdentificationReport
from calbench.bench.logformat import read_log, strip_truth
from calbench.bench.scenario import TrackerSpec, load_scenario
from calbench.bench.tracker import to_world_frame
from calbench.bench.view import _geom_archetype, measured_deflections, write_recording
from calbench.identify.cli import main as calbench_main

from rerun_cli import rerun_env, rerun_exe
from conftest import PAPER



@pytest.fixture(autouse=True)
def scratch_home(tmp_path, monkeypatch):
    """Also the in-process SDK: scratch HOME, CI=1 (no viewer is ever spawned), no analytics."""
    for k, v in rerun_env(tmp_path).items():
        if k in ("HOME", "XDG_CONFIG_HOME", "XDG_DATA_HOME", "XDG_CACHE_HOME", "CI",
                 "RERUN_ANALYTICS"):
            monkeypatch.setenv(k, v)


@pytest.fixture(scope="module")
def paper_log(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("view") / "paper_table5.mcap"
    run_campaign(load_scenario(PAPER), out)
    return out


@pytest.fixture(scope="module")
def paper_rrd(paper_log) -> Path:
    rrd = paper_log.with_name("paper.rrd")
    t0 = time.perf_counter()
    write_recording(paper_log, rrd)
    print(f"\nwrite_recording(paper campaign): {time.perf_counter() - t0:.2f} s")
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
            for p, v in zip(column(c, "pose"), column(c, component)):
                out[p] = v
    return out


def expected_deflection(log_path: Path, pose: int, reflector: str) -> np.ndarray:
    """Mean loaded minus mean unloaded world position of one reflector, straight from the log."""
    log = read_log(log_path)
    t = log.header["tracker"]
    spec = TrackerSpec(position=np.asarray(t["position"], float), yaw=float(t["yaw"]))
    mean = {}
    for state in ("unloaded", "loaded"):
        pts = [m.position[m.reflectors.index(reflector)] for m in log.measurements
               if m.pose == pose and m.state == state and m.visible[m.reflectors.index(reflector)]]
        mean[state] = to_world_frame(spec, np.mean(pts, axis=0)[None])[0]
    return mean["loaded"] - mean["unloaded"]


# ---------------------------------------------------------------------------------------------


def test_rrd_verifies_and_has_the_expected_entities(paper_rrd, tmp_path):
    exe = rerun_exe()
    r = subprocess.run([exe, "rrd", "verify", str(paper_rrd)], env=rerun_env(tmp_path),
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    r = subprocess.run([exe, "rrd", "print", str(paper_rrd)], env=rerun_env(tmp_path),
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    printed = r.stdout
    for e in ("/robot/unloaded/forearm", "/robot/loaded/link6/tool_plate",
              "/robot/unloaded/upper_arm/upper_arm_geom", "/robot/unloaded/tendon/compensator",
              "/tracker", "/measured/loaded/uncertainty_3sigma", "/deflection/x200/measured",
              "/truth/reflectors/loaded", "/truth/deflection/x200",
              "/plots/deflection_mm/refl_a", "/viewport"):
        assert f"- {e} -" in printed, e
    # loaded back through the SDK: the same entities, and geometry for every drawn body
    paths = entity_paths(paper_rrd)
    model = mujoco.MjModel.from_xml_string(read_log(paper_rrd.with_name("paper_table5.mcap"))
                                           .mjcf_text)
    for b in range(1, model.nbody):
        for state in ("unloaded", "loaded"):
            assert f"/robot/{state}/{model.body(b).name}" in paths
    assert "/parameters/table" not in paths  # no --identified


def test_arrow_is_the_magnified_deflection_of_the_log(paper_log, paper_rrd):
    vectors = rows_at(paper_rrd, "/deflection/x200/measured", "Arrows3D:vectors")
    labels = rows_at(paper_rrd, "/deflection/x200/measured", "Arrows3D:labels")
    log = read_log(paper_log)
    assert sorted(vectors) == log.complete_poses
    pose = 3
    names = [lab.split()[0] for lab in labels[pose]]
    j = names.index("refl_b")
    expected = 200.0 * expected_deflection(paper_log, pose, "refl_b")
    np.testing.assert_allclose(vectors[pose][j], expected.astype(np.float32), rtol=2e-7,
                               atol=1e-9)
    # the label states the magnification and the true-scale size
    assert labels[pose][j] == f"refl_b {np.linalg.norm(expected) / 200 * 1e3:.3f} mm (x200)"
    # and every arrow matches measured_deflections()
    d = measured_deflections(log)
    for p, vec in vectors.items():
        for lab, v in zip(labels[p], vec):
            np.testing.assert_allclose(v, 200 * d[p][lab.split()[0]], rtol=1e-6, atol=1e-8)


def test_magnify_and_truth_free_log(paper_log, tmp_path):
    """A stripped (real-campaign) log: no truth tree, the robot at the rigid configuration."""
    stripped = tmp_path / "real.mcap"
    strip_truth(paper_log, stripped)
    rrd = tmp_path / "real.rrd"
    s = write_recording(stripped, rrd, magnify=50)
    assert not s.truth and "rigid" in s.robot_source
    paths = entity_paths(rrd)
    assert not any(p.startswith("/truth") for p in paths)
    assert "/deflection/x50/measured" in paths
    vec = rows_at(rrd, "/deflection/x50/measured", "Arrows3D:vectors")
    write_recording(paper_log, tmp_path / "full.rrd")
    full = rows_at(tmp_path / "full.rrd", "/deflection/x200/measured", "Arrows3D:vectors")
    np.testing.assert_allclose(np.array(vec[0]) * 4, full[0], rtol=1e-6)
    # rigid configuration: both states draw the same robot
    tu = rows_at(rrd, "/robot/unloaded/link6", "Transform3D:translation")
    tl = rows_at(rrd, "/robot/loaded/link6", "Transform3D:translation")
    np.testing.assert_array_equal(tu[0], tl[0])


def write_identified(path: Path, log_path: Path, predictions: bool, full: bool = True) -> Path:
    names = ["k1", "k2", "k3", "k4", "k5", "k6", "compensator_stiffness", "compensator_preload"]
    truth = [0.25e-6, 0.12e-6, 0.07e-6, 0.35e-6, 0.40e-6, 0.60e-6, 2.6e6, 0.83]
    params = []
    for n, t in zip(names, truth):
        p = {"name": n, "estimate": t * 1.01}
        if full:
            p.update(unit="rad/(N*m)", std=abs(t) * 0.02, truth=t)
        params.append(p)
    doc: dict = {"method": "one-step", "parameters": params}
    if predictions:
        d = measured_deflections(read_log(log_path))
        doc["observations"] = [{"pose": p, "reflector": r, "predicted": (0.9 * v).tolist()}
                               for p, refl in d.items() for r, v in refl.items()]
        doc["observations"].append({"pose": 0, "reflector": "refl_a"})  # malformed: skipped
    path.write_text(json.dumps(doc))
    return path


def test_identified_with_predictions(paper_log, tmp_path, capsys):
    ident = write_identified(tmp_path / "id.json", paper_log, predictions=True)
    rrd = tmp_path / "id.rrd"
    s = write_recording(paper_log, rrd, identified=ident)
    assert s.predicted == s.arrows
    assert any("1 entries" in w for w in s.warnings)   # the command line prints these
    paths = entity_paths(rrd)
    for e in ("/deflection/x200/predicted", "/deflection/x200/residual",
              "/plots/residual_mm/refl_a", "/parameters/compliance/estimate",
              "/parameters/compliance/std", "/parameters/compliance/truth",
              "/parameters/relative_std_percent", "/parameters/z_score", "/parameters/table"):
        assert e in paths, e
    meas = rows_at(rrd, "/deflection/x200/measured", "Arrows3D:vectors")
    res = rows_at(rrd, "/deflection/x200/residual", "Arrows3D:vectors")
    np.testing.assert_allclose(res[2], 0.1 * np.array(meas[2]), rtol=1e-5, atol=1e-7)
    bars = [c for c in chunks(rrd) if c.entity_path == "/parameters/compliance/estimate"]
    values = [col for col in bars[0].to_record_batch().schema.names if "values" in col]
    assert values


def test_identified_minimal_report(paper_log, tmp_path):
    """Only name and estimate per parameter (no std, truth, unit, observations)."""
    ident = write_identified(tmp_path / "id.json", paper_log, predictions=False, full=False)
    rrd = tmp_path / "id.rrd"
    s = write_recording(paper_log, rrd, identified=ident)
    assert s.predicted == 0
    paths = entity_paths(rrd)
    assert "/parameters/compliance/estimate" in paths and "/parameters/table" in paths
    assert "/parameters/z_score" not in paths and "/deflection/x200/predicted" not in paths


def test_identified_report_with_an_unidentifiable_parameter(paper_log, tmp_path):
    """identify writes estimate null for a parameter the campaign cannot identify (a truncated
    log without the lateral pulls: k1); the viewer draws the rest."""
    ident = write_identified(tmp_path / "id.json", paper_log, predictions=False)
    doc = json.loads(ident.read_text())
    doc["parameters"][0].update(estimate=None, std=None, identifiable=False, reason="vertical")
    ident.write_text(json.dumps(doc))
    s = write_recording(paper_log, tmp_path / "id.rrd", identified=ident)
    assert s.poses == 16
    paths = entity_paths(tmp_path / "id.rrd")
    assert "/parameters/table" in paths and "/parameters/z_score" in paths


def test_cli_writes_next_to_the_log_without_display(paper_log, tmp_path, capsys, monkeypatch):
    log = tmp_path / "logs" / "demo.mcap"
    log.parent.mkdir()
    shutil.copy(paper_log, log)
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert calbench_main(["view", str(log)]) == 0
    out = capsys.readouterr().out
    assert (tmp_path / "logs" / "demo.rrd").exists()
    assert "no display" in out and f"rerun {tmp_path / 'logs' / 'demo.rrd'}" in out
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
    for text in ("{not json", json.dumps({"method": "x"}),
                 json.dumps({"parameters": [{"name": "k1"}]})):
        bad.write_text(text)
        assert calbench_main(["view", str(paper_log), "--rrd", str(out),
                              "--identified", str(bad)]) == 2
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
    kinds = {}
    shapes = {s.name: s for s in geom_shapes(model)}
    for shape in shapes.values():
        for wire in (False, True):
            a = _geom_archetype(rr, shape, wire)
            kinds[(shape.name, wire)] = type(a).__name__ if a is not None else None
    assert kinds[("box", False)] == "Boxes3D" and kinds[("cap", False)] == "Capsules3D"
    assert kinds[("cyl", False)] == "Cylinders3D" and kinds[("sph", False)] == "Ellipsoids3D"
    assert kinds[("ell", True)] == "Ellipsoids3D" and kinds[("msh", False)] == "Mesh3D"
    assert kinds[("msh", True)] == "LineStrips3D" and "pln" not in shapes
    # the capsule starts at one end of its segment (rerun capsules grow along +z)
    cap = _geom_archetype(rr, shapes["cap"], False)
    start = np.asarray(cap.translations.as_arrow_array().to_pylist()[0])
    ends = [np.zeros(3), np.array([1.0, 0, 0])]
    assert min(np.linalg.norm(start - e) for e in ends) < 1e-6


def test_report_tolerates_optional_fields(tmp_path):
    p = tmp_path / "id.json"
    p.write_text(json.dumps({"parameters": [{"name": "k2", "estimate": 1e-7, "std": None,
                                             "truth": None}],
                             "observations": "not a list"}))
    ident = IdentificationReport.read(p)
    assert ident.parameters[0].std is None and ident.predictions() == {}
    assert ident.read_warnings


def _quat_xyzw_to_mat(q) -> np.ndarray:
    x, y, z, w = q
    m = np.empty(9)
    mujoco.mju_quat2Mat(m, np.array([w, x, y, z], float))
    return m.reshape(3, 3)


def test_logged_body_pose_places_geoms_where_mujoco_does(paper_log, paper_rrd):
    """Body Transform3D (world from body) composed with the geom's pose in the body frame
    gives MuJoCo's geom pose at the true equilibrium (checks the wxyz -> xyzw handling)."""
    log = read_log(paper_log, include_truth=True)
    model = mujoco.MjModel.from_xml_string(log.mjcf_text)
    data = mujoco.MjData(model)
    pose = 5
    data.qpos[:] = log.truth.joints[pose].loaded.qpos
    mujoco.mj_kinematics(model, data)
    t = rows_at(paper_rrd, "/robot/loaded/link6", "Transform3D:translation")[pose]
    q = rows_at(paper_rrd, "/robot/loaded/link6", "Transform3D:quaternion")[pose]
    R = _quat_xyzw_to_mat(q[0] if np.ndim(q) == 2 else q)
    (box,) = [c for c in chunks(paper_rrd) if c.entity_path == "/robot/loaded/link6/tool_plate"]
    center = np.asarray(column(box, "Boxes3D:centers")[0][0])
    gq = column(box, "Boxes3D:quaternions")[0][0]
    g = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "tool_plate")
    np.testing.assert_allclose(np.ravel(t) + R @ center, data.geom_xpos[g], atol=1e-5)
    np.testing.assert_allclose(R @ _quat_xyzw_to_mat(gq), data.geom_xmat[g].reshape(3, 3),
                               atol=1e-5)


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
