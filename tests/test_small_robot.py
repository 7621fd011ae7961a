"""A robot smaller and softer than the heavy ones calbench was built on (a UR10-like cobot: 10 kg
payload, wrist compliance ~3e-5 rad/(N*m)), found by trying the UR10 from ur_description
through every verb (issue 21).

* design's lateral pull defaults to the payload's weight when that is less than 1200 N: a robot
  rated for 10 kg is not pulled with 1200 N (its statics would then bend far from linear);
* a compliance up to 1e-4 rad/(N*m), which the plausibility checks accept without a word, is
  inside the fit's bounds, so the one-step's chi2 profiles are not cut at 1e-5.
"""

from __future__ import annotations

import re

import pytest
from urdf_robots import TRUTH_K, arm_overlay, arm_urdf, convert_arm, scenario

from calbench.bench.model import ParamLayout
from calbench.identify.cli import main
from calbench.identify.design import read_design_settings


@pytest.mark.parametrize(
    ("table", "force"),
    [
        ("[load]\nmass = 10.0\n", 98.1),  # a cobot's rated payload: its weight
        ("[load]\nmass = 700.0\n", 1200.0),  # a heavy robot: the default, as before
        ("[load]\nmass = 10.0\n[design]\nlateral_force = 500.0\n", 500.0),  # given: kept
        ("", 1200.0),
    ],
)
def test_the_lateral_pull_defaults_to_at_most_the_payload_weight(tmp_path, table, force):
    path = tmp_path / "s.toml"
    path.write_text(table, encoding="utf-8")
    assert read_design_settings(path).lateral_force == pytest.approx(force, rel=1e-12)


def test_a_cobots_compliance_is_inside_the_fits_bounds():
    lay = ParamLayout(6, ())
    assert (lay.upper >= 1e-4).all()


def test_a_soft_arm_identifies_with_quadratic_profiles(tmp_path, capsys):
    """The tests' arm with drives 50 x softer (wrist 3e-5 rad/(N*m)) and a 10 kg payload: the
    check passes and no profile is cut at a bound (before: 'past its bound' on every wrist
    parameter, whose truth lay beyond 1e-5)."""
    rc, robot = convert_arm(tmp_path, arm_urdf(), arm_overlay())
    assert rc == 0
    soft = [50 * k for k in TRUTH_K]
    text = scenario(str(robot)).replace("mass = 400.0", "mass = 10.0")
    text = re.sub(r"^compliance = .*$", f"compliance = {soft!r}", text, flags=re.M)
    text = re.sub(r"^wrench = .*\n", "", text, flags=re.M)  # the heavy arm's kN pulls
    assert max(soft) > 1e-5
    (tmp_path / "soft.toml").write_text(text, encoding="utf-8")
    assert main(["simulate", str(tmp_path / "soft.toml"), "--out", str(tmp_path / "soft.mcap")]) == 0
    capsys.readouterr()
    assert main(["identify", str(tmp_path / "soft.mcap"), "--check"]) == 0
    out = capsys.readouterr().out
    assert "check passed" in out and "past its bound" not in out, out


def test_check_robot_loads_a_light_robot_with_at_most_a_third_of_its_mass(tmp_path, capsys):
    """The tests' arm at 1 % of its masses (about 19 kg moving): the loaded grid and the
    feasibility sample hang a third of that, not 100 kg, and nothing warns about the payload."""
    import mujoco

    rc, heavy = convert_arm(tmp_path, arm_urdf(), arm_overlay())
    assert rc == 0
    spec = mujoco.MjSpec.from_file(str(heavy))
    for b in spec.bodies:
        b.mass *= 0.01
        b.inertia = [0.01 * x for x in b.inertia]
    light = tmp_path / "light.xml"
    light.write_text(spec.to_xml(), encoding="utf-8")
    m = mujoco.MjModel.from_xml_path(str(light))
    moving = float(m.body_mass[m.body_weldid != 0].sum())
    capsys.readouterr()
    assert main(["check-robot", str(light), "--grid", "1", "--sample", "8"]) == 0
    out, err = capsys.readouterr()
    assert f"{float(f'{moving / 3:.2g}'):g} kg;" in out and "load.mass" not in err, (out, err)
    assert main(["check-robot", str(heavy), "--grid", "1", "--sample", "8"]) == 0
    assert "100 kg;" in capsys.readouterr().out  # a heavy robot: as before
