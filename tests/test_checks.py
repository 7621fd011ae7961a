"""Checks that can be trusted (issue 10): `identify --check` fails on a fit that did not
converge and never lets a parameter the plan cannot separate pass as a number; `design` answers
impossible sizes with one line.

The 2-pose plan below (q2 in {0, 120} deg, vertical loads) is the issue's: before, it printed
"WARNING: the estimator did not converge", gave K_C as a number with a standard deviation many
times its size, marked identifiable, and passed the check. Two distinct q2 leave K_C and s0
numerically present (the exact model sees the compensator's static torque) but buried in the
noise: identify/core/identifiability.py's resolution test names them unidentifiable.
"""

from __future__ import annotations

import json

import badcases as bc
import numpy as np
import pytest
from conftest import PAPER

from calbench.bench.log import IdentificationReport, ParameterEstimate
from calbench.bench.model import ParamLayout
from calbench.identify.cli import main
from calbench.identify.core import (
    MAX_RELATIVE_STD,
    Identifiability,
    analyze,
    explain,
    resolve,
)
from calbench.identify.report import check_failed

TWO_POSES = [[0, 0, -30, 0, 0, 0], [0, 120, 30, 0, 0, 0]]


def simulate_two_poses(d, seed: int):
    scn = d / f"two{seed}.toml"
    scn.write_text(bc.scenario_text(poses=TWO_POSES).replace("seed = 3", f"seed = {seed}"))
    out = d / f"two{seed}.mcap"
    assert main(["simulate", str(scn), "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def two_pose_log(tmp_path_factory):
    return simulate_two_poses(tmp_path_factory.mktemp("two"), 1)


@pytest.mark.parametrize("seed, converged", [(1, False), (7, True)])
def test_the_issues_two_pose_plan(tmp_path, capsys, seed, converged):
    """Seed 1: the fit runs off (K_C -> 0, s0 -> infinity) and does not converge: the check
    fails. Seed 7: it converges; K_C and s0 are named unidentifiable (not numbers), so the
    check has nothing false to pass."""
    log = simulate_two_poses(tmp_path, seed)
    js = tmp_path / "two.json"
    rc = main(["identify", str(log), "--check", "--json", str(js)])
    out = capsys.readouterr().out
    rep = json.loads(js.read_text())
    assert rep["converged"] is converged
    p = {x["name"]: x for x in rep["parameters"]}
    for name in ("compensator_stiffness", "compensator_preload"):
        assert p[name]["estimate"] is None and p[name]["identifiable"] is False
    assert "only 2 distinct q2" in p["compensator_stiffness"]["reason"]
    assert "not identifiable: compensator_stiffness: " in out
    if converged:
        assert rc == 0 and "check passed: the fit converged" in out
    else:
        assert rc == 1 and "check FAILED: the estimator did not converge" in out


def test_every_number_reported_is_determined(two_pose_log, tmp_path):
    """Whatever the plan, a parameter given as a number has a std below its own size."""
    js = tmp_path / "two.json"
    main(["identify", str(two_pose_log), "--json", str(js)])
    for p in json.loads(js.read_text())["parameters"]:
        if p["estimate"] is not None:
            assert 0 < p["std"] <= MAX_RELATIVE_STD * abs(p["estimate"]), p


def test_the_paper_plan_passes_the_check(tmp_path, capsys):
    log = tmp_path / "paper.mcap"
    assert main(["simulate", str(PAPER), "--out", str(log)]) == 0
    assert main(["identify", str(log), "--check"]) == 0
    assert "check passed: the fit converged" in capsys.readouterr().out


def report_with(estimate, std, converged=True, z=None) -> IdentificationReport:
    p = ParameterEstimate(
        "k1", "rad/(N*m)", estimate, std, None if z is None else 0.0, None, z, identifiable=True
    )
    return IdentificationReport(method="one-step", parameters=(p,), details={"converged": converged})


def test_check_failed_names_every_reason():
    assert check_failed(report_with(1e-7, 1e-8)) == []
    assert check_failed(report_with(1e-7, 1e-8, converged=False)) == ["the estimator did not converge"]
    assert check_failed(report_with(1e-7, 3e-7)) == ["k1 is reported as a number the plan does not determine"]
    assert check_failed(report_with(1e-7, None)) == ["k1 is reported as a number the plan does not determine"]
    assert check_failed(report_with(1e-7, 1e-8, z=4.5)) == ["k1: |z| = 4.50 > 4"]


def test_resolution_after_rank_on_a_synthetic_matrix():
    """Two parameters: both numerically present (rank 2), the second seen 1e4 times more weakly
    than the first. With the second at unit size, noise-whitened rows and sd = 1/s: it is
    determined to 1e-1 of its size at s = 10 and not at all at s = 0.1."""
    rng = np.random.default_rng(0)
    q, _ = np.linalg.qr(rng.normal(size=(20, 2)))
    for s2, resolved in ((10.0, True), (0.1, False)):
        jw = q * np.array([1e3, s2])  # columns: d f_w / d (theta / |theta|)
        ident = analyze(jw, ("k1", "k2"))
        assert ident.rank == 2 and ident.identifiable.all()  # the rank says yes
        cov = np.linalg.inv(jw.T @ jw)
        theta = np.ones(2)
        unresolved = resolve(ident, theta, cov)
        assert ident.relative_std[1] == pytest.approx(1 / s2)
        assert list(unresolved) == [False, not resolved]
        assert list(ident.identifiable) == [True, resolved]
        reasons = explain(
            ident,
            ParamLayout(2),
            {
                "motor_torque_seen": np.ones(2, bool),
                "loads_vertical": False,
                "n_distinct_q2": 3,
                "compensator_joint": None,
            },
        )
        assert ("k2" in reasons) is (not resolved)
        if not resolved:
            assert "+-1,000 % of its value" in reasons["k2"]


def test_identifiability_dict_reports_the_resolution():
    ident = Identifiability(("a",), np.ones(1), 1, np.ones(1, bool), np.zeros((1, 0)), np.ones(1))
    resolve(ident, np.array([2.0]), np.array([[9.0]]))
    d = ident.as_dict()
    assert d["relative_std"] == {"a": 1.5} and d["identifiable"] == {"a": False}


@pytest.mark.parametrize(
    "argv, words",
    [
        (["--configs", "30", "--candidates", "20"], ["--configs", "at most the 20 candidates"]),
        (["--candidates", "0"], ["--candidates", "an integer >= 1"]),
        (["--configs", "0"], ["--configs", "an integer >= 1"]),
        (["--starts", "-1"], ["--starts", "an integer >= 0"]),
        (["--processes", "0"], ["--processes", "an integer >= 1"]),
    ],
)
def test_design_impossible_sizes_exit_2_one_line(tmp_path, capsys, argv, words):
    js = tmp_path / "d.json"
    rc = main(["design", str(PAPER), "--json", str(js), *argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert len(err) == 1 and "Traceback" not in err[0]
    assert all(w in err[0] for w in words), err
    assert not js.exists()


def test_a_realistic_balancer_converges_on_its_bound_and_passes_the_check(tmp_path):
    """The shipped realistic balancer: the data prefer a spring without preload (P = K_C s0 on
    its bound); the fit must converge there, name K_C and s0 unidentifiable, and pass --check."""
    from conftest import ROOT

    from calbench.identify.cli import main

    log = tmp_path / "br.mcap"
    assert main(["simulate", str(ROOT / "scenarios" / "balancer_realistic.toml"), "--out", str(log)]) == 0
    assert main(["identify", str(log), "--check", "--json", str(tmp_path / "br.json")]) == 0
    import json

    rep = json.loads((tmp_path / "br.json").read_text())
    est = {p["name"]: p for p in rep["parameters"]}
    assert est["compensator_stiffness"]["estimate"] is None and est["compensator_preload"]["estimate"] is None
    assert rep["converged"] is True
