"""`calbench from-urdf`: a calbench MJCF from a URDF the tests write and an overlay.

End to end through the command line, for a serial arm, the same arm with a spring compensator
across J2, and a quasi-serial variant closed by a parallelogram: from-urdf, simulate, identify
--check. Each identification's |z| < 4 fails by chance with probability ~6e-5 per parameter
(seeds fixed, so the test is deterministic). The conversion is held to independent computations:
site positions to a forward kinematics written here from the URDF's own numbers (URDF rpy =
Rz(yaw) Ry(pitch) Rx(roll), joint motion about the axis in the child frame) to 1e-12 m; masses
equal the URDF's <inertial> values exactly; the parallelogram's passive angles are the exact
sums its geometry dictates; the compensator's triangle (paper Fig. 4) has the l_c, l_2 and angle
the overlay placed. (The statics of such a robot are held to eq. (1) in test_description.py.)
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import mujoco
import numpy as np
import pytest
from urdf_robots import ACTUATED, MOUNTS, TRUTH_K, arm_overlay, arm_urdf, joints, link_masses, scenario

from calbench.bench.model import Robot
from calbench.bench.robots import CONTINUOUS_RANGE, PLACEHOLDER_STIFFNESS
from calbench.identify.cli import main

VARIANTS = {"serial": (False, False), "compensator": (True, False), "loop": (False, True)}


def build(
    folder: Path,
    compensator=False,
    loop=False,
    urdf: str | None = None,
    overlay: str | None = None,
    name: str = "arm",
) -> tuple[int, Path]:
    """Write the URDF and overlay into ``folder``, run from-urdf; (exit status, output path)."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / f"{name}.urdf").write_text(urdf if urdf is not None else arm_urdf(loop=loop))
    (folder / f"{name}.toml").write_text(overlay if overlay is not None else arm_overlay(compensator, loop))
    out = folder / f"{name}.xml"
    rc = main(
        [
            "from-urdf",
            str(folder / f"{name}.urdf"),
            "--overlay",
            str(folder / f"{name}.toml"),
            "--out",
            str(out),
        ]
    )
    return rc, out


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("urdf")
    out = {}
    for tag, (comp, loop) in VARIANTS.items():
        rc, path = build(root / tag, comp, loop)
        assert rc == 0
        out[tag] = path
    return out


# --------------------------------------------------------------------------- end to end


@pytest.mark.parametrize("tag", list(VARIANTS))
def test_a_robot_from_urdf_simulates_and_identifies(built, tag, tmp_path, capsys):
    comp, loop = VARIANTS[tag]
    scn = tmp_path / "scn.toml"
    scn.write_text(scenario(built[tag].as_posix(), compensator=comp, loop=loop))
    log, js = tmp_path / "arm.mcap", tmp_path / "id.json"
    assert main(["simulate", str(scn), "--out", str(log)]) == 0
    assert main(["identify", str(log), "--json", str(js), "--check"]) == 0
    assert "check passed" in capsys.readouterr().out
    rep = json.loads(js.read_text())
    names = [p["name"] for p in rep["parameters"]]
    assert names == [f"k{i + 1}" for i in range(6)] + (
        ["balancer_stiffness", "balancer_preload"] if comp else []
    )
    for p in rep["parameters"]:  # every parameter determined, none skipped by --check
        assert p["estimate"] is not None and p["z"] is not None and abs(p["z"]) < 4.0
    assert [p["truth"] for p in rep["parameters"][:6]] == pytest.approx(TRUTH_K, rel=1e-12)


def test_discovery_names_a_compensator_between_the_mounts_the_overlay_gives(built, tmp_path, capsys):
    """The user's model, built from the URDF with the balancer's mounts but no spring
    (compensator_sites), against a campaign on the robot that has it: discovery names the
    compensator and estimates it within 4 standard deviations of the truth."""
    rc, model = build(tmp_path / "model", overlay=arm_overlay(top=MOUNTS))
    assert rc == 0
    scn = tmp_path / "scn.toml"
    scn.write_text(scenario(built["compensator"].as_posix(), compensator=True))
    log, js = tmp_path / "arm.mcap", tmp_path / "d.json"
    assert main(["simulate", str(scn), "--out", str(log)]) == 0
    assert main(["discover", str(log), "--model", str(model), "--json", str(js)]) == 0
    rep = json.loads(js.read_text())
    assert rep["named_effects"] == ["compensator"]
    est = {p["name"]: p for p in rep["parameters"]}
    for name, truth in (("compensator.K_C", 1.5e6), ("compensator.s0", 0.8)):
        assert abs(est[name]["estimate"] - truth) <= 4.0 * est[name]["std"], est[name]


def test_the_robots_pass_check_robot(built, capsys):
    for path in built.values():
        assert main(["check-robot", str(path)]) == 0
    assert capsys.readouterr().out.count("a calbench robot") == len(built)


# --------------------------------------------------------------------------- the conversion


def _rot(axis, angle) -> np.ndarray:
    x, y, z = np.asarray(axis, float) / np.linalg.norm(axis)
    c, s = math.cos(angle), math.sin(angle)
    k = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
    return np.eye(3) + s * k + (1 - c) * k @ k


def _origin(xyz, rpy) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = _rot((0, 0, 1), rpy[2]) @ _rot((0, 1, 0), rpy[1]) @ _rot((1, 0, 0), rpy[0])
    t[:3, 3] = xyz
    return t


def urdf_fk(q: dict[str, float], loop: bool = False) -> dict[str, np.ndarray]:
    """World pose (4x4) of every link from the URDF table, independently of MuJoCo."""
    poses = {"base_link": np.eye(4)}
    for name, typ, parent, child, xyz, rpy, axis, _ in joints(loop):
        t = poses[parent] @ _origin(xyz, rpy)
        if typ != "fixed":
            m = np.eye(4)
            m[:3, :3] = _rot(axis, q[name])
            t = t @ m
        poses[child] = t
    return poses


def test_sites_sit_where_the_urdf_kinematics_put_them(built):
    robot = Robot.from_file(built["serial"])
    m, d = robot.model, robot.data
    ov = {
        "payload": ("tool0", (0.35, 0, -0.15)),
        "flange": ("tool0", (0, 0, 0)),
        "r1": ("link_6", (0.25, 0.3, 0.25)),
        "r2": ("tool0", (0.15, -0.3, 0.25)),
        "r3": ("tool0", (0.15, 0, -0.35)),
    }
    rng = np.random.default_rng(7)
    for _ in range(5):
        q = rng.uniform(-1.5, 1.5, 6)
        d.qpos[:] = robot.rigid_qpos(q)
        mujoco.mj_kinematics(m, d)
        fk = urdf_fk(dict(zip(ACTUATED, q)))
        for site, (link, pos) in ov.items():
            expected = (fk[link] @ np.array([*pos, 1.0]))[:3]
            np.testing.assert_allclose(d.site(site).xpos, expected, atol=1e-12)


def test_masses_ranges_and_springs_come_from_the_urdf_and_the_overlay(built):
    for tag, (comp, loop) in VARIANTS.items():
        robot = Robot.from_file(built[tag])
        m = robot.model
        for link, mass in link_masses(loop).items():
            assert m.body(link).mass[0] == mass  # exactly the URDF's <inertial>
        assert m.body("tool0").mass[0] == 0.0  # a frame: no mass, none invented
        assert np.all(m.geom_contype == 0) and np.all(m.geom_conaffinity == 0)
        d = robot.description
        assert d.actuated == tuple(ACTUATED) and d.reflectors == ("r1", "r2", "r3")
        assert (d.payload, d.flange) == ("payload", "flange")
        assert d.compensators == (("balancer",) if comp else ()) and d.loops == (
            ("parallelogram",) if loop else ()
        )
        for name, typ, *_, lim in joints(loop):
            if typ == "fixed":
                continue
            j = m.joint(name)
            rng = CONTINUOUS_RANGE if lim is None else np.radians(lim)
            np.testing.assert_allclose(j.range, rng, rtol=1e-15)
            assert j.stiffness[0] == (PLACEHOLDER_STIFFNESS if name in ACTUATED else 0.0)
        passive = [m.joint(j).name for j in robot.passive_joint]
        assert passive == (["elbow", "rod"] if loop else [])


def test_the_same_urdf_and_overlay_give_the_same_bytes(built, tmp_path):
    rc, again = build(tmp_path / "again", compensator=True)
    assert rc == 0 and again.read_bytes() == built["compensator"].read_bytes()


def test_hints_for_design_and_discovery_reach_the_description(tmp_path):
    top = (
        'wrist = "link_5"\nlinks = ["link_2", "link_3"]\nmass_compensators = ["link_1"]\n'
        'compensator_sites = "balancer"\n'
    )
    rc, out = build(tmp_path / "named", compensator=True, overlay=arm_overlay(True, top=top))
    assert rc == 0
    d = Robot.from_file(out).description
    assert (d.wrist, d.links, d.mass_compensators) == ("link_5", ("link_2", "link_3"), ("link_1",))
    assert d.compensator_sites == ("balancer_from", "balancer_to")
    # mounts of their own sit where the spring's ends do on the robot that has one
    rc, mounts = build(tmp_path / "mounts", overlay=arm_overlay(top=MOUNTS))
    assert rc == 0
    a, b = Robot.from_file(mounts), Robot.from_file(out)
    assert a.description.compensator_sites == ("compensator_mount_from", "compensator_mount_to")
    for r in (a, b):
        r.data.qpos[:] = r.rigid_qpos(np.radians([10.0, 20.0, 30.0, 0.0, 0.0, 0.0]))
        mujoco.mj_kinematics(r.model, r.data)
    for x, y in zip(a.description.compensator_sites, b.description.compensator_sites):
        np.testing.assert_array_equal(a.data.site(x).xpos, b.data.site(y).xpos)


def test_the_parallelogram_closes_as_its_geometry_says(built):
    """Crank and upper arm are two sides of a parallelogram: the forearm's absolute pitch is the
    crank angle (q2 + elbow = q3) and the rod stays parallel to the upper arm (q3 + rod = q2)."""
    robot = Robot.from_file(built["loop"])
    m = robot.model
    qa = {n: m.jnt_qposadr[m.joint(n).id] for n in ("joint_2", "joint_3", "elbow", "rod")}
    for q2, q3 in ((0.0, 0.0), (40.0, 10.0), (-30.0, 25.0), (80.0, 30.0)):
        q = np.radians([20.0, q2, q3, 30.0, -20.0, 45.0])
        qpos = robot.rigid_qpos(q)
        assert qpos[qa["joint_2"]] + qpos[qa["elbow"]] == pytest.approx(q[2], abs=1e-12)
        assert qpos[qa["joint_3"]] + qpos[qa["rod"]] == pytest.approx(q[1], abs=1e-12)
        assert robot.loop_ok(q)


def test_the_compensator_triangle_is_the_one_the_overlay_placed(built):
    robot = Robot.from_file(built["compensator"])
    geo = robot.compensator_geometry(0)
    assert geo.joint == 1  # across J2
    assert geo.l_c == pytest.approx(0.9, abs=1e-12) and geo.l_2 == pytest.approx(0.45, abs=1e-12)
    assert abs(geo.offset) == pytest.approx(math.radians(40.0), abs=1e-12)
    p = robot.params().springs["balancer"]
    assert (p.stiffness, p.preload) == (1.5e6, 0.8)


# --------------------------------------------------------------------------- bad input


def _sub(old: str, new: str, compensator=False, loop=False) -> str:
    text = arm_overlay(compensator, loop)
    assert old in text
    return text.replace(old, new, 1)


# case -> (overlay text, URDF text or None, file named, key named)
BAD = {
    "toml syntax": (_sub("[payload]", "[payload"), None, "arm.toml", "line 3"),
    "unknown key": ("reflector = 1\n" + arm_overlay(), None, "arm.toml", "reflector: expected no such key"),
    "actuated missing": (_sub("actuated = ", "# "), None, "arm.toml", "actuated: expected this required key"),
    "actuated unknown": (
        _sub('"joint_6"]', '"joint_7"]'),
        None,
        "arm.toml",
        "actuated[5]: expected a revolute",
    ),
    "actuated fixed": (_sub('"joint_6"]', '"tool0_joint"]'), None, "arm.toml", "actuated[5]"),
    "actuated twice": (
        _sub('"joint_2"', '"joint_1"'),
        None,
        "arm.toml",
        "actuated[1]: expected each joint once",
    ),
    "a joint left free": (
        _sub(', "joint_6"]', "]"),
        None,
        "arm.toml",
        "actuated: expected every moving joint",
    ),
    "unknown link": (
        _sub('link = "tool0"', 'link = "tool9"'),
        None,
        "arm.toml",
        "payload.link: expected a link",
    ),
    "short pos": (
        _sub("pos = [0.35, 0.0, -0.15]", "pos = [0.35, 0.0]"),
        None,
        "arm.toml",
        "payload.pos: expected an array of 3",
    ),
    "too few reflectors": (
        arm_overlay().split("[reflectors.r3]")[0],
        None,
        "arm.toml",
        "reflectors: expected at least 3",
    ),
    "site name taken": (
        _sub("[reflectors.r3]", "[reflectors.payload]"),
        None,
        "arm.toml",
        "reflectors.payload: expected a site name other than 'payload'",
    ),
    "spring without stiffness": (
        _sub("stiffness = 1.5e6\n", "", compensator=True),
        None,
        "arm.toml",
        "compensators.balancer.stiffness: expected this required key",
    ),
    "spring across two joints": (
        _sub('to = { link = "link_2"', 'to = { link = "link_3"', compensator=True),
        None,
        "arm.toml",
        "compensators.balancer: expected attachments on two links with one actuated hinge",
    ),
    "loop passive incomplete": (
        _sub('passive = ["elbow", "rod"]', 'passive = ["elbow"]', loop=True),
        "loop",
        "arm.toml",
        "loops.parallelogram.passive: expected the joints between rod and link_3",
    ),
    "loop passive actuated": (
        _sub('passive = ["elbow", "rod"]', 'passive = ["elbow", "joint_2"]', loop=True),
        "loop",
        "arm.toml",
        "loops.parallelogram.passive[1]: expected a moving, not actuated joint",
    ),
    "loop that cannot close": (
        _sub("pos = [-0.4, -0.35, 0.0]", "pos = [-0.4, -0.2, 0.0]", loop=True),
        "loop",
        "arm.toml",
        "loops.parallelogram: expected sites that the passive joints can bring together",
    ),
    "mounts of no spring": (
        arm_overlay(top='compensator_sites = "spring"\n'),
        None,
        "arm.toml",
        "compensator_sites: expected the name of a [compensators.NAME] table (none)",
    ),
    "hint of no link": (
        arm_overlay(top='links = ["link_2", "link_9"]\n'),
        None,
        "arm.toml",
        "links[1]: expected a link of arm.urdf",
    ),
    "missing inertial": (
        arm_overlay(),
        arm_urdf(no_inertial="link_3"),
        "arm.urdf",
        "link 'link_3': expected an <inertial> on every moving link",
    ),
    "mimic joint": (
        arm_overlay(),
        arm_urdf().replace(
            '<axis xyz="1.0 0.0 0.0"/><limit effort="20000" velocity="2"/></joint>\n'
            '  <joint name="tool0_joint"',
            '<axis xyz="1.0 0.0 0.0"/><limit effort="20000" velocity="2"/>'
            '<mimic joint="joint_4"/></joint>\n  <joint name="tool0_joint"',
        ),
        "arm.urdf",
        "joint 'joint_6': expected no <mimic>",
    ),
    "not a URDF": (arm_overlay(), "<robot><link name='a'>", "arm.urdf", "(file): expected a readable URDF"),
}


@pytest.mark.parametrize("case", list(BAD), ids=list(BAD))
def test_bad_input_names_the_file_and_key_and_writes_nothing(case, tmp_path, capsys):
    overlay, urdf, file, key = BAD[case]
    if urdf == "loop":
        urdf = arm_urdf(loop=True)
    rc, out = build(tmp_path, urdf=urdf, overlay=overlay)
    err = capsys.readouterr().err.strip()
    assert rc == 2, err
    assert len(err.splitlines()) == 1
    assert f"{file}: {key}" in err
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["arm.toml", "arm.urdf"]


def test_why_a_missing_inertial_is_an_error_mujoco_would_invent_a_mass(tmp_path):
    """What MuJoCo makes of a URDF link without <inertial> (its URDF default
    inertiafromgeom="auto"): the mass of its collision geometry at 1000 kg/m^3. link_4's box
    is 0.25 x 0.2 x 0.2 m: 10 kg, where the URDF says nothing."""
    path = tmp_path / "arm.urdf"
    path.write_text(arm_urdf(no_inertial="link_4"))
    model = mujoco.MjSpec.from_file(str(path)).compile()
    assert model.body("link_4").mass[0] == pytest.approx(1000.0 * 0.25 * 0.2 * 0.2, rel=1e-12)


def test_a_link_without_inertial_is_an_error_even_without_geometry_unless_it_is_a_frame(tmp_path, capsys):
    """A moving link with no geometry and no <inertial> on a moving joint has no mass by
    omission (MuJoCo would refuse it, or, with geometry, invent one); a geometry-less link fixed
    to its parent (tool0) is a frame and fine; one with geometry is not."""
    bare = arm_urdf(no_inertial="link_5").replace(
        '    <visual><origin xyz="0.1 0.0 0.0" rpy="1.5707963267948966 0.0 0.0"/><geometry><cylinder radius="0.1" length="0.22"/></geometry></visual>\n'
        '    <collision><origin xyz="0.1 0.0 0.0" rpy="1.5707963267948966 0.0 0.0"/><geometry><cylinder radius="0.1" length="0.22"/></geometry></collision>\n',
        "",
    )
    assert '<cylinder radius="0.1" length="0.22"/>' not in bare
    rc, _ = build(tmp_path / "a", urdf=bare)
    assert rc == 2 and "link 'link_5': expected an <inertial>" in capsys.readouterr().err
    tool = arm_urdf().replace(
        '  <link name="tool0"/>\n',
        '  <link name="tool0"><visual><geometry><box size="0.1 0.1 0.1"/></geometry></visual></link>\n',
    )
    rc, _ = build(tmp_path / "b", urdf=tool)
    assert rc == 2 and "link 'tool0': expected an <inertial>" in capsys.readouterr().err


# --------------------------------------------------------------------------- meshes

TET = "v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nv 0 0 0.1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"
TET_V = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1]])


def _mesh(uri: str, scale=(1, 1, 1), xyz=(0, 0, 0), rpy=(0, 0, 0)) -> str:
    return (
        f'    <collision><origin xyz="{" ".join(map(str, xyz))}" rpy="{" ".join(map(str, rpy))}"/>'
        f'<geometry><mesh filename="{uri}" scale="{" ".join(map(str, scale))}"/></geometry></collision>\n'
    )


def test_meshes_found_are_written_inline_and_missing_ones_left_out_with_a_warning(tmp_path, capsys):
    """The URDF sits in a ROS package layout (arm_support/urdf/arm.urdf, meshes beside it):
    package://arm_support/ resolves through the folder above the URDF, package://tools/ through
    the overlay's [packages], a relative path from the URDF's folder. A mesh that is missing, or
    in a format MuJoCo does not read, is left out with a warning naming the link and the file.
    The output needs no mesh folder (it loads from anywhere, as the log's copy must), and the
    inlined tetrahedra sit where the URDF's frames put them (to the 1 um of the inlining)."""
    pkg = tmp_path / "arm_support"
    (pkg / "meshes").mkdir(parents=True)
    (pkg / "meshes" / "tet.obj").write_text(TET)
    (pkg / "meshes" / "shell.dae").write_text("<COLLADA/>")
    (tmp_path / "tools").mkdir()
    (tmp_path / "tools" / "tip.obj").write_text(TET)
    placed = {
        "link_6": (2.0, (0.05, 0.02, -0.01), (0.0, 0.0, 0.5), "package://arm_support/meshes/tet.obj"),
        "link_4": (1.0, (0.0, 0.1, 0.0), (0.3, 0.0, 0.0), "package://tools/tip.obj"),
        "link_2": (1.0, (0.0, 0.0, 0.3), (0.0, 0.0, 0.0), "../meshes/tet.obj"),
    }
    extra = {link: _mesh(uri, (s, s, s), xyz, rpy) for link, (s, xyz, rpy, uri) in placed.items()}
    extra["link_5"] = _mesh("package://nowhere/meshes/gone.stl")
    extra["link_3"] = _mesh("../meshes/shell.dae") + _mesh("../meshes/absent.stl")
    overlay = arm_overlay() + '\n[packages]\ntools = "../../tools"\n'
    rc, out = build(pkg / "urdf", urdf=arm_urdf(extra_links=extra), overlay=overlay)
    assert rc == 0
    warnings = capsys.readouterr().err.strip().splitlines()
    assert len(warnings) == 3 and all(w.startswith("calbench from-urdf: warning: ") for w in warnings)
    assert any(
        "link_5: mesh package://nowhere/meshes/gone.stl left out (no [packages] nowhere" in w
        for w in warnings
    )
    assert any("link_3: mesh ../meshes/shell.dae left out" in w for w in warnings)
    assert any("link_3: mesh ../meshes/absent.stl left out" in w for w in warnings)
    text = out.read_text()
    assert "file=" not in text and text.count("<mesh ") == 3
    moved = tmp_path / "elsewhere" / "robot.xml"
    moved.parent.mkdir()
    shutil.move(out, moved)
    robot = Robot.from_file(moved)
    m, d = robot.model, robot.data
    assert m.nmesh == 3 and m.ngeom == 7 + 3  # the arm's 7 primitives kept
    q = np.radians([20.0, 30.0, -40.0, 50.0, 60.0, -70.0])
    d.qpos[:] = robot.rigid_qpos(q)
    mujoco.mj_kinematics(m, d)
    fk = urdf_fk(dict(zip(ACTUATED, q)))
    for link, (s, xyz, rpy, _) in placed.items():
        g = next(
            g
            for g in range(m.ngeom)
            if m.geom_bodyid[g] == m.body(link).id and m.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH
        )
        mid = m.geom_dataid[g]
        v = m.mesh_vert[m.mesh_vertadr[mid] : m.mesh_vertadr[mid] + m.mesh_vertnum[mid]]
        world = d.geom_xpos[g] + v @ d.geom_xmat[g].reshape(3, 3).T
        t = fk[link] @ _origin(xyz, rpy)
        expected = (t[:3, :3] @ (s * TET_V).T).T + t[:3, 3]
        got = world[np.lexsort(np.round(world, 5).T)]
        # vertices rounded to 1e-6 m per coordinate: <= 0.5e-6 each, <= 0.87e-6 once rotated
        np.testing.assert_allclose(got, expected[np.lexsort(np.round(expected, 5).T)], rtol=0, atol=0.87e-6)


# --------------------------------------------------------------------------- importers


def test_from_urdf_dispatches_to_a_toy_importer_registered_in_one_file(tmp_path, capsys):
    """tests/toy_importer.py (a .urdf.gz format in one file), once registered, is what
    `from-urdf` and the library (IMPORTERS.for_path) pick for such a file: the MJCF is byte for byte the plain URDF's.
    Unregistered, the file goes to the URDF importer, which says it is no URDF (exit 2, nothing
    written)."""
    import gzip

    from toy_importer import IMPORTER

    from calbench.bench.robots import IMPORTERS

    rc, plain = build(tmp_path)
    assert rc == 0
    packed = tmp_path / "arm.urdf.gz"
    packed.write_bytes(gzip.compress((tmp_path / "arm.urdf").read_bytes()))
    args = ["from-urdf", str(packed), "--overlay", str(tmp_path / "arm.toml"), "--out"]
    assert (
        IMPORTERS.for_path(packed).name == "urdf" and IMPORTERS.for_path(tmp_path / "arm.urdf").name == "urdf"
    )
    assert main([*args, str(tmp_path / "refused.xml")]) == 2
    assert "a readable URDF (XML)" in capsys.readouterr().err
    assert not (tmp_path / "refused.xml").exists()
    IMPORTERS.register(IMPORTER)
    try:
        with pytest.raises(ValueError, match="already registered"):
            IMPORTERS.register(IMPORTER)
        assert (
            IMPORTERS.for_path(packed) is IMPORTER
            and IMPORTERS.for_path(tmp_path / "arm.urdf").name == "urdf"
        )
        assert main([*args, str(tmp_path / "unpacked.xml")]) == 0
    finally:
        IMPORTERS.unregister(IMPORTER.name)
    assert (tmp_path / "unpacked.xml").read_bytes() == plain.read_bytes()
    assert IMPORTERS.for_path(packed).name == "urdf"
