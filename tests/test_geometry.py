"""Geometric calibration (identify/geometry/): the chain against published numbers, the exact
Jacobian and the gravity torques against finite differences, the base set against the classic
parameter count, and hidden geometry recovered from synthetic readings within 4 sigma."""

import numpy as np
import pytest

from calbench.identify.geometry import (
    GRAVITY,
    MODELS,
    GeometricModel,
    base_set,
    calibrate,
    gravity_torques,
    initial_model,
    kind,
    rot,
    split,
    translation,
    ur10,
    validate,
)

CHAIN = ur10()
RNG_Q = np.random.default_rng(7)
Q = RNG_Q.uniform(-np.pi, np.pi, (300, 6))
BASE0 = translation([0.4, -3.2, 0.2]) @ rot(2, 1.2)  # a tracker ~3 m away, turned
TOOL = np.array([0.0, 0.0, 0.109])


def test_ur10_zero_pose_is_the_published_one():
    # UR10 at q = 0 (DH convention): x = a2 + a3, y = -(d4 + d6), z = d1 - d5
    np.testing.assert_allclose(
        CHAIN.flange_point(np.zeros((1, 6)), np.zeros(3))[0], [-1.1843, -0.256141, 0.0116], atol=1e-12
    )


def test_jacobian_is_the_finite_difference_one():
    model = GeometricModel(CHAIN, BASE0, TOOL)
    rng = np.random.default_rng(1)
    theta = rng.normal(0, 1e-2, model.size)  # away from zero: every parameter's own frame moves
    theta[9 + 6 : 9 + 12] = rng.normal(0, 1e-4, 6)  # compliances x ~100 N*m torques
    q = Q[:5]
    _, jac = model.jacobian(q, theta)
    h = 1e-7
    fd = np.empty_like(jac)
    for i in range(model.size):
        e = np.zeros(model.size)
        e[i] = h
        fd[:, :, i] = (model.predict(q, theta + e) - model.predict(q, theta - e)) / (2 * h)
    # central differences: truncation h^2 |y'''| ~ 1e-14 (compliance columns x tau^3 ~ 1e-8),
    # round-off 1e-16 * 3 m / h ~ 3e-9
    scale = np.maximum(1.0, np.abs(fd).max(axis=(0, 1)))
    assert np.max(np.abs(jac - fd).max(axis=(0, 1)) / scale) < 1e-7


def test_gravity_torques_are_minus_the_potentials_gradient():
    q = Q[:4]
    tau = gravity_torques(CHAIN, q)

    def potential(qq):
        frames, _ = CHAIN.joint_frames(qq)
        coms = np.einsum("nkij,kj->nki", frames[:, :, :3, :3], CHAIN.com) + frames[:, :, :3, 3]
        return -np.einsum("k,nki,i->n", CHAIN.mass, coms, GRAVITY)

    h = 1e-6
    for k in range(6):
        e = np.zeros(6)
        e[k] = h
        fd = -(potential(q + e) - potential(q - e)) / (2 * h)
        np.testing.assert_allclose(tau[:, k], fd, atol=1e-6)  # N*m; truncation h^2 * 100 N*m
    np.testing.assert_allclose(tau[:, 0], 0, atol=1e-12)  # a vertical first axis carries no weight


def test_base_set_is_the_classic_count():
    """Position readings of a 6R arm: 4R + 2P + 6 = 30 independent geometric parameters for a full
        pose (Everett, Driels and Mooring 1987), less the probe's 3 orientation parameters a point
        cannot show: 27. Compliances: 4 more, not 6: the weight puts no torque on a vertical first axis,
    nor on the last joint, whose body is centred on its axis (the probe carries no mass here). A probe
        on the last axis (the nominal T-Mac) loses two more at first order: rotations about axes
        through it (the last joint's offset, the flange's z-turn) do not move it."""
    counts = {(0.03, 0.02, 0.109): (27, 31), (0.0, 0.0, 0.109): (25, 29)}
    for tool, (geometry, complete) in counts.items():
        model = GeometricModel(CHAIN, BASE0, np.array(tool))
        _, jac = model.jacobian(Q, np.zeros(model.size))
        assert len(base_set(jac, model.names, MODELS["geometry"])) == geometry
        full = base_set(jac, model.names, MODELS["geometry+compliance"])
        assert len(full) == complete
        names = [model.names[i] for i in full]
        assert "shoulder_pan_joint.compliance" not in names and "wrist_3_joint.compliance" not in names


@pytest.mark.parametrize("seed", [0, 1])
def test_hidden_geometry_is_recovered_within_4_sigma(seed):
    rng = np.random.default_rng(seed)
    model = GeometricModel(CHAIN, BASE0, TOOL)
    _, jac = model.jacobian(Q, np.zeros(model.size))
    free = np.asarray(base_set(jac, model.names, MODELS["geometry+compliance"]))
    truth = np.zeros(model.size)
    for i in free:  # 1-3 mm, mrad and (with ~100 N*m) 0.3-3 mrad of deflection: a real arm's size
        truth[i] = {"joint_compliance": rng.uniform(3e-6, 3e-5)}.get(
            kind(model.names[i]), rng.choice([-1, 1]) * rng.uniform(1e-3, 3e-3)
        )
    sigma = 20e-6  # m per axis, a laser tracker at 3 m
    y = model.predict(Q, truth) + rng.normal(0, sigma, (len(Q), 3))
    start = initial_model(CHAIN, Q, y, TOOL)  # registered on the readings, like real data
    fit = calibrate(start, Q, y, MODELS["geometry+compliance"], sigma=sigma)
    # the start registers the base differently: compare what a point sees, and the parameters
    # that do not depend on where the base starts (offsets, compliances, links, tool)
    assert fit.rms < 1.2 * sigma * np.sqrt(3)  # the noise, not a model error, is left
    inner = [k for k, i in enumerate(fit.free) if kind(model.names[i]) != "base_frame"]
    est = fit.theta[np.asarray(fit.free)[inner]]
    err = (est - truth[np.asarray(fit.free)[inner]]) / fit.std[inner]
    assert np.max(np.abs(err)) < 4.0, model.names[np.asarray(fit.free)[inner][np.argmax(np.abs(err))]]
    # held-out: new poses predicted to the noise
    q_new = np.random.default_rng(seed + 100).uniform(-np.pi, np.pi, (100, 6))
    y_new = model.predict(q_new, truth) + rng.normal(0, sigma, (100, 3))
    assert validate(fit, q_new, y_new).rms < 1.3 * sigma * np.sqrt(3)


def test_split_is_seeded_and_disjoint():
    a, b = split(100)
    assert len(a) == 70 and len(b) == 30 and not set(a) & set(b)
    np.testing.assert_array_equal(a, split(100)[0])
