"""Simulated laser tracker: frames, noise model and its statistics, determinism, visibility."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from calbench.bench.tracker import (
    Measurement,
    TrackerSpec,
    mean_reading,
    measure,
    noise_covariance,
    to_tracker_frame,
    to_world_frame,
    tracker_rotation,
    visible_sites,
)

N_DRAWS = 20000
K_SE = 5.0  # tolerance in standard errors: a two-sided 5-sigma miss has probability ~6e-7


def spec(model: str = "spec", yaw: float = 0.7, **kw) -> TrackerSpec:
    return TrackerSpec(position=np.array([2.0, -1.0, 0.8]), yaw=yaw, model=model, **kw)


def test_rotation_is_yaw_about_z():
    r = tracker_rotation(spec(yaw=math.pi / 2))
    np.testing.assert_allclose(r @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(r @ [0, 0, 1], [0, 0, 1], atol=1e-15)
    r = tracker_rotation(spec(yaw=0.3))
    np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-15)
    assert np.linalg.det(r) == pytest.approx(1.0, abs=1e-15)


def test_frame_round_trip_and_known_point():
    s = spec(yaw=math.pi / 2)
    # the world +y direction is the tracker's +x axis after a 90 degree yaw
    np.testing.assert_allclose(to_tracker_frame(s, [s.position + [0, 3, 0]]), [[3, 0, 0]], atol=1e-15)
    pts = np.random.default_rng(0).uniform(-5, 5, (50, 3))
    s = spec(yaw=-2.1)
    np.testing.assert_allclose(to_world_frame(s, to_tracker_frame(s, pts)), pts, atol=1e-14)
    np.testing.assert_allclose(to_tracker_frame(s, to_world_frame(s, pts)), pts, atol=1e-14)
    # distances from the tracker are frame independent
    np.testing.assert_allclose(
        np.linalg.norm(to_tracker_frame(s, pts), axis=1), np.linalg.norm(pts - s.position, axis=1), rtol=1e-14
    )


def test_isotropic_covariance():
    cov = noise_covariance(spec("isotropic", sigma=20e-6), np.array([[1, 2, 3], [4, 0, 0.0]]))
    assert cov.shape == (2, 3, 3)
    np.testing.assert_array_equal(cov, np.broadcast_to(np.eye(3) * (20e-6) ** 2, (2, 3, 3)))


def test_spec_covariance_eigenstructure():
    s = spec("spec", distance=(10e-6, 0.3e-6), transverse=(15e-6, 6e-6))
    p = np.array([[3.0, 4.0, 0.0], [0.0, 0.0, -2.0]])
    cov = noise_covariance(s, p)
    for pt, c in zip(p, cov):
        r = np.linalg.norm(pt)
        u = pt / r
        v = np.cross(u, [0.3, 0.1, 0.9])
        v /= np.linalg.norm(v)
        w = np.cross(u, v)
        sd, st = 10e-6 + 0.3e-6 * r, 15e-6 + 6e-6 * r
        np.testing.assert_allclose(c @ u, sd**2 * u, rtol=1e-12, atol=1e-24)
        np.testing.assert_allclose(c @ v, st**2 * v, rtol=1e-12, atol=1e-24)
        np.testing.assert_allclose(c @ w, st**2 * w, rtol=1e-12, atol=1e-24)
        np.testing.assert_allclose(c, c.T, atol=0)
    with pytest.raises(ValueError):
        noise_covariance(s, np.zeros((1, 3)))


@pytest.mark.parametrize("model", ["isotropic", "spec"])
def test_sample_statistics_match_model(model):
    """20000 draws at one point: mean, covariance and line-of-sight variances within K_SE SE.

    For Gaussian samples, SE(mean_i) = sqrt(S_ii / n) and SE(cov_ij) = sqrt((S_ij^2 +
    S_ii S_jj) / n); a variance along a fixed direction has SE = var * sqrt(2 / (n - 1)).
    """
    s = spec(model, sigma=20e-6)
    truth_w = np.array([[5.0, 3.0, 1.5]])
    truth_t = to_tracker_frame(s, truth_w)[0]
    m = measure(s, np.repeat(truth_w, N_DRAWS, axis=0), np.ones(N_DRAWS, bool), np.random.default_rng(12345))
    sigma = noise_covariance(s, truth_t[None])[0]
    np.testing.assert_allclose(m.covariance, np.broadcast_to(sigma, (N_DRAWS, 3, 3)))
    err = m.position - truth_t
    n = N_DRAWS
    se_mean = np.sqrt(np.diag(sigma) / n)
    assert np.all(np.abs(err.mean(axis=0)) < K_SE * se_mean)
    s_hat = np.cov(err.T)
    se_cov = np.sqrt((sigma**2 + np.outer(np.diag(sigma), np.diag(sigma))) / n)
    assert np.all(np.abs(s_hat - sigma) < K_SE * se_cov)
    u = truth_t / np.linalg.norm(truth_t)
    v = np.cross(u, [0.0, 0.0, 1.0])
    v /= np.linalg.norm(v)
    for d in (u, v):
        model_var = d @ sigma @ d
        assert abs(np.var(err @ d, ddof=1) - model_var) < K_SE * model_var * np.sqrt(2 / (n - 1))
    if model == "spec":  # anisotropy really present: along-sight sd well below transverse sd
        assert np.std(err @ u) < 0.5 * np.std(err @ v)


def test_measurement_deterministic_for_a_seed():
    s = spec("spec")
    pts = np.array([[4.0, 1.0, 1.0], [3.0, -2.0, 0.5], [6.0, 0.0, 2.0]])
    vis = np.array([True, False, True])
    a = measure(s, pts, vis, np.random.default_rng(7))
    b = measure(s, pts, vis, np.random.default_rng(7))
    c = measure(s, pts, vis, np.random.default_rng(8))
    assert isinstance(a, Measurement)
    np.testing.assert_array_equal(a.position, b.position)
    np.testing.assert_array_equal(a.covariance, b.covariance)
    assert not np.allclose(a.position[vis], c.position[vis], rtol=0, atol=1e-9)


def test_invisible_points_are_nan_and_draw_no_noise():
    """Documented behaviour: draws are made only for visible points, in order."""
    s = spec("spec")
    pts = np.array([[4.0, 1.0, 1.0], [3.0, -2.0, 0.5], [6.0, 0.0, 2.0]])
    vis = np.array([True, False, True])
    m = measure(s, pts, vis, np.random.default_rng(3))
    np.testing.assert_array_equal(m.visible, vis)
    assert np.all(np.isnan(m.position[1])) and np.all(np.isnan(m.covariance[1]))
    assert not np.any(np.isnan(m.position[vis]))
    only = measure(s, pts[vis], np.ones(2, bool), np.random.default_rng(3))
    np.testing.assert_array_equal(m.position[vis], only.position)
    with pytest.raises(ValueError):
        measure(s, pts, np.array([1, 0, 1]), np.random.default_rng(0))


SCENE = """
<mujoco>
  <worldbody>
    <geom name="wall" type="box" pos="1 0 1" size="0.05 0.2 0.2"/>
    <geom name="ghost" type="box" pos="1 1 1" size="0.05 0.2 0.2" group="3"/>
    <body name="arm" pos="0 0 0">
      <joint name="slide" type="slide" axis="0 1 0"/>
      <geom type="sphere" size="0.01" pos="5 5 5" mass="1"/>
      <site name="hidden" pos="2 0 1"/>
      <site name="side" pos="2 1.5 1"/>
      <site name="behind" pos="-2 0 1"/>
      <site name="past_ghost" pos="2 2 1"/>
      <site name="on_face" pos="0.95 0 1"/>
    </body>
  </worldbody>
</mujoco>
"""


@pytest.fixture
def scene():
    model = mujoco.MjModel.from_xml_string(SCENE)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    ids = [
        mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, n)
        for n in ("hidden", "side", "behind", "past_ghost", "on_face")
    ]
    tracker = TrackerSpec(position=np.array([0.0, 0.0, 1.0]), yaw=0.4)
    return model, data, tracker, ids


def test_visibility_occlusion(scene):
    model, data, tracker, ids = scene
    vis = visible_sites(model, data, tracker, ids)
    #                          hidden side  behind past_ghost on_face
    np.testing.assert_array_equal(vis, [False, True, True, True, True])


def test_visibility_group_below_3_blocks(scene):
    model, data, tracker, ids = scene
    ghost = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "ghost")
    model.geom_group[ghost] = 0  # the same box, now in a blocking group, hides past_ghost
    assert not visible_sites(model, data, tracker, ids)[3]


def test_visibility_follows_the_pose(scene):
    model, data, tracker, ids = scene
    data.qpos[0] = 0.5  # slide the sites 0.5 m along y: "hidden" clears the wall
    mujoco.mj_kinematics(model, data)
    assert visible_sites(model, data, tracker, ids)[0]
    with pytest.raises(ValueError):
        visible_sites(model, data, tracker, [model.nsite])


def test_mean_reading_against_a_hand_computation():
    """Two readings of three reflectors, tracker at (1, 2, 3) turned 90 deg: world = (-y, x, z)
    + (1, 2, 3). Reflector 0 is seen twice, 1 once (hidden in the first reading), 2 never (its
    only 'visible' row has no position)."""
    s = TrackerSpec(position=np.array([1.0, 2.0, 3.0]), yaw=math.pi / 2)
    nan3, nan33 = [np.nan] * 3, np.full((3, 3), np.nan)
    first = Measurement(
        position=np.array([[1.0, 0.0, 0.0], nan3, nan3]),
        covariance=np.array([np.diag([1.0, 4.0, 9.0]) * 1e-10, nan33, nan33]),
        visible=np.array([True, False, True]),
    )
    second = Measurement(
        position=np.array([[3.0, 2.0, 0.0], [0.0, 1.0, 1.0], nan3]),
        covariance=np.array([np.eye(3) * 1e-10, np.eye(3) * 4e-10, nan33]),
        visible=np.array([True, True, False]),
    )
    m = mean_reading(s, [first, second])
    assert m.seen.tolist() == [True, True, False] and m.count.tolist() == [2, 1, 0]
    # reflector 0: tracker-frame mean (2, 1, 0) -> world (-1, 2, 0) + (1, 2, 3)
    np.testing.assert_allclose(m.position[0], [0.0, 4.0, 3.0], rtol=0, atol=1e-15)
    # covariance of the mean: (diag(1,4,9) + I) e-10 / 2^2 = diag(0.5, 1.25, 2.5) e-10 in the
    # tracker frame; the 90 deg yaw swaps x and y
    np.testing.assert_allclose(m.covariance[0], np.diag([1.25, 0.5, 2.5]) * 1e-10, rtol=1e-15, atol=1e-25)
    # reflector 1: one reading (0, 1, 1) -> world (-1, 0, 1) + (1, 2, 3), its own covariance
    np.testing.assert_allclose(m.position[1], [0.0, 2.0, 4.0], rtol=0, atol=1e-15)
    np.testing.assert_allclose(m.covariance[1], np.eye(3) * 4e-10, rtol=1e-15, atol=1e-25)
    assert np.isnan(m.position[2]).all() and np.isnan(m.covariance[2]).all()
    with pytest.raises(ValueError):
        mean_reading(s, [])
