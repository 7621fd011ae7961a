"""`calbench discover` on logs where an effect is hidden in the truth (paper plan, 20 um).

Magnitudes (flange displacement they add under 700 kg: see benchmarks/discover_bench.py):
  link_compliance forearm   [1.8e-7, 0, 1.8e-7] rad/(N*m)   (lateral bending + torsion; the
                            in-plane y spring is exactly a k3 change and is never testable)
  link_compliance upper_arm [1.5e-8, 1.5e-8, 1.5e-8]
  base_compliance           [4e-9, 4e-9]
  joint_nonlinearity j3     cubic 6e12 N*m/rad^3 (the j3 spring is 2x stiffer at the largest
                            deflection of the plan): named, but RMS before only ~1.55x noise.
                            The 2x of the issue is out of reach at plausible magnitudes: the
                            cubic stiffens the joint and so limits its own deflection (2e13
                            gives only 1.69x).
  compensator (user model without one; truth K_C 6e6 N/m, s0 0.83 m): named, before ~1.3x. At
                            the shipped K_C = 2.6e6 N/m the model without a compensator fits the
                            paper plan to the noise level (global chi2 p = 0.55), yet the targeted
                            likelihood ratio names it (LR 22 for 2 parameters, p = 2e-5): there
                            is no global gate in front of the tests. 2x needs K_C ~ 1.2e7.
  tracker_drift [30, -20, 25] um (tracker frame, measurement side): named, before ~1.2x.
  tool_compliance [4e-7, 4e-7] (truth only, outside the library): `unexplained`.
"""

from __future__ import annotations

import json
from pathlib import Path

import mujoco
import numpy as np
import pytest
from conftest import MJCF, PAPER

from calbench.bench.campaign import run_campaign
from calbench.bench.log import read_log, strip_truth
from calbench.bench.model import Robot
from calbench.bench.model.effects import REGISTRY, apply_effects, without_compensator
from calbench.bench.scenario import load_scenario, scenario_variant
from calbench.identify.cli import main as cli_main
from calbench.identify.discover import ALPHA_EFFECT, DISCOVERY_EFFECTS, UNEXPLAINED, discover, library, story

HIDDEN = {
    "forearm": (
        '[truth.effects.link_compliance]\nlink = "forearm"\ncompliance = [1.8e-7, 0.0, 1.8e-7]',
        "link_compliance",
        "forearm",
    ),
    "upper_arm": (
        '[truth.effects.link_compliance]\nlink = "upper_arm"\ncompliance = [1.5e-8, 1.5e-8, 1.5e-8]',
        "link_compliance",
        "upper_arm",
    ),
    "base": ("[truth.effects.base_compliance]\ncompliance = [4e-9, 4e-9]", "base_compliance", ""),
    "j3": ("[truth.effects.joint_nonlinearity]\njoint = 3\ncubic = 6e12", "joint_nonlinearity", "j3"),
    "drift": ("[truth.effects.tracker_drift]\noffset = [30e-6, -20e-6, 25e-6]", "tracker_drift", ""),
}
BEFORE_MIN = {"forearm": 2.0, "upper_arm": 2.0, "base": 2.0, "j3": 1.5, "drift": 1.2}  # see the docstring
AFTER_MAX = 1.3


def scenario(tmp: Path, name: str, extra: str = "", compensator: tuple | None = None) -> Path:
    return scenario_variant(PAPER, tmp / f"{name}.toml", compensator=compensator, extra=extra)


def bare_model(tmp: Path) -> Path:
    """The user's model without the compensator tendon (and its sites)."""
    path = tmp / "bare.xml"
    path.write_text(without_compensator(MJCF))
    return path


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("discover")
    out = {}
    cases = {k: v[0] for k, v in HIDDEN.items()}
    cases["none"] = ""
    cases["tool"] = "[truth.effects.tool_compliance]\ncompliance = [4e-7, 4e-7]"
    cases["two"] = HIDDEN["forearm"][0] + "\n" + HIDDEN["base"][0]
    for name, extra in cases.items():
        run_campaign(load_scenario(scenario(tmp, name, extra)), tmp / f"{name}.mcap")
        out[name] = tmp / f"{name}.mcap"
    for name, comp in (("comp_default", (2.6e6, 0.83)), ("comp_strong", (6e6, 0.83))):
        run_campaign(load_scenario(scenario(tmp, name, "", comp)), tmp / f"{name}.mcap")
        out[name] = tmp / f"{name}.mcap"
    spec = scenario(tmp, "spec")
    spec.write_text(spec.read_text().replace("[tracker]\n", '[tracker]\nmodel = "spec"\n', 1))
    run_campaign(load_scenario(spec), tmp / "spec_null.mcap")
    out["spec_null"] = tmp / "spec_null.mcap"
    out["bare"] = bare_model(tmp)
    out["tmp"] = tmp
    return out


_REPORTS: dict = {}


def run(logs, case, model=None):
    """discover() on a case's log, once per module (the augmented MJCF next to the log)."""
    key = (case, str(model))
    if key not in _REPORTS:
        _REPORTS[key] = discover(logs[case], model, out_model=logs["tmp"] / f"{case}.augmented.xml")
    return _REPORTS[key]


def ratios(rep):
    return rep["rms_before"] / rep["noise_rms_before"], rep["rms_after"] / rep["noise_rms_after"]


# --------------------------------------------------------------------------- the library


def test_library_is_the_contract_effects_with_options():
    lib = library(Robot.from_file(MJCF))
    assert (
        {e.name for e in lib}
        == set(DISCOVERY_EFFECTS)
        == {"compensator", "joint_nonlinearity", "link_compliance", "base_compliance", "tracker_drift"}
    )
    assert "tool_compliance" in REGISTRY and "tool_compliance" not in {e.name for e in lib}
    # the options come from the robot description: its calbench:links, its actuated joints
    assert sorted(e.detail for e in lib if e.name == "link_compliance") == ["forearm", "upper_arm"]
    assert sorted(e.detail for e in lib if e.name == "joint_nonlinearity") == [f"j{j}" for j in range(1, 7)]
    assert [e.options["body"] for e in lib if e.name == "base_compliance"] == ["base"]
    # a robot that names no links and no compensator mounts gets neither candidate
    from robots import serial_mjcf

    serial = library(Robot.from_xml(serial_mjcf()))
    assert {e.name for e in serial} == {"joint_nonlinearity", "base_compliance", "tracker_drift"}
    assert [e.options["body"] for e in serial if e.name == "base_compliance"] == ["pedestal"]
    assert len([e for e in serial if e.name == "joint_nonlinearity"]) == 4


def test_tool_compliance_truth_effect(tmp_path):
    """The truth-only effect: loads through the scenario, moves the payload and reflectors onto
    the compliant tool (same positions), set_params equals apply."""
    scn = load_scenario(scenario(tmp_path, "t", "[truth.effects.tool_compliance]\ncompliance = [3e-7, 0.0]"))
    assert scn.effects["tool_compliance"]["compliance"].tolist() == [3e-7, 0.0]
    eff = REGISTRY["tool_compliance"]()
    robot = apply_effects(MJCF, [(eff, [3e-7, 2e-7])])
    plain = Robot.from_file(MJCF)
    assert robot.model.nv == plain.model.nv + 2
    tool = robot.model.body("tool").id
    for s in ["payload", "refl_a", "refl_b", "refl_c"]:
        assert robot.model.site_bodyid[robot.model.site(s).id] == tool
    q = np.radians([10, 40, 5, 20, -30, 50])
    for r in (robot, plain):
        r.data.qpos[:] = r.rigid_qpos(q)
        mujoco.mj_kinematics(r.model, r.data)
    np.testing.assert_allclose(
        robot.data.site_xpos[robot.reflector_sites], plain.data.site_xpos[plain.reflector_sites], atol=1e-12
    )
    eff.set_params(robot, [1e-7, 1e-7])
    assert robot.model.jnt_stiffness[robot.model.joint("tool_ry").id] == pytest.approx(1e7)


# --------------------------------------------------------------------------- the workflow


@pytest.mark.parametrize("case", list(HIDDEN))
def test_hidden_effect_is_named_and_gap_closes(logs, case):
    _, effect, detail = HIDDEN[case]
    out = logs["tmp"] / f"{case}.augmented.xml"
    rep = run(logs, case)
    before, after = ratios(rep)
    assert rep["named_effects"] == [effect], rep["rounds"]
    assert rep["steps"][0]["effect"] == effect and rep["steps"][0]["detail"] == detail
    assert before >= BEFORE_MIN[case]
    assert after <= AFTER_MAX
    assert rep["p_after"] > 1e-3
    assert rep["seconds"] > 0  # reported; its speed is benchmarks/discover_speed_bench.py's
    # the augmented MJCF loads and carries the identified parameters
    aug = Robot.from_file(out)
    assert rep["augmented_model"] == str(out)
    fitted = {p["name"]: p["estimate"] for p in rep["steps"][0]["parameters"]}
    if effect == "link_compliance":
        for ax in "xyz":
            j = aug.model.joint(f"{detail}_r{ax}").id
            assert aug.model.jnt_stiffness[j] == pytest.approx(1.0 / fitted[f"c{ax}"], rel=1e-9)
    if effect == "base_compliance":
        assert aug.model.jnt_stiffness[aug.model.joint("base_rx").id] == pytest.approx(
            1 / fitted["cx"], rel=1e-9
        )
    if effect == "joint_nonlinearity":
        assert aug.model.jnt_stiffnesspoly[aug.model.joint(detail).id][1] == pytest.approx(
            fitted["cubic"], rel=1e-9
        )


def test_identified_values_are_close_to_the_truth(logs):
    """Where the plan determines them, the named effect's parameters match the hidden truth."""
    rep = run(logs, "base")
    est = [p["estimate"] for p in rep["steps"][0]["parameters"]]
    np.testing.assert_allclose(est, [4e-9, 4e-9], rtol=0.25)
    rep = run(logs, "j3")
    assert rep["steps"][0]["parameters"][0]["estimate"] == pytest.approx(6e12, rel=0.3)


def test_no_hidden_effect_names_nothing(logs):
    rep = discover(logs["none"])
    assert rep["named_effects"] == [] and rep["steps"] == []
    assert rep["augmented_model"] is None
    assert rep["p_before"] > 1e-3
    assert rep["rms_after"] == rep["rms_before"]


def test_effect_outside_the_library_is_unexplained(logs):
    rep = discover(logs["tool"])
    before, after = ratios(rep)
    assert rep["named_effects"] == [UNEXPLAINED]
    assert before >= 2.0 and after >= 2.0
    # no library candidate mimics it: the best removes less than the share the rule asks of a
    # named effect (decide.py's MIN_EXPLAINED) and leaves a fit the noise cannot explain
    from calbench.identify.discover import MIN_EXPLAINED

    best = max((c for c in rep["candidates"] if c["score"] is not None), key=lambda c: c["explained"])
    assert best["explained"] < MIN_EXPLAINED and best["p_fit"] < 1e-3
    assert rep["augmented_model"] is None
    # issue 22: a model the readings reject determines nothing (every std would assume it); the
    # std it would have had, scaled by the Birge ratio, is kept apart, as a lower bound
    assert not any(p["determined"] or p["std"] is not None for p in rep["parameters"])
    assert rep["combinations"] == []
    mis = rep["unexplained_misfit"]
    assert mis["birge_ratio"] == pytest.approx((rep["chi2_after"] / rep["dof_after"]) ** 0.5)
    assert mis["birge_ratio"] > 1 and mis["std_if_the_model_were_right"]


def test_tracker_drift_null_with_spec_noise_names_nothing(logs):
    """The measurement-side candidate on a log with no effect and the distance/transverse
    (spec) noise model: the tests hold their level under correlated, anisotropic noise."""
    rep = run(logs, "spec_null")
    assert rep["named_effects"] == [] and rep["p_before"] > 1e-3
    drift = [c for c in rep["candidates"] if c["effect"] == "tracker_drift"][0]
    assert not drift["significant"] and drift["k"] == 3


def test_tracker_drift_is_the_offset_in_the_tracker_frame(logs):
    """The named drift matches the truth's offset within 4 of its reported standard deviations."""
    rep = run(logs, "drift")
    est = {p["name"]: p for p in rep["steps"][0]["parameters"]}
    for name, truth in zip(("bx", "by", "bz"), (30e-6, -20e-6, 25e-6)):
        assert est[name]["determined"] and abs(est[name]["estimate"] - truth) < 4 * est[name]["std"]


def test_text_and_file_agree_with_two_effects(logs, capsys):
    """Each "Named:" line prints the FINAL joint refit, the values the augmented MJCF holds (the
    values of the round an effect was named in stay in ``parameters_at_naming``)."""
    rep = run(logs, "two")
    assert sorted(rep["named_effects"]) == ["base_compliance", "link_compliance"]
    # the two explain different parts (each still significant once the other is in): no near-tie
    assert rep["ambiguous"] == []
    aug = Robot.from_file(logs["tmp"] / "two.augmented.xml")
    text = story(rep)
    first = rep["steps"][0]
    assert first["parameters"] != first["parameters_at_naming"]  # the joint refit moved them
    for s in rep["steps"]:
        prefix = "forearm" if s["effect"] == "link_compliance" else "base"
        line = [ln for ln in text.splitlines() if ln.startswith(f"Named: {s['effect']}")][0]
        assert "()" not in line  # an effect without a detail has no brackets
        for p in s["parameters"]:
            assert f"{p['name']} = {p['estimate']:.4g}" in line
            if p["determined"]:
                k = aug.model.jnt_stiffness[aug.model.joint(f"{prefix}_r{p['name'][1]}").id]
                assert 1.0 / k == pytest.approx(p["estimate"], rel=1e-9)


def test_only_the_combination_of_k3_and_the_forearm_pitch_is_reported(logs):
    """The forearm's in-plane spring is exactly a k3 (the parallelogram): the split is not
    determined, the sum is, and it is the truth's k3 (+ 0 in-plane bending) within 4 std."""
    rep = run(logs, "forearm")
    pars = {p["name"]: p for p in rep["parameters"]}
    assert not pars["k3"]["determined"] and not pars["link_compliance[forearm].cy"]["determined"]
    assert pars["k3"]["std"] is None
    combo = [
        c for c in rep["combinations"] if set(c["combination"]) == {"k3", "link_compliance[forearm].cy"}
    ][0]
    assert all(v == pytest.approx(1.0, rel=1e-3) for v in combo["combination"].values())
    assert abs(combo["estimate"] - 0.07e-6) < 4 * combo["std"]


def test_compensator_missing_from_the_user_model(logs):
    rep = discover(logs["comp_strong"], logs["bare"], out_model=logs["tmp"] / "c.xml")
    assert rep["named_effects"] == ["compensator"]
    before, after = ratios(rep)
    assert before > 1.2 and after <= AFTER_MAX
    est = {p["name"]: p["estimate"] for p in rep["steps"][0]["parameters"]}
    assert est["K_C"] == pytest.approx(6e6, rel=0.3) and est["s0"] == pytest.approx(0.83, abs=0.1)
    aug = Robot.from_file(logs["tmp"] / "c.xml")
    # the tendon the effect added is a compensator of the augmented robot description
    assert aug.description.compensators == ("compensator",)
    assert aug.model.tendon_stiffness[aug.tendons[0]] == pytest.approx(est["K_C"], rel=1e-9)
    # the shipped compensator (2.6e6 N/m): the user's model without it passes the global chi2
    # test, and the targeted likelihood-ratio test still names it (no global gate)
    rep = discover(logs["comp_default"], logs["bare"], out_model=logs["tmp"] / "c2.xml")
    assert rep["p_before"] > 1e-3
    assert rep["named_effects"] == ["compensator"]
    assert (
        rep["steps"][0]["p_lr"]
        < rep["steps"][0]["alpha"]
        == pytest.approx(ALPHA_EFFECT / len(library(Robot.from_file(MJCF))))
    )


def test_truth_never_read(logs, tmp_path):
    """The same answer from a log stripped of every truth record."""
    stripped = tmp_path / "stripped.mcap"
    strip_truth(logs["upper_arm"], stripped)
    assert read_log(stripped, include_truth=True).truth is None
    a = run(logs, "upper_arm")
    b = discover(stripped, out_model=tmp_path / "b.xml")
    assert a["named_effects"] == b["named_effects"]
    assert a["rms_after"] == pytest.approx(b["rms_after"], rel=1e-9)


def test_cli_json_plot_view(logs, tmp_path, capsys):
    js = tmp_path / "d.json"
    aug = tmp_path / "aug.xml"
    assert (
        cli_main(
            [
                "discover",
                str(logs["forearm"]),
                "--model",
                str(MJCF),
                "--json",
                str(js),
                "--out-model",
                str(aug),
            ]
        )
        == 0
    )
    text = capsys.readouterr().out
    assert "Named: link_compliance (forearm)" in text and "does not fit" in text
    rep = json.loads(js.read_text())
    for key in (
        "named_effects",
        "steps",
        "rms_before",
        "rms_after",
        "noise_sigma",
        "candidates",
        "augmented_model",
        "parameters",
        "noise_rms_before",
        "noise_rms_after",
        "ambiguous",
        "aliasing",
    ):
        assert key in rep
    assert rep["ambiguous"] == []
    named = {(a["effect"], a["detail"]) for a in rep["aliasing"]}
    assert ("link_compliance", "forearm") not in named and ("load_scale", "hung weights") in named
    assert {(e.name, e.detail) for e in library(Robot.from_file(MJCF))} - {
        ("link_compliance", "forearm")
    } <= named
    for a in rep["aliasing"]:
        assert {"effect", "detail", "parameter", "visible", "visible_share", "biases"} <= set(a)
    for s in rep["steps"]:
        assert {"effect", "detail", "rms_before", "rms_after"} <= set(s)
    assert all({"effect", "score"} <= set(c) for c in rep["candidates"])
    assert rep["noise_sigma"] == pytest.approx(20e-6)
    assert rep["augmented_model"] == str(aug) and Robot.from_file(aug).model.nv > 0
    assert Path(rep["plot"]).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    from calbench.bench.log import IdentificationReport

    ident = IdentificationReport.read(rep["view_json"])
    assert len(ident.predictions()) == rep["n_poses"] and not ident.read_warnings
    # bad input: exit status 2
    assert cli_main(["discover", str(tmp_path / "missing.mcap")]) == 2
    assert cli_main(["discover", str(logs["forearm"]), "--model", str(tmp_path / "nope.xml")]) == 2


def test_augmented_jacobian_matches_finite_differences(logs):
    """d dp / d theta of the augmented forward model (implicit function theorem with the effect
    columns from the passive force) against central differences of the solved equilibria."""
    from calbench.bench.model.effects import link_compliance
    from calbench.identify.core import from_log
    from calbench.identify.discover import build

    obs = from_log(read_log(logs["none"]))
    obs = obs.subset(obs.labels[:9])
    eff = link_compliance("forearm")
    _, fm = build(MJCF, [(eff, [5e-8, 2e-8, 5e-8])], obs)
    theta = np.r_[[0.25e-6, 0.12e-6, 0.07e-6, 0.35e-6, 0.40e-6, 0.60e-6], 2.6e6, 0.83, 5e-8, 2e-8, 5e-8]
    _, jac = fm.evaluate(theta)
    for i in (1, 6, 8, 10):
        h = 1e-4 * theta[i]
        tp, tm = theta.copy(), theta.copy()
        tp[i] += h
        tm[i] -= h
        fd = (fm.evaluate(tp, jacobian=False)[0] - fm.evaluate(tm, jacobian=False)[0]) / (2 * h)
        np.testing.assert_allclose(jac[..., i], fd, atol=1e-4 * np.abs(fd).max())


@pytest.mark.parametrize("effect", library(Robot.from_file(MJCF)), ids=lambda e: e.name + e.detail)
def test_effects_write_only_spring_values(effect):
    """bench/model/effects/'s rule that discovery's analytic stiffness matrix relies on: set_params
    changes nothing in the compiled model but joint and tendon spring values: the fields the
    batched statics' copy of the model is given after each write (AugmentedForward.sync_fields)."""
    from calbench.identify.discover import AugmentedForward, effect_priors

    start, _, _, size = effect_priors(effect)
    src = without_compensator(MJCF) if effect.name == "compensator" else MJCF
    robot = apply_effects(src, [(effect, start)])
    m = robot.model
    fields = [f for f in dir(m) if not f.startswith("_") and isinstance(getattr(m, f), np.ndarray)]
    before = {f: getattr(m, f).copy() for f in fields}
    effect.set_params(robot, np.where(start != 0, 3 * start, size))
    changed = {f for f in fields if not np.array_equal(before[f], getattr(m, f))}
    assert changed <= set(AugmentedForward.sync_fields), changed
    assert changed or effect.measurement_side


@pytest.mark.parametrize("effect", library(Robot.from_file(MJCF)), ids=lambda e: e.name + e.detail)
def test_effect_force_columns_match_finite_differences(logs, effect):
    """dg/dtheta of every effect through the spring values it writes (chain rule, analytic in q)
    equals central differences of MuJoCo's passive force (relative 1e-7: the differences' O(h^2)
    error is ~1e-12, their round-off ~1e-10), at a loaded equilibrium of the paper plan."""
    from calbench.bench.statics import statics_options
    from calbench.identify.core import from_log
    from calbench.identify.discover import build, effect_priors

    obs = from_log(read_log(logs["none"]))
    obs = obs.subset([lab for lab in obs.labels if lab[0] == 12])  # a lateral pull: every joint loaded
    start, _, _, size = effect_priors(effect)
    p = np.where(start != 0, 3 * start, 0.5 * size)
    src = MJCF
    if effect.name == "compensator":
        src, p = without_compensator(MJCF), np.array([2.6e6, 0.83])
    _, fm = build(src, [(effect, p)], obs)
    base = np.r_[[0.25e-6, 0.12e-6, 0.07e-6, 0.35e-6, 0.40e-6, 0.60e-6], 2.6e6, 0.83]
    theta = np.r_[base[: fm.n_base], p]
    NP = fm.n_base
    fm.evaluate(theta)
    with statics_options(fm.robot):
        fm.statics.forward(fm._cache[0][1].qpos)
        analytic = fm._dforce(theta)[:, NP:]
        fd = fm._dforce_fd(theta)[:, NP:]
    np.testing.assert_allclose(analytic, fd, rtol=1e-7, atol=1e-7 * max(np.abs(fd).max(), 1e-300))


@pytest.mark.parametrize("effect", library(Robot.from_file(MJCF)), ids=lambda e: e.name + e.detail)
def test_augmented_model_batched_as_pose_by_pose(logs, effect):
    """A model with effects runs its warm evaluations stacked on bench/statics/batched.py (every
    spring value synced into the batch, S and dg/dtheta stacked) and gets what it gets pose by
    pose: the deflections to the statics' precision (~3e-11 m at a reflector: 1e-10 m), the
    Jacobian in relative coordinates (columns times |theta|) to 1e-5 of each column's largest
    entry (A_base is a forward difference of step 1e-7 rad, re-taken where a solution moved
    1e-3 rad: the two paths' Jacobians differ by ~5e-7 where they re-take it; the Jacobian's own
    accuracy is 1e-3, forward.py), a column 1e6 times weaker than the strongest (k1 on these
    poses: round-off) to 1e-5 of 1e-6 of that, along a path of parameters that moves every
    equilibrium (re-takes included, but for j2, whose stiff cubic keeps it within KKT_QTOL).
    Both paths do the same work (Newton iterations, re-takes), the batched one none of it
    through the scalar fallbacks. The compensator effect is given the shipped spring (2.6e6
    N/m, 0.83 m): at three times its prior start (s0 = 3 m) no warm start holds and every row
    falls back to a cold solve in both paths, which would leave the stacked Newton untested."""
    from calbench.identify.core import from_log
    from calbench.identify.discover import build, effect_priors

    obs = from_log(read_log(logs["none"]))
    obs = obs.subset(obs.labels[:9])
    start, _, _, size = effect_priors(effect)
    p = np.where(start != 0, 3 * start, 0.5 * size)
    src = MJCF
    if effect.name == "compensator":
        src, p = without_compensator(MJCF), np.array([2.6e6, 0.83])
    base = np.r_[[0.25e-6, 0.12e-6, 0.07e-6, 0.35e-6, 0.40e-6, 0.60e-6], 2.6e6, 0.83]
    runs, stats = [], []
    for batched in (False, True):
        _, fm = build(src, [(effect, p)], obs)
        fm.batched = batched
        theta = np.r_[base[: fm.n_base], p]
        runs.append([fm.evaluate(theta * s) for s in (1.0, 1.05, 0.9, 1.0)])
        assert (fm._batch is not None) == batched  # the stacked path was taken
        stats.append(fm.stats)
    assert stats[1]["fallbacks"] == 0
    assert stats[1] == stats[0]
    for (dp_a, jac_a), (dp_b, jac_b) in zip(*runs):
        np.testing.assert_allclose(dp_b, dp_a, rtol=0, atol=1e-10)
        rel_a, rel_b = jac_a * np.abs(theta), jac_b * np.abs(theta)
        col = np.abs(rel_a).max(axis=(0, 1))
        assert np.all(np.abs(rel_b - rel_a) <= 1e-5 * np.maximum(col, 1e-6 * col.max()))


def test_self_check_replicas_batched_as_pose_by_pose(logs, monkeypatch):
    """The self-check's replicas refitted on the batched statics come out where they do pose by
    pose: each replica's estimate within its stopping tolerance (REPLICA_STEP_TOL = 1e-2 of
    each reported std; the statics agree to ~1e-15 m), the verdict the same."""
    import copy

    from calbench.bench.model.effects import link_compliance
    from calbench.identify.core import Whitener, from_log
    from calbench.identify.discover import (
        build,
        determination,
        effect_priors,
        fit_augmented,
        self_check,
        uncertainty,
    )

    monkeypatch.setattr(uncertainty, "REPLICAS", 8)  # the same replicas both ways: 8 are enough
    obs = from_log(read_log(logs["forearm"]))
    white = Whitener.from_observations(obs)
    eff = link_compliance("forearm")
    _, lo_e, hi_e, _ = effect_priors(eff)
    _, fm = build(MJCF, [(eff, [1e-7, 0.0, 1e-7])], obs)
    lo, hi = np.r_[fm.layout.lower, lo_e], np.r_[fm.layout.upper, hi_e]
    start = np.r_[[0.25e-6, 0.12e-6, 0.07e-6, 0.35e-6, 0.40e-6, 0.60e-6], 2.6e6, 0.83, 1e-7, 0.0, 1e-7]
    hold = np.zeros(start.size, bool)
    f = fit_augmented(fm, obs.dp, white, start, lo, hi, hold)
    f.extra["bounds"] = (lo, hi, hold)
    det = determination(f, f.extra["jw"])
    out = []
    for batched in (False, True):
        fm.batched = batched
        est: list = []
        rec = self_check(f, obs, white, copy.deepcopy(det), estimates=est)
        out.append((np.array(est), rec))
    (a, rec_a), (b, rec_b) = out
    assert a.shape == (8, start.size) and np.all(np.isfinite(a))
    std = np.where(det.determined, det.std, np.nan)
    assert np.nanmax(np.abs(b - a) / std) <= uncertainty.REPLICA_STEP_TOL
    assert rec_a["failed"] == rec_b["failed"]


def test_a_split_the_data_do_not_fix_gets_no_dishonest_std(tmp_path):
    """An upper arm bending about x and z (no y) is braced by the coupler rod: alone neither
    moves it, together they do, so the data see a nonlinear function of the two and the Fisher
    std of the split is dishonest (on noise seed 0 below it put the true cx 5.5 sigma away,
    the chi2 profile only 2.4). Each named parameter's profile is checked at +-2 Fisher std
    (identify/discover/uncertainty.py): cx is reported not determined, with the profile's rise,
    and every parameter still reported with a std is within 4 of them of the truth."""
    from calbench.bench.campaign import remeasure, simulate, truth_robot
    from calbench.identify.core import from_campaign
    from calbench.identify.discover import discover_observations
    from calbench.identify.study import true_theta

    extra = '[truth.effects.link_compliance]\nlink = "upper_arm"\ncompliance = [1.5e-8, 0.0, 1.5e-8]'
    scn = load_scenario(scenario(tmp_path, "xz", extra))
    tr = truth_robot(scn)
    campaign = simulate(scn, None, robot=tr)
    truth = dict(zip(tr.layout.names, true_theta(scn, tr)))
    truth.update({f"link_compliance[upper_arm].c{a}": v for a, v in zip("xyz", (1.5e-8, 0.0, 1.5e-8))})
    for seed in (0, 4):
        obs = from_campaign(remeasure(campaign, np.random.default_rng([99, seed])))
        rep, _ = discover_observations(obs, Path(scn.robot))
        assert rep["named_effects"] == ["link_compliance"]
        pars = {p["name"]: p for p in rep["parameters"]}
        cx = pars["link_compliance[upper_arm].cx"]
        assert not cx["determined"] and cx["std"] is None
        rise = cx["chi2_rise_at_2_fisher_std"]
        assert any(r is None or not 2.0 <= r <= 8.0 for r in rise)  # a quadratic rises by 4
        for name, p in pars.items():
            if p["std"] is not None:
                assert abs(p["estimate"] - truth[name]) < 4 * p["std"], (seed, name)
