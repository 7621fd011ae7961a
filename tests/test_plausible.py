"""Plausibility of typed quantities (issue 21): a slipped unit exits 2 naming the file, the key
and the likely mistake; an odd but possible value warns; nothing ends in a traceback.

The fuzz scales scenario and overlay values by the usual unit factors (1e+-3, 1e+-6, pi/180)
and runs simulate and identify (from-urdf for the overlay): each run exits 0 (maybe with a
warning) or 2, never anything else (an exception would fail the test before its assertion).
"""

from __future__ import annotations

import math
import re
import warnings
from pathlib import Path

import badcases as bc
import numpy as np
import pytest
from conftest import ROOT
from urdf_robots import arm_overlay, arm_urdf

from calbench.bench.campaign import simulate, truth_robot
from calbench.bench.model import Robot
from calbench.bench.scenario import PlausibilityWarning, check_scenario, load_scenario
from calbench.identify.cli import main
from calbench.identify.core import ForwardModel, NoEquilibrium, design_from_observations, from_campaign
from calbench.identify.design import load_design_scenario

BASE = bc.scenario_text(n_poses=4)  # the FANUC, 700 kg, sigma 20 um, compensator 2.6e6 N/m 0.83 m


def _run(tmp_path: Path, text: str, capsys, name="s") -> tuple[int, str]:
    scn = tmp_path / f"{name}.toml"
    scn.write_text(text, encoding="utf-8")
    rc = main(["simulate", str(scn), "--out", str(tmp_path / f"{name}.mcap")])
    return rc, capsys.readouterr().err


MISTAKES = {
    "sigma in um": ("sigma = 20e-6", "sigma = 20", "tracker.sigma", "micrometres written as metres"),
    "compliance in urad": (
        "compliance = [0.25e-6, ",
        "compliance = [0.25, ",
        "truth.compliance[0]",
        "urad/(N*m)",
    ),
    "a stiffness": (
        "compliance = [0.25e-6, ",
        "compliance = [4e6, ",
        "truth.compliance[0]",
        "a stiffness in N*m/rad",
    ),
    "tonnes": ("mass = 700.0", "mass = 0.7", "load.mass", "tonnes written as kg"),
    "grams": ("mass = 700.0", "mass = 700000.0", "load.mass", "grams written as kg"),
    "preload in mm": ("preload = 0.83", "preload = 830.0", "truth.compensator.preload", "millimetres"),
    "tracker in mm": (
        "position = [3.5, -3.5, 3.2]",
        "position = [3500, -3500, 3200]",
        "tracker.position",
        "millimetres",
    ),
}


@pytest.mark.parametrize("case", sorted(MISTAKES))
def test_a_slipped_unit_exits_2_naming_file_key_and_mistake(tmp_path, capsys, case):
    old, new, key, mistake = MISTAKES[case]
    assert old in BASE
    rc, err = _run(tmp_path, BASE.replace(old, new), capsys)
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1, err
    assert f"s.toml: {key}: expected" in lines[0] and mistake in lines[0]
    assert not (tmp_path / "s.mcap").exists()


@pytest.mark.parametrize("verb", ["design", "montecarlo"])
def test_a_slipped_unit_found_on_a_worker_names_the_users_file(tmp_path, capsys, verb):
    """design and montecarlo check the scenario where its copy is rebuilt (a worker's private
    folder): the message still names the file the user typed, not that copy."""
    scn = tmp_path / "mine.toml"
    scn.write_text(BASE.replace("sigma = 20e-6", "sigma = 20"), encoding="utf-8")
    out = ["--out", str(tmp_path / "d.toml")] if verb == "design" else ["--runs", "2"]
    assert main([verb, str(scn), *out]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"calbench {verb}: error: {scn}: tracker.sigma: expected"), err


def test_angles_in_radians_exit_2_with_the_degrees_meant(tmp_path, capsys):
    text = re.sub(
        r"^q = \[(.*)\]$",
        lambda m: "q = [" + ", ".join(f"{math.radians(float(x)):.4f}" for x in m[1].split(",")) + "]",
        BASE,
        flags=re.M,
    )
    rc, err = _run(tmp_path, text, capsys)
    assert rc == 2 and "s.toml: pose: expected joint angles in degrees" in err
    assert "radians written for degrees" in err and "-30.0, -45.0, 30.0, 135.0] deg" in err


@pytest.mark.parametrize(
    "old, new, key",
    [("sigma = 20e-6", "sigma = 2e-3", "tracker.sigma"), ("mass = 700.0", "mass = 7000.0", "load.mass")],
)
def test_an_odd_but_possible_value_warns_once_and_runs(tmp_path, capsys, old, new, key):
    rc, err = _run(tmp_path, BASE.replace(old, new), capsys)
    assert rc == 0, err
    warned = [x for x in err.splitlines() if "warning" in x]
    assert len(warned) == 1 and "calbench simulate: warning: " in warned[0] and f": {key}: " in warned[0]


def _from_urdf(tmp_path: Path, overlay: str, out: str) -> int:
    """from-urdf of the test arm with this overlay text."""
    (tmp_path / "arm.urdf").write_text(arm_urdf())
    (tmp_path / "arm.toml").write_text(overlay)
    args = [str(tmp_path / "arm.urdf"), "--overlay", str(tmp_path / "arm.toml"), "--out", str(tmp_path / out)]
    return main(["from-urdf", *args])


def test_an_overlay_position_in_mm_exits_2(tmp_path, capsys):
    rc = _from_urdf(
        tmp_path, arm_overlay().replace("pos = [0.25, 0.3, 0.25]", "pos = [250, 300, 250]"), "a.xml"
    )
    err = capsys.readouterr().err
    assert rc == 2 and "arm.toml: reflectors.r1.pos: expected an offset" in err and "(0.464 m)" in err
    assert not (tmp_path / "a.xml").exists()


def test_the_shipped_scenarios_raise_no_warning():
    paths = sorted((ROOT / "scenarios").glob("*.toml"))
    assert len(paths) >= 5
    with warnings.catch_warnings():
        warnings.simplefilter("error", PlausibilityWarning)
        for p in paths:
            scn, _ = load_design_scenario(p)
            check_scenario(scn, Robot.from_file(scn.robot))


def test_no_equilibrium_in_a_fit_names_the_pose_and_the_likely_cause(tmp_path):
    """The fit's parameters 10^4 x a robot's: the forward model says which pose and why (it
    was a bare RuntimeError with theta, reaching the user as a traceback)."""
    path = tmp_path / "s.toml"
    path.write_text(BASE, encoding="utf-8")
    scn = load_scenario(path)
    tr = truth_robot(scn)
    obs = from_campaign(simulate(scn, None, robot=tr))
    robot = Robot.from_file(scn.robot)
    fm = ForwardModel(robot, design_from_observations(robot, obs))
    theta = robot.layout.theta(robot.params())
    theta[:6] = 1e-2
    with pytest.raises(NoEquilibrium) as got:
        fm.evaluate(theta)
    msg = str(got.value)
    assert msg.startswith(f"pose {got.value.pose} (q = ") and "no static equilibrium" in msg
    assert "k1 = 1e+04 urad/(N*m)" in msg and "unit slip" in msg
    assert isinstance(got.value, RuntimeError)  # an estimator's trial step still rejects it


# --------------------------------------------------------------------------- the fuzz

FACTORS = (1e3, 1e-3, 1e6, 1e-6, math.pi / 180)
SCENARIO_KEYS = ("sigma", "compliance", "mass", "preload", "position", "q")
OVERLAY_KEYS = ("reflectors", "payload")


def _scaled(m: re.Match, f: float) -> str:
    """A ``key = value`` or ``key = [values]`` match with its numbers times f."""
    vals = [repr(float(x) * f) for x in m[2].strip("[]").split(",")]
    return m[1] + (f"[{', '.join(vals)}]" if m[2].startswith("[") else vals[0])


def _scale_line(text: str, key: str, f: float) -> str:
    """Every line ``key = ...`` of a scenario with its numbers scaled by f."""
    pattern = re.compile(rf"^({key} = )(\[.*\]|[-\d.e+]+)$", re.M)
    return pattern.sub(lambda m: _scaled(m, f), text)


def _scale_attach(text: str, table: str, f: float) -> str:
    """The ``pos`` of every overlay table ``[table...]`` scaled by f."""
    pattern = re.compile(rf"^(\[{table}[^\]]*\]\nlink = \"\w+\"\npos = )(\[.*\])$", re.M)
    return pattern.sub(lambda m: _scaled(m, f), text)


def test_fuzz_unit_factors_end_in_exit_0_or_2(tmp_path, capsys):
    seen = {0: 0, 2: 0}
    for i, (key, f) in enumerate((k, f) for k in SCENARIO_KEYS for f in FACTORS):
        text = _scale_line(BASE, key, f)
        assert text != BASE, key
        rc, err = _run(tmp_path, text, capsys, name=f"f{i}")
        assert rc in (0, 2), (key, f, err)
        if rc == 0:
            rc = main(["identify", str(tmp_path / f"f{i}.mcap")])
            err = capsys.readouterr().err
            assert rc in (0, 2), (key, f, err)
        seen[rc] += 1
    for key in OVERLAY_KEYS:
        for f in (1e3, 1e-3):
            text = _scale_attach(arm_overlay(), key, f)
            assert text != arm_overlay()
            rc = _from_urdf(tmp_path, text, f"a{key}{f}.xml")
            assert rc in (0, 2), (key, f, capsys.readouterr().err)
            seen[rc] += 1
    assert seen[0] and seen[2]  # both outcomes met: the fuzz reaches past the checks


def test_the_compliance_messages_quote_the_fits_own_bound(tmp_path, capsys):
    """One constant: the band the messages quote ends where a fit may move (bench/model's
    MAX_COMPLIANCE, the top of BOUNDS), a value at that bound runs quietly, one above it warns."""
    from calbench.bench.model import MAX_COMPLIANCE

    robot = Robot.from_file(ROOT / "mjcf" / "m900ib700.xml")
    assert np.all(robot.layout.upper[: robot.n_act] == MAX_COMPLIANCE) and MAX_COMPLIANCE == 1e-4
    old = "compliance = [0.25e-6, "
    rc, err = _run(tmp_path, BASE.replace(old, "compliance = [4e6, "), capsys, "stiff")
    assert rc == 2 and "(a joint's: 1e-10 ... 1e-4)" in err, err
    rc, err = _run(tmp_path, BASE.replace(old, f"compliance = [{MAX_COMPLIANCE!r}, "), capsys, "edge")
    assert rc == 0 and "warning" not in err, err
    rc, err = _run(tmp_path, BASE.replace(old, f"compliance = [{2 * MAX_COMPLIANCE!r}, "), capsys, "soft")
    assert (
        rc == 0
        and "truth.compliance[0]: compliance 0.0002 rad/(N*m) is outside a robot joint's 1e-10 ... 1e-4"
        in err
    ), err
