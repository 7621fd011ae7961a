"""The complete model on robots with a kinematic loop or a compensator spring
(identify/geometry/statics.py): the FANUC M-900iB/700 (parallelogram closed by a `connect`
equality, balancer tendon) and the KR 270 (balancer tendon). Its readings are the bench's statics
with the geometry written into the compiled model; checked here against the bench's own campaign
(the same truth as MjSpec edits of the MJCF, compiled, solved by bench/campaign), and fitted to a
bench campaign with hidden joint offsets and a link frame (recovered within 4 sigma)."""

from pathlib import Path

import mujoco
import numpy as np
import pytest

from calbench.bench.campaign import plan_campaign, truth_robot
from calbench.bench.model import Robot
from calbench.bench.scenario import parse_scenario
from calbench.bench.statics import StaticsSolver
from calbench.bench.tracker import to_tracker_frame
from calbench.identify.geometry import MODELS, calibrate, calibrated_xml, kind, statics_model

MJCF = Path(__file__).resolve().parent.parent / "mjcf"
SIGMA = 20e-6  # m per axis
# the robots' realistic balancers (scenarios/*balancer_realistic.toml) and compliances of the
# paper's class (scenarios/paper_table5.toml, kr270_paper.toml)
ROBOTS = {
    "m900ib700": {
        "reflector": "refl_a",
        "compliance": [0.25e-6, 0.12e-6, 0.07e-6, 0.35e-6, 0.40e-6, 0.60e-6],
        "spring": ("compensator", "[truth.compensator]", 7.06e4, 0.6261),
        "lo": [-90, 5, -30, -150, -100, -150],
        "hi": [90, 100, 15, 150, 100, 150],
        "link": "link4",
    },
    "kr270": {
        "reflector": "smr_left",
        "compliance": [0.25e-6, 0.16e-6, 0.35e-6, 1.6e-6, 1.4e-6, 2.0e-6],
        "spring": ("balancer", "[truth.compensators.balancer]", 6.86e4, 0.1124),
        "lo": [-100, -120, -60, -150, -100, -150],
        "hi": [100, -20, 100, 150, 100, 150],
        "link": "wrist_a4",
    },
}
OFFSETS = [0.0, 1.0e-3, -0.8e-3, 1.5e-3, -1.2e-3, 0.0]  # rad: 1-3 mm at the reflector
FRAME = [1.5e-3, -1e-3, 2e-3, 1e-3, -0.5e-3, 0.8e-3]  # m and rad


def campaign(name: str, n: int, seed: int):
    """A bench campaign of ``name``: commanded angles and the reflector's true unloaded readings
    (tracker frame), the truth's joint offsets and link frame hidden as MjSpec edits."""
    r = ROBOTS[name]
    path = MJCF / f"{name}.xml"
    rng = np.random.default_rng(seed)
    robot = Robot.from_file(path)
    poses = []
    while len(poses) < n:
        q = rng.uniform(r["lo"], r["hi"])
        if robot.loops and not np.all(robot.loop_conditioning(np.radians(q)) > 0.3):
            continue
        poses.append(q)
    _, table, k, s0 = r["spring"]
    text = f"""robot = "{path}"
seed = 0
[truth]
compliance = {r["compliance"]}
{table}
stiffness = {k}
preload = {s0}
[truth.effects.joint_offset]
offset = {OFFSETS}
[truth.effects.link_geometry]
link = "{r["link"]}"
offset = {FRAME}
[tracker]
sigma = {SIGMA}
position = [3.5, -3.5, 3.2]
[load]
mass = 100.0
"""
    text += "".join(f"[[pose]]\nq = {np.round(q, 4).tolist()}\n" for q in poses)
    scn = parse_scenario(text, MJCF / "geometry_statics.toml")
    rb = truth_robot(scn)
    plans = plan_campaign(scn, rb)
    i = rb.reflector_names.index(r["reflector"])
    y = to_tracker_frame(scn.tracker, np.array([p.reflectors_world[0, i] for p in plans]))
    return np.array([p.q for p in plans]), y


def truth_theta(model, name: str) -> np.ndarray:
    """The campaign's truth in the model's vector (the registration aside)."""
    r = ROBOTS[name]
    theta = np.zeros(model.size)
    theta[model.lay.offset] = OFFSETS
    theta[model.lay.compliance] = np.asarray(r["compliance"]) - model.compliance0
    _, _, k, s0 = r["spring"]
    theta[model.lay.spring] = [k, k * s0]
    k = model.bodies.index(r["link"])
    theta[model.lay.link.start + 6 * k : model.lay.link.start + 6 * k + 6] = FRAME
    return theta


@pytest.mark.parametrize("name", sorted(ROBOTS))
def test_the_model_puts_the_reflector_where_the_bench_campaign_does(name, tmp_path):
    """The model at the truth's parameters against the bench's campaign of the same truth (the
    MJCF edited by the effects as MjSpec edits, compiled, solved by bench/campaign): equal to the
    statics' tolerance once the registration (a rigid motion) is fitted."""
    q, y = campaign(name, 12, seed=1)
    model = statics_model(MJCF / f"{name}.xml", None, ROBOTS[name]["reflector"], q, y, name)
    theta = truth_theta(model, name)
    free = tuple(range(6))  # the registration alone
    fit = calibrate(model, q, y, free=free, theta0=theta)
    assert fit.rms < 1e-9  # m: the statics solve to ~3e-11 m
    # and the calibrated MJCF (calibrated_xml) is that robot too, solved by the bench again
    rb = Robot.from_xml(calibrated_xml(model, fit.theta))
    solver, site = (
        StaticsSolver(rb),
        mujoco.mj_name2id(rb.model, mujoco.mjtObj.mjOBJ_SITE, ROBOTS[name]["reflector"]),
    )
    world = []
    for row in q:
        rb.data.qpos[:] = solver.solve(row).qpos
        mujoco.mj_kinematics(rb.model, rb.data)
        world.append(rb.data.site_xpos[site].copy())
    b = model.base(fit.theta)
    np.testing.assert_allclose(np.array(world) @ b[:3, :3].T + b[:3, 3], fit.predict(q), atol=1e-9)
    # without the hidden geometry the readings are millimetres off: the check is not empty
    plain = theta.copy()
    plain[model.lay.offset] = 0.0
    assert np.max(np.linalg.norm(model.predict(q, plain) - fit.predict(q), axis=1)) > 1e-3


@pytest.mark.parametrize("name", sorted(ROBOTS))
def test_geometry_compliance_and_spring_are_recovered_from_a_bench_campaign(name):
    """identify --geometry's complete model (MODELS["geometry+compliance"]: registration, probe,
    joint offsets, link frames, joint compliances, the balancer's K_C and K_C s0) fitted to the
    unloaded readings of a bench campaign with hidden joint offsets of 1-3 mm and a link frame
    off by 1-2 mm and 1 mrad, 20 um tracker: the fit leaves the noise, and every parameter lies
    within 4 of its std of the truth's share in the base set (the same fit to the noiseless
    readings); the compliances and the spring of that share are the truth's."""
    q, y0 = campaign(name, 30, seed=2)
    y = y0 + np.random.default_rng(5).normal(0, SIGMA, y0.shape)
    model = statics_model(MJCF / f"{name}.xml", None, ROBOTS[name]["reflector"], q, y, name)
    fit = calibrate(model, q, y, MODELS["geometry+compliance"], sigma=SIGMA)
    dof = y.size - len(fit.free)
    assert abs(fit.chi2 - dof) < 5 * np.sqrt(2 * dof)
    share = calibrate(model, q, y0, sigma=SIGMA, free=fit.free, theta0=fit.theta)
    assert share.rms < 1e-7  # m: the truth is in the model (the statics' precision aside)
    z = (fit.theta[list(fit.free)] - share.theta[list(fit.free)]) / fit.std
    assert np.max(np.abs(z)) < 4.0, dict(zip(fit.names, z.round(2), strict=True))
    truth = truth_theta(model, name)
    kinds = [kind(n) for n in fit.names]
    assert "joint_offset" in kinds and "compensator" in kinds and "link_geometry" in kinds
    for i, k in zip(fit.free, kinds, strict=True):
        if k in ("joint_compliance", "compensator"):  # seen directly: the share is the truth
            assert share.theta[i] == pytest.approx(truth[i], rel=1e-3, abs=1e-10), model.names[i]
