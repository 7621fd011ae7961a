"""Masses estimated from collision geometry at a stated density (issue 21), held to MuJoCo's own
computation of the same bodies (``inertiafromgeom``; meshes with its exact mesh inertia), and
marked ASSUMED wherever they show: from-urdf's notes and summary, the MJCF's header and
``calbench:assumed_masses``, check-robot.
"""

from __future__ import annotations

import re

import mujoco
import numpy as np
import pytest
from shared_data import shared_data
from urdf_robots import FANUC_TOOL, arm_overlay, arm_urdf, convert_arm

from calbench.bench.model import Robot
from calbench.identify.cli import main

LINKS = ["link_1", "link_2", "link_3", "link_4", "link_5", "link_6"]


def _no_inertials(text: str) -> str:
    return re.sub(r"\s*<inertial>.*?</inertial>", "", text, flags=re.S)


def _mujoco_masses(urdf_text: str, density: float, exact_meshes: bool = False) -> mujoco.MjModel:
    """MuJoCo's own filling of the collision geometry (the independent computation)."""
    spec = mujoco.MjSpec.from_string(urdf_text)
    spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_TRUE
    spec.compiler.fusestatic = False
    for g in spec.geoms:
        g.density = density
    if exact_meshes:
        for mesh in spec.meshes:
            mesh.inertia = mujoco.mjtMeshInertia.mjMESH_INERTIA_EXACT
    return spec.compile()


def _tensor(m: mujoco.MjModel, body: int) -> np.ndarray:
    r = np.zeros(9)
    mujoco.mju_quat2Mat(r, m.body_iquat[body])
    r = r.reshape(3, 3)
    return r @ np.diag(m.body_inertia[body]) @ r.T


def test_boxes_and_cylinders_at_a_density_match_mujocos_filling(tmp_path, capsys):
    """The tests' arm (boxes, cylinders, one laid along x by an rpy) without inertials, at
    2700 kg/m^3: every link's mass, centre and inertia tensor as MuJoCo computes them, to
    rounding; marked ASSUMED in the notes, the summary, the header and the description."""
    urdf = _no_inertials(arm_urdf())
    rc, out = convert_arm(tmp_path, urdf, "assumed_density = 2700.0\n" + arm_overlay())
    err = capsys.readouterr()
    assert rc == 0, err.err
    assert "note: link_3: mass" in err.err and "ASSUMED: its collision geometry" in err.err
    assert "(ASSUMED for link_1 link_2 link_3 link_4 link_5 link_6" in err.out
    ours = mujoco.MjModel.from_xml_path(str(out))
    ref = _mujoco_masses(urdf, 2700.0)
    for name in LINKS:
        a, b = ours.body(name).id, ref.body(name).id
        assert ours.body_mass[a] == pytest.approx(ref.body_mass[b], rel=1e-12)
        np.testing.assert_allclose(ours.body_ipos[a], ref.body_ipos[b], atol=1e-12)
        np.testing.assert_allclose(
            _tensor(ours, a), _tensor(ref, b), rtol=1e-10, atol=1e-10 * ref.body_mass[b]
        )
    text = out.read_text(encoding="utf-8")
    assert "ASSUMED, estimated from the collision geometry filled at a stated density" in text
    assert Robot.from_file(out).description.assumed_masses == tuple(LINKS)
    assert main(["check-robot", str(out), "--grid", "1", "--sample", "0"]) == 0
    assert "masses ASSUMED (a guess, not the maker's" in capsys.readouterr().out


def test_a_link_table_density_and_given_masses_mix(tmp_path, capsys):
    """One link estimated ([inertials.link_2] density), another given, the rest the URDF's."""
    urdf = arm_urdf()
    extra = (
        "\n[inertials.link_2]\ndensity = 7850.0\n\n[inertials.link_4]\nmass = 61.0\ncom = [0.1, 0.0, 0.0]\n"
    )
    rc, out = convert_arm(tmp_path, urdf, arm_overlay(extra=extra))
    assert rc == 0, capsys.readouterr().err
    m = mujoco.MjModel.from_xml_path(str(out))
    ref = _mujoco_masses(_no_inertials(urdf), 7850.0)
    assert m.body("link_2").mass[0] == pytest.approx(ref.body("link_2").mass[0], rel=1e-12)
    assert m.body("link_4").mass[0] == 61.0 and m.body("link_3").mass[0] == 300.0
    assert Robot.from_file(out).description.assumed_masses == ("link_4", "link_2")


def test_density_and_a_mass_in_one_table_exit_2(tmp_path, capsys):
    extra = "\n[inertials.link_2]\ndensity = 7850.0\nmass = 10.0\ncom = [0.0, 0.0, 0.0]\n"
    rc, out = convert_arm(tmp_path, arm_urdf(), arm_overlay(extra=extra))
    assert rc == 2 and not out.exists()
    assert "arm.toml: inertials.link_2.density: expected either a density" in capsys.readouterr().err


def test_an_open_mesh_is_named_approximate():
    from calbench.bench.robots import is_closed, mesh_moments

    verts = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    faces = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])  # outward
    vol, first, _ = mesh_moments(verts, faces)
    assert vol == pytest.approx(1 / 6) and np.allclose(first / vol, 0.25)
    assert is_closed(faces) and not is_closed(faces[:3])


def test_the_fanuc_meshes_at_a_density_match_mujocos_exact_mesh_inertia(tmp_path, capsys):
    """The FANUC M-900iB/700's collision meshes (../shared/data), every moving link filled at
    2000 kg/m^3: mass, centre and inertia as MuJoCo's exact mesh inertia gives them (float32
    vertices: to 1e-6)."""
    xacro = shared_data("robots", "fanuc_m900ib_support", "urdf", "m900ib700.xacro")
    overlay = "assumed_density = 2000.0\n" + FANUC_TOOL
    (tmp_path / "f.toml").write_text(overlay, encoding="utf-8")
    out = tmp_path / "f.xml"
    assert main(["from-urdf", str(xacro), "--overlay", str(tmp_path / "f.toml"), "--out", str(out)]) == 0
    assert "(a mesh not closed" not in capsys.readouterr().err
    ours = mujoco.MjModel.from_xml_path(str(out))
    # MuJoCo fills the same meshes, inlined in our MJCF, in the frames they are drawn in
    spec = mujoco.MjSpec.from_file(str(out))
    spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_TRUE
    for g in spec.geoms:
        g.density = 2000.0
    for mesh in spec.meshes:
        mesh.inertia = mujoco.mjtMeshInertia.mjMESH_INERTIA_EXACT
    ref = spec.compile()
    for name in LINKS + ["plink_1", "plink_2"]:
        a = ours.body(name).id
        assert ours.body_mass[a] == pytest.approx(ref.body_mass[a], rel=1e-6)
        np.testing.assert_allclose(ours.body_ipos[a], ref.body_ipos[a], atol=1e-6)
        np.testing.assert_allclose(
            _tensor(ours, a), _tensor(ref, a), atol=1e-6 * np.abs(_tensor(ref, a)).max()
        )


@pytest.mark.parametrize(
    ("typed", "key", "mistake"),
    [
        ("assumed_density = 7.85\n", "assumed_density", "g/cm^3 written as kg/m^3? (7.85e+03 kg/m^3)"),
        ("assumed_density = 7.85e6\n", "assumed_density", "denser than any metal"),
    ],
)
def test_a_density_in_the_wrong_unit_exits_2_naming_it(tmp_path, capsys, typed, key, mistake):
    rc, out = convert_arm(tmp_path, _no_inertials(arm_urdf()), typed + arm_overlay())
    err = capsys.readouterr().err
    assert rc == 2 and not out.exists()
    assert f"arm.toml: {key}: expected a density in kg/m^3" in err and mistake in err, err
