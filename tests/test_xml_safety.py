"""XML from strangers (bench/core/xmlsafe.py): entity bombs and external entities are refused in
URDF and MJCF, a model file may not read files outside its folder, and MJCF text (a log's robot)
may read no file at all; each refusal is one InputError naming the file and the element."""

from __future__ import annotations

from pathlib import Path

import pytest

from calbench.bench.core import InputError, check_mjcf_text, check_model_file
from calbench.bench.model import Robot
from calbench.bench.robots import read_urdf

BOMB = """<?xml version="1.0"?>
<!DOCTYPE lolz [<!ENTITY lol "lol"><!ENTITY lol2 "&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;">
<!ENTITY lol3 "&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;">]>
<{root}><link name="&lol3;"/></{root}>"""

EXTERNAL = """<?xml version="1.0"?>
<!DOCTYPE r [<!ENTITY secret SYSTEM "file:///etc/passwd">]>
<{root}><link name="&secret;"/></{root}>"""

ARM = """<mujoco model="arm">
  {compiler}
  <worldbody><body name="l1"><joint name="j1" axis="0 0 1"/>
    <geom type="capsule" size="0.05" fromto="0 0 0 0 0 0.5" mass="10"/></body></worldbody>
  {extra}
</mujoco>"""


@pytest.mark.parametrize("doc", [BOMB, EXTERNAL], ids=["entity bomb", "external entity"])
def test_a_urdf_with_entities_is_refused(tmp_path, doc):
    p = tmp_path / "evil.urdf"
    p.write_text(doc.format(root="robot"))
    with pytest.raises(
        InputError, match=r"evil\.urdf: \(file\): expected a readable URDF \(XML\), got .entity declarations"
    ):
        read_urdf(p)


@pytest.mark.parametrize("doc", [BOMB, EXTERNAL], ids=["entity bomb", "external entity"])
def test_mjcf_with_entities_is_refused_as_a_file_and_as_text(tmp_path, doc):
    p = tmp_path / "evil.xml"
    p.write_text(doc.format(root="mujoco"))
    with pytest.raises(InputError, match=r"evil\.xml: <!DOCTYPE>: expected XML without entity declarations"):
        Robot.from_file(p)
    with pytest.raises(InputError, match=r"<!DOCTYPE>"):
        Robot.from_xml(doc.format(root="mujoco"), where="LOG.mcap's robot")


def test_a_log_robot_that_reads_a_file_is_refused(tmp_path):
    secret = tmp_path / "secret.xml"
    secret.write_text("<mujoco/>")
    text = ARM.format(compiler="", extra=f'<include file="{secret}"/>')
    with pytest.raises(InputError, match=r"robot: <include file>: expected a self-contained MJCF.*--model"):
        Robot.from_xml(text, where="robot")
    text = ARM.format(
        compiler='<compiler meshdir="/home"/>', extra='<asset><mesh name="m" file="x.stl"/></asset>'
    )
    with pytest.raises(InputError, match=r"<mesh file>.*'/home/x.stl'"):
        check_mjcf_text(text)
    assert check_mjcf_text(ARM.format(compiler="", extra="")).tag == "mujoco"  # reads nothing: fine


@pytest.mark.parametrize(
    "compiler, extra, ok",
    [
        ("", '<include file="parts/more.xml"/>', True),
        ("", '<include file="../outside.xml"/>', False),
        ('<compiler meshdir="meshes"/>', '<asset><mesh name="m" file="../../outside.stl"/></asset>', False),
        ('<compiler meshdir="/etc"/>', '<asset><mesh name="m" file="x.stl"/></asset>', False),
        ('<compiler assetdir="a"/>', '<asset><texture name="t" type="2d" file="t.png"/></asset>', True),
    ],
)
def test_a_model_file_reads_only_inside_its_folder(tmp_path, compiler, extra, ok):
    home = tmp_path / "robot"
    (home / "parts").mkdir(parents=True)
    (home / "parts" / "more.xml").write_text("<mujoco/>")
    model = home / "arm.xml"
    model.write_text(ARM.format(compiler=compiler, extra=extra))
    if ok:
        check_model_file(model)
    else:
        with pytest.raises(
            InputError, match=r"arm\.xml: <\w+ file>: expected a file inside the model's folder"
        ):
            check_model_file(model)


def test_an_included_file_is_checked_too(tmp_path):
    home = tmp_path / "robot"
    home.mkdir()
    (home / "more.xml").write_text(
        '<mujoco><asset><mesh name="m" file="../../../etc/x.stl"/></asset></mujoco>'
    )
    (home / "arm.xml").write_text(ARM.format(compiler="", extra='<include file="more.xml"/>'))
    with pytest.raises(InputError, match=r"more\.xml: <mesh file>"):
        check_model_file(home / "arm.xml")


def test_the_shipped_robots_pass(mjcf_dir=Path(__file__).parent.parent / "mjcf"):
    for p in sorted(mjcf_dir.glob("*.xml")):
        check_model_file(p)
        check_mjcf_text(p.read_text(), p)
