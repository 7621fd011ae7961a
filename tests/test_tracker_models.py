"""The tracker family (bench/tracker/base.py): the models are the files of bench/tracker/models/,
and a new model is one new file. A toy fourth model, defined and registered HERE only (the
package never names it), goes through every verb that depends on the tracker's error model: the
scenario's keys (read, refused, written back), the log header, simulate, identify, the report's
words, a design's candidate, the registration of ``calbench import``, a study's choice of the
log. Any code path that still tested the model's name would miss the toy's own behaviour (its
key, its covariance, its correlated drift) and fail a check below.

The toy: each reading's independent error sigma per axis, plus a translation of the tracker's
frame that random-walks from the first reading, c(t) = walk W(t / 1 h) with W a 3-D standard
Wiener process (correlated between readings: K_kl = walk^2 min(t_k, t_l) / 1 h I). A pose's
deflections dp_r (one reading per state, taken dt apart) then have, for reflectors r, s,

    Cov(dp_r, dp_s) = [r = s] 2 sigma^2 I + walk^2 dt / 1 h I                      (the block)

With walk = 300 um per sqrt(hour) and dt = 5.5 min the drift's 91 um per axis dwarfs the
readings' 28 um, so a campaign that forgot to draw it, or an identification that forgot to weight
by it, is far outside the statistical bounds used here.

Tolerances. chi2 statistics are held within their 1e-5 and 1 - 1e-5 quantiles (the run is
seeded, so this is a fixed check; the bounds say it is the model's expected behaviour, not tuned);
covariances computed two ways agree to round-off (rtol 1e-9).
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
from conftest import MJCF, PAPER
from scipy import stats

from calbench.bench.core import InputError, Table
from calbench.bench.log import read_log
from calbench.bench.scenario import LOAD_S, load_scenario, reading_seconds, scenario_as_dict, scenario_to_toml
from calbench.bench.tracker import (
    DEFAULT_MODEL,
    TrackerModel,
    TrackerSpec,
    register_tracker_model,
    to_tracker_frame,
    tracker_model,
    tracker_models,
    unregister_tracker_model,
)
from calbench.identify.cli import main
from calbench.identify.core import from_log
from calbench.identify.report import format_table, html, run_identify
from calbench.identify.study import needs_log

HOUR = 3600.0
TOY = "random_walk"
SIGMA = 20e-6  # m per axis
WALK = 300e-6  # m per sqrt(hour)
P_OUT = 1e-5  # chi2 statistics inside their P_OUT and 1 - P_OUT quantiles
MODELS = Path(__file__).resolve().parent.parent / "bench" / "tracker" / "models"


class RandomWalkTracker(TrackerModel):
    """The toy of the module docstring: sigma per axis, plus a frame translation that random-walks
    (its key ``walk``, m per sqrt(hour), kept in TrackerSpec.params)."""

    name = TOY
    summary = "σ per axis plus a translation of the frame that random-walks"
    keys = ("walk",)
    correlated = True
    uses_times = True

    def parse(self, c: Table, degrees: bool) -> dict:
        return {"params": {"walk": c.number("walk", nonneg=True) if c.has("walk") else 0.0}}

    def header(self, spec: TrackerSpec, degrees: bool) -> dict:
        return {"walk": float(spec.params.get("walk", 0.0))}

    def covariance(self, spec, y):
        return spec.sigma**2 * np.tile(np.eye(3), (len(y), 1, 1))

    def correlated_covariance(self, spec, ya, ta, yb, tb):
        tmin = np.maximum(np.minimum(np.asarray(ta)[:, None], np.asarray(tb)[None, :]), 0.0) / HOUR
        return spec.params["walk"] ** 2 * tmin[:, None, :, None] * np.eye(3)[None, :, None, :]

    def draw_correlated(self, spec, y, t, rng):
        times, at = np.unique(np.maximum(t, 0.0), return_inverse=True)
        steps = np.sqrt(np.diff(np.concatenate([[0.0], times])) / HOUR)[:, None]
        return spec.params["walk"] * np.cumsum(steps * rng.standard_normal((len(times), 3)), axis=0)[at]

    def describe(self, spec):
        return f"random walk, σ = {spec.sigma * 1e6:.3g} µm, walk {spec.params['walk'] * 1e6:.3g} µm per √h"


POSES = [  # a few of the paper plan's poses (degrees): three q2 levels, two lateral pulls for k1
    ([0, 0, -30, -45, 30, 135], None),
    ([90, 0, 30, 45, -30, 45], None),
    ([180, 35, -30, 135, -30, -45], None),
    ([-90, 35, 30, 135, 30, 135], None),
    ([0, 120, -30, -135, 30, -135], None),
    ([180, 120, 30, -135, 30, -135], None),
    ([0, 120, 30, 0, 0, 0], [0, 1200, 0, 0, 0, 0]),
    ([90, 120, 30, 0, 0, 0], [1200, 0, 0, 0, 0, 0]),
]


def scenario_text(tracker: str, truth: bool = True, position: bool = True) -> str:
    """The paper scenario with POSES, the robot path absolute and ``tracker`` in [tracker]; a
    plan (no [truth]) when not ``truth``, its tracker unplaced when not ``position``."""
    s = PAPER.read_text().replace('robot = "../mjcf/m900ib700.xml"', f'robot = "{MJCF.as_posix()}"')
    s = s.replace("sigma = 20e-6                     # m per axis (isotropic)", tracker)
    s = s[: s.index("[[pose]]")]
    if not truth:
        s = s[: s.index("[truth]")] + s[s.index("[tracker]") :]
    if not position:
        s = re.sub(r"position = \[3.5, -3.5, 3.2\].*\n", "", s)
    for q, w in POSES:
        s += f"[[pose]]\nq = {q}\n" + (f"wrench = {w}\n" if w else "")
    return s


TOY_TRACKER = f'model = "{TOY}"\nsigma = {SIGMA}\nwalk = {WALK}'


@pytest.fixture(scope="module")
def toy():
    model = register_tracker_model(RandomWalkTracker())
    yield model
    unregister_tracker_model(TOY)


@pytest.fixture(scope="module")
def campaign(toy, tmp_path_factory) -> Path:
    """The toy's campaign: d/toy.toml simulated into d/toy.mcap."""
    d = tmp_path_factory.mktemp("toy_tracker")
    (d / "toy.toml").write_text(scenario_text(TOY_TRACKER))
    assert main(["simulate", str(d / "toy.toml"), "--out", str(d / "toy.mcap")]) == 0
    return d


# --------------------------------------------------------------------------- the registry


def test_the_shipped_models_are_the_files_of_their_folder():
    files = {p.stem for p in MODELS.glob("*.py") if not p.name.startswith("_")}
    models = tracker_models()
    assert {n for n in models if n != TOY} == files == {"isotropic", "spec", "iso10360"}
    assert next(iter(models)) == DEFAULT_MODEL
    for name in files:
        assert tracker_model(name).name == name


@pytest.mark.parametrize("name", ["isotropic", "spec", "iso10360"])
def test_a_shipped_model_keeps_its_own_promises(name):
    """Its single-reading share of the correlated error is the diagonal of K (the protocol's
    default from correlated_covariance, computed here for iso10360's own version), zero for
    independent readings; its description is one line."""
    model = tracker_model(name)
    spec = TrackerSpec(np.array([3.5, -3.5, 3.2]), model=name)
    y = np.array([[2.0, 3.0, -0.5], [4.0, -1.0, 1.0], [-1.0, 2.5, 0.3]])
    t = np.array([0.0, 600.0, 5400.0])
    marginal = model.correlated_marginal(spec, y, t)
    if model.correlated:
        k = model.correlated_covariance(spec, y, t, y, t)
        np.testing.assert_allclose(marginal, k[np.arange(3), :, np.arange(3), :], rtol=1e-12, atol=0)
        assert np.all(np.linalg.eigvalsh(marginal) > 0)
    else:
        assert np.array_equal(marginal, np.zeros((3, 3, 3)))
    words = model.describe(spec)
    assert words and "\n" not in words and words.startswith(name)


def test_a_registered_name_is_unique_and_a_shipped_model_stays(toy):
    with pytest.raises(ValueError, match="registered already"):
        register_tracker_model(RandomWalkTracker())
    with pytest.raises(ValueError, match="bench/tracker/models/"):
        unregister_tracker_model("spec")
    with pytest.raises(ValueError, match="unknown tracker noise model 'fancy'"):
        tracker_model("fancy")


def test_a_correlated_model_must_say_how_readings_share_error():
    with pytest.raises(TypeError, match="correlated_covariance and draw_correlated"):

        class Half(TrackerModel):  # noqa: F841
            name, summary, correlated = "half", "?", True

            def covariance(self, spec, y):
                return np.zeros((len(y), 3, 3))

            def describe(self, spec):
                return "?"


# --------------------------------------------------------------------------- the toy


def test_the_scenario_reads_refuses_and_writes_the_toy_s_key(toy, tmp_path):
    path = tmp_path / "toy.toml"
    path.write_text(scenario_text(TOY_TRACKER))
    scn = load_scenario(path)
    assert scn.tracker.model == TOY and scn.tracker.params == {"walk": WALK}
    assert scn.tracker.error_model is toy
    back = tmp_path / "back.toml"
    back.write_text(scenario_to_toml(scenario_as_dict(scn, tmp_path)))
    assert load_scenario(back).tracker.params == {"walk": WALK}
    assert TrackerSpec.from_dict(scn.tracker.to_dict()).params == {"walk": WALK}
    for tracker, key, owner in (
        ('model = "spec"\nwalk = 1e-4', "walk", TOY),
        (f'model = "{TOY}"\nrandom = 0.5', "random", "iso10360"),
    ):
        path.write_text(scenario_text(tracker))
        with pytest.raises(InputError, match=rf'tracker.{key}: expected model = "{owner}" for this key'):
            load_scenario(path)


def test_simulate_draws_the_toy_s_noise_and_its_walk(campaign):
    """Every reading carries the toy's covariance; the common mode of each pose's readings moves
    between its unloaded and loaded readings by the walk (the truth topics say where the
    reflectors were): sum |d|^2 / (walk^2 dt + 2 sigma^2 / n) is chi2 with 3 per pose."""
    log = read_log(campaign / "toy.mcap", include_truth=True)
    spec = log.tracker_spec()
    assert spec.model == TOY and spec.params == {"walk": WALK}
    s, dof = 0.0, 0
    for p in log.complete_poses:
        means, times = [], []
        (u,), (ld,) = log.readings(p, "unloaded"), log.readings(p, "loaded")
        both = u.visible & ld.visible
        if not both.any():
            continue
        for m in (u, ld):
            vis = m.visible
            assert np.array_equal(m.covariance[vis], SIGMA**2 * np.tile(np.eye(3), (int(vis.sum()), 1, 1)))
            truth = log.truth.reflectors[p].get(m.state)
            true = to_tracker_frame(spec, truth.position_world)[
                [truth.reflectors.index(r) for r in m.reflectors]
            ]
            means.append(np.mean((m.position - true)[both], axis=0))
            times.append(m.time / 1e9)
        dt = (times[1] - times[0]) / HOUR
        s += float(np.sum((means[1] - means[0]) ** 2)) / (WALK**2 * dt + 2 * SIGMA**2 / both.sum())
        dof += 3
    assert stats.chi2.ppf(P_OUT, dof) < s < stats.chi2.ppf(1 - P_OUT, dof)


def test_identify_weights_by_the_toy_s_covariance(campaign):
    """The observations carry the block of the module docstring (an independent computation from
    the log's stamps), and identify's chi2 is chi2-distributed: drawn and weighted alike."""
    log = read_log(campaign / "toy.mcap")
    obs = from_log(log)
    for ob in obs.poses:
        (u,), (ld,) = log.readings(ob.index, "unloaded"), log.readings(ob.index, "loaded")
        n = len(ob.reflectors)
        walk = WALK**2 * (ld.time - u.time) / 1e9 / HOUR
        expect = np.einsum("rs,ij->risj", walk * np.ones((n, n)) + 2 * SIGMA**2 * np.eye(n), np.eye(3))
        assert ob.cov_block is not None
        np.testing.assert_allclose(ob.cov_block, expect, rtol=1e-9, atol=0)
    rep = run_identify(campaign / "toy.mcap", check_profile=False)
    assert stats.chi2.ppf(P_OUT, rep.dof) < rep.chi2 < stats.chi2.ppf(1 - P_OUT, rep.dof)
    assert rep.details["tracker_noise_model"] == TOY
    assert f"its {TOY} error model, {RandomWalkTracker.summary}" in format_table(rep)
    section = html.campaign_section(log, simulated=True)
    assert section["tracker_noise"] == "random walk, σ = 20 µm, walk 300 µm per √h"


def test_a_study_runs_the_toy_through_its_log(campaign):
    assert needs_log(load_scenario(campaign / "toy.toml"))


def test_a_design_whitens_a_candidate_by_the_toy_s_block(campaign):
    from calbench.identify.design import InfoEngine, load_design_scenario

    p0 = np.array([[1.2, 0.3, 1.9], [1.2, -0.3, 1.9], [1.3, 0.0, 1.3]])
    p1 = p0 + np.array([[0.0, 0.0, -0.002], [0.0, 0.0, -0.0021], [0.0005, 0.0, -0.0015]])
    eng = InfoEngine(*load_design_scenario(campaign / "toy.toml"))
    one = eng.sigma_dp(p0, p1)
    assert np.allclose(eng.sigma_dp_blocks(p0[None], p1[None])[0], one, rtol=1e-12, atol=0)
    walk = WALK**2 * (LOAD_S + reading_seconds(3)) / HOUR  # the campaign clock: hang, read
    expect = np.kron(walk * np.ones((3, 3)) + 2 * SIGMA**2 * np.eye(3), np.eye(3))
    np.testing.assert_allclose(one, expect, rtol=1e-9, atol=0)


def test_the_registration_weights_each_point_by_all_of_the_toy_s_error(toy, tmp_path):
    """``calbench import`` of the toy's readings with the tracker pose withheld: the walk is error
    the registration weights each point by (TrackerModel.correlated_marginal), so no geometry
    alarm (weighted by sigma alone, chi2/dof is 3.4 here, measured, and the alarm goes off). A
    third of the other tests' walk, 100 um per sqrt(hour) (~100 um by the campaign's end, 5
    sigma): at 300 the joint registration of these 8 poses does not converge within its budget."""
    tracker = f'model = "{TOY}"\nsigma = {SIGMA}\nwalk = {WALK / 3}'
    (tmp_path / "toy.toml").write_text(scenario_text(tracker))
    (tmp_path / "plan.toml").write_text(scenario_text(tracker, truth=False, position=False))
    for verb in (
        ["simulate", "toy.toml", "--out", "toy.mcap"],
        ["export", "toy.mcap", "--csv", "toy.csv"],
        ["import", "toy.csv", "--plan", "plan.toml", "--out", "in.mcap"],
    ):
        assert main([verb[0], *(str(tmp_path / a) if "." in a else a for a in verb[1:])]) == 0
    imported = read_log(tmp_path / "in.mcap")
    reg = imported.header["imported"]["registration"]
    assert imported.header["imported"]["tracker_pose"] == "registered" and reg["converged"]
    assert reg["warnings"] == []
    spec = imported.tracker_spec()
    assert spec.params == {"walk": WALK / 3}
    marginal = toy.correlated_marginal(spec, np.ones((1, 3)), np.array([HOUR]))
    np.testing.assert_allclose(marginal[0], (WALK / 3) ** 2 * np.eye(3), rtol=1e-12)
    assert math.isfinite(run_identify(tmp_path / "in.mcap", check_profile=False).chi2)
