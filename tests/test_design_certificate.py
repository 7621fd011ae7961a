"""The certificate of a plan (issue 16): approximate optimal designs, the equivalence-theorem
bounds, distinct plans, and the normalised export.

The bounds are proofs, so the tests compare them with the truth they bound: the best exact plan,
found by exhaustive search over every multiset (or set, for distinct plans) of M = 3 of 12
candidates. Tolerance 1e-9 (absolute in log det, relative in the traces): the rounding of an 8 x 8
Cholesky factorisation in double precision, far below any gap the bounds leave.
"""

from __future__ import annotations

import itertools
import json
import math
import tomllib

import numpy as np
import pytest

from calbench.identify.design.optimal import (
    ALGORITHMS,
    Exchanger,
    a_bound,
    approximate_design,
    certify,
    column_scale,
    criterion_value,
    d_bound,
    information,
    normalise_blocks,
    plan_logdet,
)

ROUND = 1e-9


def _blocks(seed: int, n=12, m=3, p=4) -> np.ndarray:
    """Random blocks with column scales spanning 1e3 (like the exported ones: 1.9 to 71)."""
    rng = np.random.default_rng(seed)
    return rng.standard_normal((n, m, p)) * np.geomspace(0.1, 100, p)


def _exhaustive(blocks, M, value, distinct):
    combos = itertools.combinations if distinct else itertools.combinations_with_replacement
    return [value(c) for c in combos(range(len(blocks)), M)]


@pytest.mark.parametrize("seed, m, p", [(0, 3, 4), (1, 3, 4), (2, 2, 5), (3, 9, 8)])
@pytest.mark.parametrize("distinct", [False, True])
def test_d_bound_is_above_the_best_exact_plan_for_any_design(seed, m, p, distinct):
    """Exhaustive search over all plans of 3 of 12 candidates; the bound of converged AND
    unconverged designs (1, 3, 10 iterations) is never below the best plan's log det, and the
    converged one leaves a gap the certificate reports as the plan's efficiency."""
    b = _blocks(seed, m=m, p=p)
    M = 3
    best = max(_exhaustive(b, M, lambda c: plan_logdet(b, c), distinct))
    cap = 1 / M if distinct else None
    for alg in ALGORITHMS if not distinct else ("fw-away",):
        for it in (1, 3, 10, 100000):
            d = approximate_design(b, "D", algorithm=alg, cap=cap, tol=1e-10, max_iter=it)
            assert d_bound(d, M) >= best - ROUND, (alg, it)
    cert = certify(b, list(range(M)), "D", distinct=distinct, tol=1e-10)
    assert cert.bound >= best - ROUND
    assert cert.efficiency == pytest.approx(math.exp((plan_logdet(b, range(M)) - cert.bound) / p))
    assert 0 < cert.efficiency <= 1


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("crit", ["A", "pose", "AD"])
@pytest.mark.parametrize("distinct", [False, True])
def test_a_type_bounds_are_below_the_best_exact_plan(seed, crit, distinct):
    b = _blocks(seed)
    G = np.random.default_rng(10 + seed).standard_normal((2, 4))
    M = 3
    best = min(_exhaustive(b, M, lambda c: criterion_value(crit, information(b, c), G), distinct))
    cert = certify(b, [0, 1, 2], crit, G=G, distinct=distinct, tol=1e-10)
    assert cert.bound <= best * (1 + ROUND)
    # unconverged designs bound too (4): a few iterations from the plan's own weights
    W = G.T @ G if crit == "pose" else None
    if crit != "AD":
        for it in (1, 5):
            d = approximate_design(
                b,
                "A",
                W,
                start=np.bincount([0, 1, 2], minlength=12),
                cap=1 / M if distinct else None,
                max_iter=it,
            )
            assert a_bound(d, M) <= best * (1 + ROUND)


def test_the_bound_is_attained_when_the_approximate_optimum_is_an_exact_plan():
    """p orthogonal candidates c e_k plus candidates on the diagonals (c (e_a + e_b) / 2, d = 2 <
    p): the D-optimal design is uniform on the p axes, the plan of those p candidates attains
    p ln M + log det M(xi*) exactly, and its efficiency is 1 (the bound is not loose)."""
    p, c = 4, 3.0
    axes = [np.vstack([c * np.eye(p)[k], np.zeros(p)]) for k in range(p)]
    diag = [
        np.vstack([c * (np.eye(p)[a] + np.eye(p)[b]) / 2, np.zeros(p)])
        for a, b in itertools.combinations(range(p), 2)
    ]
    blocks = np.array(diag[:3] + axes + diag[3:])
    rows = [3, 4, 5, 6]
    assert plan_logdet(blocks, rows) == pytest.approx(p * math.log(c * c))
    for alg in ALGORITHMS:
        d = approximate_design(blocks, "D", algorithm=alg, tol=1e-10, max_iter=100000)
        assert d_bound(d, p) == pytest.approx(p * math.log(c * c), abs=1e-8)
        assert sorted(d.support().tolist()) == rows
        np.testing.assert_allclose(d.weights[rows], 0.25, atol=1e-6)
    cert = certify(blocks, rows, "D")
    assert cert.efficiency == pytest.approx(1.0, abs=1e-9)


def test_equivalence_theorem_holds_at_the_computed_optimum():
    """sum_i w_i g_i = 1 for every design (definition); at the optimum max g = 1 and g = 1 on the
    support (Kiefer-Wolfowitz); both algorithms find the same optimum within their gap."""
    b = _blocks(5, n=40, m=3, p=5)
    out = {}
    for alg in ALGORITHMS:
        for crit in ("D", "A"):
            d = approximate_design(b, crit, algorithm=alg, tol=1e-8, max_iter=200000, max_seconds=60)
            assert d.weights @ d.sensitivity == pytest.approx(1.0, abs=1e-12)
            assert d.g_bound - 1 <= 1e-8
            if alg == "fw-away":
                np.testing.assert_allclose(d.sensitivity[d.weights > 0], 1.0, atol=1e-6)
            out[alg, crit] = d
    p = b.shape[2]
    assert (
        abs(out["fw-away", "D"].logdet - out["multiplicative", "D"].logdet) <= p * math.log(1 + 1e-8) + ROUND
    )
    assert out["fw-away", "A"].trace_w == pytest.approx(out["multiplicative", "A"].trace_w, rel=2e-8)


def test_normalising_the_columns_shifts_every_log_det_by_one_constant():
    b = _blocks(7, n=200, m=9, p=8)
    nb, s = normalise_blocks(b)
    np.testing.assert_allclose(np.einsum("nij,nij->j", nb, nb) / len(b), 1.0, rtol=1e-12)
    np.testing.assert_allclose(s, column_scale(b))
    shift = -2 * np.log(s).sum()
    rng = np.random.default_rng(0)
    for _ in range(5):
        rows = rng.choice(len(b), 12)
        assert plan_logdet(nb, rows) == pytest.approx(plan_logdet(b, rows) + shift, abs=1e-9)
    r, rn = Exchanger(b, "D").optimise(12, n_random=2), Exchanger(nb, "D").optimise(12, n_random=2)
    assert r.idx.tolist() == rn.idx.tolist()


def test_distinct_exchange_never_repeats_and_its_scan_skips_the_excluded():
    b = _blocks(8, n=300, m=3, p=8)
    ex = Exchanger(b, "D")
    rep, dis = ex.optimise(30, n_random=2), ex.optimise(30, n_random=2, distinct=True)
    assert len(np.unique(rep.idx)) < 30  # at 30 of 300 the unconstrained plan repeats
    assert len(np.unique(dis.idx)) == 30
    assert plan_logdet(b, dis.idx) <= plan_logdet(b, rep.idx) + ROUND
    cert_d = certify(b, dis.idx, "D", distinct=True)
    cert_r = certify(b, rep.idx, "D")
    assert cert_d.bound <= cert_r.bound + ROUND  # distinct plans are a subset of plans
    P, ld, tr = ex.state(dis.idx[:10])
    exclude = np.zeros(len(b), bool)
    exclude[dis.idx[:10]] = True
    full = ex.scan(P, ld, tr, full=True, exclude=exclude)
    j, v = ex.scan(P, ld, tr, exclude=exclude)
    assert not exclude[j] and j == int(np.argmin(full)) and v == pytest.approx(full.min(), rel=1e-12)
    with pytest.raises(ValueError):
        ex.optimise(301, distinct=True)


# ------------------------------------------------------------------------------ command line

from conftest import PAPER  # noqa: E402

from calbench.identify.cli import main  # noqa: E402


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """150 paper-scenario candidates, raw and normalised, and the design's JSON on them."""
    d = tmp_path_factory.mktemp("cands")
    common = [str(PAPER), "--candidates", "150", "--processes", "1"]
    assert (
        main(
            [
                "design",
                *common,
                "--export-candidates",
                str(d / "raw.npz"),
                "--configs",
                "8",
                "--criterion",
                "D",
                "--json",
                str(d / "design.json"),
                "--starts",
                "2",
                "--no-refine",
            ]
        )
        == 0
    )
    assert main(["design", *common, "--export-candidates", str(d / "norm.npz"), "--normalise"]) == 0
    return d


def test_design_json_records_rows_and_a_certificate_of_them(exported, capsys):
    out = json.loads((exported / "design.json").read_text())
    z = np.load(exported / "raw.npz")
    cert = out["certificate"]
    assert cert["criterion"] == "D" and len(out["rows"]) == 8
    assert cert["plan_logdet"] == pytest.approx(plan_logdet(z["blocks"], out["rows"]), abs=1e-9)
    assert cert["plan_logdet"] <= cert["bound_logdet"]
    assert cert["efficiency"] == pytest.approx(math.exp((cert["plan_logdet"] - cert["bound_logdet"]) / 8))
    sup = out["continuous_design"]["D"]["support"]
    assert sum(s["poses_of_M"] for s in sup) <= 8 + 1e-9 and all(len(s["q_deg"]) == 6 for s in sup)
    # the same optimiser on the exported file: the same rows and certificate
    js = exported / "from.json"
    assert (
        main(
            [
                "design",
                "--from-candidates",
                str(exported / "raw.npz"),
                "--configs",
                "8",
                "--criterion",
                "D",
                "--starts",
                "2",
                "--json",
                str(js),
            ]
        )
        == 0
    )
    text = capsys.readouterr().out
    assert "efficiency" in text and "provably within" in text
    again = json.loads(js.read_text())
    assert again["rows"] == out["rows"]
    assert again["certificate"]["bound_logdet"] == pytest.approx(cert["bound_logdet"], abs=1e-3)


def test_normalised_export_rescales_columns_and_keeps_the_d_optimal_plan(exported, tmp_path):
    raw, norm = np.load(exported / "raw.npz"), np.load(exported / "norm.npz")
    s = norm["column_scale"]
    np.testing.assert_allclose(norm["blocks"] * s, raw["blocks"], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(np.einsum("nij,nij->j", norm["blocks"], norm["blocks"]) / len(norm["q"]), 1.0)
    assert "NORMALISED" in str(norm["note"])
    rows = {}
    for name in ("raw", "norm"):
        js = tmp_path / f"{name}.json"
        assert (
            main(
                [
                    "design",
                    "--from-candidates",
                    str(exported / f"{name}.npz"),
                    "--configs",
                    "8",
                    "--criterion",
                    "D",
                    "--starts",
                    "2",
                    "--json",
                    str(js),
                ]
            )
            == 0
        )
        rows[name] = json.loads(js.read_text())
    assert rows["raw"]["rows"] == rows["norm"]["rows"]
    shift = -2 * np.log(s).sum()
    assert rows["norm"]["certificate"]["plan_logdet"] == pytest.approx(
        rows["raw"]["certificate"]["plan_logdet"] + shift, abs=1e-8
    )
    assert rows["norm"]["certificate"]["efficiency"] == pytest.approx(
        rows["raw"]["certificate"]["efficiency"], rel=1e-3
    )


def test_distinct_from_candidates_never_repeats_and_brackets_its_cost(exported, tmp_path):
    js = tmp_path / "d.json"
    assert (
        main(
            [
                "design",
                "--from-candidates",
                str(exported / "raw.npz"),
                "--configs",
                "30",
                "--criterion",
                "A",
                "--starts",
                "1",
                "--distinct",
                "--json",
                str(js),
            ]
        )
        == 0
    )
    out = json.loads(js.read_text())
    assert len(set(out["rows"])) == 30 and out["certificate"]["distinct"] is True
    assert len(set(out["distinct"]["repeats_rows"])) < 30  # 30 of 150: with repeats it repeats
    cost = out["distinct"]["cost"]
    assert 0 <= cost["at_least"] <= cost["at_most"] < 1
    assert (
        out["certificate"]["bound_value"] >= out["distinct"]["repeats_bound"]
    )  # A: a smaller set, a higher floor


def test_from_candidates_writes_a_runnable_plan_with_the_scenario(exported, tmp_path):
    plan = tmp_path / "plan.toml"
    assert (
        main(
            [
                "design",
                str(PAPER),
                "--from-candidates",
                str(exported / "raw.npz"),
                "--configs",
                "6",
                "--criterion",
                "pose",
                "--starts",
                "1",
                "--out",
                str(plan),
            ]
        )
        == 0
    )
    z = np.load(exported / "raw.npz")
    doc = tomllib.loads(plan.read_text())
    assert sum(p["repeats"] for p in doc["pose"]) == 6
    assert all(np.min(np.abs(z["q"] - p["q"]).max(axis=1)) < 1e-8 for p in doc["pose"])


def _npz(path, **arrays):
    np.savez(path, **arrays)
    return path


@pytest.mark.parametrize(
    "arrays, key",
    [
        (lambda z: {"q": z["q"]}, "blocks"),  # missing array
        (lambda z: {"q": z["q"][:, 0], "blocks": z["blocks"]}, "q"),  # not N x n
        (lambda z: {"q": z["q"], "blocks": z["blocks"][:-1]}, "blocks"),  # N mismatch
        (
            lambda z: {
                "q": z["q"],
                "blocks": np.where(np.arange(150)[:, None, None] == 7, np.nan, z["blocks"]),
            },
            "blocks",
        ),  # NaN
        (lambda z: {"q": z["q"], "blocks": z["blocks"], "load_kind": np.array(["up"] * 150)}, "load_kind"),
        (lambda z: {"q": z["q"], "blocks": z["blocks"] * 0}, "blocks"),  # no information at all
    ],
)
def test_a_bad_candidate_file_is_bad_input_naming_the_file_and_the_array(
    exported, tmp_path, capsys, arrays, key
):
    z = np.load(exported / "raw.npz")
    bad = _npz(tmp_path / "bad.npz", **arrays(z))
    js = tmp_path / "out.json"
    rc = main(
        ["design", "--from-candidates", str(bad), "--configs", "4", "--criterion", "D", "--json", str(js)]
    )
    err = capsys.readouterr().err
    assert rc == 2 and str(bad) in err and f": {key}:" in err, err
    assert len(err.strip().splitlines()) == 1 and not js.exists()


def test_a_file_that_is_no_npz_and_misused_flags_are_bad_input(tmp_path, capsys):
    txt = tmp_path / "c.npz"
    txt.write_text("not an archive")
    assert main(["design", "--from-candidates", str(txt), "--configs", "4"]) == 2
    assert str(txt) in capsys.readouterr().err
    assert main(["design", str(PAPER), "--normalise", "--json", str(tmp_path / "x.json")]) == 2
    assert "--normalise" in capsys.readouterr().err
    assert main(["design", "--configs", "4", "--json", str(tmp_path / "x.json")]) == 2
    assert "SCENARIO" in capsys.readouterr().err


def test_a_refined_distinct_design_prints_and_records_its_certificate(tmp_path, capsys):
    plan, js = tmp_path / "plan.toml", tmp_path / "plan.json"
    assert (
        main(
            [
                "design",
                str(PAPER),
                "--configs",
                "8",
                "--criterion",
                "D",
                "--distinct",
                "--out",
                str(plan),
                "--json",
                str(js),
                "--candidates",
                "150",
                "--starts",
                "1",
                "--processes",
                "1",
            ]
        )
        == 0
    )
    text = capsys.readouterr().out
    out = json.loads(js.read_text())
    cert = out["certificate"]
    assert f"efficiency {100 * cert['efficiency']:.1f} %" in text and "no repeats: costs" in text
    assert cert["distinct"] and len(set(out["rows"])) == 8
    assert cert["refined_plan"] >= cert["plan_logdet"]  # refinement only accepts improvements
    assert "Certified efficiency" in plan.read_text()
    assert all(p["repeats"] == 1 for p in tomllib.loads(plan.read_text())["pose"])
