"""`calbench discover LOG --geometry` (identify/discover/geometric.py): geometric effects named from
absolute readings on the bench, nothing named where the truth hides none, the candidates reduced to
the base set, and the gravity torques at the model's own deflected pose checked against calbench's
MuJoCo statics (a second solver). The rates over many seeds are benchmarks/geometry_discover_bench.py's."""

import json

import numpy as np
import pytest

from calbench.bench.model import Params, Robot
from calbench.bench.model.effects import DISCOVERY_OPTIONS, GEOMETRY_OPTIONS, discovery_library
from calbench.bench.statics import StaticsSolver
from calbench.identify.cli import main
from calbench.identify.discover import Readings, geometric_library, global_base, reduced
from calbench.identify.geometry import GeometricModel, load_arm, ur10, write_chain_mjcf

SIGMA = 2e-5  # m per axis
TOOL = np.array([0.0, 0.0, 0.109])
OFFSETS = [0.0, 0.0015, -0.002, 0.0012, -0.0018, 0.0]  # rad: 1-3 mm at the probe
COMPLIANCE = [1e-6, 1.5e-5, 1e-5, 2e-5, 2e-5, 2e-5]  # rad/(N*m)


def scenario(path, seed, n, hidden) -> None:
    lines = ['robot = "ur10.xml"', f"seed = {seed}", "[truth]", f"compliance = {COMPLIANCE}"]
    if hidden:
        lines += ["[truth.effects.joint_offset]", f"offset = {OFFSETS}"]
        frame = [0.001, -0.002, 0.0015, 0.001, -0.002, 0.0015]  # m, rad
        lines += ["[truth.effects.link_geometry]", 'link = "link3"', f"offset = {frame}"]
    base = [0.01, -0.02, 0.005, 0.002, -0.001, 0.003]  # the arm off its drawn place: the registration
    lines += ["[truth.effects.base_frame]", f"offset = {base}", "[tracker]"]
    lines += [f"sigma = {SIGMA}", "position = [3.0, 1.0, 0.5]", "[load]", "mass = 2.0"]
    for q in np.random.default_rng(seed).uniform(-170, 170, (n, 6)):
        lines += ["[[pose]]", "q = [" + ", ".join(f"{v:.3f}" for v in q) + "]"]
    path.write_text("\n".join(lines) + "\n")


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("geometry_discover")
    write_chain_mjcf(d / "ur10.xml", ur10(), TOOL, name="ur10")
    for name, seed, n, hidden in (("hidden", 1, 120, True), ("held", 2, 60, True), ("null", 3, 120, False)):
        scenario(d / f"{name}.toml", seed, n, hidden)
        assert main(["simulate", str(d / f"{name}.toml"), "--out", str(d / f"{name}.mcap")]) == 0
    return d


def test_hidden_offsets_and_a_link_frame_are_named_and_held_out_poses_fall_to_the_noise(logs, capsys):
    d = logs
    args = ["discover", str(d / "hidden.mcap"), "--geometry", "--validate", str(d / "held.mcap")]
    assert main([*args, "--json", str(d / "hidden.json"), "--out-model", str(d / "cal.xml")]) == 0
    rep = json.loads((d / "hidden.json").read_text())
    labels = {s["effect"] + (f"[{s['detail']}]" if s["detail"] else "") for s in rep["steps"]}
    assert {"joint_offset", "link_geometry[link3]"} <= labels
    assert "tool_frame" not in labels  # the probe is where the drawing puts it
    # the start (registration + compliances) leaves millimetres on the held-out poses; the named
    # model leaves the noise: the 3-D RMS of pure noise is sigma sqrt(3), estimated from 60 points
    by_step = rep["validation"]["by_step"]
    assert by_step[0]["model"] == "start" and by_step[0]["position_rms"] > 1e-3
    assert rep["validation"]["position_rms"] < 1.3 * SIGMA * np.sqrt(3)
    # the wrists' offsets own no share of the link3 frame's error: they come back within 4 sigma
    fitted = {p["name"]: p for p in rep["parameters"]}
    for k, joint in ((3, "wrist_1_joint"), (4, "wrist_2_joint")):
        p = fitted[f"{joint}.offset"]
        assert abs(p["value"] - OFFSETS[k]) < 4 * p["std"], (joint, p)
    # the classic redundancies are said: the first joint's offset is a turn of the base, the elbow
    # frame's z-turn is the elbow's offset
    said = {r["parameter"]: r for r in rep["redundancies"]}
    assert said["shoulder_pan_joint.offset"]["as"][0][0] == "base.rz"
    assert said["elbow_joint.link_rz"]["as"][0] == ["elbow_joint.offset", pytest.approx(1.0, abs=1e-6)]
    out = capsys.readouterr().out
    assert "named joint_offset" in out and "held-out RMS" in out and "not separable" in out
    # the calibrated arm is a serial calbench MJCF again, with the compliances as joint stiffness
    assert load_arm(d / "cal.xml").chain.joints == ur10().joints


def test_a_campaign_without_geometric_errors_names_nothing(logs, capsys):
    d = logs
    assert main(["discover", str(d / "null.mcap"), "--geometry", "--json", str(d / "null.json")]) == 0
    rep = json.loads((d / "null.json").read_text())
    assert rep["named_effects"] == [] and rep["augmented_model"] is None
    assert not (d / "null.augmented.xml").exists()
    # every candidate was tested, none past its level
    assert {c["effect"] for c in rep["candidates"]} == {"joint_offset", "link_geometry", "tool_frame"}
    assert all(not c.get("accepted") for c in rep["candidates"])
    assert "nothing named" in capsys.readouterr().out


@pytest.mark.parametrize(
    "extra, message",
    [(["--validate", "held.mcap"], "--geometry beside it"), (["--geometry", "--plot", "x.png"], "no plot")],
)
def test_bad_discover_geometry_flags_are_bad_input(logs, capsys, extra, message):
    d = logs
    extra = [str(d / e) if e.endswith(".mcap") else e for e in extra]
    assert main(["discover", str(d / "null.mcap"), *extra]) == 2
    assert message in capsys.readouterr().err


def test_discover_geometry_reads_logs_without_their_truth(logs, monkeypatch):
    import calbench.bench.log as log_face

    calls = []
    real = log_face.read_log

    def spy(path, *args, **kwargs):
        calls.append(kwargs.get("include_truth", True if not args else args[0]))
        return real(path, *args, **kwargs)

    monkeypatch.setattr("calbench.identify.discover.geometric_run.read_log", spy)
    d = logs
    args = ["discover", str(d / "null.mcap"), "--geometry", "--validate", str(d / "held.mcap")]
    assert main(args) == 0
    assert calls == [False, False]


def test_the_geometric_candidates_are_registered_for_absolute_readings_only(tmp_path):
    """discover --geometry's library comes from the registry; deflection discovery's is unchanged."""
    assert set(GEOMETRY_OPTIONS) == {"joint_offset", "tool_frame", "link_geometry"}
    assert not set(GEOMETRY_OPTIONS) & set(DISCOVERY_OPTIONS)
    path = write_chain_mjcf(tmp_path / "ur10.xml", ur10(), TOOL, name="ur10")
    robot = Robot.from_file(path)
    labels = [(e.name, e.detail) for e in discovery_library(robot, "absolute")]
    assert labels == [("joint_offset", ""), ("tool_frame", "")] + [
        ("link_geometry", f"link{k}") for k in range(1, 7)
    ]
    assert not {e.name for e in discovery_library(robot)} & set(GEOMETRY_OPTIONS)


def test_reduced_candidates_share_no_direction_and_make_up_the_base_set(tmp_path):
    """Each candidate keeps its share of the complete base set: together with the registration and
    the compliances they are the base set, of full rank; the first joint's offset (a turn of the
    base) and the last one's (a probe on its axis) are in no candidate."""
    path = write_chain_mjcf(tmp_path / "ur10.xml", ur10(), TOOL, name="ur10")
    arm, robot = load_arm(path), Robot.from_file(path)
    model = GeometricModel(ur10(), np.eye(4), TOOL)
    q = np.random.default_rng(0).uniform(-np.pi, np.pi, (80, 6))
    data = Readings(q, model.predict(q, np.zeros(model.size)), SIGMA, model.torques(q))
    base = global_base(model, data)
    cands = reduced(geometric_library(model, discovery_library(robot, "absolute"), arm.bodies), base)
    owned = [i for c in cands for i in c.indices]
    assert len(owned) == len(set(owned))
    start = [i for i in base if model.names[i].startswith("base.") or model.names[i].endswith(".compliance")]
    assert sorted(owned + start) == sorted(base)
    _, jac = model.jacobian(q, np.zeros(model.size))
    cols = jac.reshape(-1, model.size)[:, base]
    assert np.linalg.matrix_rank(cols / np.linalg.norm(cols, axis=0)) == len(base)
    offsets = {model.names[i] for i in cands[0].indices}
    assert offsets == {f"{j}.offset" for j in ur10().joints[1:5]}
    # the classic count for a probe on the last axis: 27 - 2, as identify --geometry finds
    assert len(base) == 25 + 4  # with the four compliances the robot's weight loads


def test_torques_at_the_deflected_pose_match_calbenchs_statics(tmp_path):
    """The gravity torques at the model's own deflected pose (GeometricModel.torques_at) against a
    second solver: calbench's MuJoCo equilibrium of the same arm with joint springs 1/c. At
    equilibrium k (q - q_cmd) = tau(q), so q - q_cmd = c tau; the nominal torques at q_cmd miss the
    sag's own change of the torques (~1e-3 relative here), which torques_at must not."""
    k = np.array([5e-6, 3e-5, 2e-5, 2e-5, 2e-5, 2e-5])
    path = write_chain_mjcf(tmp_path / "ur10.xml", ur10(), TOOL, name="ur10", compliance=k)
    robot = Robot.from_file(path)
    robot.set_params(Params(k))
    solver = StaticsSolver(robot)
    q = np.random.default_rng(5).uniform(-np.pi, np.pi, (10, 6))
    sag = np.array([solver.solve(row).qpos[robot.act_qpos] - row for row in q])
    model = GeometricModel(ur10(), np.eye(4), TOOL)
    theta = np.zeros(model.size)
    theta[[model.names.index(f"{j}.compliance") for j in ur10().joints]] = k
    at = k * model.torques_at(q, theta)
    nominal = k * model.torques(q)
    scale = np.abs(sag).max()
    np.testing.assert_allclose(at, sag, atol=1e-9 * scale + 1e-12)
    assert np.abs(nominal - sag).max() > 1e-4 * scale  # what the refresh is for
