"""Batched candidates (identify/design/batch_info.py) against today's, one at a time (issue 16).

The batched chunk must give the same candidates (same commands, loads, order, rejection counts)
and the same information blocks as candidates.scalar_block (InfoEngine.pose per candidate)
within 1e-6 of each block's largest entry, the accuracy the issue asks for. What is left is the
forward-difference noise of the tangents' stiffness matrix, which today's blocks carry
themselves: changing the scalar path's own finite-difference step by 1e-4 moves its blocks by up
to ~4e-7 of their largest entry (measured on 40 candidates), and the batched blocks differ from
the scalar ones by as much (the loaded-minus-unloaded difference cancels most of each state's
gravity-driven sensitivity, which magnifies the ~1e-10 relative noise of each matrix).
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import PAPER

from calbench.bench.statics import Load
from calbench.identify.design import (
    EQUILIBRIUM_RULES,
    BatchInfo,
    InfoEngine,
    generate_candidates,
    horizontal_clearance,
    lateral_wrench,
    load_design_scenario,
)


@pytest.fixture(scope="module")
def paper():
    return load_design_scenario(PAPER)


@pytest.fixture(scope="module")
def both(paper):
    scn, st = paper
    return (
        generate_candidates(scn, st, n=300, processes=1, progress=False),
        generate_candidates(scn, st, n=300, progress=False, batched=False),
    )


def test_batched_candidates_are_todays_within_1e6(both):
    new, old = both
    assert np.array_equal(new.q, old.q) and np.array_equal(new.wrench, old.wrench)
    assert np.array_equal(new.kind, old.kind) and 0 < new.kind.sum() < len(new)
    for key in ("raw_commands", "passed_command_rules", "rejected_first_rule"):
        assert new.stats[key] == old.stats[key], key
    assert new.stats["rejected_first_rule"]["visibility"] > 0  # the equilibrium rules did reject
    scale = np.abs(old.blocks).max(axis=(1, 2))
    err = np.abs(new.blocks - old.blocks).max(axis=(1, 2)) / scale
    assert err.max() <= 1e-6, (err.argmax(), err.max())


def test_threads_do_not_change_the_candidates(paper, both):
    scn, st = paper
    two = generate_candidates(scn, st, n=300, processes=2, progress=False)
    assert np.array_equal(two.q, both[0].q) and np.array_equal(two.blocks, both[0].blocks)


def test_equilibrium_rules_agree_with_the_scalar_checks(paper):
    """Row by row on poses that break each rule: the visibility pose of Table 5 (refl_c hidden),
    two that pass the command rules but collide once gravity sags the arm, two whose mass
    compensator stands over a passive hinge (§3.3), and feasible ones; both loads."""
    scn, st = paper
    eng = InfoEngine(scn, st)
    info = BatchInfo(eng, nthread=1)
    q = np.radians(
        [
            [90, 0, 30, 45, -30, 45],
            [90, 120, 30, 0, 0, 0],
            [-119.3, -24.2, -107.4, -144.4, -18.3, 117.4],
            [112.5, -23.7, -109.6, -154.6, -101.0, -120.2],
            [82.5, 37.9, -59.2, 133.1, -120.5, -108.0],
            [53.1, 35.3, -13.0, -112.6, 97.1, 122.3],
            [180, 120, 30, -135, 30, -135],
        ]
    )
    w = np.array(
        [
            np.r_[eng.robot.weight(700.0), 0, 0, 0] if i % 2 == 0 else lateral_wrench(q[i, 0], 1.0, 1200.0)
            for i in range(len(q))
        ]
    )
    e0 = info.statics.solve(q)
    a0 = info.statics.stiffness(e0, None)
    load = Load(w[:, :3], w[:, 3:], eng.robot.payload_site)
    e1 = info.statics.solve(q, load, warm=e0, warm_stiffness=a0)
    s0, s1 = info.state(e0), info.state(e1)
    stacked = [np.stack(x, axis=1) for x in zip(s0, s1)]
    bad, seen = eng.feas.equilibrium_violations(*stacked)
    found = set()
    for i in range(len(q)):
        ref0 = eng.solver.solve(q[i])
        ref1 = eng.solver.solve(q[i], Load(w[i, :3], w[i, 3:], eng.robot.payload_site), warm=ref0)
        ref_bad, ref_seen = eng.feas.check_equilibria(ref0, ref1)
        assert [r for r, b in zip(EQUILIBRIUM_RULES, bad[i]) if b] == ref_bad, i
        assert np.array_equal(seen[i], ref_seen)
        for e, s in ((ref0, s0), (ref1, s1)):
            assert s[2][i] == pytest.approx(eng.feas.compensator_clearance(e.qpos), rel=1e-9)
        found.update(ref_bad)
    assert {"visibility", "self_collision", "compensator_discontinuity"} <= found
    assert any(not b.any() for b in bad)


def test_horizontal_clearance_by_hand():
    """A point 1 m beside a horizontal axis, one right above it, and a vertical axis's foot."""
    centres = np.array([[[0.0, 1.0, 5.0], [3.0, 0.0, -2.0]]])  # (1, 2, 3)
    x_axis = np.array([[[0.0, 0.0, 0.0]]]), np.array([[[2.0, 0.0, 0.0]]])
    assert horizontal_clearance(centres, *x_axis)[0] == pytest.approx(0.0)
    assert horizontal_clearance(centres[:, :1], *x_axis)[0] == pytest.approx(1.0)
    vertical = np.array([[[1.0, 1.0, 0.0]]]), np.array([[[0.0, 0.0, 1.0]]])
    assert horizontal_clearance(centres, *vertical)[0] == pytest.approx(1.0)  # (0, 1) from (1, 1)
