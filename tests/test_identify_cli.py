"""`calbench identify` end to end on simulated logs: accuracy, the CI gate, no truth leaks,
crashed logs, bad input, outliers.

Statistics: every |z| < 4 on a noisy log fails by chance with probability ~8 x 6e-5 = 5e-4
(the seed is fixed, so the test is deterministic; the Monte Carlo test checks the calibration
of the z's over many seeds). The altered-truth log shifts k3 by 10 % = 13 of its standard
deviations (0.52e-9 of 0.07e-6), so its |z| ~ 13 > 4 whatever the noise.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import badcases as bc
import numpy as np
import pytest
from conftest import K_TRUE, PAPER

from calbench.bench.log import IdentificationReport, read_log, strip_truth
from calbench.identify.cli import main
from calbench.identify.report import run_identify

NAMES = ["k1", "k2", "k3", "k4", "k5", "k6", "compensator_stiffness", "compensator_preload"]


@pytest.fixture(scope="module")
def paper_log(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("paper") / "paper.mcap"
    assert main(["simulate", str(PAPER), "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def paper_report(paper_log, tmp_path_factory) -> dict:
    js = tmp_path_factory.mktemp("rep") / "id.json"
    assert main(["identify", str(paper_log), "--json", str(js), "--check"]) == 0
    return json.loads(js.read_text())


def rewrite(src: Path, dst: Path, message=None, metadata=None, drop_topic: str | None = None) -> None:
    """Copy an MCAP log record by record, letting ``message(topic, dict) -> dict`` edit JSON
    messages and ``metadata(name, dict) -> dict`` edit metadata records (tests/badcases.py)."""
    bc.rewrite_json(src, dst, message, drop=drop_topic, metadata=metadata)


def estimates(rep: dict | IdentificationReport) -> np.ndarray:
    """The estimates of a JSON report or of run_identify's report (NaN: not identifiable)."""
    if isinstance(rep, IdentificationReport):
        rep = rep.to_dict()
    return np.array([np.nan if p["estimate"] is None else p["estimate"] for p in rep["parameters"]])


# --------------------------------------------------------------------------- accuracy and JSON


def test_noisy_log_every_z_below_4_and_contract_json(paper_report):
    rep = paper_report
    assert rep["method"] == "one-step"
    assert [p["name"] for p in rep["parameters"]] == NAMES
    assert [p["unit"] for p in rep["parameters"]] == ["rad/(N*m)"] * 6 + ["N/m", "m"]
    for key in ("residual_rms", "noise_sigma", "chi2_per_dof"):
        assert isinstance(rep[key], float)
    assert rep["noise_sigma"] == pytest.approx(20e-6)
    truth = np.concatenate([K_TRUE, [2.6e6, 0.83]])
    for p, t in zip(rep["parameters"], truth):
        assert p["truth"] == pytest.approx(t, rel=1e-12)
        assert p["std"] > 0 and abs(p["z"]) < 4, p
    # chi2/dof of a correct model: mean 1, sd sqrt(2/dof) = 0.13 at 124 dof; 4 sd
    assert abs(rep["chi2_per_dof"] - 1) < 4 * np.sqrt(2 / rep["dof"])
    assert rep["n_lost_poses"] == 0 and rep["outliers"] == []
    assert rep["seconds"] > 0  # reported; its speed is benchmarks/identify_bench.py's, not a timed test


def test_two_step_runs_and_reports_its_steps(paper_log, tmp_path):
    js = tmp_path / "two.json"
    rc = main(["identify", str(paper_log), "--method", "two-step", "--json", str(js)])
    assert rc == 0
    rep = json.loads(js.read_text())
    assert rep["method"] == "two-step"
    assert len(rep["step1"]["names"]) == 5 + 3  # k1, k2 at 3 q2, k3..k6 (eq. 19)
    assert rep["step2"]["n_distinct_q2"] == 3
    # the typed report reads its own output back exactly, estimator details included
    assert IdentificationReport.read(js).to_json() == js.read_text()


def test_two_step_iterated_reports_its_sagged_pose(paper_log, tmp_path):
    """`--method two-step-iterated`: the same report, and its step 2 names the pose it was
    linearised at, the Newton iterations and a converged fixed point: the sag of the
    compensator's joint per distinct q2 (|R| < 1e-9 rad)."""
    js = tmp_path / "it.json"
    assert main(["identify", str(paper_log), "--method", "two-step-iterated", "--json", str(js)]) == 0
    rep = json.loads(js.read_text())
    assert rep["method"] == "two-step-iterated"
    st = rep["step2"]
    assert st["converged"] and len(st["sag_rad"]) == 3 and st["newton_iterations"] >= 1
    assert abs(np.array(st["history"][-1]["residual_deg"])).max() < np.degrees(1e-9)
    assert IdentificationReport.read(js).to_json() == js.read_text()


# --------------------------------------------------------------------------- the CI gate


def test_check_fails_on_a_log_whose_truth_was_altered(paper_log, tmp_path):
    bad = tmp_path / "altered.mcap"

    def msg(topic, m):
        if topic == "/truth/parameters":
            m["compliance"][2] *= 1.10
        return m

    def meta(name, md):
        if name == "ground_truth":
            p = json.loads(md["parameters"])
            p["compliance"][2] *= 1.10
            md["parameters"] = json.dumps(p)
        return md

    rewrite(paper_log, bad, msg, meta)
    assert read_log(bad, include_truth=True).truth.parameters.compliance[2] == pytest.approx(0.077e-6)
    assert main(["identify", str(bad), "--check"]) == 1
    # and the estimate itself is the same as on the original log
    assert np.allclose(estimates(run_identify(bad)), estimates(run_identify(paper_log)), rtol=0, atol=0)


def test_check_without_truth_passes_with_a_note(paper_log, tmp_path, capsys):
    stripped = tmp_path / "stripped.mcap"
    strip_truth(paper_log, stripped)
    assert main(["identify", str(stripped), "--check"]) == 0
    assert "no ground truth" in capsys.readouterr().out


# --------------------------------------------------------------------------- no leaks


def test_estimates_unchanged_by_stripping_the_truth(paper_log, paper_report, tmp_path):
    stripped = tmp_path / "stripped.mcap"
    strip_truth(paper_log, stripped)
    js = tmp_path / "s.json"
    assert main(["identify", str(stripped), "--json", str(js)]) == 0
    rep = json.loads(js.read_text())
    assert np.array_equal(estimates(rep), estimates(paper_report))
    assert all(p["truth"] is None and p["z"] is None for p in rep["parameters"])


def test_estimates_unchanged_by_scaling_every_stiffness_in_the_mjcf(paper_log, paper_report, tmp_path):
    text = read_log(paper_log).mjcf_text

    def times10(m):
        vals = " ".join(repr(10 * float(x)) for x in m.group(2).split())
        return f'{m.group(1)}="{vals}"'

    edited = re.sub(r'\b(stiffness|springlength)="([^"]*)"', times10, text)
    assert edited.count("stiffness=") == text.count("stiffness=") >= 7 and edited != text
    model = tmp_path / "scaled.xml"
    model.write_text(edited)
    rep = run_identify(paper_log, model=model)
    assert np.array_equal(estimates(rep), estimates(paper_report))


# --------------------------------------------------------------------------- crashed logs, bad input


def test_truncated_log_is_identified_from_its_complete_poses(paper_log, tmp_path):
    data = paper_log.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.6)])
    log = read_log(cut)
    assert log.truncated and 0 < len(log.complete_poses) < 16
    js = tmp_path / "cut.json"
    assert main(["identify", str(cut), "--json", str(js)]) == 0
    rep = json.loads(js.read_text())
    assert rep["n_poses_used"] == len(log.complete_poses)
    assert rep["n_lost_poses"] == 16 - len(log.complete_poses) == len(rep["lost_poses"])
    assert rep["truncated"] is True
    assert IdentificationReport.read(js).to_json() == js.read_text()
    # the lateral pulls (poses 12-15) come last: without them k1 is named, not estimated
    if max(log.complete_poses) < 12:
        k1 = rep["parameters"][0]
        assert k1["estimate"] is None and "vertical" in k1["reason"]


def test_not_mcap_missing_model_missing_channel_exit_2(paper_log, tmp_path, capsys):
    junk = tmp_path / "junk.mcap"
    junk.write_text("not an mcap file")
    assert main(["identify", str(junk)]) == 2
    assert "MCAP" in capsys.readouterr().err
    assert main(["identify", str(paper_log), "--model", str(tmp_path / "nope.xml")]) == 2
    assert "--model" in capsys.readouterr().err
    nowrench = tmp_path / "nowrench.mcap"
    rewrite(paper_log, nowrench, drop_topic="/campaign/wrench")
    assert main(["identify", str(nowrench)]) == 2
    assert "/campaign/wrench" in capsys.readouterr().err


# --------------------------------------------------------------------------- outliers


def test_outlier_is_reported_and_can_be_dropped(paper_log, paper_report, tmp_path):
    bad = tmp_path / "outlier.mcap"

    def msg(topic, m):
        if topic == "/tracker/measurement" and m["pose"] == 5 and m["state"] == "loaded":
            i = next(i for i, v in enumerate(m["visible"]) if v)
            m["position"][i][2] += 10 * 20e-6 * np.sqrt(2)  # a 10 sigma reading
        return m

    rewrite(paper_log, bad, msg)
    rep = run_identify(bad)
    assert [o.pose for o in rep.outliers] == [5]
    refl = rep.outliers[0].reflector
    rep2 = run_identify(bad, drop_outliers=True)
    assert rep2.dropped_outliers[0].pose == 5 and rep2.dropped_outliers[0].reflector == refl
    assert rep2.outliers == () and rep2.n_observations == paper_report["n_observations"] - 1


def test_the_residual_line_names_the_trackers_error_model(paper_log, tmp_path, capsys):
    """The expected residual comes from the readings' own covariances: with an isotropic tracker
    the line gives its sigma; with a range-dependent one it names the model instead of the
    (unused) isotropic sigma."""
    assert main(["identify", str(paper_log), "--method", "one-step"]) == 0
    assert "σ = 20 µm per reading" in capsys.readouterr().out
    scn = tmp_path / "spec.toml"
    scn.write_text(
        PAPER.read_text()
        .replace("[tracker]\n", '[tracker]\nmodel = "spec"\n', 1)
        .replace('"../mjcf/', f'"{PAPER.parent.parent.as_posix()}/mjcf/')
    )
    log, js = tmp_path / "spec.mcap", tmp_path / "spec.json"
    assert main(["simulate", str(scn), "--out", str(log)]) == 0
    capsys.readouterr()
    assert main(["identify", str(log), "--method", "one-step", "--json", str(js)]) == 0
    out = capsys.readouterr().out
    assert "its spec error model" in out and "µm per reading" not in out
    assert json.loads(js.read_text())["tracker_noise_model"] == "spec"
    html = tmp_path / "spec.html"
    assert main(["report", str(log), "--identified", str(js), "--out", str(html)]) == 0
    assert "the tracker's noise (its spec error model, σ growing with range) leaves" in html.read_text()
