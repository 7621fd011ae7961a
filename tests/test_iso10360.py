"""The iso10360 tracker: its covariance against independent computations, its draws against its
covariance, the per-pose whitening, and an honest Monte Carlo under it.

Statistics. An empirical covariance entry from N independent draws has a standard error of
sqrt((C_ii C_jj + C_ij^2) / N); tests compare within 4.5 of those (a 1e-5 chance per entry under
a normal approximation; ~100 entries are compared in all). The Monte Carlo's empirical/reported
std ratio has sampling error sqrt(1 / (2 (N - 1))); it is held within 4 of those.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import PAPER

from calbench.bench.core import InputError
from calbench.bench.scenario import parse_scenario, reading_times
from calbench.bench.tracker import (
    Measurement,
    TrackerSpec,
    deflection_covariance,
    measure_campaign,
    noise_covariance,
    to_tracker_frame,
)
from calbench.bench.tracker.models import (
    correlated_covariance,
    draw_correlated,
    field_kernel,
    marginal_covariance,
    spec_covariance,
)
from calbench.identify.core import Whitener

SPEC = TrackerSpec(
    np.array([3.5, -3.5, 3.2]),
    model="iso10360",
    random=0.3,
    correlation_angle=math.radians(8.0),
    correlation_range=0.8,
    drift=(20e-6, 5e-6),
)


def _within(emp: np.ndarray, ref: np.ndarray, n: int, k: float = 4.5) -> None:
    d = np.sqrt(np.diag(ref))
    se = np.sqrt((np.outer(d, d) ** 2 + ref**2) / n)
    assert np.all(np.abs(emp - ref) <= k * se + 1e-30), np.max(np.abs(emp - ref) / se)


def test_one_reading_has_the_spec_covariance_at_the_start():
    """Field plus noise make the spec model's single-point covariance; the drift adds with time."""
    y = np.array([[2.0, 3.0, -0.5], [4.0, -1.0, 1.0]])
    assert np.allclose(marginal_covariance(SPEC, y, np.zeros(2)), spec_covariance(SPEC, y), rtol=1e-12)
    assert np.allclose(noise_covariance(SPEC, y), 0.3**2 * spec_covariance(SPEC, y))
    later = marginal_covariance(SPEC, y, np.full(2, 3600.0)) - spec_covariance(SPEC, y)
    # after an hour: translation a^2 per axis plus rotation/scale b^2 |y|^2 spread over the axes
    assert np.trace(later[0]) == pytest.approx(3 * 20e-6**2 + 3 * (5e-6) ** 2 * (y[0] @ y[0]), rel=1e-9)


def test_kernel_is_one_at_a_point_and_falls_with_angle_and_range():
    y = np.array([[3.0, 0.0, 0.0]])
    turned = np.array([[3 * math.cos(0.1), 3 * math.sin(0.1), 0.0]])  # 0.1 rad apart
    farther = np.array([[3.8, 0.0, 0.0]])
    assert field_kernel(SPEC, y, y)[0, 0] == 1.0
    chord = 2 * math.sin(0.05)
    assert field_kernel(SPEC, y, turned)[0, 0] == pytest.approx(
        math.exp(-(chord**2) / (2 * math.radians(8.0) ** 2)), rel=1e-12
    )
    assert field_kernel(SPEC, y, farther)[0, 0] == pytest.approx(math.exp(-0.5), rel=1e-12)


def test_draws_follow_the_covariance():
    """Field and drift drawn at 4 readings (two points, one repeated later) over 6000 campaigns
    against correlated_covariance."""
    y = np.array([[2.0, 3.0, -0.5], [2.001, 3.0, -0.502], [2.0, 3.0, -0.5], [2.4, 2.6, 0.3]])
    t = np.array([0.0, 300.0, 900.0, 900.0])
    n = 6000
    rng = np.random.default_rng(11)
    draws = np.array([draw_correlated(SPEC, y, t, rng).ravel() for _ in range(n)])
    ref = correlated_covariance(SPEC, y, t, y, t).reshape(12, 12)
    _within(np.cov(draws.T, bias=True), ref, n)


def test_deflection_covariance_against_the_drawn_campaign():
    """A pose of two reflectors read twice per state: the analytic covariance of its two
    deflections (every reading, the field, the drift, the means) against 4000 campaigns drawn by
    measure_campaign, the simulator's own path."""
    world = np.array(
        [[[0.6, 0.2, 1.9], [0.6, -0.4, 1.9]], [[0.6015, 0.2, 1.8978], [0.6015, -0.4, 1.8975]]]
    )  # (2 states, 2, 3)
    vis = np.ones((2, 2), bool)
    times = reading_times([2], 2)
    n = 4000
    rng = np.random.default_rng(5)
    dps = []
    for _ in range(n):
        m = measure_campaign(SPEC, [world], [vis], [2], rng, times)
        mean = [np.mean([m[(0, s, r)].position for r in range(2)], axis=0) for s in ("unloaded", "loaded")]
        dps.append((mean[1] - mean[0]).ravel())
    reads = [[m[(0, s, r)] for r in range(2)] for s in ("unloaded", "loaded")]
    when = tuple([times[(0, s, r)] for r in range(2)] for s in ("unloaded", "loaded"))
    ref = deflection_covariance(SPEC, reads[0], reads[1], np.arange(2), when).reshape(6, 6)
    _within(np.cov(np.array(dps).T, bias=True), ref, n)
    # the correlated part matters here: the pose's two reflectors share the drift
    corr = ref[0:3, 3:6] / np.sqrt(np.outer(np.diag(ref)[0:3], np.diag(ref)[3:6]))
    assert np.max(np.abs(corr)) > 0.3


def test_per_pose_whitening_equals_per_reflector_without_correlation():
    rng = np.random.default_rng(3)
    covs = []
    for _ in range(6):
        a = rng.standard_normal((3, 3))
        covs.append(a @ a.T + np.eye(3))
    per = Whitener.per_reflector(np.array(covs))
    blocks = [
        np.block(
            [
                [covs[0], np.zeros((3, 6))],
                [np.zeros((3, 3)), covs[1], np.zeros((3, 3))],
                [np.zeros((3, 6)), covs[2]],
            ]
        ),
        covs[3],
        np.block([[covs[4], np.zeros((3, 3))], [np.zeros((3, 3)), covs[5]]]),
    ]
    blk = Whitener(blocks)
    x, j = rng.standard_normal((6, 3)), rng.standard_normal((6, 3, 4))
    assert np.allclose(per.vec(x), blk.vec(x), rtol=0, atol=1e-12)
    assert np.allclose(per.mat(j), blk.mat(j), rtol=0, atol=1e-12)
    assert np.allclose(blk.unwhiten(blk.vec(x)), x, rtol=0, atol=1e-12)
    # whitening makes a correlated block's draws standard normal
    full = np.cov(rng.standard_normal((9, 50)))
    w = Whitener([full * 1e-10])
    assert np.allclose(
        w.mat(np.eye(9).reshape(3, 3, 9)) @ (full * 1e-10) @ w.mat(np.eye(9).reshape(3, 3, 9)).T,
        np.eye(9),
        atol=1e-9,
    )


def test_scenario_keys(tmp_path):
    base = PAPER.read_text().replace(
        'robot = "../mjcf/m900ib700.xml"',
        f'robot = "{(PAPER.parent.parent / "mjcf" / "m900ib700.xml").as_posix()}"',
    )

    def tracker(extra: str):
        text = base.replace("sigma = 20e-6                     # m per axis (isotropic)", extra)
        return parse_scenario(text, tmp_path / "s.toml").tracker

    t = tracker('model = "iso10360"\nrandom = 0.5\ncorrelation_angle = 20.0\ndrift = [1e-6, 0.0]')
    assert (t.random, t.correlation_angle, t.drift) == (0.5, pytest.approx(math.radians(20)), (1e-6, 0.0))
    back = TrackerSpec.from_dict(t.to_dict())
    assert (back.model, back.random, back.correlation_angle, back.drift) == (
        t.model,
        t.random,
        t.correlation_angle,
        t.drift,
    )
    assert "random" not in tracker('model = "spec"').to_dict()  # other models' headers unchanged
    with pytest.raises(InputError, match=r'tracker.random: expected model = "iso10360" for this key'):
        tracker('model = "spec"\nrandom = 0.5')
    with pytest.raises(InputError, match=r"tracker.random: expected the share of the 1-sigma"):
        tracker('model = "iso10360"\nrandom = 1.5')
    with pytest.raises(InputError, match=r"tracker.drift\[1\]: expected a finite number >= 0"):
        tracker('model = "iso10360"\ndrift = [1e-6, -1e-6]')


def test_a_deflection_is_far_more_accurate_than_two_independent_readings():
    """The point of the model: the field is shared by a reflector's two readings 2.7 mm apart."""
    world = np.array([[[0.6, 0.2, 1.9]], [[0.6015, 0.2, 1.8978]]])
    y = [to_tracker_frame(SPEC, world[s]) for s in range(2)]
    reads = [[Measurement(y[s], noise_covariance(SPEC, y[s]), np.ones(1, bool))] for s in range(2)]
    c = deflection_covariance(SPEC, reads[0], reads[1], np.arange(1), ([60.0], [390.0])).reshape(3, 3)
    assert np.all(np.linalg.eigvalsh(c) > 0)
    # far less than two independent spec readings: the field is shared
    assert np.trace(c) < 0.5 * np.trace(2 * spec_covariance(SPEC, y[0])[0])


def _variant(tmp_path, tracker: str):
    from calbench.bench.scenario import load_scenario

    text = (
        PAPER.read_text()
        .replace(
            'robot = "../mjcf/m900ib700.xml"',
            f'robot = "{(PAPER.parent.parent / "mjcf" / "m900ib700.xml").as_posix()}"',
        )
        .replace("sigma = 20e-6                     # m per axis (isotropic)", tracker)
    )
    p = tmp_path / "variant.toml"
    p.write_text(text)
    return load_scenario(p)


STRESS = (
    'model = "iso10360"\nrandom = 0.1\ncorrelation_angle = 3.0\ncorrelation_range = 0.5\n'
    "drift = [20e-6, 5e-6]"
)


def test_monte_carlo_is_honest_under_the_correlated_model(tmp_path):
    """The paper campaign with a tracker whose deflection error is mostly drift (common to a
    pose's reflectors, correlated between its loaded and unloaded readings): 300 runs, the
    one-step estimator's empirical std over its reported std within 4 sampling errors of 1, and
    its variance at the Cramer-Rao bound. A weighting that ignored the correlation would report
    the spec model's sigma (the single-point covariance of each reading), which the last
    assertion shows is far off."""
    from calbench.identify.runtime import blas_threads
    from calbench.identify.study import run_montecarlo

    runs = 300
    with blas_threads(1):
        s = run_montecarlo(_variant(tmp_path, STRESS), runs, ("one-step",)).summary()
        naive = run_montecarlo(_variant(tmp_path, 'model = "spec"'), 2, ("one-step",))
    tol = 4 * math.sqrt(1 / (2 * (runs - 1)))
    rows = s["methods"]["one-step"]["parameters"]
    for p in rows:
        assert abs(p["empirical_over_reported_std"] - 1) < tol, p
        assert abs(p["bias_over_sigma"]) < 4 / math.sqrt(runs), p
        assert abs(p["variance_over_crb"] - 1) < 4 * math.sqrt(2 / (runs - 1)), p
    naive_sd = np.sqrt(np.diag(naive.crb))
    # measured 1.5 (k1) to 7.5 (k6): every parameter more than 3 tolerances from honest
    assert all(sd / p["empirical_std"] > 1 + 3 * tol for sd, p in zip(naive_sd, rows))


def test_design_whitens_a_candidate_by_the_same_covariance(tmp_path):
    """The design's candidates (one at a time and batched) use the estimator's covariance of a
    pose's deflections: block diagonal by reflector for the spec tracker, correlated for
    iso10360."""
    from calbench.identify.design import InfoEngine, load_design_scenario

    p0 = np.array([[1.2, 0.3, 1.9], [1.2, -0.3, 1.9], [1.3, 0.0, 1.3]])
    p1 = p0 + np.array([[0.0, 0.0, -0.002], [0.0, 0.0, -0.0021], [0.0005, 0.0, -0.0015]])
    for tracker, correlated in (('model = "spec"', False), (STRESS, True)):
        scn = _variant(tmp_path, tracker)
        eng = InfoEngine(*load_design_scenario(scn.path))
        one = eng.sigma_dp(p0, p1)
        assert np.allclose(eng.sigma_dp_blocks(p0[None], p1[None])[0], one, rtol=1e-12, atol=0)
        off = one.copy()
        for i in range(3):
            off[3 * i : 3 * i + 3, 3 * i : 3 * i + 3] = 0
        assert (np.abs(off).max() > 1e-3 * one.max()) == correlated
