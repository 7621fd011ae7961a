"""The exposure's SPRUNG JOINT rule (identify/discover/exposure.py): on the joint a compensator
spring acts on, the parameters ``coupled`` names for an effect (the workflow: that joint's
compliance) are profiled in its candidate fit where it exposes them beyond REGION_SIGMAS std, not
only the springs. Here the exposure is taken on a synthetic whitened
Jacobian (two base columns, one effect column half absorbed) with a stand-in profile, so what is
checked is the gate and what the reach becomes: the profile's reach beyond the parameter's own
spread at that level (sqrt(T_u) std) is its exposure to the effect, and the effects not named in
``coupled`` keep the first-order statement."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
from conftest import MJCF

from calbench.bench.model import Robot
from calbench.bench.model.effects import joint_nonlinearity
from calbench.identify.discover import (
    REGION_SIGMAS,
    exposure_report,
    label,
    library,
    sprung_joint_effects,
    unseen_chi2,
)

KR270 = MJCF.parent / "kr270.xml"


def test_the_effects_on_a_sprung_joint_are_the_j2_cubic_on_both_shipped_robots():
    """Both shipped robots' compensators span J2 alone (bench/model/robot.py's
    compensator_joint): of their library, only the J2 cubic acts on it."""
    for path in (MJCF, KR270):
        robot = Robot.from_file(path)
        got = sprung_joint_effects(SimpleNamespace(robot=robot), library(robot))
        assert got == {"joint_nonlinearity[j2]": {1}}  # and k2 its compliance


def _case():
    rng = np.random.default_rng(3)
    jb = rng.normal(size=(40, 2))
    effect = joint_nonlinearity(2)
    # the effect's column: mostly the first base column (absorbed), a tenth of it seen
    col = 0.995 * jb[:, :1] + 0.1 * rng.normal(size=(40, 1))
    final = SimpleNamespace(
        free=np.array([True, True]),
        at_bound=np.array([False, False]),
        values=np.array([1.0, 2.0]),
        names=("k1", "k2"),
        units=("rad/(N*m)", "rad/(N*m)"),
    )
    std = np.sqrt(np.diag(np.linalg.inv(jb.T @ jb)))
    return final, jb, std, [(effect, col)]


def test_a_sprung_effect_profiles_its_coupled_parameters_it_exposes_beyond_two_std():
    final, jw, std, cols = _case()
    lab = label(cols[0][0])
    plain = exposure_report(final, jw, std, cols, 1)
    first = np.array([p["by_effect"][lab] for p in plain])
    assert np.any(first > REGION_SIGMAS * std)  # the case exposes some parameter beyond the gate
    calls = []

    def profile(lab_, i, sigma, thr):
        calls.append((lab_, i))
        return 100.0 * sigma  # the candidate's profile reaches 100 std

    thr = unseen_chi2(1, 1)
    springs = np.zeros(2, bool)
    got = exposure_report(
        final, jw, std, cols, 1, profile=profile, profiled=springs, coupled={lab: frozenset({0, 1})}
    )
    gated = [i for i in range(2) if first[i] > REGION_SIGMAS * std[i]]
    assert sorted(i for _, i in calls) == gated
    for i in gated:
        beyond = (100.0 - math.sqrt(thr)) * std[i]
        assert got[i]["by_effect_profile"][lab] == beyond
        assert got[i]["bias"] >= beyond
    # only the parameters the effect is coupled to
    calls.clear()
    exposure_report(final, jw, std, cols, 1, profile=profile, profiled=springs, coupled={lab: frozenset({9})})
    assert calls == []
    # not coupled and not a spring: the profile is not walked, the first order stands
    calls.clear()
    same = exposure_report(final, jw, std, cols, 1, profile=profile, profiled=springs)
    assert calls == [] and [p["bias"] for p in same] == [p["bias"] for p in plain]
