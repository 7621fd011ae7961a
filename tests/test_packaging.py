"""A plain (non-editable) install: one import name, the shipped files as package data, and a
demo that runs outside the checkout and writes under the directory it is run from."""

from __future__ import annotations

import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from conftest import ROOT


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    r = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(out), str(ROOT)],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stderr
    (whl,) = out.glob("calbench-*.whl")
    return whl


def test_wheel_installs_one_namespace_with_the_models_and_scenarios(wheel):
    names = zipfile.ZipFile(wheel).namelist()
    top = {n.split("/")[0] for n in names if not n.split("/")[0].endswith(".dist-info")}
    assert top == {"calbench"}  # no top-level bench or identify
    assert "calbench/mjcf/m900ib700.xml" in names
    assert "calbench/scenarios/paper_table5.toml" in names
    assert "calbench/studies/discovery_power.toml" in names and "calbench/identify/study/run.py" in names
    assert "calbench/identify/design/plan.py" in names and "calbench/identify/discover/fit.py" in names
    # data folders inside the packages: the Foxglove schemas and the report template
    assert "calbench/bench/log/foxglove_schemas/foxglove.SceneUpdate.json" in names
    assert "calbench/identify/report/templates/report.html.j2" in names


def test_the_wheel_holds_every_room_and_its_face(wheel):
    """Every package folder of bench/ and identify/ (a room; pyproject.toml lists them one by one)
    ships with its modules and its face: a room left out installs nothing and fails only at its
    first import (the tracker models' room found by bench/tracker/base.py at run time, say)."""
    names = set(zipfile.ZipFile(wheel).namelist())
    for top in ("bench", "identify"):
        for init in (ROOT / top).rglob("__init__.py"):
            folder = init.parent.relative_to(ROOT).as_posix()
            for module in init.parent.glob("*.py"):
                assert f"calbench/{folder}/{module.name}" in names, folder
            if init.with_suffix(".pyi").exists():
                assert f"calbench/{folder}/__init__.pyi" in names, folder


def test_demo_runs_from_a_plain_install_outside_the_checkout(wheel, tmp_path):
    site = tmp_path / "site"
    subprocess.run(
        [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(site), str(wheel)],
        check=True,
        capture_output=True,
    )
    work = tmp_path / "elsewhere"
    work.mkdir()
    code = (
        "import calbench.identify.cli as c, sys; "
        "print(c.__file__, file=sys.stderr); sys.exit(c.main(['demo']))"
    )
    env = {**os.environ, "PYTHONPATH": str(site), "MPLBACKEND": "Agg", "RERUN_ANALYTICS": "0"}
    r = subprocess.run(
        [sys.executable, "-c", code], cwd=work, env=env, capture_output=True, text=True, timeout=600
    )
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stderr.splitlines()[0].startswith(str(site))  # the installed copy ran, not the checkout
    for f in ("paper_table5.mcap", "paper_table5.rrd", "paper_table5_hidden.discover.json"):
        assert (work / "logs" / f).is_file(), f
    # the list the command line checks up front is exactly what the demo wrote
    from calbench.identify.demo import demo_files

    assert {p.name for p in (work / "logs").iterdir()} == {p.name for p in demo_files(work / "logs").values()}
