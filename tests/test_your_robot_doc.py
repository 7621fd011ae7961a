"""docs/your-robot.md's walkthrough runs as written (issue 21): its TOML blocks are written to the
files their first line names, its commands run in order in a fresh folder whose ``robots/`` is
``../shared/data/robots`` (the ROS-Industrial packages; skipped where absent), each exits 0 and
writes what it names; check-robot reports design's feasibility and identify --check passes."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys

import pytest
from conftest import ROOT
from shared_data import shared_data

DOC = ROOT / "docs" / "your-robot.md"
SECTION = "## A ROS-Industrial robot, step by step"


def section() -> str:
    text = DOC.read_text(encoding="utf-8")
    start = text.index(SECTION)
    end = text.find("\n## ", start + len(SECTION))
    return text[start : end if end > 0 else None]


def blocks(lang: str) -> list[str]:
    return re.findall(rf"^```{lang}\n(.*?)^```", section(), flags=re.M | re.S)


COMMANDS = [c.strip() for b in blocks("sh") for c in b.splitlines() if c.strip()]


@pytest.fixture(scope="module")
def walk(tmp_path_factory) -> dict:
    robots = shared_data("robots", "kuka_quantec_support")
    here = tmp_path_factory.mktemp("walk")
    (here / "robots").symlink_to(robots.parent, target_is_directory=True)
    for b in blocks("toml"):
        name = b.splitlines()[0].removeprefix("# ").strip()
        assert re.fullmatch(r"[\w.]+\.toml", name), name
        (here / name).write_text(b, encoding="utf-8")
    bin_dir = os.path.dirname(sys.executable)
    env = dict(os.environ, PATH=f"{bin_dir}{os.pathsep}{os.environ.get('PATH', '')}", MPLBACKEND="Agg")
    env.update(RERUN_ANALYTICS="0", DASK_SCHEDULER_ADDRESS="")
    out = {"folder": here}
    for cmd in COMMANDS:
        out[cmd] = subprocess.run(
            ["bash", "-c", cmd], cwd=here, env=env, capture_output=True, text=True, timeout=600
        )
    return out


def test_the_walkthrough_is_the_five_verbs():
    assert [shlex.split(c)[1] for c in COMMANDS] == [
        "from-urdf",
        "check-robot",
        "design",
        "simulate",
        "identify",
    ]
    assert len(blocks("toml")) == 2


@pytest.mark.parametrize("cmd", COMMANDS, ids=lambda c: shlex.split(c)[1])
def test_every_command_exits_0_and_writes_what_it_names(walk, cmd):
    res = walk[cmd]
    assert res.returncode == 0, f"{cmd}\n{res.stdout[-2000:]}\n{res.stderr[-2000:]}"
    words = shlex.split(cmd)
    if "--out" in words:
        written = walk["folder"] / words[words.index("--out") + 1]
        assert written.is_file() and written.stat().st_size > 0


def test_the_outputs_say_what_the_page_says(walk):
    check = next(walk[c].stdout for c in COMMANDS if " check-robot " in f" {c} ")
    assert re.search(r"design's feasibility rules on 256 sampled commands .*: [\d.]+ % feasible", check)
    assert "flange: origin [2.915, -0.000, 0.760], axes x+X y+Y z+Z" in check  # the frame the page names
    design = next(walk[c].stdout for c in COMMANDS if " design " in f" {c} ")
    assert "certificate (A, every 12-pose distinct plan" in design
    identify = next(walk[c].stdout for c in COMMANDS if " identify " in f" {c} ")
    assert "check passed" in identify
