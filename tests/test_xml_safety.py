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


# --------------------------------------------------------------------------- through the command line


LAUGHS = (
    '<?xml version="1.0"?>\n<!DOCTYPE lolz [<!ENTITY l0 "lol">'
    + "".join(f'<!ENTITY l{i} "{f"&l{i - 1};" * 10}">' for i in range(1, 10))
    + ']>\n<robot name="x"><link name="&l9;"/></robot>\n'
)  # a billion laughs: 10^9 "lol"s, 3 GB if expanded


@pytest.mark.parametrize(
    "doc", [LAUGHS, EXTERNAL.format(root="robot")], ids=["billion laughs", "external entity"]
)
def test_from_urdf_refuses_entities_in_one_line_without_expanding_them(tmp_path, doc, capsys):
    import resource

    from urdf_robots import arm_overlay

    from calbench.identify.cli import main

    (tmp_path / "evil.urdf").write_text(doc)
    (tmp_path / "overlay.toml").write_text(arm_overlay())
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    rc = main(
        [
            "from-urdf",
            str(tmp_path / "evil.urdf"),
            "--overlay",
            str(tmp_path / "overlay.toml"),
            "--out",
            str(tmp_path / "o.xml"),
        ]
    )
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and "entity declarations" in err, err
    assert "evil.urdf" in err and not (tmp_path / "o.xml").exists()
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before < 100_000  # kB: nothing expanded


def logged_robot_log(tmp_path: Path, mjcf_text: str, src: Path) -> Path:
    """The campaign log ``src`` written again with ``mjcf_text`` as its robot attachment."""
    from calbench.bench.log import LogHeader, LogWriter, read_log

    log = read_log(src)
    h = log.header
    out = tmp_path / "sent.mcap"
    header = LogHeader(
        h["scenario_name"], log.scenario_text or "", "sent.toml", h["robot"], mjcf_text, list(h["reflectors"]),
        h["payload_site"], h["tracker"], h["seed"], n_poses=h["n_poses"], n_joints=h.get("n_joints"),
    )  # fmt: skip
    with LogWriter(out, header) as w:
        for p in log.complete_poses:
            wr = log.wrenches[p]
            w.pose(p, "unloaded", log.poses[p].unloaded)
            for m in log.readings(p, "unloaded"):
                w.measurement(p, "unloaded", m.repeat, m.reflectors, m.position, m.covariance, m.visible)
            w.wrench(p, wr.force, wr.moment, wr.site, wr.mass)
            w.pose(p, "loaded", log.poses[p].loaded)
            for m in log.readings(p, "loaded"):
                w.measurement(p, "loaded", m.repeat, m.reflectors, m.position, m.covariance, m.visible)
            w.pose_done(p)
    return out


@pytest.fixture(scope="module")
def paper_log(tmp_path_factory) -> Path:
    from conftest import PAPER

    from calbench.identify.cli import main

    d = tmp_path_factory.mktemp("sent")
    assert main(["simulate", str(PAPER), "--out", str(d / "paper.mcap")]) == 0
    return d / "paper.mcap"


def test_a_log_whose_robot_includes_etc_passwd_is_refused_by_every_verb(tmp_path, paper_log, capsys):
    from conftest import MJCF

    from calbench.identify.cli import main

    text = MJCF.read_text().replace("<worldbody>", '<include file="/etc/passwd"/>\n  <worldbody>', 1)
    log = logged_robot_log(tmp_path, text, paper_log)
    for verb in (["identify"], ["discover"], ["view", "--rrd", str(tmp_path / "v.rrd")]):
        rc = main([verb[0], str(log), *verb[1:]])
        err = capsys.readouterr().err.strip()
        assert rc == 2 and len(err.splitlines()) == 1, (verb, err)
        assert "<include file>" in err and "/etc/passwd" in err and "self-contained" in err, (verb, err)
    # the report loads no robot: written, and nothing of /etc/passwd in it
    assert main(["report", str(log), "--out", str(tmp_path / "r.html")]) == 0
    assert "root:" not in (tmp_path / "r.html").read_text()
    # with the user's own model the log's robot is not read
    assert main(["identify", str(log), "--model", str(MJCF)]) == 0


def test_a_log_whose_robot_is_not_the_one_recorded_is_refused(tmp_path, paper_log, capsys):
    """/campaign/info records the robot attachment's SHA-256; a log whose attachment is another
    MJCF (spliced, or the record edited) is refused whole, naming both hashes."""
    import badcases as bc

    from calbench.identify.cli import main

    def other(topic, m):
        if topic == "/campaign/info":
            m["robot_sha256"] = "0" * 64
        return m

    bad = bc.rewrite_json(paper_log, tmp_path / "spliced.mcap", other)
    rc = main(["identify", str(bad)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1, err
    assert (
        "attachment 'm900ib700.xml': expected the robot MJCF whose SHA-256 /campaign/info records (000000000000...)"
        in err
    )
