"""Discovery's statistics held to theory: the decision rule, the near-tie spread, honest standard
deviations and the aliasing report (identify/discover/decide.py, uncertainty.py, aliasing.py)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import MJCF, PAPER
from scipy import stats

from calbench.bench.campaign import simulate, truth_robot
from calbench.bench.model import Robot
from calbench.bench.scenario import parse_scenario
from calbench.identify.core import Fit, Whitener, from_campaign
from calbench.identify.discover import (
    ALPHA_DISCOVERY,
    ALPHA_EFFECT,
    ALPHA_MISFIT,
    MAX_RELATIVE_STD,
    alias_columns,
    aliasing_report,
    base_fit,
    compare,
    determination,
    library,
    lr_spread,
    lr_threshold,
    near_ties,
    score_statistic,
)


def fit_stats(chi2, dof, rank, n=132):
    return SimpleNamespace(chi2=chi2, dof=dof, n_res=n, n_free=rank)


# --------------------------------------------------------------------------- the decision rule


def test_every_candidate_is_tested_without_a_global_gate():
    """A model that fits to the noise level (chi2 = dof) still names a candidate whose targeted
    likelihood ratio passes the family-wise level: 11 candidates, k = 2, LR 22 (the compensator
    at the shipped K_C: p = 2e-5 < 5e-4 / 11)."""
    base = fit_stats(124.0, 124, 8)
    st = compare(base, fit_stats(102.0, 122, 10), 11)
    assert st["p_lr"] == pytest.approx(stats.chi2.sf(22.0, 2)) and st["p_lr"] < ALPHA_EFFECT / 11
    assert st["significant"] and st["accept"]
    # the threshold is the chi2(k) quantile at the Bonferroni level
    assert lr_threshold(2, 11) == pytest.approx(stats.chi2.isf(ALPHA_EFFECT / 11, 2))
    below = compare(base, fit_stats(124.0 - 0.99 * lr_threshold(2, 11), 122, 10), 11)
    assert not below["significant"] and not below["accept"]


def _linear_score(rng, effect, n=120, p=4, m=None):
    """A linear model y = A b + C c + e (whitened, unit noise): the current fit on A alone and a
    candidate on [A C], as discovery passes them (the warm Jacobian; the current free, at_bound, residual)."""

    m = m or len(effect.param_names)
    A, C = rng.normal(size=(n, p)), rng.normal(size=(n, m))
    C[:, 0] += 0.8 * A[:, 0]  # partly absorbed by the current model, as a real candidate
    y = rng.normal(size=n)
    b = np.linalg.lstsq(A, y, rcond=None)[0]
    full = np.linalg.lstsq(np.c_[A, C], y, rcond=None)[0]
    cur = SimpleNamespace(
        values=b, free=np.ones(p, bool), at_bound=np.zeros(p, bool), residual=(y - A @ b).reshape(-1, 3)
    )
    jw = np.c_[A, C]
    lr = float((y - A @ b) @ (y - A @ b) - (y - np.c_[A, C] @ full) @ (y - np.c_[A, C] @ full))
    white = SimpleNamespace(vec=lambda x: np.asarray(x, float).reshape(-1))
    return cur, effect, jw, white, lr


def test_the_score_is_the_linear_models_lr_and_chi2_under_the_null():
    """Rao's score at the current model (decide.score_statistic) is, for a model linear in every
    parameter, exactly the likelihood ratio, with rank the candidate's columns; over 4000 null
    draws its tail follows chi2(rank) (the level's share within 3 binomial sigma). A new spring
    (no first-order test: its free length means nothing at zero rate) has none."""
    from calbench.bench.model.effects import REGISTRY

    drift = REGISTRY["tracker_drift"]()
    rng = np.random.default_rng(7)
    cur, eff, jw, white, lr = _linear_score(rng, drift)
    s, rank = score_statistic(cur, eff, jw, white)
    assert rank == 3 and s == pytest.approx(lr, rel=1e-9)
    draws = np.array([score_statistic(*_linear_score(rng, drift)[:4])[0] for _ in range(4000)])
    for a in (0.05, 0.01):
        share = np.mean(draws > stats.chi2.isf(a, 3))
        assert abs(share - a) < 3 * np.sqrt(a * (1 - a) / draws.size), (a, share)
    assert score_statistic(cur, REGISTRY["compensator"](), jw, white) is None


def test_a_candidate_whose_first_order_score_fails_is_not_significant():
    """The LR past its level but the score not (the fit's gain comes from moving what the current
    model leaves undetermined along its valley, decide.py): not significant, not accepted; the
    score past it too: both are. The whole verdict spends ALPHA_DISCOVERY, half on the candidates'
    tests and half on the misfit test of `unexplained`."""
    assert ALPHA_EFFECT + ALPHA_MISFIT == pytest.approx(ALPHA_DISCOVERY) == 1e-3
    base = fit_stats(124.0, 124, 8)
    cand = fit_stats(100.0, 123, 9)  # LR 24, k 1
    thr = lr_threshold(1, 11)
    assert compare(base, cand, 11)["significant"]
    low = compare(base, cand, 11, (0.9 * thr, 1))
    assert not low["significant"] and not low["accept"] and low["p_score"] > ALPHA_EFFECT / 11
    high = compare(base, cand, 11, (1.1 * thr, 1))
    assert high["significant"] and high["accept"] and high["score_statistic"] == pytest.approx(1.1 * thr)


def test_a_hint_says_why_it_is_not_named():
    """A hint past the LR level but not the score's says both numbers and why it is not named; one
    below the level says what it needs (the text the story prints when nothing is named)."""
    from calbench.identify.discover import hint_line

    h = {"effect": "joint_nonlinearity", "detail": "j2", "lr": 18.9, "k": 1, "p_lr": 1.4e-5}
    past = hint_line(h | {"alpha": 4.5e-5, "score_statistic": 15.3, "p_score": 9.1e-5})
    assert "lower chi2 by 18.9" in past and "not at first order" in past and "15.3 (p = 9e-05)" in past
    assert "Not named" in past
    below = hint_line(h | {"p_lr": 0.007, "alpha": 4.5e-5, "score_statistic": 7.0, "p_score": 0.008})
    assert "below the family-wise threshold: needs < 5e-05" in below and "first order" not in below


def test_a_candidate_that_only_nibbles_at_a_misfit_is_not_named():
    """Significant, but removes 10 % of a large excess and leaves a rejected fit: unexplained."""
    base = fit_stats(1124.0, 124, 8)
    st = compare(base, fit_stats(1024.0, 123, 9), 11)
    assert st["significant"] and st["explained"] < 0.5 and st["p_fit"] < 1e-3
    assert not st["accept"]
    # removing most of the excess is enough even if the fit is still rejected
    assert compare(base, fit_stats(300.0, 123, 9), 11)["accept"]


def test_lr_difference_spread_is_twice_the_prediction_distance():
    """Monte Carlo of LR_A - LR_B = |y - f_B|^2 - |y - f_A|^2 for fixed predictions: its
    standard deviation is 2 |f_A - f_B| (decide.py). N = 4000 draws: the sd's relative sampling
    error is 1/sqrt(2N) = 1.1 %; 4 of them allowed."""
    rng = np.random.default_rng(5)
    n, draws = 60, 4000
    truth = rng.normal(size=n)
    fa, fb = truth + 0.3 * rng.normal(size=n), truth + 0.3 * rng.normal(size=n)
    y = truth + rng.standard_normal((draws, n))
    d = ((y - fb) ** 2).sum(1) - ((y - fa) ** 2).sum(1)
    a, b = SimpleNamespace(residual_w=(y[0] - fa)), SimpleNamespace(residual_w=(y[0] - fb))
    assert d.std(ddof=1) == pytest.approx(lr_spread(a, b), rel=4 / np.sqrt(2 * draws))


def test_near_ties_name_both_and_far_ones_neither():
    y = np.zeros(30)
    fa = SimpleNamespace(residual_w=y + 0.01)
    close = SimpleNamespace(residual_w=y + 0.02)
    far = SimpleNamespace(residual_w=y + np.r_[5.0, np.zeros(29)])
    best = ("A", fa, {"lr": 40.0, "k": 1, "bic_gain": 35.0})
    tied = near_ties(best, [("B", close, {"lr": 39.0, "k": 1, "bic_gain": 34.0})])
    assert [t["candidate"] for t in tied] == ["A", "B"]
    # a 30 chi2 lower LR and a 25 lower BIC gain, 10 sd of the LR difference apart: no tie
    assert near_ties(best, [("C", far, {"lr": 10.0, "k": 1, "bic_gain": 5.0})]) == []


# --------------------------------------------------------------------------- honest std


def synthetic_fit(jw: np.ndarray, values: np.ndarray, names) -> Fit:
    p = values.size
    return Fit(
        values,
        np.full((p, p), np.nan),
        np.ones(p, bool),
        np.zeros((1, 3)),
        np.zeros((1, 3)),
        0.0,
        jw.shape[0],
        p,
        1,
        1,
        True,
        names=tuple(names),
        units=("1",) * p,
        at_bound=np.zeros(p, bool),
    )


def test_only_the_combination_is_determined():
    """Two parameters whose columns differ by 1e-3: each one's std from the Fisher information
    is ~1000 x its value, so the split is not determined; their sum is, with the std of the
    exact linear algebra. A third, independent parameter keeps its ordinary std."""
    rng = np.random.default_rng(2)
    a, c = rng.normal(size=(40, 1)) * 50, rng.normal(size=(40, 1)) * 30
    jw = np.hstack([a, a * (1 + 1e-3 * rng.normal(size=(40, 1))), c])
    values = np.array([1.0, 1.0, 2.0])
    det = determination(synthetic_fit(jw, values, ["x", "z", "w"]), jw)
    cov = np.linalg.inv(jw.T @ jw)
    assert det.determined.tolist() == [False, False, True]
    assert det.std[2] == pytest.approx(np.sqrt(cov[2, 2]), rel=1e-9)
    assert np.sqrt(cov[0, 0]) > MAX_RELATIVE_STD * values[0]  # the split really is undetermined
    (combo,) = det.combinations
    coef = np.array([combo["combination"]["x"], combo["combination"]["z"]])
    assert max(coef) == pytest.approx(1.0) and min(coef) == pytest.approx(1.0, rel=1e-2)  # the sum x + z
    g = np.r_[coef, 0.0]
    assert combo["estimate"] == pytest.approx(g @ values)
    assert combo["std"] == pytest.approx(np.sqrt(g @ cov @ g), rel=1e-6)


# --------------------------------------------------------------------------- aliasing


@pytest.fixture(scope="module")
def exact_fits():
    """The user's model fitted to exact data of the paper plan (16 poses) and of Table 5 alone
    (vertical loads only), with their aliasing reports."""
    text = PAPER.read_text().replace('robot = "../mjcf/m900ib700.xml"', f'robot = "{MJCF}"')
    head, *poses = text.split("[[pose]]")
    out = {}
    for n in (12, 16):
        scn = parse_scenario(head + "".join("[[pose]]" + p for p in poses[:n]), Path(f"/tmp/alias{n}.toml"))
        robot = truth_robot(scn)
        obs = from_campaign(simulate(scn, None, robot=robot))
        white = Whitener.from_observations(obs)
        f = base_fit(MJCF, obs, white)
        det = determination(f, f.extra["jw"])
        rep = aliasing_report(
            f,
            f.extra["jw"],
            det.std,
            alias_columns(MJCF, obs, white, f, library(Robot.from_file(MJCF))),
            obs,
            white,
            11,
        )
        out[n] = (f, {(a["effect"], a["detail"], a["parameter"]): a for a in rep})
    return out


def test_cubic_on_j1_under_equal_pulls_is_invisible_and_biases_k1(exact_fits):
    """Every pull loads J1 with the same torque, so a cubic term there is exactly a k1 change
    (a hardening one: k1 low); under vertical loads only, J1 is not excited at all."""
    _, al = exact_fits[16]
    a = al[("joint_nonlinearity", "j1", "cubic")]
    assert not a["visible"] and a["visible_share"] < 1e-6 and a["detectable_magnitude"] is None
    top = a["biases"][0]
    assert top["parameter"] == "k1" and top["per_unit"] < 0
    assert all(abs(b["at_reference_sigma"]) < 1e-6 for b in a["biases"][1:])
    _, al12 = exact_fits[12]
    assert not al12[("joint_nonlinearity", "j1", "cubic")]["excited"]


def test_forearm_inplane_bending_is_a_k3(exact_fits):
    """The forearm's y spring at its root turns the forearm about the elbow like motor 3 does
    through the parallelogram (bench/model/effects/): invisible, absorbed by k3 alone."""
    _, al = exact_fits[16]
    a = al[("link_compliance", "forearm", "cy")]
    assert not a["visible"]
    assert a["biases"][0]["parameter"] == "k3" and a["biases"][0]["per_unit"] > 0
    assert all(
        abs(b["at_reference_sigma"]) < 1e-3 * abs(a["biases"][0]["at_reference_sigma"])
        for b in a["biases"][1:]
    )


def test_payload_mass_error_is_a_common_scale_of_k2_to_k6(exact_fits):
    """Table 5 hangs the same weight in every pose: dp is linear in it to first order, so a mass
    x % high reads as every loaded compliance x % high (the gravity-only sag is not scaled,
    hence the small departures: within 3 %), and almost nothing is left to see."""
    f, al = exact_fits[12]
    a = al[("load_scale", "hung weights", "scale")]
    rel = {b["parameter"]: b["per_percent_mass_relative_percent"] for b in a["biases"]}
    for k in ("k2", "k3", "k4", "k5", "k6"):
        assert rel[k] == pytest.approx(1.0, abs=0.03)
    assert a["visible_share"] < 0.02


def test_the_payload_mass_line_says_what_the_record_says(exact_fits):
    """load_scale is never NAMED (no candidate: deflections alone cannot tell a mass error from
    the compliances), but a sliver of its signature escapes the compliances (the unloaded sag
    and the compensator's nonlinearity are not scaled), so a large enough error leaves a
    misfit. The printed line must not call it invisible when the record says it is visible,
    and gives the same share and size; and a mass error of plausible size (a few per cent,
    up to 20 %) stays hidden on both plans. docs/discovery.md quotes these figures."""
    from calbench.identify.discover import alias_lines

    page = " ".join((PAPER.parent.parent / "docs" / "discovery.md").read_text().split())
    a16, a12 = (exact_fits[n][1][("load_scale", "hung weights", "scale")] for n in (16, 12))
    t5 = f"{100 * a12['detectable_magnitude']:.2g} %" if a12["visible"] else "absorbed exactly"
    assert (
        f"only {100 * a16['visible_share']:.2g} % of its signature escapes" in page
        and f"once the mass is ~{100 * a16['detectable_magnitude']:.2g} % off (Table 5 alone: {t5})" in page
    )
    for n in (12, 16):
        _, al = exact_fits[n]
        a = al[("load_scale", "hung weights", "scale")]
        (line,) = [ln for ln in alias_lines([a]) if "load_scale" in ln]
        assert "never named" in line
        if a["visible"]:
            assert "never visible" not in line
            assert f"{100 * a['detectable_magnitude']:.2g} %" in line
            assert a["detectable_magnitude"] > 0.2
        assert f"{100 * (1 - a['visible_share']):.3g} %" in line


def test_first_round_events_are_discoverys_own_and_bound_its_verdict():
    """first_round_events (the false-alarm bound of benchmarks/discover_null_bench.py
    --first-order) reads the same first-order scores, misfit p and level as discovery's own first
    round (workflow.run_round, on the same readings and user's model), and where it finds no
    event no candidate of that round is significant and the misfit test passes, so discovery
    names nothing: the paper plan with nothing hidden, one noise draw."""
    from calbench.bench.campaign import remeasure
    from calbench.identify.discover import first_round_events, hold_mask, run_round

    text = PAPER.read_text().replace('robot = "../mjcf/m900ib700.xml"', f'robot = "{MJCF}"')
    campaign = simulate(parse_scenario(text, Path("/tmp/null_bound.toml")), None)
    obs = from_campaign(remeasure(campaign, np.random.default_rng([20261, 1])))
    ev = first_round_events(obs, MJCF)
    white = Whitener.from_observations(obs)
    base = base_fit(MJCF, obs, white)
    cands = run_round(MJCF, obs, white, base, hold_mask(base), base.extra["fresh_start"], library(base.robot))
    first = {c.label: c for c in cands if c.stats is not None}
    assert set(ev["p_score"]) == {k for k, c in first.items() if "p_score" in c.stats}
    for k, p in ev["p_score"].items():
        assert p == pytest.approx(first[k].stats["p_score"], rel=1e-9, abs=1e-300)
    for k, p in ev["p_lr_no_first_order"].items():
        assert p == pytest.approx(first[k].stats["p_lr"], rel=1e-6, abs=1e-12)
    assert ev["p_before"] == pytest.approx(stats.chi2.sf(base.chi2, base.dof), rel=1e-12)
    assert all(ev["alpha"] == pytest.approx(c.stats["alpha"], rel=1e-12) for c in first.values())
    if not ev["event"]:
        assert not any(c.stats["significant"] for c in first.values())
        assert ev["p_before"] >= ALPHA_MISFIT
