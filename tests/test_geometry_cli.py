"""`calbench identify LOG --geometry [--validate HELDOUT.mcap] [--out-model CALIBRATED.xml]`
(docs/contract.md) end to end: a probe series on a UR10 with hidden geometry and joint compliance,
converted to a plan and readings (bench/shopfloor/probe.py), imported as a real campaign is, then
identified; the held-out readings are predicted to the tracker's noise."""

import json
from pathlib import Path

import numpy as np
import pytest

from calbench.bench.shopfloor import ProbeSeries, campaign_files, euler_xyz
from calbench.identify.cli import main
from calbench.identify.geometry import (
    MODELS,
    GeometricModel,
    base_set,
    chain_from_mjcf,
    kind,
    rot,
    translation,
    ur10,
    write_chain_mjcf,
)

SIGMA = 20e-6  # m per axis
TOOL = np.array([0.0, 0.0, 0.109])


def series(q, y) -> ProbeSeries:
    n = len(q)
    return ProbeSeries(
        Path("synthetic.csv"), ur10().joints, np.arange(2, n + 2), q, y, euler_xyz(np.zeros((n, 3))),
        np.full((n, 3), SIGMA), np.zeros((n, 3)), np.full(n, 21.0), np.full((n, 6), np.nan),
    )  # fmt: skip


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    d = tmp_path_factory.mktemp("geometry_cli")
    chain = ur10()
    write_chain_mjcf(d / "ur10.xml", chain, TOOL, name="ur10")
    model = GeometricModel(chain, translation([0.4, -3.2, 0.2]) @ rot(2, 1.2), TOOL)
    rng = np.random.default_rng(11)
    q = rng.uniform(-np.pi, np.pi, (260, 6))
    _, jac = model.jacobian(q, np.zeros(model.size))
    truth = np.zeros(model.size)
    for i in base_set(jac, model.names, MODELS["geometry+compliance"]):
        comp = kind(model.names[i]) == "joint_compliance"
        truth[i] = rng.uniform(3e-6, 3e-5) if comp else rng.choice([-1, 1]) * rng.uniform(1e-3, 3e-3)
    y = model.predict(q, truth) + rng.normal(0, SIGMA, (len(q), 3))
    s = series(q, y)
    for name, rows in (("fit", np.arange(200)), ("held", np.arange(200, 260))):
        plan, readings = campaign_files(s, rows, "ur10.xml", sigma=SIGMA)
        (d / f"{name}.toml").write_text(plan)
        (d / f"{name}.csv").write_text(readings)
        args = [
            "import",
            str(d / f"{name}.csv"),
            "--plan",
            str(d / f"{name}.toml"),
            "--out",
            str(d / f"{name}.mcap"),
        ]
        assert main(args) == 0
    return d


def test_identify_geometry_predicts_held_out_readings_to_the_noise(campaign, capsys):
    d = campaign
    out = ["--json", str(d / "geo.json"), "--out-model", str(d / "cal.xml")]
    assert (
        main(["identify", str(d / "fit.mcap"), "--geometry", "--validate", str(d / "held.mcap"), *out]) == 0
    )
    rep = json.loads((d / "geo.json").read_text())
    assert rep["point"] == "probe" and rep["n"] == 200
    v = rep["validation"]
    assert v["n"] == 60
    # the 3-D RMS of pure noise is sigma sqrt(3); 60 points: its estimate varies by ~1/sqrt(360)
    assert v["position_rms"] < 1.3 * SIGMA * np.sqrt(3)
    # geometry alone leaves the compliance's sag (0.3-3 mrad of joint deflection): mm, not um
    assert v["by_model"]["geometry"]["position_rms"] > 5 * v["position_rms"]
    assert "held-out RMS" in capsys.readouterr().out
    # the calibrated MJCF is a serial calbench arm again
    assert chain_from_mjcf(d / "cal.xml").joints == ur10().joints


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--validate", "held.mcap"], "--geometry beside it"),
        (["--geometry", "--check"], "no --method, --check"),
        (["--geometry", "--out-model", "fit.mcap"], "fit.mcap"),
    ],
)
def test_bad_geometry_flags_are_bad_input(campaign, capsys, extra, message):
    d = campaign
    extra = [str(d / e) if e.endswith(".mcap") else e for e in extra]
    assert main(["identify", str(d / "fit.mcap"), *extra]) == 2
    assert message in capsys.readouterr().err


def test_geometry_reads_logs_without_their_truth(campaign, monkeypatch):
    """Truth never leaks: every log identify --geometry opens is read with include_truth=False."""
    import calbench.bench.log as log_face

    calls = []
    real = log_face.read_log

    def spy(path, *args, **kwargs):
        calls.append(kwargs.get("include_truth", True if not args else args[0]))
        return real(path, *args, **kwargs)

    monkeypatch.setattr("calbench.identify.geometry.run.read_log", spy)
    d = campaign
    assert main(["identify", str(d / "fit.mcap"), "--geometry", "--validate", str(d / "held.mcap")]) == 0
    assert calls == [False, False]


def test_hidden_geometry_and_compliances_match_calbenchs_own_statics(tmp_path):
    """A second solver: calbench's MuJoCo equilibrium (bench/statics) sags a UR10 of known joint
    compliances under its own weight, with joint offsets and a probe off its drawing hidden in the
    truth ([truth.effects.joint_offset], [truth.effects.tool_frame]: MjSpec edits,
    bench/model/effects.py). identify --geometry, with its linear model c_k tau_k at the commanded
    pose (identify/geometry/model.py), must find them within 4 sigma and leave only the noise."""
    write_chain_mjcf(tmp_path / "ur10.xml", ur10(), TOOL, name="ur10")
    k = [1e-6, 1.5e-5, 1e-5, 2e-5, 2e-5, 2e-5]  # rad/(N*m)
    offsets = [0.0, 0.0015, -0.002, 0.0012, -0.0018, 0.0]  # rad: 1-3 mm at the probe
    lines = ['robot = "ur10.xml"', "seed = 1", "[truth]", f"compliance = {k}"]
    lines += ["[truth.effects.joint_offset]", f"offset = {offsets}"]
    lines += ["[truth.effects.tool_frame]", "offset = [0.0, 0.0, 0.002]"]
    lines += ["[truth.effects.link_geometry]", 'link = "link3"', "offset = [0.001, 0, 0, 0.001, 0, 0]"]
    base = [0.01, -0.02, 0.005, 0.002, -0.001, 0.003]  # m, rad: the arm off its drawn place
    lines += ["[truth.effects.base_frame]", f"offset = {base}", "[tracker]"]
    lines += [f"sigma = {SIGMA}", "position = [3.0, 1.0, 0.5]", "[load]", "mass = 2.0"]
    for q in np.random.default_rng(0).uniform(-170, 170, (120, 6)):
        lines += ["[[pose]]", "q = [" + ", ".join(f"{v:.3f}" for v in q) + "]"]
    (tmp_path / "sag.toml").write_text("\n".join(lines) + "\n")
    assert main(["simulate", str(tmp_path / "sag.toml"), "--out", str(tmp_path / "sag.mcap")]) == 0
    out = ["--json", str(tmp_path / "g.json"), "--out-model", str(tmp_path / "cal.xml")]
    assert main(["identify", str(tmp_path / "sag.mcap"), "--geometry", *out]) == 0
    rep = json.loads((tmp_path / "g.json").read_text())
    found = {p["name"].split(".")[0]: p for p in rep["parameters"] if p["effect"] == "joint_compliance"}
    assert set(found) == {"shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint"}
    joints = list(ur10().joints)
    for j, p in found.items():
        truth = k[joints.index(j)]
        assert abs(p["value"] - truth) < 4 * p["std"], (j, p, truth)
    # the offsets the base set holds (the first joint's is the base's turn, the last one's turns
    # a probe on its axis) and the probe's displacement along the flange axis
    fitted = {p["name"]: p for p in rep["parameters"]}
    for j in joints[1:5]:
        p = fitted[f"{j}.offset"]
        assert abs(p["value"] - offsets[joints.index(j)]) < 4 * p["std"], (j, p)
    # each reflector is its own point (the truth's tool_frame moves all three by one vector)
    for pt in ("probe", "probe_aux_x", "probe_aux_y"):
        p = fitted[f"tool.{pt}.z"]
        assert abs(p["value"] - 0.002) < 4 * p["std"], (pt, p)
    # the elbow's link frame (body link3 is joint 3's frame): its base-set share, 1 mm and 1 mrad
    for key, truth in (("tx", 0.001), ("rx", 0.001), ("ry", 0.0)):
        p = fitted[f"elbow_joint.link_{key}"]
        assert abs(p["value"] - truth) < 4 * p["std"], (key, p)
    # the base: the tracker stands at (3, 1, 0.5), unturned, so tracker-from-base is the base's
    # true pose less that; its std: the base translation's and 3 m times the rotation's
    t_b = np.array(rep["tracker_from_base"])[:3, 3]
    sd = np.linalg.norm([fitted[f"base.t{a}"]["std"] for a in "xyz"])
    sd += 3.0 * np.linalg.norm([fitted[f"base.r{a}"]["std"] for a in "xyz"])
    assert np.linalg.norm(t_b - (np.array(base[:3]) - [3.0, 1.0, 0.5])) < 4 * sd
    assert found["shoulder_lift_joint"]["std"] < 0.01 * k[1]  # the shoulder's is well determined
    assert rep["models"]["geometry+compliance"]["fit_rms"] < 1.2 * SIGMA * np.sqrt(3)
    # without the compliance the sag is left: the geometry cannot absorb it
    assert rep["models"]["geometry"]["fit_rms"] > 10 * SIGMA


def test_a_hidden_offset_beyond_a_geometric_error_is_bad_input(tmp_path, capsys):
    write_chain_mjcf(tmp_path / "ur10.xml", ur10(), TOOL, name="ur10")
    lines = ['robot = "ur10.xml"', "seed = 1", "[truth]", "compliance = [1e-6, 1e-6, 1e-6, 1e-6, 1e-6, 1e-6]"]
    lines += ["[truth.effects.joint_offset]", "offset = [0, 5, 0, 0, 0, 0]", "[tracker]", "sigma = 2e-5"]
    lines += ["position = [3.0, 1.0, 0.5]", "[load]", "mass = 2.0", "[[pose]]", "q = [0, 0, 0, 0, 0, 0]"]
    (tmp_path / "bad.toml").write_text("\n".join(lines) + "\n")
    assert main(["simulate", str(tmp_path / "bad.toml"), "--out", str(tmp_path / "bad.mcap")]) == 2
    err = capsys.readouterr().err
    assert "truth.effects.joint_offset.offset" in err and "within +-0.1 rad" in err
    assert not (tmp_path / "bad.mcap").exists()
