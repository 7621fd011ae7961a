"""Outputs never destroy inputs, every output is checked before work starts, and files are
written whole or not at all (bench/core/outputs.py), for every verb alike."""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import pytest
from conftest import PAPER

from calbench.bench.core import InputError, atomic_path, check_outputs, write_text
from calbench.identify.cli import main


def digest(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("outputs")
    shutil.copy(PAPER, d / "s.toml")
    (d / "s.toml").write_text(
        PAPER.read_text().replace('robot = "../mjcf/', f'robot = "{PAPER.parent.parent}/mjcf/')
    )
    assert main(["simulate", str(d / "s.toml"), "--out", str(d / "l.mcap")]) == 0
    return d


def same_as_input_cases(d: Path):
    s, log = str(d / "s.toml"), str(d / "l.mcap")
    return [
        ["simulate", s, "--out", s],
        ["identify", log, "--json", log],
        ["discover", log, "--json", log],
        ["discover", log, "--out-model", log],
        ["design", s, "--out", s, "--candidates", "50"],
        ["montecarlo", s, "--runs", "2", "--json", s],
        ["view", log, "--rrd", log],
    ]


@pytest.mark.parametrize("case", range(7))
def test_an_output_equal_to_an_input_is_refused_and_the_input_is_untouched(work, case, capsys):
    argv = same_as_input_cases(work)[case]
    before = {p: digest(p) for p in (work / "s.toml", work / "l.mcap")}
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "an output path other than the input" in err and err.count("\n") == 1
    assert {p: digest(p) for p in before} == before


def test_an_output_through_a_link_to_the_input_is_refused(work, tmp_path):
    link = tmp_path / "alias.mcap"
    link.symlink_to(work / "l.mcap")
    before = digest(work / "l.mcap")
    assert main(["identify", str(work / "l.mcap"), "--json", str(link)]) == 2
    assert digest(work / "l.mcap") == before


@pytest.mark.parametrize("where", ["proc", "directory", "under_file"])
def test_unwritable_outputs_are_refused_up_front(work, tmp_path, where, capsys):
    (tmp_path / "afile").write_text("x")
    out = {
        "proc": Path("/proc/calbench.mcap"),
        "directory": tmp_path,
        "under_file": tmp_path / "afile" / "log.mcap",
    }[where]
    assert main(["simulate", str(work / "s.toml"), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("calbench simulate: error:") and err.count("\n") == 1
    assert not (tmp_path / "afile" / "log.mcap").exists()


@pytest.mark.parametrize("where", ["file", "proc", "output_is_directory"])
def test_demo_checks_all_its_outputs_before_it_starts(tmp_path, where, capsys):
    """`demo --logs` onto a file gave a traceback (FileExistsError) after the campaign began."""
    (tmp_path / "afile").write_text("x")
    (tmp_path / "d" / "paper_table5_hidden.discover.rrd").mkdir(parents=True)  # the last output
    logs = {
        "file": tmp_path / "afile",
        "proc": Path("/proc/calbench-logs"),
        "output_is_directory": tmp_path / "d",
    }[where]
    assert main(["demo", "--logs", str(logs)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("calbench demo: error:") and "--logs" in err and err.count("\n") == 1
    assert (tmp_path / "afile").read_text() == "x"
    assert [p.name for p in (tmp_path / "d").iterdir()] == [
        "paper_table5_hidden.discover.rrd"
    ]  # nothing begun


def test_missing_output_folders_are_created_for_every_verb(work, tmp_path):
    out = tmp_path / "new" / "deeper" / "id.json"
    assert main(["identify", str(work / "l.mcap"), "--json", str(out)]) == 0
    assert out.is_file()
    out = tmp_path / "mc" / "x" / "mc.json"
    assert (
        main(["montecarlo", str(work / "s.toml"), "--runs", "2", "--method", "two-step", "--json", str(out)])
        == 0
    )
    assert out.is_file()


def test_two_outputs_may_not_be_the_same_file(tmp_path):
    with pytest.raises(InputError, match="other than --json"):
        check_outputs({"--json": tmp_path / "a.json", "--plot": tmp_path / "a.json"})


def test_interrupted_write_leaves_the_old_file_whole(tmp_path):
    target = tmp_path / "report.json"
    write_text(target, "the good report\n")
    with pytest.raises(KeyboardInterrupt):
        with atomic_path(target) as tmp:
            tmp.write_text("half of a new rep")
            raise KeyboardInterrupt
    assert target.read_text() == "the good report\n"
    assert [p.name for p in tmp_path.iterdir()] == ["report.json"]  # no temporary left behind


def test_atomic_outputs_get_the_permissions_of_an_ordinary_file(tmp_path):
    import os

    umask = os.umask(0o022)
    try:
        write_text(tmp_path / "a.json", "{}")
        (tmp_path / "b.json").write_text("{}")
    finally:
        os.umask(umask)
    assert (
        (tmp_path / "a.json").stat().st_mode & 0o777 == (tmp_path / "b.json").stat().st_mode & 0o777 == 0o644
    )


def test_the_command_line_routes_mujocos_warnings_to_stderr_not_a_file(tmp_path):
    """Left to itself MuJoCo writes its warnings into MUJOCO_LOG.TXT in the working folder, a file
    the user did not ask for: `calbench` installs a handler that says them on stderr instead
    (a fresh process: the suite's own handler is installed in this one)."""
    import subprocess
    import sys

    code = (
        "import mujoco, numpy as np\n"
        "from calbench.identify.cli import main\n"
        f"assert main(['check-robot', {str(PAPER.parent.parent / 'mjcf' / 'kr270.xml')!r}]) == 0\n"
        "m = mujoco.MjModel.from_xml_string(\"<mujoco><worldbody><body><joint/><geom size='.1'/>"
        '</body></worldbody></mujoco>")\n'
        "d = mujoco.MjData(m); d.qpos[:] = np.nan; mujoco.mj_step(m, d)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "MuJoCo: Nan, Inf or huge value in QPOS" in r.stderr
    assert list(tmp_path.iterdir()) == []
