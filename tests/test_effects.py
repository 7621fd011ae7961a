"""Hidden physical effects (bench/model/effects/), each held to an independent computation.

The reference for the compliances is the linear VJM with the loop closed (paper eq. 1 extended
to the new hinges and eq. 16's loop handling): at the rigid pose with gravity off,
dq = Z (Z^T K Z)^-1 Z^T J^T W, Z a basis of the loop Jacobian's null space, K the diagonal of
joint stiffnesses. It shares no code with the Newton solver; the small loads keep the
geometric nonlinearity ~1e-5 relative.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest
import scipy.linalg
from conftest import MJCF, PAPER, ROOT, fanuc_params, fanuc_truth

from calbench.bench.campaign import run_campaign, truth_robot
from calbench.bench.core import InputError
from calbench.bench.log import read_log
from calbench.bench.model import Params, Robot, loop_jacobian
from calbench.bench.model.effects import (
    REGISTRY,
    Effect,
    EffectRobot,
    apply_effects,
    base_compliance,
    compensator,
    effect_from_truth,
    joint_nonlinearity,
    link_compliance,
)
from calbench.bench.scenario import load_scenario
from calbench.bench.statics import Load, StaticsSolver

K = np.array([0.25e-6, 0.12e-6, 0.07e-6, 0.35e-6, 0.40e-6, 0.60e-6])
NO_COMP = fanuc_params(K, 0.0, 0.83)  # compensator off
Q = np.radians([30.0, 60.0, -10.0, 20.0, 30.0, 40.0])  # a generic pose, far from the loop's singularity
FORCE = np.array([30.0, -20.0, -50.0])  # N: small load
MOMENT = np.array([5.0, 8.0, -3.0])  # N*m


def flange(robot: Robot, qpos) -> np.ndarray:
    d = mujoco.MjData(robot.model)
    d.qpos[:] = qpos
    mujoco.mj_kinematics(robot.model, d)
    return d.site_xpos[robot.flange_site].copy()


def solved_deflection(robot: Robot, q=Q, force=FORCE, moment=MOMENT):
    """Newton statics, gravity off: flange displacement under the load, and the equilibrium."""
    solver = StaticsSolver(robot)
    eq = solver.solve(q, Load(force, moment, robot.payload_site), gravity=False)
    assert eq.residual < 1e-9 and eq.loop_violation < 1e-10
    return flange(robot, eq.qpos) - flange(robot, robot.rigid_qpos(q)), eq


def jacobians(robot: Robot, q, site):
    m = robot.model
    d = mujoco.MjData(m)
    d.qpos[:] = robot.rigid_qpos(q)
    mujoco.mj_kinematics(m, d)
    mujoco.mj_comPos(m, d)
    jp, jr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    mujoco.mj_jacSite(m, d, jp, jr, site)
    return jp, jr, d


def linear_deflection(robot: Robot, q=Q, force=FORCE, moment=MOMENT) -> np.ndarray:
    """Linear VJM with the loop closed: flange displacement = J_f Z (Z^T K Z)^-1 Z^T J^T W."""
    m = robot.model
    jp, jr, d = jacobians(robot, q, robot.payload_site)
    jf, _, _ = jacobians(robot, q, robot.flange_site)
    z = scipy.linalg.null_space(loop_jacobian(robot, d), rcond=1e-9)
    kdiag = m.jnt_stiffness[m.dof_jntid]
    tau = jp.T @ force + jr.T @ moment
    dq = z @ np.linalg.solve(z.T @ (kdiag[:, None] * z), z.T @ tau)
    return jf @ dq


def dofs(robot: Robot, names) -> np.ndarray:
    return np.array([robot.model.jnt_dofadr[robot.model.joint(n).id] for n in names])


# --------------------------------------------------------------------------- structure


def test_registry_and_new_joints_start_at_zero():
    assert set(REGISTRY) >= {"link_compliance", "base_compliance", "joint_nonlinearity", "compensator"}
    eff = link_compliance("forearm")
    assert isinstance(eff, Effect) and eff.param_names == ("cx", "cy", "cz")
    robot = apply_effects(MJCF, [(eff, [1e-8, 2e-8, 3e-8]), (base_compliance(), [1e-9, 2e-9])])
    m = robot.model
    new = ["forearm_rx", "forearm_ry", "forearm_rz", "base_rx", "base_ry"]
    adr = [m.jnt_qposadr[m.joint(n).id] for n in new]
    assert np.all(m.qpos0[adr] == 0) and np.all(m.qpos_spring[adr] == 0)
    q = np.radians([10, 40, 5, 20, -30, 50])
    robot.set_command(q)
    qpos = robot.rigid_qpos(q)
    assert np.all(qpos[adr] == 0)
    np.testing.assert_array_equal(qpos[robot.act_qpos], q)
    np.testing.assert_allclose(m.jnt_stiffness[[m.joint(n).id for n in new]], [1e8, 5e7, 1 / 3e-8, 1e9, 5e8])
    # the hinges' axes are the link frame's x, y, z at the link's origin
    d = mujoco.MjData(m)
    d.qpos[:] = qpos
    mujoco.mj_kinematics(m, d)
    fa = m.body("forearm").id
    for i, n in enumerate(["forearm_rx", "forearm_ry", "forearm_rz"]):
        np.testing.assert_allclose(d.xaxis[m.joint(n).id], d.xmat[fa].reshape(3, 3)[:, i], atol=1e-12)
        np.testing.assert_allclose(d.xanchor[m.joint(n).id], d.xpos[fa], atol=1e-12)
    # total mass and first moment of the split link unchanged: unloaded gravity loads identical
    plain = Robot.from_file(MJCF)
    assert m.body_subtreemass[m.body("forearm").id] == pytest.approx(
        plain.model.body_subtreemass[fa], rel=1e-12
    )


def test_zero_compliance_in_truth_means_no_hinge():
    eff, p = effect_from_truth(
        "link_compliance", {"link": "forearm", "compliance": np.array([0.0, 4e-8, 0.0])}
    )
    assert eff.options["axes"] == "y" and eff.param_names == ("cy",) and p.tolist() == [4e-8]
    robot = apply_effects(MJCF, [(eff, p)])
    assert robot.model.nv == Robot.from_file(MJCF).model.nv + 1
    with pytest.raises(ValueError, match="no body 'wrist'"):  # any body of the MJCF, checked there
        apply_effects(MJCF, [(link_compliance("wrist"), [1e-8, 1e-8, 1e-8])])
    with pytest.raises(ValueError):
        eff.apply(mujoco.MjSpec.from_file(str(MJCF)), [1.0, 2.0])


# --------------------------------------------------------------------------- link_compliance


def test_forearm_compliance_is_eq1_with_three_more_springs():
    """Outside the loop: extra flange deflection = J_f,e C J_e^T W for the three new hinges."""
    c = np.array([2e-7, 1e-7, 3e-7])
    plain = Robot.from_file(MJCF)
    plain.set_params(NO_COMP)
    robot = apply_effects(MJCF, [(link_compliance("forearm"), c)])
    robot.set_params(NO_COMP)
    d0, _ = solved_deflection(plain)
    d1, eq = solved_deflection(robot)
    extra = d1 - d0
    hinges = dofs(robot, ["forearm_rx", "forearm_ry", "forearm_rz"])
    jp, jr, _ = jacobians(robot, Q, robot.payload_site)
    jf, _, _ = jacobians(robot, Q, robot.flange_site)
    je = np.vstack([jp, jr])[:, hinges]
    predicted = jf[:, hinges] @ np.diag(c) @ je.T @ np.r_[FORCE, MOMENT]
    assert np.linalg.norm(extra) > 5e-6
    np.testing.assert_allclose(extra, predicted, atol=1e-3 * np.linalg.norm(predicted))
    # the loop-aware reference agrees, and the loop stays closed
    np.testing.assert_allclose(
        extra, linear_deflection(robot) - linear_deflection(plain), atol=1e-3 * np.linalg.norm(predicted)
    )
    assert eq.loop_violation < 1e-7


def test_forearm_compliance_closed_loop_under_gravity_and_700kg():
    scn = load_scenario(PAPER)
    robot = apply_effects(MJCF, [(link_compliance("forearm"), [1e-7, 1e-8, 1e-7])])
    robot.set_params(fanuc_truth(scn))
    solver = StaticsSolver(robot)
    for pose in scn.poses[:12]:
        e0 = solver.solve(pose.q)
        e1 = solver.solve(pose.q, Load.mass(robot, 700.0), warm=e0)
        for e in (e0, e1):
            assert e.residual < 1e-8 * e.gravity_scale
            assert e.loop_violation < 1e-7  # 0.1 um


@pytest.mark.parametrize("axes,c", [("xyz", [1e-7, 2e-7, 3e-7]), ("y", [2e-7])])
def test_upper_arm_compliance_inside_the_loop(axes, c):
    """The upper-arm springs carry the elbow, so they sit inside the parallelogram loop: the
    reference is eq. 1 extended with the loop closed (Z^T K Z); the loop stays closed."""
    plain = Robot.from_file(MJCF)
    plain.set_params(NO_COMP)
    robot = apply_effects(MJCF, [(link_compliance("upper_arm", axes), c)])
    robot.set_params(NO_COMP)
    d0, _ = solved_deflection(plain)
    d1, eq = solved_deflection(robot)
    extra = d1 - d0
    predicted = linear_deflection(robot) - linear_deflection(plain)
    assert np.linalg.norm(extra) > 5e-6
    np.testing.assert_allclose(extra, predicted, atol=1e-3 * np.linalg.norm(predicted))
    assert eq.loop_violation < 1e-7
    # the reference itself matches the plain robot's solved deflection (no effect)
    np.testing.assert_allclose(d0, linear_deflection(plain), atol=1e-3 * np.linalg.norm(d0))


# --------------------------------------------------------------------------- base_compliance


def test_base_tilts_by_compliance_times_moment():
    c = np.array([3e-8, 5e-8])
    force, moment = np.array([400.0, -300.0, 0.0]), np.array([20.0, -10.0, 0.0])
    robot = apply_effects(MJCF, [(base_compliance(), c)])
    robot.set_params(NO_COMP)
    _, eq = solved_deflection(robot, Q, force, moment)
    tilt = eq.qpos[[robot.model.jnt_qposadr[robot.model.joint(n).id] for n in ("base_rx", "base_ry")]]
    p = jacobians(robot, Q, robot.payload_site)[2].site_xpos[robot.payload_site]
    hinge_point = np.zeros(3)  # base origin: the floor under axis 1
    m_base = np.cross(p - hinge_point, force) + moment
    assert np.all(np.abs(tilt) > 1e-6)
    np.testing.assert_allclose(tilt, c * m_base[:2], rtol=1e-3)


# --------------------------------------------------------------------------- joint_nonlinearity


def test_cubic_stiffness_torque_matches_polynomial():
    cubic = 3e11
    robot = apply_effects(MJCF, [(joint_nonlinearity(3), [cubic])])
    robot.set_params(NO_COMP)
    m, d = robot.model, robot.data
    j = robot.act_joint[2]
    kl = m.jnt_stiffness[j]
    assert kl == pytest.approx(1 / K[2]) and m.jnt_stiffnesspoly[j].tolist() == [0.0, cubic]
    q = np.radians([10, 40, 5, 20, -30, 50])
    robot.set_command(q)
    for theta in (-3e-3, -1e-4, 2e-4, 1e-3, 5e-3):
        d.qpos[:] = robot.rigid_qpos(q)
        d.qpos[robot.act_qpos[2]] += theta
        d.qvel[:] = 0.0
        mujoco.mj_forward(m, d)  # springs are computed in the velocity stage
        got = d.qfrc_spring[robot.act_dof[2]]
        assert got == pytest.approx(-(kl * theta + cubic * theta**3), rel=1e-9)


def test_cubic_equilibrium_solves_the_cubic():
    """J1 under a horizontal pull: K1 theta + c theta^3 = moment of the load about the J1 axis."""
    cubic = 5e9
    robot = apply_effects(MJCF, [(joint_nonlinearity(1), [cubic])])
    robot.set_params(NO_COMP)
    force = np.array([0.0, 20000.0, 0.0])
    _, eq = solved_deflection(robot, Q, force, np.zeros(3))
    d = robot.data
    d.qpos[:] = eq.qpos
    mujoco.mj_kinematics(robot.model, d)
    j = robot.act_joint[0]
    tau = d.xaxis[j] @ np.cross(d.site_xpos[robot.payload_site] - d.xanchor[j], force)
    k1 = 1 / K[0]
    roots = np.roots([cubic, 0.0, k1, -tau])
    theta = roots[np.abs(roots.imag) < 1e-12].real
    assert theta.size == 1
    assert eq.deflection[0] == pytest.approx(theta[0], rel=1e-9)
    assert cubic * theta[0] ** 3 > 0.1 * k1 * theta[0]  # the cubic term matters here


# --------------------------------------------------------------------------- compensator


def without_compensator() -> str:
    """The FANUC without its spring: the tendon and its description entry gone, the mounts
    (calbench:compensator_sites) kept."""
    spec = mujoco.MjSpec.from_file(str(MJCF))
    spec.delete(spec.tendon("compensator"))
    spec.delete(next(t for t in spec.texts if t.name == "calbench:compensators"))
    spec.compiler.savecompiled = False  # exact numbers (the compiled values are rounded)
    return spec.to_xml()


def test_compensator_added_to_a_model_without_one_reproduces_the_tendon():
    bare = without_compensator()
    assert "<tendon" not in bare and "calbench:compensators" not in bare
    assert mujoco.MjModel.from_xml_string(bare).ntendon == 0
    scn = load_scenario(PAPER)
    params = fanuc_truth(scn)
    orig = Robot.from_file(MJCF)
    orig.set_params(params)
    spring = params.springs["compensator"]
    added = apply_effects(bare, [(compensator(), [spring.stiffness, spring.preload])])
    assert added.model.ntendon == 1 and added.model.nv == orig.model.nv
    assert added.layout.n == 6  # not described: the effect's own spring, not a parameter
    added.set_params(Params(params.compliance))
    for qdeg in (
        [0, 0, -30, 0, 0, 0],
        [0, 35, 10, 0, 0, 0],
        [0, 120, 30, 0, 0, 0],
        [40, 80, -20, 10, 20, 30],
    ):
        q = np.radians(qdeg)
        for r in (orig, added):
            r.set_command(q)
            r.data.qpos[:] = r.rigid_qpos(q)
            r.data.qvel[:] = 0.0
            mujoco.mj_forward(r.model, r.data)
        j2 = orig.act_dof[1]
        assert added.data.ten_length[0] == pytest.approx(orig.data.ten_length[orig.tendons[0]], rel=1e-12)
        np.testing.assert_allclose(added.data.qfrc_spring, orig.data.qfrc_spring, rtol=1e-10, atol=1e-6)
        assert abs(orig.data.qfrc_spring[j2]) > 1e3
    e_orig = StaticsSolver(orig).solve(scn.poses[8].q, Load.mass(orig, 700.0))
    e_added = StaticsSolver(added).solve(scn.poses[8].q, Load.mass(added, 700.0))
    np.testing.assert_allclose(e_added.qpos, e_orig.qpos, atol=1e-12)
    # on a model that has the tendon, only its values change
    spec = mujoco.MjSpec.from_file(str(MJCF))
    compensator().apply(spec, [1.0e6, 0.9])
    model = spec.compile()
    assert model.ntendon == 1 and model.tendon_stiffness[0] == 1.0e6
    assert model.tendon_lengthspring[0].tolist() == [0.9, 0.9]


# --------------------------------------------------------------------------- fast path, round trip

CASES = [
    (link_compliance("forearm"), [1e-7, 1e-8, 1e-7], [3e-8, 2e-8, 5e-8]),
    (link_compliance("upper_arm"), [1.5e-8, 2e-8, 1.5e-8], [4e-8, 1e-8, 2e-8]),
    (base_compliance(), [4e-9, 4e-9], [1e-9, 6e-9]),
    (joint_nonlinearity(3), [2e12], [-1e11]),
    (compensator(), [2.6e6, 0.83], [1.5e6, 0.80]),
]


def loaded(robot: Robot, q) -> np.ndarray:
    solver = StaticsSolver(robot)
    e0 = solver.solve(q)
    return solver.solve(q, Load.mass(robot, 700.0), warm=e0).qpos


@pytest.mark.parametrize("eff,a,b", CASES, ids=[c[0].name + c[0].detail for c in CASES])
def test_set_params_equals_apply_and_compile(eff, a, b):
    scn = load_scenario(PAPER)
    fast = apply_effects(MJCF, [(eff, a)])
    fast.set_params(fanuc_truth(scn))
    eff.set_params(fast, b)
    fresh = apply_effects(MJCF, [(eff, b)])
    fresh.set_params(fanuc_truth(scn))
    if eff.name == "compensator":  # Robot.set_params writes the scenario's tendon values: redo
        eff.set_params(fast, b)
        eff.set_params(fresh, b)
    q = scn.poses[4].q
    np.testing.assert_allclose(loaded(fast, q), loaded(fresh, q), atol=1e-12)


@pytest.mark.parametrize("eff,a,b", CASES, ids=[c[0].name + c[0].detail for c in CASES])
def test_augmented_xml_round_trips(eff, a, b, tmp_path):
    scn = load_scenario(PAPER)
    robot = apply_effects(MJCF, [(eff, a)])
    out = tmp_path / "augmented.xml"
    out.write_text(robot.to_xml())
    again = Robot.from_file(out)
    assert again.model.nv == robot.model.nv and again.model.nbody == robot.model.nbody
    np.testing.assert_array_equal(again.model.jnt_stiffness, robot.model.jnt_stiffness)
    np.testing.assert_array_equal(again.model.jnt_stiffnesspoly, robot.model.jnt_stiffnesspoly)
    # the written file holds the effect's values; equilibrium with the file's own values
    for q in (scn.poses[0].q, scn.poses[10].q):
        np.testing.assert_allclose(loaded(again, q), loaded(robot, q), atol=1e-12)
    # and after the scenario's truth is written into both
    again.set_params(fanuc_truth(scn))
    robot.set_params(fanuc_truth(scn))
    np.testing.assert_allclose(loaded(again, scn.poses[5].q), loaded(robot, scn.poses[5].q), atol=1e-12)


# --------------------------------------------------------------------------- campaign

EFFECT_TOML = """
[truth.effects.link_compliance]
link = "forearm"
compliance = [8.0e-8, 1.0e-8, 8.0e-8]
"""


def scenario_with_effect(tmp_path: Path, extra: str) -> Path:
    text = PAPER.read_text().replace('robot = "../mjcf/m900ib700.xml"', f'robot = "{MJCF}"')
    # the [truth.effects.*] tables go right after [truth.compensator] (before [tracker])
    text = text.replace("[tracker]", extra.strip() + "\n\n[tracker]", 1)
    path = tmp_path / "hidden.toml"
    path.write_text(text)
    return path


def flange_moves(plans, robot) -> np.ndarray:
    out = []
    for p in plans:
        out.append(flange(robot, p.equilibria[1].qpos) - flange(robot, p.equilibria[0].qpos))
    return np.array(out)


def test_campaign_with_hidden_effect(tmp_path):
    path = scenario_with_effect(tmp_path, EFFECT_TOML)
    scn = load_scenario(path)
    assert "link_compliance" in scn.effects
    robot = truth_robot(scn)
    assert isinstance(robot, EffectRobot) and robot.model.joint("forearm_rz").id >= 0
    plans = run_campaign(scn, tmp_path / "hidden.mcap").plans
    plain_plans = run_campaign(load_scenario(PAPER), tmp_path / "plain.mcap").plans
    log = read_log(tmp_path / "hidden.mcap", include_truth=True)
    eff = log.truth.parameters.effects["link_compliance"]
    assert eff == {"link": "forearm", "compliance": [8.0e-8, 1.0e-8, 8.0e-8]}
    assert "forearm_rx" not in log.mjcf_text  # the log carries the user's model, not the truth
    diff = np.linalg.norm(
        flange_moves(plans, robot) - flange_moves(plain_plans, Robot.from_file(MJCF)), axis=1
    )
    # 0.1-0.3 mm at the flange under 700 kg (measured 0.18 / 0.23 / 0.31 mm min / median / max)
    assert 1e-4 < np.median(diff) < 3e-4 and diff.max() < 5e-4
    # the measurements moved accordingly: loaded-minus-unloaded differ by the same order
    plain_log = read_log(tmp_path / "plain.mcap", include_truth=True)
    a = np.array([r.loaded.position_world for r in log.truth.reflectors.values()])
    b = np.array([r.loaded.position_world for r in plain_log.truth.reflectors.values()])
    assert 5e-5 < np.median(np.linalg.norm(a - b, axis=-1)) < 1e-3


def test_register_carries_discovery_options_and_priors():
    """Adding an effect is one decorated function: @register_effect alone puts it (with its
    options and priors) into discovery's library; nothing in identify/ names it."""
    from calbench.bench.model.effects import UNIT_PRIORS, Prior, register_effect, unregister_effect
    from calbench.identify.discover import effect_priors, library

    @register_effect(
        "toy_spring",
        discover=[{"axis": "x"}, {"axis": "y"}],
        priors={"c": Prior(start=2e-9, lower=0.0, upper=1e-7, size=1e-9)},
    )
    def toy_spring(axis: str = "x") -> Effect:
        return Effect("toy_spring", ("c", "k"), {"axis": axis}, ("rad/(N*m)", "N/m"))

    try:
        toys = [e for e in library(Robot.from_file(MJCF)) if e.name == "toy_spring"]
        assert [e.options["axis"] for e in toys] == ["x", "y"]
        start, lower, upper, size = effect_priors(toys[0])
        assert start.tolist() == [2e-9, UNIT_PRIORS["N/m"].start]  # own prior, then the unit's
        assert upper.tolist() == [1e-7, UNIT_PRIORS["N/m"].upper]
        with pytest.raises(ValueError, match="already registered"):
            register_effect("toy_spring")(toy_spring)
    finally:
        unregister_effect("toy_spring")
    assert all(e.name != "toy_spring" for e in library(Robot.from_file(MJCF)))
    assert "toy_spring" not in REGISTRY


@pytest.fixture
def toy_effect():
    """tests/toy_effect.py registered (its import does it), and gone afterwards."""
    import importlib

    import toy_effect as toy

    from calbench.bench.model.effects import unregister_effect

    if toy.NAME not in REGISTRY:  # registered by an earlier test, then removed
        importlib.reload(toy)
    yield toy
    unregister_effect(toy.NAME)


# m: two Newton equilibria of the same statics agree to the solver's tolerance (residual < 1e-9 N*m
# times compliances <= 1e-6 rad/(N*m) and a 4 m reach: ~1e-14 m); 1e-10 m leaves the loop's share
EQUAL_STATICS = 1e-10


def first_poses(text: str, n: int) -> str:
    head, *poses = text.split("[[pose]]")
    return head + "".join("[[pose]]" + p for p in poses[:n])


def test_a_toy_effect_in_one_file_is_parsed_checked_and_simulated(tmp_path, toy_effect):
    """tests/toy_effect.py alone (a factory and its table's keys in @register_effect) makes
    [truth.effects.toy_hung_mass] a scenario table: checked key by key, applied to the truth,
    simulated and logged. Its physics held to an independent computation: hung at the payload
    site, the toy's mass makes the unloaded robot exactly the plain robot loaded by that mass
    (bench.statics.Load.mass), so the toy's unloaded reflectors are the plain campaign's loaded
    ones with load.mass = 50 kg."""
    text = first_poses(PAPER.read_text(), 3)
    toy_path = scenario_with_effect(tmp_path, "[truth.effects.toy_hung_mass]\nmass = 50.0")
    toy_path.write_text(first_poses(toy_path.read_text(), 3))
    scn = load_scenario(toy_path)
    assert scn.effects == {"toy_hung_mass": {"mass": 50.0}}  # the optional offset stays absent
    # the schema's checks, with the file, the key and what was expected
    bad = tmp_path / "bad.toml"
    for table, key, expected in (
        ("mass = -1.0", "mass", "a finite number > 0"),
        ('mass = "heavy"', "mass", "a finite number > 0"),
        ("offset = [0.0, 0.1, 0.0]", "mass", "this required key to be present"),
        ("mass = 5.0\noffset = [0.0, 0.1]", "offset", "an array of 3 numbers"),
        ("mass = 5.0\nmas = 5.0", "mas", "no such key; allowed keys here: mass, offset"),
    ):
        bad.write_text(toy_path.read_text().replace("mass = 50.0", table))
        with pytest.raises(InputError) as err:
            load_scenario(bad)
        assert err.value.file == str(bad) and err.value.key == f"truth.effects.toy_hung_mass.{key}"
        assert expected in err.value.expected
    with pytest.raises(InputError, match="allowed keys here: link_compliance, .*toy_hung_mass"):
        bad.write_text(toy_path.read_text().replace("toy_hung_mass]", "toy_hung_mas]"))
        load_scenario(bad)

    run_campaign(scn, tmp_path / "toy.mcap")
    plain = tmp_path / "plain50.toml"
    plain.write_text(
        text.replace('robot = "../mjcf/m900ib700.xml"', f'robot = "{MJCF}"').replace(
            "mass = 700.0", "mass = 50.0"
        )
    )
    run_campaign(load_scenario(plain), tmp_path / "plain50.mcap")
    toy_log = read_log(tmp_path / "toy.mcap", include_truth=True)
    plain_log = read_log(tmp_path / "plain50.mcap", include_truth=True)
    assert toy_log.truth.parameters.effects == {"toy_hung_mass": {"mass": 50.0}}
    for i in range(3):
        a = toy_log.truth.reflectors[i].unloaded.position_world
        b = plain_log.truth.reflectors[i].loaded.position_world
        assert np.linalg.norm(a - b, axis=-1).max() < EQUAL_STATICS
        # and the toy does something: 50 kg sag the arm by 0.1-0.2 mm (measured 0.12-0.21 mm)
        unloaded = plain_log.truth.reflectors[i].unloaded.position_world
        assert np.linalg.norm(a - unloaded, axis=-1).max() > 5e-5
    # set_params writes the mass into the compiled model: same statics as building it so
    eff, _ = effect_from_truth("toy_hung_mass", {"mass": 50.0})
    heavier = apply_effects(MJCF, [(eff, [80.0])])
    lighter = apply_effects(MJCF, [(eff, [50.0])])
    eff.set_params(lighter, [80.0])
    for r in (heavier, lighter):
        r.set_params(fanuc_truth(scn))
    q = scn.poses[0].q
    sag = [StaticsSolver(r).solve(q, None).qpos for r in (heavier, lighter)]
    np.testing.assert_allclose(sag[0], sag[1], rtol=0, atol=1e-12)


def test_tracker_drift_offsets_only_the_loaded_readings(tmp_path):
    """The measurement-side effect: same scenario and seed with and without the drift give the
    same unloaded readings and loaded readings shifted by exactly the offset (tracker frame,
    here yawed), the same truth; discovery's deflection term is R b on every row."""
    from calbench.bench.model.effects import ObservationRows, tracker_drift
    from calbench.bench.tracker import tracker_rotation

    text = PAPER.read_text().replace("position = [3.5, -3.5, 3.2]", "position = [3.5, -3.5, 3.2]\nyaw = 30.0")
    plain = tmp_path / "yawed.toml"
    plain.write_text(text.replace('robot = "../mjcf/m900ib700.xml"', f'robot = "{MJCF}"'))
    offset = np.array([30e-6, -20e-6, 25e-6])
    drift = scenario_with_effect(tmp_path, f"[truth.effects.tracker_drift]\noffset = {offset.tolist()}")
    drift.write_text(
        drift.read_text().replace("position = [3.5, -3.5, 3.2]", "position = [3.5, -3.5, 3.2]\nyaw = 30.0")
    )
    scn = load_scenario(drift)
    assert scn.effects["tracker_drift"]["offset"].tolist() == offset.tolist()
    run_campaign(load_scenario(plain), tmp_path / "a.mcap")
    run_campaign(scn, tmp_path / "b.mcap")
    a, b = read_log(tmp_path / "a.mcap"), read_log(tmp_path / "b.mcap")
    assert len(a.measurements) == len(b.measurements)
    for ma, mb in zip(a.measurements, b.measurements):
        vis = ma.visible
        shift = offset if ma.state == "loaded" else np.zeros(3)
        np.testing.assert_allclose(
            mb.position[vis] - ma.position[vis], np.tile(shift, (vis.sum(), 1)), rtol=0, atol=1e-15
        )
    rot = tracker_rotation(scn.tracker)
    term = tracker_drift().deflection_term(offset, ObservationRows(((0, "refl_a"), (1, "refl_b")), rot))
    np.testing.assert_allclose(term, np.tile(rot @ offset, (2, 1)), rtol=1e-15)
    assert tracker_drift().measurement_side and not link_compliance("forearm").measurement_side


def test_the_contract_shows_each_effect_table_with_the_keys_and_units_its_registration_declares():
    """docs/contract.md's `[truth.effects.NAME]` examples held to the registry: each shows exactly
    the keys the effect's @register_effect declares, in that order, each unit in its comment
    (tool_compliance, truth only, is the one the contract does not show)."""
    from calbench.bench.model.effects import TRUTH_SCHEMAS

    text = (ROOT / "docs" / "contract.md").read_text(encoding="utf-8")
    shown = {}
    for block in text.split("\n[truth.effects.")[1:]:
        name, body = block.split("]", 1)
        lines = [ln for ln in body.split("\n[", 1)[0].splitlines()[1:] if ln.strip() and "=" in ln]
        shown[name] = [(ln.split("=")[0].strip(), ln.partition("#")[2]) for ln in lines]
    assert set(shown) == set(TRUTH_SCHEMAS) - {"tool_compliance"}
    for name, keys in shown.items():
        schema = TRUTH_SCHEMAS[name]
        assert [k for k, _ in keys] == [f.key for f in schema], name
        for (_, comment), f in zip(keys, schema):
            assert f.unit in comment, f"{name}.{f.key}: the contract's comment lacks {f.unit}"
