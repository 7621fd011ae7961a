"""A scenario travels as texts (identify/runtime/portable.py) and comes back the same on any machine."""

from __future__ import annotations

import numpy as np
from conftest import MJCF, PAPER

from calbench.bench.scenario import load_scenario
from calbench.identify.runtime import PortableScenario, with_robot


def test_a_portable_scenario_rebuilds_the_same_scenario_without_the_users_files():
    scn = load_scenario(PAPER)
    p = PortableScenario.from_scenario(scn)
    assert str(PAPER.parent) not in p.text and "../mjcf" not in p.text  # no path into the checkout
    back = p.scenario()
    assert back.robot != scn.robot and back.robot.name == scn.robot.name
    assert back.robot.read_text() == MJCF.read_text()
    for f in ("seed", "load_mass", "compensators", "effects"):
        assert getattr(back, f) == getattr(scn, f), f
    assert np.array_equal(back.compliance, scn.compliance)
    assert all(np.array_equal(a.q, b.q) for a, b in zip(back.poses, scn.poses))
    assert p.scenario(seed=7).seed == 7 and p.scenario().robot == back.robot  # one file per robot text


def test_the_robot_key_is_replaced_whatever_its_quotes_and_comments_stay():
    assert (
        with_robot('# c\nrobot = "../a.xml"  # here\nseed = 1\n', "b.xml")
        == '# c\nrobot = "b.xml"  # here\nseed = 1\n'
    )
    assert with_robot("robot = '../a.xml'\n", 'we"ird.xml') == 'robot = "we\\"ird.xml"\n'
    assert 'robot = "b.xml"' in with_robot('"robot" = "../a.xml"\nseed = 1\n', "b.xml")  # rewritten whole
