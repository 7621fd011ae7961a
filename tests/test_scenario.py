"""Scenario loading: a valid file, every class of bad input, seed override, limits, writing."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
from conftest import PAPER

from calbench.bench.core import InputError
from calbench.bench.model import Spring
from calbench.bench.scenario import (
    Scenario,
    check_joint_limits,
    load_scenario,
    parse_scenario,
    scenario_as_dict,
    scenario_to_toml,
)
from calbench.bench.tracker import (
    DEFAULT_DISTANCE,
    DEFAULT_SIGMA,
    DEFAULT_TRANSVERSE,
    TrackerSpec,
    noise_covariance,
)

BASE = """\
name = "unit"
description = "a small valid scenario"
robot = "robot.xml"
seed = 7

[truth]
compliance = [1e-7, 2e-7, 3e-7, 4e-7, 5e-7, 6e-7]

[truth.compensator]
stiffness = 1.0e6
preload = 0.5

[truth.effects.link_compliance]
link = "forearm"
compliance = [1e-8, 0.0, 2e-8]

[truth.effects.base_compliance]
compliance = [1e-9, 2e-9]

[truth.effects.joint_nonlinearity]
joint = 3
cubic = 1.5e5

[tracker]
sigma = 2.5e-5
position = [3.0, -1.0, 0.5]
yaw = 90.0
model = "spec"
distance = [1e-5, 3e-7]
transverse = [1.5e-5, 6e-6]

[load]
mass = 700.0

[work]
q = [0, 10, -20, 30, 40, 50]
wrench = [0, 0, -1000, 0, 0, 0]

[[pose]]
q = [0, 0, 0, 0, 0, 0]

[[pose]]
q = [10, 20, 30, 40, 50, 60]
wrench = [0, 0, -6867, 0, 0, 0]
repeats = 3
"""

POSES = BASE[BASE.index("[[pose]]") :]


def write(tmp_path: Path, text: str, name: str = "scenario.toml") -> Path:
    """Write a scenario next to a dummy robot file (only its existence is checked here)."""
    (tmp_path / "robot.xml").write_text("<mujoco/>\n")
    path = tmp_path / name
    path.write_text(text)
    return path


def test_valid_scenario_parses_in_si_units(tmp_path):
    path = write(tmp_path, BASE)
    scn = load_scenario(path)
    assert isinstance(scn, Scenario)
    assert scn.path == path and scn.text == BASE
    assert scn.robot == (tmp_path / "robot.xml").resolve()
    assert scn.seed == 7
    np.testing.assert_array_equal(scn.compliance, [1e-7, 2e-7, 3e-7, 4e-7, 5e-7, 6e-7])
    assert scn.compensators == {"compensator": Spring(1.0e6, 0.5)}
    assert scn.effects["link_compliance"]["link"] == "forearm"
    np.testing.assert_array_equal(scn.effects["link_compliance"]["compliance"], [1e-8, 0, 2e-8])
    np.testing.assert_array_equal(scn.effects["base_compliance"]["compliance"], [1e-9, 2e-9])
    assert scn.effects["joint_nonlinearity"] == {"joint": 3, "cubic": 1.5e5}
    t = scn.tracker
    np.testing.assert_array_equal(t.position, [3.0, -1.0, 0.5])
    assert t.yaw == pytest.approx(math.pi / 2, rel=1e-15)
    assert (t.model, t.sigma, t.distance, t.transverse) == ("spec", 2.5e-5, (1e-5, 3e-7), (1.5e-5, 6e-6))
    assert scn.load_mass == 700.0
    np.testing.assert_allclose(scn.work.q, np.radians([0, 10, -20, 30, 40, 50]), rtol=1e-15)
    np.testing.assert_array_equal(scn.work.wrench, [0, 0, -1000, 0, 0, 0])
    assert len(scn.poses) == 2
    p0, p1 = scn.poses
    np.testing.assert_array_equal(p0.q, np.zeros(6))
    assert p0.wrench is None and p0.repeats == 1
    np.testing.assert_allclose(p1.q, np.radians([10, 20, 30, 40, 50, 60]), rtol=1e-15)
    np.testing.assert_array_equal(p1.wrench, [0, 0, -6867, 0, 0, 0])
    assert p1.repeats == 3
    with pytest.raises(ValueError):  # arrays are read-only: the dataclass is really frozen
        p1.q[0] = 1.0


def test_minimal_scenario_gets_defaults(tmp_path):
    text = """robot = "robot.xml"
seed = 0
[truth]
compliance = [1, 1, 1, 1, 1, 1]
[truth.compensator]
stiffness = 0
preload = 0
[tracker]
position = [1, 2, 3]
[load]
mass = 1
[[pose]]
q = [0, 0, 0, 0, 0, 0]
"""
    scn = load_scenario(write(tmp_path, text))
    t = scn.tracker
    assert (t.yaw, t.model, t.sigma) == (0.0, "isotropic", DEFAULT_SIGMA)
    assert (t.distance, t.transverse) == (DEFAULT_DISTANCE, DEFAULT_TRANSVERSE)
    assert scn.effects == {} and scn.work is None
    assert isinstance(scn.compensators["compensator"].stiffness, float)


def test_robot_resolved_relative_to_scenario_not_cwd(tmp_path, monkeypatch):
    (tmp_path / "mjcf").mkdir()
    (tmp_path / "mjcf" / "arm.xml").write_text("<mujoco/>\n")
    (tmp_path / "scenarios").mkdir()
    path = tmp_path / "scenarios" / "s.toml"
    path.write_text(BASE.replace('robot = "robot.xml"', 'robot = "../mjcf/arm.xml"'))
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    assert load_scenario(path).robot == (tmp_path / "mjcf" / "arm.xml").resolve()


def _drop(line: str) -> tuple[str, str]:
    return (line + "\n", "")


# (text to replace, replacement, key path the error must name); old=None prepends `new`.
BAD = {
    "syntax": ("seed = 7", "seed = = 7", "line 4"),
    "unknown top key": (None, "colour = 1\n", "colour"),
    "unknown tracker key": ("sigma = 2.5e-5", "sgima = 2.5e-5", "tracker.sgima"),
    "unknown pose key": ("repeats = 3", "repeat = 3", "pose[1].repeat"),
    "unknown effect": (
        "[truth.effects.base_compliance]",
        "[truth.effects.base_tilt]",
        "truth.effects.base_tilt",
    ),
    "missing seed": (*_drop("seed = 7"), "seed"),
    "missing robot key": (*_drop('robot = "robot.xml"'), "robot"),
    "missing mass": (*_drop("mass = 700.0"), "load.mass"),
    "missing load": ("[load]\nmass = 700.0\n", "", "load"),
    "missing stiffness": (*_drop("stiffness = 1.0e6"), "truth.compensator.stiffness"),
    "missing position": (*_drop("position = [3.0, -1.0, 0.5]"), "tracker.position"),
    "missing pose q": (*_drop("q = [0, 0, 0, 0, 0, 0]"), "pose[0].q"),
    "missing link": (*_drop('link = "forearm"'), "truth.effects.link_compliance.link"),
    "no poses": (POSES, "", "pose"),
    "pose not array": (POSES, "[pose]\nq = [0, 0, 0, 0, 0, 0]\n", "pose"),
    "seed float": ("seed = 7", "seed = 7.5", "seed"),
    "seed string": ("seed = 7", 'seed = "7"', "seed"),
    "seed bool": ("seed = 7", "seed = true", "seed"),
    "seed negative": ("seed = 7", "seed = -1", "seed"),
    "robot not string": ('robot = "robot.xml"', "robot = 5", "robot"),
    "name not string": ('name = "unit"', "name = 3", "name"),
    "mass bool": ("mass = 700.0", "mass = true", "load.mass"),
    "sigma string": ("sigma = 2.5e-5", 'sigma = "20um"', "tracker.sigma"),
    "q element bool": ("q = [0, 0, 0, 0, 0, 0]", "q = [0, 0, true, 0, 0, 0]", "pose[0].q[2]"),
    "q not array": ("q = [0, 0, 0, 0, 0, 0]", "q = 0", "pose[0].q"),
    "link not a name": ('link = "forearm"', "link = 3", "truth.effects.link_compliance.link"),
    "joint out of range": ("joint = 3", "joint = 0", "truth.effects.joint_nonlinearity.joint"),
    "joint float": ("joint = 3", "joint = 3.0", "truth.effects.joint_nonlinearity.joint"),
    "model unknown": ('model = "spec"', 'model = "fancy"', "tracker.model"),
    "compliance length": (
        "compliance = [1e-7, 2e-7, 3e-7, 4e-7, 5e-7, 6e-7]",
        "compliance = [1e-7, 2e-7, 3e-7, 4e-7, 5e-7]",
        "truth.compliance",
    ),
    "position length": ("position = [3.0, -1.0, 0.5]", "position = [3.0, -1.0]", "tracker.position"),
    "wrench length": ("wrench = [0, 0, -6867, 0, 0, 0]", "wrench = [0, 0, -6867, 0, 0]", "pose[1].wrench"),
    "work q length": ("q = [0, 10, -20, 30, 40, 50]", "q = [0, 10, -20, 30, 40, 50, 60]", "work.q"),
    "base compliance length": (
        "compliance = [1e-9, 2e-9]",
        "compliance = [1e-9]",
        "truth.effects.base_compliance.compliance",
    ),
    "preload nan": ("preload = 0.5", "preload = nan", "truth.compensator.preload"),
    "cubic inf": ("cubic = 1.5e5", "cubic = inf", "truth.effects.joint_nonlinearity.cubic"),
    "position inf": ("position = [3.0, -1.0, 0.5]", "position = [3.0, -inf, 0.5]", "tracker.position[1]"),
    "yaw nan": ("yaw = 90.0", "yaw = nan", "tracker.yaw"),
    "mass zero": ("mass = 700.0", "mass = 0.0", "load.mass"),
    "mass negative": ("mass = 700.0", "mass = -1.0", "load.mass"),
    "sigma zero": ("sigma = 2.5e-5", "sigma = 0", "tracker.sigma"),
    "compliance zero": ("compliance = [1e-7,", "compliance = [0.0,", "truth.compliance[0]"),
    "compliance negative": ("6e-7]", "-6e-7]", "truth.compliance[5]"),
    "distance a zero": ("distance = [1e-5, 3e-7]", "distance = [0, 3e-7]", "tracker.distance"),
    "transverse b negative": (
        "transverse = [1.5e-5, 6e-6]",
        "transverse = [1.5e-5, -6e-6]",
        "tracker.transverse[1]",
    ),
    "stiffness negative": ("stiffness = 1.0e6", "stiffness = -1.0e6", "truth.compensator.stiffness"),
    "preload negative": ("preload = 0.5", "preload = -0.5", "truth.compensator.preload"),
    "link compliance negative": (
        "compliance = [1e-8, 0.0, 2e-8]",
        "compliance = [1e-8, -1e-9, 2e-8]",
        "truth.effects.link_compliance.compliance[1]",
    ),
    "repeats zero": ("repeats = 3", "repeats = 0", "pose[1].repeats"),
    "repeats float": ("repeats = 3", "repeats = 2.0", "pose[1].repeats"),
    "robot missing file": ('robot = "robot.xml"', 'robot = "nope.xml"', "robot"),
}


@pytest.mark.parametrize("case", list(BAD), ids=list(BAD))
def test_bad_input_names_file_key_and_expectation(tmp_path, case):
    old, new, key = BAD[case]
    if old is None:
        text = new + BASE
    else:
        assert old in BASE, "the test case must actually change the base text"
        text = BASE.replace(old, new, 1)
    path = write(tmp_path, text, "bad_scenario.toml")
    with pytest.raises(InputError) as info:
        load_scenario(path)
    msg = str(info.value)
    assert str(path) in msg
    assert f": {key}: expected" in msg, msg
    assert info.value.key == key


def test_section_that_is_not_a_table(tmp_path):
    text = "load = 700.0\n" + BASE.replace("[load]\nmass = 700.0\n", "")
    with pytest.raises(InputError) as info:
        load_scenario(write(tmp_path, text))
    assert info.value.key == "load" and "expected a table" in str(info.value)


def test_unknown_key_lists_allowed_keys(tmp_path):
    path = write(tmp_path, BASE.replace("sigma = 2.5e-5", "sgima = 2.5e-5"))
    with pytest.raises(InputError, match="allowed keys here: sigma, position, yaw"):
        load_scenario(path)


def test_syntax_error_carries_tomllib_line_info(tmp_path):
    path = write(tmp_path, BASE.replace("seed = 7", "seed = = 7"))
    with pytest.raises(InputError, match=r"valid TOML.*line 4, column"):
        load_scenario(path)


def test_unreadable_file_is_input_error(tmp_path):
    with pytest.raises(InputError, match="absent.toml"):
        load_scenario(tmp_path / "absent.toml")


def test_seed_override(tmp_path):
    path = write(tmp_path, BASE)
    assert load_scenario(path).seed == 7
    assert load_scenario(path, seed=99).seed == 99
    no_seed = write(tmp_path, BASE.replace("seed = 7\n", ""), "noseed.toml")
    assert load_scenario(no_seed, seed=3).seed == 3
    for bad in (-1, True, 2.5):
        with pytest.raises(InputError, match="seed: expected an integer >= 0"):
            load_scenario(path, seed=bad)
    # a malformed seed in the file is still reported even when overridden
    with pytest.raises(InputError, match="seed"):
        load_scenario(write(tmp_path, BASE.replace("seed = 7", "seed = 1.5"), "b.toml"), seed=1)


def _limits(j2_deg=(-60.0, 75.0)) -> np.ndarray:
    lim = np.radians(np.tile([-180.0, 180.0], (6, 1)))
    lim[1] = np.radians(j2_deg)
    return lim


def test_check_joint_limits(tmp_path):
    scn = load_scenario(write(tmp_path, BASE))
    check_joint_limits(scn, _limits())  # everything inside: no error
    check_joint_limits(scn, _limits((-60.0, 20.0)))  # pose[1].q[1] exactly at the limit
    with pytest.raises(InputError) as info:
        check_joint_limits(scn, _limits((-60.0, 15.0)))
    msg = str(info.value)
    assert info.value.key == "pose[1].q[1]"
    assert str(scn.path) in msg and "expected" in msg
    assert "[-60.000, 15.000] degrees" in msg and "20.0" in msg
    with pytest.raises(ValueError):
        check_joint_limits(scn, np.zeros((6, 3)))


def test_check_joint_limits_reports_work_pose(tmp_path):
    scn = load_scenario(write(tmp_path, BASE))
    lim = _limits()
    lim[2] = np.radians([-10.0, 90.0])  # work.q[2] = -20 deg; poses are >= 0
    with pytest.raises(InputError) as info:
        check_joint_limits(scn, lim)
    assert info.value.key == "work.q[2]"


def _assert_same(a: Scenario, b: Scenario) -> None:
    close = dict(rtol=1e-14, atol=0)
    assert a.robot == b.robot and a.seed == b.seed and a.load_mass == b.load_mass
    np.testing.assert_array_equal(a.compliance, b.compliance)
    assert a.compensators == b.compensators
    assert a.effects.keys() == b.effects.keys()
    for name in a.effects:
        for k, v in a.effects[name].items():
            np.testing.assert_array_equal(v, b.effects[name][k])
    ta, tb = a.tracker, b.tracker
    np.testing.assert_array_equal(ta.position, tb.position)
    assert (ta.model, ta.sigma, ta.distance, ta.transverse) == (
        tb.model,
        tb.sigma,
        tb.distance,
        tb.transverse,
    )
    np.testing.assert_allclose(ta.yaw, tb.yaw, **close)
    np.testing.assert_allclose(a.work.q, b.work.q, **close)
    np.testing.assert_array_equal(a.work.wrench, b.work.wrench)
    assert len(a.poses) == len(b.poses)
    for pa, pb in zip(a.poses, b.poses):
        np.testing.assert_allclose(pa.q, pb.q, **close)
        assert pa.repeats == pb.repeats
        assert (pa.wrench is None) == (pb.wrench is None)
        if pa.wrench is not None:
            np.testing.assert_array_equal(pa.wrench, pb.wrench)


def test_round_trip_through_toml_writer(tmp_path):
    original = load_scenario(write(tmp_path, BASE))
    plan_dir = tmp_path / "plans"
    plan_dir.mkdir()
    text = scenario_to_toml(scenario_as_dict(original, plan_dir))
    again = parse_scenario(text, plan_dir / "plan.toml")
    _assert_same(original, again)
    assert again.text == text
    assert "q = [10.0, 20.0, 30.0, 40.0, 50.0, 60.0]" in text  # degrees, tidily rounded
    assert 'name = "unit"' in text


def test_writer_orders_tables_escapes_strings_and_skips_none(tmp_path):
    (tmp_path / "robot.xml").write_text("<mujoco/>\n")
    name = 'plan "A" \\ 2\nline two \u00b5m \x7f'
    doc = {  # deliberately scalars after tables: the writer must reorder them
        "pose": [{"q": [1.5, 2, 3, 4, 5, 6], "repeats": 2}, {"q": np.arange(6.0)}],
        "truth": {
            "compensator": {"stiffness": 2.0, "preload": 0.25},
            "effects": {"joint_nonlinearity": {"joint": 2, "cubic": -1e-300}},
            "compliance": np.full(6, 1e-7),
        },
        "tracker": {"position": [0.1, 0.2, 0.3]},
        "load": {"mass": np.float64(12.5)},
        "work": None,
        "name": name,
        "robot": "robot.xml",
        "seed": 11,
    }
    scn = parse_scenario(scenario_to_toml(doc), tmp_path / "w.toml")
    assert scn.seed == 11 and scn.load_mass == 12.5 and scn.work is None
    assert scn.effects["joint_nonlinearity"] == {"joint": 2, "cubic": -1e-300}
    assert [p.repeats for p in scn.poses] == [2, 1]
    np.testing.assert_allclose(scn.poses[0].q, np.radians([1.5, 2, 3, 4, 5, 6]), rtol=1e-15)
    import tomllib

    assert tomllib.loads(scenario_to_toml(doc))["name"] == name
    with pytest.raises(ValueError):
        scenario_to_toml({"seed": float("nan")})


def test_design_table_keys_match_the_design_module():
    """bench/scenario/parse.py accepts exactly the [design] keys identify/design_candidates.py reads."""
    from calbench.bench.scenario import DESIGN_KEYS as accepted
    from calbench.identify.design import DESIGN_KEYS as read

    assert set(accepted) == set(read)


def test_scenario_variant_overrides_and_validates(tmp_path):
    from calbench.bench.scenario import load_scenario, scenario_variant

    paper = PAPER
    out = scenario_variant(
        paper,
        tmp_path / "v.toml",
        name="v",
        seed=7,
        compensator=(6e6, 0.7),
        extra="[truth.effects.base_compliance]\ncompliance = [4e-9, 4e-9]",
    )
    scn = load_scenario(out)
    assert (scn.name, scn.seed) == ("v", 7)
    assert scn.compensators == {"compensator": Spring(6e6, 0.7)}
    np.testing.assert_array_equal(scn.effects["base_compliance"]["compliance"], [4e-9, 4e-9])
    assert scn.robot == (paper.parent.parent / "mjcf" / "m900ib700.xml").resolve()
    assert "Table 5" in out.read_text()  # comments kept
    bad = tmp_path / "bad.toml"
    with pytest.raises(InputError):
        scenario_variant(paper, bad, extra="[truth.effects.base_compliance]\ncompliance = [-1, 0]")
    assert not bad.exists()
    # another MJCF, and the compensator's table dropped with its keys (a robot without the spring)
    other = tmp_path / "robot.xml"
    other.write_text((paper.parent.parent / "mjcf" / "m900ib700.xml").read_text())
    bare = load_scenario(
        scenario_variant(paper, tmp_path / "bare.toml", robot=other, drop=("truth.compensator",))
    )
    assert bare.robot == other.resolve() and bare.compensators == {}
    assert bare.tracker.to_dict() == load_scenario(paper).tracker.to_dict()
    assert len(bare.poses) == len(load_scenario(paper).poses)
    with pytest.raises(ValueError, match="no table"):
        scenario_variant(out, tmp_path / "again.toml", drop=("truth.no_such_table",))


# --------------------------------------------------------------------------- TrackerSpec as a dict

TRACKERS = {
    "isotropic": TrackerSpec(position=np.array([3.25, -1.5, 0.75]), yaw=0.3, model="isotropic", sigma=25e-6),
    "spec": TrackerSpec(
        position=np.array([-2.0, 4.0, 1.1]),
        yaw=-1.2,
        model="spec",
        sigma=7e-6,
        distance=(12e-6, 0.4e-6),
        transverse=(18e-6, 5e-6),
    ),
    "iso10360": TrackerSpec(
        position=np.array([1.0, 5.0, 2.2]),
        yaw=0.7,
        model="iso10360",
        distance=(11e-6, 0.5e-6),
        transverse=(16e-6, 4e-6),
        random=0.4,
        correlation_angle=0.2,
        correlation_range=0.6,
        drift=(3e-6, 2e-6),
    ),
}


def assert_same_tracker(a: TrackerSpec, b: TrackerSpec) -> None:
    np.testing.assert_array_equal(a.position, b.position)
    assert (a.yaw, a.model, a.sigma, a.distance, a.transverse) == (
        b.yaw,
        b.model,
        b.sigma,
        b.distance,
        b.transverse,
    )
    assert (a.random, a.correlation_angle, a.correlation_range, a.drift) == (
        b.random,
        b.correlation_angle,
        b.correlation_range,
        b.drift,
    )


@pytest.mark.parametrize("model", ["isotropic", "spec", "iso10360"])
def test_tracker_dict_round_trip_keeps_the_noise_model(model):
    spec = TRACKERS[model]
    d = spec.to_dict()
    assert list(d) == ["position", "yaw", "model", "sigma", "distance", "transverse"] + (
        ["random", "correlation_angle", "correlation_range", "drift"] if model == "iso10360" else []
    )
    back = TrackerSpec.from_dict(json.loads(json.dumps(d)))  # through JSON, as in a log
    assert_same_tracker(back, spec)
    assert back.to_dict() == d
    # the noise model survives: the covariance it gives is the original's, bit for bit
    pts = np.array([[2.0, 0.5, -0.3], [5.0, -1.0, 2.0]])
    np.testing.assert_array_equal(noise_covariance(back, pts), noise_covariance(spec, pts))
    with pytest.raises(ValueError):  # frozen, like the scenario's
        back.position[0] = 0.0


def test_tracker_from_dict_defaults_and_bad_values():
    spec = TrackerSpec.from_dict({"position": [1, 2, 3], "vendor": "ignored"})
    assert (spec.yaw, spec.model, spec.sigma) == (0.0, "isotropic", DEFAULT_SIGMA)
    assert (spec.distance, spec.transverse) == (DEFAULT_DISTANCE, DEFAULT_TRANSVERSE)
    cases = {
        "model": ({"position": [0, 0, 0], "model": "laser"}, "log.mcap: info.tracker.model"),
        "position": ({"position": [0, 0]}, "log.mcap: info.tracker.position"),
        "sigma": ({"position": [0, 0, 0], "sigma": -1}, "log.mcap: info.tracker.sigma"),
        "table": (None, "log.mcap: info.tracker: expected a table"),
    }
    for d, msg in cases.values():
        with pytest.raises(InputError, match=re.escape(msg)):
            TrackerSpec.from_dict(d, "log.mcap", "info.tracker")
