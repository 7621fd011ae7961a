"""A chain as a calbench MJCF and back (identify/geometry/mjcf.py): MuJoCo, a second solver, puts
the probe where the numpy chain does and gives the same gravity forces; the UR10 passes
check-robot; a calibrated fit written as an MJCF predicts what the fit predicts."""

import mujoco
import numpy as np
import pytest
from conftest import MJCF

from calbench.bench.core import InputError
from calbench.bench.robots import check_robot
from calbench.identify.geometry import (
    MODELS,
    GeometricModel,
    base_set,
    calibrate,
    chain_from_mjcf,
    chain_mjcf,
    gravity_torques,
    rot,
    translation,
    ur10,
    write_chain_mjcf,
)

CHAIN = ur10()
TOOL = np.array([0.001, 0.002, 0.109])
Q = np.random.default_rng(3).uniform(-np.pi, np.pi, (20, 6))


def mujoco_probe(path, q):
    """The probe site and the generalised gravity forces from MuJoCo itself."""
    model = mujoco.MjModel.from_xml_path(str(path))
    data = mujoco.MjData(model)
    site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "probe")
    pos, grav = [], []
    for row in q:
        data.qpos[:], data.qvel[:] = row, 0.0
        mujoco.mj_forward(model, data)
        pos.append(data.site_xpos[site].copy())
        grav.append(-data.qfrc_bias.copy())  # at rest the bias force is minus gravity's
    return np.asarray(pos), np.asarray(grav)


@pytest.fixture(scope="module")
def ur10_xml(tmp_path_factory):
    return write_chain_mjcf(tmp_path_factory.mktemp("ur10") / "ur10.xml", CHAIN, TOOL, name="ur10")


def test_mujoco_agrees_with_the_chain(ur10_xml):
    pos, grav = mujoco_probe(ur10_xml, Q)
    np.testing.assert_allclose(pos, CHAIN.flange_point(Q, TOOL), atol=1e-12)  # m, rounding only
    np.testing.assert_allclose(grav, gravity_torques(CHAIN, Q), atol=1e-10)  # N*m


def test_the_generated_ur10_is_a_calbench_robot(ur10_xml):
    report = check_robot(ur10_xml)
    assert report is not None


def test_a_serial_mjcf_reads_back_as_the_same_chain(ur10_xml):
    back = chain_from_mjcf(ur10_xml)
    assert back.joints == CHAIN.joints
    np.testing.assert_allclose(back.mass, CHAIN.mass)
    np.testing.assert_allclose(back.flange_point(Q, TOOL), CHAIN.flange_point(Q, TOOL), atol=1e-12)
    np.testing.assert_allclose(gravity_torques(back, Q), gravity_torques(CHAIN, Q), atol=1e-10)


def test_a_robot_with_a_loop_is_refused():
    with pytest.raises(InputError, match="serial arm"):
        chain_from_mjcf(MJCF)  # the FANUC's parallelogram


def test_a_calibrated_model_as_mjcf_predicts_what_the_fit_does(tmp_path):
    base0 = translation([0.4, -3.2, 0.2]) @ rot(2, 1.2)
    model = GeometricModel(CHAIN, base0, TOOL)
    _, jac = model.jacobian(Q, np.zeros(model.size))
    rng = np.random.default_rng(5)
    truth = np.zeros(model.size)
    truth[list(base_set(jac, model.names, MODELS["geometry"]))] = rng.normal(0, 2e-3, 27)
    y = model.predict(Q, truth)
    fit = calibrate(model, Q, y, MODELS["geometry"], sigma=1e-6)
    chain, tool, base, _ = fit.calibrated()
    path = tmp_path / "calibrated.xml"
    path.write_text(chain_mjcf(chain, tool, name="ur10_calibrated"))
    pos, _ = mujoco_probe(path, Q)
    np.testing.assert_allclose(pos @ base[:3, :3].T + base[:3, 3], fit.predict(Q), atol=1e-9)
    np.testing.assert_allclose(fit.predict(Q), y, atol=1e-8)  # noise-free readings: fitted exactly


def test_a_robot_with_a_compensator_spring_is_refused():
    with pytest.raises(InputError, match="compensator springs"):
        chain_from_mjcf(MJCF.with_name("kr270.xml"))  # its balancer is a tendon


def test_geometric_truth_effects_edit_the_spec_and_the_model_alike(ur10_xml):
    """The geometric truth effects (bench/model/effects.py): set_params on a compiled model gives
    the model apply builds, and an offset o on joint k is the same probe as the command q_k + o."""
    from calbench.bench.model.effects import apply_effects, effect_from_truth

    offsets = np.array([0.01, -0.02, 0.015, 0.0, -0.01, 0.005])
    q = Q[:5]
    for name, table, p2 in (
        ("joint_offset", {"offset": offsets}, -0.5 * offsets),
        ("tool_frame", {"offset": [0.001, -0.002, 0.003]}, np.array([-0.002, 0.0, 0.001])),
        ("link_geometry", {"link": "link3", "offset": [1e-3, 0, 2e-3, 1e-3, -2e-3, 0]}, np.full(6, 5e-4)),
        ("base_frame", {"offset": [0.01, 0.02, 0, 0, 0, 0.01]}, np.array([0, 0, 0.01, 0.003, 0, 0])),
    ):
        effect, p1 = effect_from_truth(name, table)
        fast = apply_effects(ur10_xml, [(effect, p1)])
        effect.set_params(fast, p2)
        built = apply_effects(ur10_xml, [(effect_from_truth(name, table)[0], p2)])
        np.testing.assert_allclose(
            mujoco_probe_model(fast.model, q), mujoco_probe_model(built.model, q), atol=1e-12
        )
    effect, p1 = effect_from_truth("joint_offset", {"offset": offsets})
    turned = mujoco_probe_model(apply_effects(ur10_xml, [(effect, p1)]).model, q)
    np.testing.assert_allclose(turned, CHAIN.flange_point(q + offsets, TOOL), atol=1e-12)


def mujoco_probe_model(model, q):
    data = mujoco.MjData(model)
    site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "probe")
    out = []
    for row in q:
        data.qpos[:] = row
        mujoco.mj_kinematics(model, data)
        out.append(data.site_xpos[site].copy())
    return np.asarray(out)
