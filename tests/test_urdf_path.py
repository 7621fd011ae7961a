"""The URDF path of a robot nobody here wrote (issue 21): a well-formed MJCF header, ``.xacro``
through the xacro package with ``$(find PKG)`` from the overlay, an overlay ``[inertials]``
table, unique geom names (no MuJoCo warnings), and check-robot's link frames.

Held to independent computations: the xacro's conversion equals the plain URDF's, number for
number; overlay inertials give exactly the masses and centres typed; the frames check-robot
prints are MuJoCo's kinematics of the MJCF. The ROS-Industrial packages of ``../shared/data``
(KUKA's xacro) are skipped where absent.
"""

from __future__ import annotations

import logging
import re
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import numpy as np
from conftest import MJCF
from shared_data import shared_data
from urdf_robots import LINKS, arm_overlay, arm_urdf, link_masses

from calbench.bench.log import read_log
from calbench.bench.model import Robot
from calbench.identify.cli import main


def _convert(
    folder: Path, urdf: str, overlay: str, name: str = "arm", suffix: str = ".urdf"
) -> tuple[int, Path]:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / f"{name}{suffix}").write_text(urdf, encoding="utf-8")
    (folder / f"{name}.toml").write_text(overlay, encoding="utf-8")
    out = folder / f"{name}.xml"
    args = [str(folder / f"{name}{suffix}"), "--overlay", str(folder / f"{name}.toml"), "--out", str(out)]
    return main(["from-urdf", *args]), out


def _numbers(path: Path) -> dict[str, np.ndarray]:
    m = mujoco.MjModel.from_xml_path(str(path))
    return {
        k: getattr(m, k).copy()
        for k in ("body_pos", "body_quat", "body_mass", "body_ipos", "body_inertia", "jnt_axis", "jnt_range")
    } | {"geom_size": m.geom_size.copy(), "site_pos": m.site_pos.copy()}


def test_the_header_is_a_well_formed_xml_comment_even_for_dashed_names(tmp_path):
    rc, out = _convert(tmp_path, arm_urdf(), arm_overlay(), name="my--arm")
    assert rc == 0
    text = out.read_text(encoding="utf-8")
    ET.fromstring(text)  # ElementTree refuses '--' inside a comment
    comment = text[text.index("<!--") + 4 : text.index("-->")]
    assert "--" not in comment and "from-urdf from my- -arm.urdf with the overlay my- -arm.toml" in comment


def _arm_macros(tmp_path: Path, urdf: str, base_height: str) -> tuple[Path, str]:
    """The arm's links as a macro ``arm_links`` in links.xacro of a package folder
    ``elsewhere/arm_macros``, and its joints' XML with the base height written ``base_height``:
    (the package folder, the joints)."""
    links = urdf[urdf.index("  <link") : urdf.index("  <joint")]
    joints = urdf[urdf.index("  <joint") : urdf.index("</robot>")].replace(
        'xyz="0.0 0.0 0.45"', f'xyz="0 0 {base_height}"', 1
    )
    assert base_height in joints
    pkg = tmp_path / "elsewhere" / "arm_macros"
    pkg.mkdir(parents=True)
    (pkg / "links.xacro").write_text(
        f'<robot xmlns:xacro="http://www.ros.org/wiki/xacro"><xacro:macro name="arm_links">\n{links}'
        "</xacro:macro></robot>\n",
        encoding="utf-8",
    )
    return pkg, joints


def test_a_xacro_with_find_converts_to_the_same_robot_as_its_urdf(tmp_path):
    urdf = arm_urdf()
    rc, plain = _convert(tmp_path / "plain", urdf, arm_overlay())
    assert rc == 0
    # the same arm as a xacro: the links in a macro file of package 'arm_macros' (a folder the
    # overlay's [packages] names), a property for the base height
    _, joints = _arm_macros(tmp_path, urdf, "${h}")
    xacro = (
        '<?xml version="1.0"?>\n<robot name="arm6" xmlns:xacro="http://www.ros.org/wiki/xacro">\n'
        '  <xacro:property name="h" value="0.45"/>\n'
        '  <xacro:include filename="$(find arm_macros)/links.xacro"/>\n  <xacro:arm_links/>\n'
        f"{joints}</robot>\n"
    )
    overlay = arm_overlay() + '\n[packages]\narm_macros = "../elsewhere/arm_macros"\n'
    rc, made = _convert(tmp_path / "x", xacro, overlay, suffix=".urdf.xacro")
    assert rc == 0
    a, b = _numbers(plain), _numbers(made)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    assert "from arm.urdf.xacro (expanded by xacro)" in made.read_text(encoding="utf-8")


def test_xacro_arguments_come_from_the_overlay_and_their_lack_is_named(tmp_path, capsys):
    """A top-level xacro that needs arguments (ur_description's ur.xacro needs robot_model and
    its parameter files): the overlay's [xacro] table gives them, $(find PKG) in a value
    resolved from [packages]; the arm comes out number for number as from its plain URDF. No
    value: one line naming the [xacro] key to add; a file that is not there: one line naming it
    (ur_description here lacks config/ur5/); [xacro] on a plain URDF: refused."""
    urdf = arm_urdf()
    rc, plain = _convert(tmp_path / "plain", urdf, arm_overlay())
    assert rc == 0
    pkg, joints = _arm_macros(tmp_path, urdf, "$(arg base_height)")
    xacro = (
        '<?xml version="1.0"?>\n<robot name="arm6" xmlns:xacro="http://www.ros.org/wiki/xacro">\n'
        '  <xacro:arg name="base_height" default=""/>\n'
        '  <xacro:include filename="$(arg links_file)"/>\n  <xacro:arm_links/>\n'
        f"{joints}</robot>\n"
    )
    packages = '\n[packages]\narm_macros = "../elsewhere/arm_macros"\n'
    args = '\n[xacro]\nbase_height = "0.45"\nlinks_file = "$(find arm_macros)/links.xacro"\n'
    rc, made = _convert(tmp_path / "x", xacro, arm_overlay() + packages + args, suffix=".xacro")
    assert rc == 0
    a, b = _numbers(plain), _numbers(made)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    capsys.readouterr()
    rc, out = _convert(tmp_path / "none", xacro, arm_overlay() + packages, suffix=".xacro")
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and not out.exists(), err
    assert (
        'arm.xacro: (xacro) $(arg links_file): expected a value for it: [xacro] links_file = "VALUE"'
        in err[0]
    )
    gone = args.replace("links.xacro", "gone.xacro")
    rc, out = _convert(tmp_path / "gone", xacro, arm_overlay() + packages + gone, suffix=".xacro")
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and not out.exists(), err
    assert "arm.xacro: (xacro): expected every file the xacro reads" in err[0]
    assert f"{pkg / 'gone.xacro'} is missing" in err[0]
    rc, out = _convert(tmp_path / "plainargs", urdf, arm_overlay() + args)
    err = capsys.readouterr().err
    assert rc == 2 and "arm.toml: xacro: expected arguments only for a .xacro robot file" in err


def test_a_missing_find_package_exits_2_naming_it(tmp_path, capsys):
    xacro = (
        '<robot name="x" xmlns:xacro="http://www.ros.org/wiki/xacro">'
        '<xacro:include filename="$(find no_such_pkg)/a.xacro"/></robot>\n'
    )
    rc, out = _convert(tmp_path, xacro, arm_overlay(), suffix=".xacro")
    err = capsys.readouterr().err
    assert rc == 2 and "arm.xacro: $(find no_such_pkg): expected a [packages] no_such_pkg" in err
    assert not out.exists()


def test_overlay_inertials_give_the_masses_typed_and_are_marked_assumed(tmp_path, capsys):
    urdf = re.sub(r"    <inertial>.*?</inertial>\n", "", arm_urdf(), flags=re.S)
    assert "<inertial>" not in urdf
    rc, _ = _convert(tmp_path / "none", urdf, arm_overlay())
    assert rc == 2 and "an <inertial> on every moving link" in capsys.readouterr().err
    serial = {n: LINKS[n] for n in link_masses()}  # the moving links of the serial arm
    tables = "".join(
        f"\n[inertials.{name}]\nmass = {mass!r}\ncom = [{', '.join(repr(float(c)) for c in com)}]\n"
        + (f"inertia = [{', '.join(repr(float(i)) for i in inertia)}]\n" if name != "link_6" else "")
        for name, (mass, com, inertia, *_) in serial.items()
    )
    rc, out = _convert(tmp_path / "typed", urdf, arm_overlay() + tables)
    assert rc == 0
    text = out.read_text(encoding="utf-8")
    assert "ASSUMED in the overlay's [inertials] for link_1, " in text
    m = mujoco.MjModel.from_xml_path(str(out))
    for name, (mass, com, inertia, *_) in serial.items():
        b = m.body(name)
        assert b.mass[0] == mass, name
        # the centre of mass in the link frame, as typed (MuJoCo may rotate the inertial frame)
        np.testing.assert_allclose(b.ipos, com, atol=1e-12, err_msg=name)
        expected = np.sort(inertia) if name != "link_6" else np.full(3, mass * 0.1**2)
        np.testing.assert_allclose(np.sort(b.inertia), expected, rtol=1e-12, err_msg=name)


def test_duplicate_geom_names_are_renamed_without_mujoco_warnings(tmp_path, caplog):
    urdf = (
        arm_urdf()
        .replace("<collision>", '<collision name="collision">')
        .replace("<visual>", '<visual name="visual">')
    )
    assert urdf.count('name="collision"') == 7
    with caplog.at_level(logging.WARNING, logger="calbench.mujoco"):
        rc, out = _convert(tmp_path, urdf, arm_overlay())
    assert rc == 0 and not [r for r in caplog.records if "duplicate name" in r.getMessage()]
    m = mujoco.MjModel.from_xml_path(str(out))
    names = [m.geom(g).name for g in range(m.ngeom)]
    assert "link_2_collision" in names and len(set(names)) == len(names)


def test_check_robot_prints_each_links_frame_as_mujoco_computes_it(capsys):
    assert main(["check-robot", str(MJCF), "--grid", "1", "--sample", "0"]) == 0
    out = capsys.readouterr().out
    robot = Robot.from_file(MJCF)
    m = robot.model
    d = mujoco.MjData(m)
    d.qpos[:] = robot.rigid_qpos(np.zeros(robot.n_act))
    mujoco.mj_kinematics(m, d)
    for b in range(1, m.nbody):
        got = re.search(rf"^    {m.body(b).name}: origin \[([^\]]*)\]", out, flags=re.M)
        assert got, m.body(b).name
        np.testing.assert_allclose([float(x) for x in got[1].split(",")], d.xpos[b], atol=5e-4)
    # link5's cylinder (radius 0.13, along y from -0.14 to 0.14) and neck capsule (to x = 0.32)
    box = re.search(r"^    link5: .*box \[(.*)\] \.\. \[(.*)\]$", out, flags=re.M)
    lo, hi = (np.array([float(x) for x in g.split(",")]) for g in box.groups())
    np.testing.assert_allclose(lo, [-0.13, -0.14, -0.13], atol=5e-4)
    np.testing.assert_allclose(hi, [0.32, 0.14, 0.13], atol=5e-4)


def test_kukas_xacro_from_ros_industrial_converts(tmp_path):
    xacro = shared_data("robots", "kuka_quantec_support", "urdf", "kr210_r2700_2.urdf.xacro")
    overlay = "\n".join(
        ['actuated = ["joint_1", "joint_2", "joint_3", "joint_4", "joint_5", "joint_6"]']
        + [f'[{t}]\nlink = "link_6"\npos = {p}' for t, p in (("payload", "[0.0, 0.0, 0.2]"),)]
        + [
            f'[reflectors.{n}]\nlink = "link_6"\npos = {p}'
            for n, p in (("r1", "[0.2, 0.0, 0.1]"), ("r2", "[-0.1, 0.2, 0.1]"), ("r3", "[-0.1, -0.2, 0.1]"))
        ]
    )
    (tmp_path / "kuka.toml").write_text(overlay + "\n", encoding="utf-8")
    out = tmp_path / "kuka.xml"
    assert main(["from-urdf", str(xacro), "--overlay", str(tmp_path / "kuka.toml"), "--out", str(out)]) == 0
    m = mujoco.MjModel.from_xml_path(str(out))
    assert m.nmesh >= 6 and 800 < m.body_mass.sum() < 2000  # the macro's inertials, a KR 210's links
    ET.parse(out)


def test_the_view_legend_names_the_colour_it_draws(tmp_path):
    from calbench.bench.model import geom_shapes
    from calbench.bench.view import Legend, colour_name, legend

    rc, out = _convert(tmp_path, arm_urdf(), arm_overlay())  # no <material>: MuJoCo's grey
    assert rc == 0
    for path, colour in ((out, "grey"), (MJCF, "yellow")):
        shapes = geom_shapes(mujoco.MjModel.from_xml_path(str(path)))
        name = colour_name(np.array([g.rgba for g in shapes]))
        assert name == colour
        assert legend(Legend(1.0, 1.0, robot_colour=name)).startswith(f"- **{colour} robot**")


def test_check_robot_on_a_urdf_says_run_from_urdf_first(tmp_path, capsys):
    (tmp_path / "arm.urdf").write_text(arm_urdf())
    (tmp_path / "arm.txt").write_text(arm_urdf())  # a URDF by its <robot> root, whatever its name
    for name in ("arm.urdf", "arm.txt"):
        assert main(["check-robot", str(tmp_path / name)]) == 2
        err = capsys.readouterr().err
        assert "convert a URDF first, calbench from-urdf" in err and "got 'a URDF'" in err


CYLINDER = """  <link name="cyl"><visual><geometry><cylinder radius="0.08" length="0.6"/></geometry></visual></link>
  <link name="rod_in"><visual><geometry><cylinder radius="0.05" length="0.6"/></geometry></visual></link>
  <joint name="cyl_joint" type="continuous"><parent link="link_1"/><child link="cyl"/>
    <origin xyz="-0.25 0.35 1.2" rpy="0 0 0"/><axis xyz="0 1 0"/><mimic joint="joint_2" multiplier="{m_f}"/></joint>
  <joint name="rod_joint" type="continuous"><parent link="link_2"/><child link="rod_in"/>
    <origin xyz="0 0.35 0.45" rpy="0 0 0"/><axis xyz="0 1 0"/><mimic joint="joint_2" multiplier="{m_t}"/></joint>
"""


def _with_cylinder(m_f: float, m_t: float) -> str:
    return arm_urdf().replace("</robot>", CYLINDER.format(m_f=m_f, m_t=m_t) + "</robot>")


def test_a_balancer_cylinder_drawn_as_mimic_joints_becomes_a_spring(tmp_path, capsys):
    """ROS-Industrial's pattern: cylinder on link_1, piston on link_2, both mimic joint_2 and stay
    collinear (m_f = 1 + m_t). The spring joins the two pivots; its free length is their distance
    at q = 0, here recomputed by MuJoCo from the sites of the MJCF."""
    rc, out = _convert(tmp_path, _with_cylinder(-0.3, -1.3), arm_overlay())
    err = capsys.readouterr().err
    assert rc == 0, err
    assert "note: balancer cylinder cyl/rod_in (mimic joints cyl_joint, rod_joint of joint_2)" in err
    m = mujoco.MjModel.from_xml_path(str(out))
    assert "cyl" not in [m.body(b).name for b in range(m.nbody)]
    t = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_TENDON, "balancer")
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)
    a, b = (d.site(n).xpos for n in ("balancer_from", "balancer_to"))
    np.testing.assert_allclose(m.tendon_lengthspring[t, 0], np.linalg.norm(a - b), rtol=1e-12)
    np.testing.assert_array_equal(m.site("balancer_from").pos, [-0.25, 0.35, 1.2])
    robot = Robot.from_file(out)
    assert robot.layout.names[6:] == ("balancer_stiffness", "balancer_preload")
    assert robot.description.actuated[robot.compensator_joint(0)] == "joint_2"
    assert (
        "Balancer cylinders drawn as URDF mimic joints: the compensator springs balancer" in out.read_text()
    )


def test_mimic_joints_that_turn_against_each_other_are_no_balancer(tmp_path, capsys):
    """A parallelogram's crank and rod (m_f != 1 + m_t): refused, the loop named as the way."""
    rc, _ = _convert(tmp_path, _with_cylinder(-1.0, 1.0), arm_overlay())
    err = capsys.readouterr().err
    assert rc == 2 and "joint 'cyl_joint': expected no <mimic>" in err and "[loops]" in err


def test_the_abb_xacro_converts_without_hand_surgery(tmp_path, capsys):
    """The IRB 6640's own xacro, cylinder and piston included: the spring lands on the pivots the
    case's hand-written overlay (../shared/data/cases/irb6640/) gives."""
    xacro = shared_data("robots", "abb_irb6640_support", "urdf", "irb6640_185_280.xacro")
    case = shared_data("cases", "irb6640", "irb6640.toml").read_text(encoding="utf-8")
    overlay = case[: case.index("# the balancing cylinder")].replace('compensator_sites = "balancer"\n', "")
    masses = {
        "link_1": 450.0,
        "link_2": 220.0,
        "link_3": 200.0,
        "link_4": 120.0,
        "link_5": 40.0,
        "link_6": 5.0,
    }
    overlay += "".join(f"\n[inertials.{k}]\nmass = {v}\ncom = [0.0, 0.0, 0.0]\n" for k, v in masses.items())
    (tmp_path / "irb.toml").write_text(overlay, encoding="utf-8")
    out = tmp_path / "irb.xml"
    assert main(["from-urdf", str(xacro), "--overlay", str(tmp_path / "irb.toml"), "--out", str(out)]) == 0
    assert "became the compensator spring 'balancer'" in capsys.readouterr().err
    m = mujoco.MjModel.from_xml_path(str(out))
    np.testing.assert_array_equal(m.site("balancer_from").pos, [-0.3647, 0.0, -0.1455])
    np.testing.assert_array_equal(m.site("balancer_to").pos, [-0.22, 0.0, -0.0672])
    assert m.body(m.site("balancer_from").bodyid[0]).name == "link_1"
    assert m.body(m.site("balancer_to").bodyid[0]).name == "link_2"
    assert main(["check-robot", str(out), "--grid", "1", "--sample", "0"]) == 0


def test_controller_conventions_give_the_same_campaign_in_the_controllers_angles(tmp_path):
    """joint_2 counted the other way from -90 deg, joint_3 from +90 deg: the scenario written in
    those angles simulates the campaign the URDF's angles simulate on the plain conversion
    (readings equal to rounding), and the MJCF's ranges are the mapped limits."""
    from urdf_robots import scenario

    conv = {"joint_2": (-90.0, -1), "joint_3": (90.0, 1)}
    extra = "".join(f"\n[conventions.{j}]\nzero = {z}\nsign = {s}\n" for j, (z, s) in conv.items())
    rc, plain = _convert(tmp_path / "plain", arm_urdf(), arm_overlay())
    assert rc == 0
    rc, ctrl = _convert(tmp_path / "ctrl", arm_urdf(), arm_overlay() + extra)
    assert rc == 0
    a, b = (mujoco.MjModel.from_xml_path(str(p)) for p in (plain, ctrl))
    for j, (z, s) in conv.items():
        lo, hi = np.degrees(a.joint(j).range)
        np.testing.assert_allclose(np.degrees(b.joint(j).range), sorted((s * lo + z, s * hi + z)), atol=1e-9)
    text = scenario(str(plain))
    mapped = text.replace(str(plain), str(ctrl))

    def to_ctrl(m: re.Match) -> str:
        q = [float(x) for x in m[1].split(",")]
        for j, (z, s) in conv.items():
            k = int(j[-1]) - 1
            q[k] = s * q[k] + z
        return "q = [" + ", ".join(repr(x) for x in q) + "]"

    mapped = re.sub(r"^q = \[(.*)\]$", to_ctrl, mapped, flags=re.M)
    assert mapped != text.replace(str(plain), str(ctrl))
    logs = []
    for name, t in (("plain", text), ("ctrl", mapped)):
        (tmp_path / f"{name}.toml").write_text(t, encoding="utf-8")
        assert (
            main(["simulate", str(tmp_path / f"{name}.toml"), "--out", str(tmp_path / f"{name}.mcap")]) == 0
        )
        logs.append(read_log(tmp_path / f"{name}.mcap"))
    pa, pb = ([m.position for m in log.measurements] for log in logs)
    assert len(pa) == len(pb) > 0
    np.testing.assert_allclose(np.array(pa), np.array(pb), atol=1e-9, equal_nan=True)
    assert "Joint angles are the controller's" in ctrl.read_text(encoding="utf-8")


def test_a_bad_convention_exits_2_naming_it(tmp_path, capsys):
    for extra, key in (
        ("\n[conventions.joint_2]\nsign = 2\n", "conventions.joint_2.sign"),
        ("\n[conventions.tool0_joint]\nzero = 5.0\n", "conventions.tool0_joint"),
    ):
        rc, _ = _convert(tmp_path, arm_urdf(), arm_overlay() + extra)
        err = capsys.readouterr().err
        assert rc == 2 and f"arm.toml: {key}: expected" in err, err


def test_a_xacro_without_the_xacro_package_names_the_fix(tmp_path, capsys, monkeypatch):
    """A user whose environment lacks the xacro package: one line naming the file and `pip
    install xacro`, exit 2, no output file."""
    monkeypatch.setitem(sys.modules, "xacro", None)  # import xacro -> ImportError
    xacro = '<?xml version="1.0"?>\n<robot name="a" xmlns:xacro="http://www.ros.org/wiki/xacro"/>\n'
    rc, out = _convert(tmp_path, xacro, arm_overlay(), suffix=".urdf.xacro")
    err = capsys.readouterr().err.strip()
    assert rc == 2 and not out.exists() and len(err.splitlines()) == 1
    assert (
        "arm.urdf.xacro: (file): expected the xacro package (pip install xacro), got 'not installed'" in err
    )
