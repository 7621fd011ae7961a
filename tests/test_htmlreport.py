"""`calbench report` (identify/report/html.py): one offline HTML file, rendered by a real browser.

Headless Chromium loads the report through the DevTools protocol (tests/chromium.py): no console
message, no exception, no request other than the file itself and its data: images, every
section present, every image decoded. The numbers the page states are checked against the
inputs they come from. The identify report is a real one (this campaign); the discover and
design reports follow the CONTRACT.md shapes, with the optional fields (ambiguous, aliasing,
the certificate) that other commands add.
"""

from __future__ import annotations

import html as htmllib
import json
import os
import re
from pathlib import Path

import numpy as np
import pytest
from chromium import chromium_exe, render
from conftest import PAPER

from calbench.bench.campaign import run_campaign
from calbench.bench.scenario import load_scenario
from calbench.identify.cli import main
from calbench.identify.report import Z95, html_report, run_identify, write_report

SECTIONS = ["campaign", "parameters", "correlation", "residuals", "discovery", "design", "reproduce"]
UNIDENTIFIABLE = "compensator_preload"
REASON = "the compensator's preload and stiffness enter only as their product on this plan"

DISCOVER = {
    "named_effects": ["link_compliance"],
    "steps": [
        {
            "effect": "link_compliance",
            "detail": "forearm",
            "rms_before": 6.8e-05,
            "rms_after": 2.48e-05,
            "parameters": [
                {"name": "cx", "unit": "rad/(N*m)", "estimate": 1.9e-07, "std": 8e-09, "determined": True},
                {"name": "cy", "unit": "rad/(N*m)", "estimate": 0.0, "std": None, "determined": False},
            ],
        }
    ],
    "rms_before": 6.8e-05,
    "rms_after": 2.48e-05,
    "noise_sigma": 2e-05,
    "noise_rms_before": 2.74e-05,
    "noise_rms_after": 2.71e-05,
    "chi2_before": 765.2,
    "dof_before": 124,
    "p_before": 5.7e-93,
    "chi2_after": 101.4,
    "dof_after": 121,
    "p_after": 0.9,
    "candidates": [
        {
            "effect": "link_compliance",
            "detail": "forearm",
            "score": 649.2,
            "lr": 663.8,
            "k": 3,
            "p_lr": 1.5e-143,
            "accepted": True,
        },
        {"effect": "compensator", "detail": "", "score": None, "error": "no tendon"},
    ],
    "per_pose": [{"pose": p, "rms_before": 6e-05 + 1e-06 * p, "rms_after": 2.5e-05} for p in range(16)],
    "where_before": {"words": ["The model does not fit: chi2 = 765.2 for 124 degrees of freedom."]},
    "ambiguous": [
        {
            "round": 1,
            "candidates": [
                {
                    "candidate": "joint_nonlinearity[j2]",
                    "lr": 42.4,
                    "k": 1,
                    "bic_gain": 37.5,
                    "lr_difference": 0.0,
                    "bic_difference": 0.0,
                    "lr_difference_spread": 0.0,
                },
                {
                    "candidate": "base_compliance",
                    "lr": 44.6,
                    "k": 2,
                    "bic_gain": 34.8,
                    "lr_difference": -2.2,
                    "bic_difference": 2.7,
                    "lr_difference_spread": 9.5,
                },
            ],
        }
    ],
    "aliasing": [
        {
            "effect": "joint_nonlinearity",
            "detail": "j1",
            "parameter": "cubic",
            "unit": "N*m/rad^3",
            "visible": False,
            "visible_share": 1e-13,
            "excited": True,
            "detectable_magnitude": None,
            "reference_magnitude": 3.8e10,
            "biases": [
                {
                    "parameter": "k1",
                    "per_unit": -6.3e-20,
                    "at_reference_sigma": -3.9,
                    "at_reference_percent": -0.96,
                }
            ],
        },
        {
            "effect": "base_compliance",
            "detail": "",
            "parameter": "cx",
            "unit": "rad/(N*m)",
            "visible": True,
            "visible_share": 0.79,
            "excited": True,
            "detectable_magnitude": 1.05e-9,
            "reference_magnitude": 8.3e-10,
            "biases": [],
        },
        {
            "effect": "load_scale",
            "detail": "hung weights",
            "parameter": "scale",
            "unit": "1",
            "visible": True,
            "visible_share": 0.019,
            "excited": True,
            "detectable_magnitude": 0.35,
            "reference_magnitude": 0.0068,
            "biases": [
                {
                    "parameter": "k2",
                    "per_unit": 1.16e-7,
                    "per_percent_mass": 1.16e-9,
                    "per_percent_mass_relative_percent": 0.98,
                    "at_reference_sigma": 0.71,
                    "at_reference_percent": 0.67,
                }
            ],
        },
    ],
    "augmented_model": "robot.augmented.xml",
}
CERTIFICATE = {"criterion": "D", "plan_logdet": 70.31883, "bound_logdet": 70.41250, "efficiency": 0.98836}
DESIGN = {
    "scenario": "paper_table5.toml",
    "criterion": "D",
    "configs": 2,
    "rows": [84, 721],
    "certificate": CERTIFICATE,
    "measures": {"A": 0.015, "D": 0.000146, "relative_std": {"k1": 0.0031}},
    "candidates": {"count": 1000},
    "poses": [
        {
            "q_deg": [68.6, 46.0, 5.9, -160.7, 11.5, 62.7],
            "load": "vertical",
            "wrench": [0, 0, -6867, 0, 0, 0],
            "repeats": 1,
        },
        {
            "q_deg": [-152.6, 81.8, 14.3, 90.6, 79.6, -178.0],
            "load": "lateral",
            "wrench": [1200, 0, 0, 0, 0, 0],
            "repeats": 1,
        },
    ],
}


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("report")
    log = d / "campaign.mcap"
    run_campaign(load_scenario(PAPER), log)
    ident = run_identify(log).to_dict()
    # one parameter as identify writes an unidentifiable one: no estimate, no std, a reason,
    # its covariance row and column null
    i = [p["name"] for p in ident["parameters"]].index(UNIDENTIFIABLE)
    ident["parameters"][i].update(
        estimate=None, std=None, z=None, error=None, identifiable=False, reason=REASON
    )
    ident["unidentifiable"] = {UNIDENTIFIABLE: REASON}
    for row in ident["covariance"]:
        row[i] = None
    ident["covariance"][i] = [None] * len(ident["covariance"])
    paths = {
        "log": log,
        "identified": d / "identify.json",
        "discover": d / "discover.json",
        "design": d / "design.json",
    }
    paths["identified"].write_text(json.dumps(ident))
    paths["discover"].write_text(json.dumps(DISCOVER))
    paths["design"].write_text(json.dumps(DESIGN))
    return paths


def full_report(inputs, out: Path) -> Path:
    return write_report(inputs["log"], out, inputs["identified"], inputs["discover"], inputs["design"])


@pytest.fixture(scope="module")
def report(inputs) -> Path:
    """The report of every input, built once for the tests below."""
    return full_report(inputs, inputs["log"].with_name("report.html"))


def test_report_renders_offline_in_chromium_with_every_section(report, tmp_path):
    if chromium_exe() is None:
        if os.environ.get("CI"):
            pytest.fail("chromium is not installed (.ci/run installs the Debian package)")
        pytest.skip("chromium not installed (apt-get install chromium)")
    page = report
    shot = tmp_path / "report.png"
    r = render(page, shot)
    assert r.sections == SECTIONS
    assert r.console == [] and r.exceptions == [] and r.log_errors == [] and r.failed == []
    assert r.requests[0] == page.resolve().as_uri()
    assert all(u.startswith("data:image/svg+xml;base64,") for u in r.requests[1:])
    # relative std, correlation, residual map and bars, discovery before/after
    assert len(r.images) == 5 and all(i["ok"] for i in r.images)
    assert r.title.startswith("Calibration report")
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and r.height > 3000


def _row(html: str, name: str) -> list[str]:
    m = re.search(rf"<tr[^>]*><td>{re.escape(name)}</td>(.*?)</tr>", html, re.S)
    assert m, name
    return re.findall(r"<td[^>]*>(.*?)</td>", m.group(1), re.S)


def test_the_numbers_on_the_page_are_those_of_the_inputs(inputs, report):
    raw = report.read_text()
    html = htmllib.unescape(raw)
    ident = json.loads(inputs["identified"].read_text())
    for p in ident["parameters"]:
        cells = _row(html, p["name"])
        if p["estimate"] is None:  # named, with its reason
            assert "not identifiable" in cells[1] and REASON in cells[1]
            continue
        f = 1e6 if p["unit"] == "rad/(N*m)" else 1e-3 if p["unit"] == "N/m" else 1e3
        est, std, lo_hi = float(cells[1]), float(cells[2]), cells[3]
        lo, hi = (float(x) for x in lo_hi.strip("[]").split(","))
        half_ulp = 0.5 * 10.0 ** -len(cells[1].split(".")[1]) if "." in cells[1] else 0.5
        assert abs(est - p["estimate"] * f) <= half_ulp
        assert abs(std - p["std"] * f) <= half_ulp
        assert abs(lo - (p["estimate"] - Z95 * p["std"]) * f) <= half_ulp
        assert abs(hi - (p["estimate"] + Z95 * p["std"]) * f) <= half_ulp
    assert f"<b>{UNIDENTIFIABLE}</b>: {REASON}" in html
    # residual RMS per reflector: all residual components of that reflector's observations
    for refl in ("refl_a", "refl_b", "refl_c"):
        r = np.array([o["residual"] for o in ident["observations"] if o["reflector"] == refl])
        cells = _row(html, refl)
        assert int(cells[0]) == len(r)
        assert abs(float(cells[1]) - np.sqrt(np.mean(r**2)) * 1e6) <= 0.05
        assert abs(float(cells[2]) - np.sqrt(np.mean(r**2)) / ident["expected_residual_rms"]) <= 0.005
    # discovery: the verdict, the before/after and the aliasing and ambiguity warnings
    assert "Named: link_compliance (forearm)." in html
    assert _row(html, "the user's model")[:2] == ["68.0", "27.4"]
    assert "load_scale" in html and "Aliasing" in html and "Ambiguous" in html
    # ... in words, with the contract's numbers, never the JSON's field names
    text = htmllib.unescape(html)
    assert (
        "round 1: joint_nonlinearity[j2] (LR 42.4, k = 1, BIC gain 37.5) and base_compliance "
        "(LR 44.6, k = 2, BIC gain 34.8)"
    ) in text
    assert (
        "<td>joint_nonlinearity j1</td><td>absorbed exactly, never seen: cubic (at 3.8e+10 "
        "N·m/rad³: k1 -3.9 σ (-0.96 %))</td>"
    ) in text  # the page's symbols
    assert "<td>base_compliance</td><td>named cx from 1.1e-09 rad/(N·m)</td>" in text
    assert (
        "never named (deflections alone cannot tell it from the compliances); 98.1 % of its "
        "signature is absorbed, the rest leaves a misfit (not a name) from a mass 35 % off; a mass "
        "1 % high biases k2 +0.98 %"
    ) in text
    for field in ("at_reference_sigma", "per_unit", "visible_share", "lr_difference", "{"):
        assert field not in text[text.index('<section id="discovery">') : text.index('<section id="design">')]
    assert "the tracker's noise (σ = 20 µm per reading) leaves" in html  # an isotropic tracker
    assert "cy = 0.000 µrad/(N·m) (not determined)" in html  # the unit before the verdict
    # the certificate
    assert "within 1.16 % of the best possible 2-configuration plan" in html
    assert "efficiency 98.84 %" in html and "70.4125" in html
    # the commands that reproduce it, with the inputs' own paths
    assert f"calbench identify {inputs['log']} --method one-step --json {inputs['identified']}" in html
    assert f"--configs 2 --criterion D --candidates 1000 --json {inputs['design']}" in html
    # offline: every src and href is a data URI or an anchor in the page
    assert re.findall(r'(?:src|href)="(?!data:|#)', raw) == []


def test_sections_say_which_command_fills_them_and_the_page_is_reproducible(inputs, report, tmp_path):
    html = html_report(inputs["log"])
    for sid in SECTIONS:
        assert f'<section id="{sid}">' in html
    assert "No identification given: run <code>calbench identify" in html
    assert "No discovery given" in html and "No design given" in html
    assert html_report(inputs["log"]) == html  # no clock in it
    first = report.read_bytes()
    assert full_report(inputs, report).read_bytes() == first  # rebuilt in place: same bytes
    # a log cut short by a crash: its lost poses are named
    cut = tmp_path / "cut.mcap"
    data = inputs["log"].read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    html = html_report(cut)
    m = re.search(r"<dt>lost poses</dt><dd><span class=\"flag\">([\d, ]+)</span>", html)
    assert m and "the campaign did not finish" in html
    lost = [int(x) for x in m.group(1).split(",")]
    assert lost == list(range(lost[0], 16)) and 0 < lost[0] < 16


@pytest.mark.parametrize(
    "case",
    [
        "missing log",
        "missing json",
        "discover as identify",
        "not json",
        "design without criterion",
        "aliasing not the contract's",
        "out is the log",
    ],
)
def test_bad_input_exits_2_naming_the_file(inputs, tmp_path, capsys, case):
    out = tmp_path / "never.html"
    bad = tmp_path / "bad.json"
    args = {
        "log": str(inputs["log"]),
        "--identified": None,
        "--discover": None,
        "--design": None,
        "--out": str(out),
    }
    named = bad
    if case == "missing log":
        args["log"] = named = str(tmp_path / "absent.mcap")
    elif case == "missing json":
        args["--identified"] = named = str(tmp_path / "absent.json")
    elif case == "discover as identify":
        args["--identified"] = named = str(inputs["discover"])
    elif case == "not json":
        bad.write_text("{ not json")
        args["--identified"] = str(bad)
    elif case == "design without criterion":
        bad.write_text(json.dumps({k: v for k, v in DESIGN.items() if k != "criterion"}))
        args["--design"] = str(bad)
    elif case == "aliasing not the contract's":
        bad.write_text(
            json.dumps(
                {**DISCOVER, "aliasing": [{"effect": "load_scale", "visible": False, "biases": {"k2": -0.9}}]}
            )
        )
        args["--discover"] = str(bad)
    else:
        args["--out"] = named = str(inputs["log"])
    argv = ["report", args.pop("log")] + [x for k, v in args.items() if v for x in (k, v)]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert str(named) in err and "expected" in err
    assert not out.exists()
    if case == "discover as identify":
        assert "calbench identify --json" in err
    if case == "aliasing not the contract's":
        assert ": aliasing: expected" in err and len(err.strip().splitlines()) == 1


def test_a_certificate_of_a_criterion_to_minimise_is_labelled_a_lower_bound():
    """A, AD and pose certificates carry plan_value/bound_value (docs/contract.md): the page
    names them as the criterion and its certified lower bound, not as log dets."""
    from calbench.identify.report import design_section

    cert = {
        "criterion": "A",
        "plan_value": 0.0103684,
        "bound_value": 0.0096494,
        "efficiency": 0.9307,
        "configs": 2,
        "distinct": False,
    }
    c = design_section({**DESIGN, "criterion": "A", "certificate": cert})["certificate"]
    assert (c["plan"], c["bound"]) == ("0.01037", "0.009649")
    assert c["plan_label"].startswith("A of the plan") and "lower bound" in c["bound_label"]
    assert (c["gap"], c["efficiency"]) == ("6.93", "93.07")
    d = design_section(DESIGN)["certificate"]
    assert (d["plan"], d["bound"]) == ("70.3188", "70.4125") and "upper bound" in d["bound_label"]


def test_an_unexplained_verdict_says_nothing_is_determined():
    """Issue 22: a discovery left `unexplained` reports no parameter as determined, and the
    report's verdict says why."""
    from calbench.identify.report import discovery_section

    steps = [{"effect": "unexplained", "rms_before": 1e-4, "rms_after": 1e-4}]
    verdict = discovery_section({"named_effects": ["unexplained"], "steps": steps})["verdict"]
    assert "no candidate of the library explains" in verdict
    assert "No parameter is reported as determined" in verdict
