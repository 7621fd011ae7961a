"""The aliasing report's detectable sizes on the exact statics (identify/discover/aliasing.py, EXACT).

A joint cubic's deflection is not linear in its size: on the KUKA KR 270 paper plan its column
said a J6 cubic is named from 1.6e12 N*m/rad^3, where the exact statics leave it an LR of 1.4
(T = 15.3), and a stiffening one never more than 2.1. Each check here is against an independent
computation: the first-order column where the response is linear, a full refit of the user's
model to the effect's noise-free readings where it is not.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import ROOT

from calbench.bench.scenario import load_scenario
from calbench.identify.core import Whitener
from calbench.identify.discover import (
    EXACT_BISECT,
    EXACT_STEPS,
    alias_columns,
    alias_lines,
    aliasing_report,
    base_fit,
    build,
    effect_priors,
    exact_detection,
    fit_augmented,
    label,
    library,
    lr_threshold,
    noncentrality,
    with_exact,
)
from calbench.identify.study import simulate_in_memory

KR270 = ROOT / "scenarios" / "kr270_paper.toml"
WANT = (
    "link_compliance[link_arm]",
    "joint_nonlinearity[j3]",
    "joint_nonlinearity[j4]",
    "joint_nonlinearity[j6]",
)


@pytest.fixture(scope="module")
def kr270():
    sim = simulate_in_memory(load_scenario(KR270))
    white = Whitener.from_observations(sim.obs)
    base = base_fit(sim.mjcf, sim.obs, white)
    lib = library(base.robot)
    cols = [(e, b) for e, b in alias_columns(sim.mjcf, sim.obs, white, base, lib) if label(e) in WANT]
    models = [
        (e, build(sim.mjcf, [(e, effect_priors(e)[0])], sim.obs)[1], effect_priors(e)[0]) for e, _ in cols
    ]
    std = np.sqrt(np.abs(np.diag(np.nan_to_num(base.cov))))
    first = aliasing_report(base, base.extra["jw"], std, cols, sim.obs, white, len(lib))
    first = [a for a in first if a["effect"] != "load_scale"]
    import copy

    exact = with_exact(copy.deepcopy(first), models, white, base, base.extra["jw"], len(lib))
    return sim, white, base, lib, models, first, exact


def _row(rows, effect, detail, parameter):
    return next(a for a in rows if (a["effect"], a["detail"], a["parameter"]) == (effect, detail, parameter))


def _refit_lambda(sim, white, base, fm, effect, values) -> float:
    """The independent computation: the user's model refitted to the noise-free readings of the
    model with the effect; the chi2 it leaves is the test's noncentrality."""
    dp, _ = fm.evaluate(values, jacobian=False)
    start = effect_priors(effect)[0]
    ref, _ = fm.evaluate(np.r_[base.values, start], jacobian=False)
    lo, hi, hold = base.extra["bounds"]
    pred = base.model.evaluate(base.values, jacobian=False)[0]
    target = pred + (dp - ref)  # the effect's signature on top of the user's model at its estimate
    f = fit_augmented(base.model, target, white, base.values, lo, hi, hold, max_iter=60)
    return f.chi2


def test_a_linear_effect_keeps_its_first_order_size(kr270):
    sim, white, base, lib, models, first, exact = kr270
    thr = lr_threshold(1, len(lib))
    a = _row(first, "link_compliance", "link_arm", "cy")
    e, fm, start = next(m for m in models if label(m[0]) == "link_compliance[link_arm]")
    v = start.copy()
    v[1] += a["detectable_magnitude"]
    lam = noncentrality(
        fm,
        white,
        np.r_[base.values, v],
        white.vec(fm.evaluate(np.r_[base.values, start], jacobian=False)[0]),
        base.extra["jw"][:, base.free | base.at_bound],
    )
    # the column's size leaves the threshold on the exact statics: the response is linear to
    # within the bending's own geometric change (a few per cent)
    assert lam == pytest.approx(thr, rel=0.05)
    assert (
        _row(exact, "link_compliance", "link_arm", "cy")["detectable_magnitude"] == a["detectable_magnitude"]
    )


def test_a_cubic_is_named_from_its_exact_size(kr270):
    sim, white, base, lib, models, first, exact = kr270
    thr = lr_threshold(1, len(lib))
    e, fm, start = next(m for m in models if label(m[0]) == "joint_nonlinearity[j3]")
    a = _row(exact, "joint_nonlinearity", "j3", "cubic")
    f0 = _row(first, "joint_nonlinearity", "j3", "cubic")["detectable_magnitude"]
    assert a["detectable_magnitude_first_order"] == f0
    est = base.free | base.at_bound
    for rec in a["exact"]:
        m = rec["magnitude"]
        assert m is not None and not rec["never_named"]
        # the first-order size is off by more than the tolerance that triggers the solve
        assert abs(rec["lambda_first_order"] / thr - 1) > 0.25
        at = np.r_[base.values, start + rec["sign"] * m]
        lam = _refit_lambda(sim, white, base, fm, e, at)
        # at the solved size a full refit leaves the threshold: within the bisection's last
        # bracket (a factor EXACT_STEPS[1] ** (2 ** -EXACT_BISECT) in size, ~2x that in lambda)
        # and the projection's first order in what the fit absorbs (a few per cent)
        tol = EXACT_STEPS[1] ** (2.0 ** (1 - EXACT_BISECT)) - 1 + 0.05
        assert lam == pytest.approx(thr, rel=tol)
        # and the projection is what the refit says
        ref = white.vec(fm.evaluate(np.r_[base.values, start], jacobian=False)[0])
        assert noncentrality(fm, white, at, ref, base.extra["jw"][:, est]) == pytest.approx(lam, rel=0.05)
    assert a["detectable_magnitude"] == min(r["magnitude"] for r in a["exact"])


def test_a_stiffening_j6_cubic_is_never_named_and_the_text_says_so(kr270):
    sim, white, base, lib, models, first, exact = kr270
    thr = lr_threshold(1, len(lib))
    a = _row(exact, "joint_nonlinearity", "j6", "cubic")
    plus = next(r for r in a["exact"] if r["sign"] > 0)
    assert plus["never_named"] and plus["magnitude"] is None
    assert plus["lambda_max"] < thr
    # the refit at the largest size walked agrees: a hundred times the column's size is not named
    e, fm, start = next(m for m in models if label(m[0]) == "joint_nonlinearity[j6]")
    big = start + EXACT_STEPS[-1] * a["detectable_magnitude_first_order"]
    assert _refit_lambda(sim, white, base, fm, e, np.r_[base.values, big]) < thr
    line = next(x for x in alias_lines(exact) if "joint_nonlinearity j6" in x)
    assert "never named at any size: cubic +" in line and "first order said" in line


def test_exact_detection_skips_a_sign_outside_the_prior(kr270):
    sim, white, base, lib, models, first, exact = kr270
    e, fm, start = next(m for m in models if label(m[0]) == "link_compliance[link_arm]")
    est = base.free | base.at_bound
    got = exact_detection(e, fm, white, base, base.extra["jw"], est, 0, 1e-7, lr_threshold(1, len(lib)))
    # a compliance cannot be negative: only the + sign is walked
    assert [r["sign"] for r in got] == [1.0]


def test_each_size_is_solved_from_the_unique_equilibrium_whatever_came_before(kr270):
    """A softening cubic's statics have other branches: warm starts from the sizes walked before
    found one (the KR 270's J4 cubic, softening, was "named from 4.3e10", where a model solved
    from rest leaves LR 0.0; the KR 210's "from 6e8", 100 times below its linear size). Every size
    is solved from the equilibrium at the columns' point, which is unique: a fresh model at each
    reported size agrees, and the answer does not depend on what the model was evaluated at
    before."""
    sim, white, base, lib, models, first, exact = kr270
    thr = lr_threshold(1, len(lib))
    est = base.free | base.at_bound
    jb = base.extra["jw"][:, est]
    for lab, det in (("joint_nonlinearity[j3]", "j3"), ("joint_nonlinearity[j4]", "j4")):
        e, fm, start = next(m for m in models if label(m[0]) == lab)
        a = _row(exact, "joint_nonlinearity", det, "cubic")
        for rec in a["exact"]:
            if rec["magnitude"] is None:
                continue
            fresh = build(sim.mjcf, [(e, start)], sim.obs)[1]
            ref = white.vec(fresh.evaluate(np.r_[base.values, start], jacobian=False)[0])
            fresh = build(sim.mjcf, [(e, start)], sim.obs)[1]
            at = np.r_[base.values, start + rec["sign"] * rec["magnitude"]]
            assert noncentrality(fresh, white, at, ref, jb) >= thr
        first_size = _row(first, "joint_nonlinearity", det, "cubic")["detectable_magnitude"]
        once = exact_detection(e, fm, white, base, base.extra["jw"], est, 0, first_size, thr)
        for far in (-3e11, 5e13):  # near the softening edge, deep in the stiffening saturation
            try:
                fm.evaluate(np.r_[base.values, far], jacobian=False)
            except (ValueError, RuntimeError):
                pass
            again = exact_detection(e, fm, white, base, base.extra["jw"], est, 0, first_size, thr)
            # the same answer to the statics' tolerance (Newton stops at ~1e-10 of a deflection)
            assert [(r["sign"], r["never_named"]) for r in again] == [
                (r["sign"], r["never_named"]) for r in once
            ]
            for r, q in zip(again, once):
                for k in ("magnitude", "lambda_first_order", "lambda_max", "no_equilibrium_from"):
                    assert (r[k] is None) == (q[k] is None)
                    if r[k] is not None:
                        assert r[k] == pytest.approx(q[k], rel=1e-6)
