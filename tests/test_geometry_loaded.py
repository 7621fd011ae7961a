"""Loaded readings in the complete model (identify/geometry: model.py Rows, statics.py): a load is a
known second force term in the statics, each reflector its own point. Checked against calbench's
MuJoCo statics (a second solver) on a serial UR10 and on the FANUC of the paper's campaign; the
recovery over many seeds is benchmarks/geometry_loaded_bench.py's (docs/geometry.md)."""

from pathlib import Path

import mujoco
import numpy as np

from calbench.bench.campaign import plan_campaign, truth_robot
from calbench.bench.model import Params, Robot
from calbench.bench.scenario import parse_scenario
from calbench.bench.statics import Load, StaticsSolver
from calbench.bench.tracker import to_tracker_frame
from calbench.identify.geometry import (
    GeometricModel,
    Rows,
    calibrate,
    load_torques,
    statics_model,
    ur10,
    write_chain_mjcf,
)

ROOT = Path(__file__).resolve().parent.parent
TOOL = np.array([0.0, 0.0, 0.109])
AUX = np.array([0.05, 0.0, 0.109])
OFFSETS = [0.0, 1.0e-3, -0.8e-3, 1.5e-3, -1.2e-3, 0.0]  # rad: 1-3 mm at the FANUC's reflectors
FRAME = [1.5e-3, -1e-3, 2e-3, 1e-3, -0.5e-3, 0.8e-3]  # m and rad: link4's frame


def ur10_loads(n: int, rng) -> tuple[np.ndarray, list]:
    """n commands, half of them under a 30 kg mass at the probe, half under a wrench there."""
    q = rng.uniform(-np.pi, np.pi, (n, 6))
    loads = []
    for i in range(n):
        w = rng.uniform(-200, 200, 6) if i % 2 else np.array([0, 0, -30 * 9.81, 0, 0, 0])
        loads.append((w, 30.0 if i % 2 == 0 else 0.0))
    return q, loads


def test_a_load_is_a_second_torque_term_that_matches_calbenchs_statics(tmp_path):
    """The serial arm (model.py): the load's torques J^T W against MuJoCo's site Jacobian, and the
    loaded readings of the model at its own deflected pose (torques_at: the weight AND the load at
    q + c tau) against calbench's equilibrium of the same arm with joint springs 1/c and the same
    load, to the solver's tolerance; the nominal torques at the command miss the sag's change."""
    k = np.array([5e-6, 3e-5, 2e-5, 2e-5, 2e-5, 2e-5])  # rad/(N*m)
    path = write_chain_mjcf(tmp_path / "ur10.xml", ur10(), TOOL, name="ur10", compliance=k)
    robot = Robot.from_file(path)
    robot.set_params(Params(k))
    solver = StaticsSolver(robot)
    q, loads = ur10_loads(10, np.random.default_rng(3))
    site = mujoco.mj_name2id(robot.model, mujoco.mjtObj.mjOBJ_SITE, "probe")
    aux = mujoco.mj_name2id(robot.model, mujoco.mjtObj.mjOBJ_SITE, "probe_aux_x")
    # J^T W from MuJoCo's Jacobian of the site at the command
    d = robot.data
    jt = []
    for row, (w, _) in zip(q, loads, strict=True):
        d.qpos[robot.act_qpos] = row
        mujoco.mj_kinematics(robot.model, d)
        mujoco.mj_comPos(robot.model, d)
        jp, jr = np.zeros((3, robot.model.nv)), np.zeros((3, robot.model.nv))
        mujoco.mj_jacSite(robot.model, d, jp, jr, site)
        jt.append((jp.T @ w[:3] + jr.T @ w[3:])[robot.act_qpos])
    w = np.array([x for x, _ in loads])
    ours = load_torques(ur10(), q, w[:, :3], w[:, 3:], np.tile(TOOL, (len(q), 1)))
    np.testing.assert_allclose(ours, np.array(jt), atol=1e-9 * np.abs(jt).max())
    # the loaded equilibria: two points (the probe, where the load hangs, and an auxiliary one)
    world, sag = [], []
    for row, (wr, mass) in zip(q, loads, strict=True):
        load = Load.mass(robot, mass) if mass else Load.wrench(robot, wr)
        e = solver.solve(row, load)
        d.qpos[:] = e.qpos
        mujoco.mj_kinematics(robot.model, d)
        world += [d.site_xpos[site].copy(), d.site_xpos[aux].copy()]
        sag.append(e.deflection)
    n = len(q)
    force = np.array([[0, 0, -9.81 * m] if m else wr[:3] for wr, m in loads])
    moment = np.array([np.zeros(3) if m else wr[3:] for wr, m in loads])
    rows = Rows(
        np.repeat(q, 2, axis=0), np.tile([0, 1], n), np.repeat(force, 2, axis=0), np.repeat(moment, 2, axis=0),
        ("probe",) * 2 * n, np.repeat([m for _, m in loads], 2),
    )  # fmt: skip
    model = GeometricModel(
        ur10(), np.eye(4), np.array([TOOL, AUX]), ("probe", "probe_aux_x"), {"probe": TOOL}
    )
    theta = np.zeros(model.size)
    theta[[model.names.index(f"{j}.compliance") for j in ur10().joints]] = k
    tau = model.torques_at(rows, theta, steps=12)  # the fixed point converged (it contracts by ~1e-2)
    scale = np.abs(sag).max()
    np.testing.assert_allclose((k * tau)[::2], np.array(sag), atol=1e-9 * scale)
    np.testing.assert_allclose(model.predict(rows, theta, tau), np.array(world), atol=1e-9)
    # the check is not empty: the load's sag is millimetres, and the nominal torques miss its change
    unloaded = model.predict(rows, theta, model.torques_at(Rows(rows.q, rows.point, 0 * force.repeat(2, 0),
                             0 * moment.repeat(2, 0), rows.site, 0 * rows.mass), theta))  # fmt: skip
    assert np.max(np.linalg.norm(unloaded - np.array(world), axis=1)) > 1e-3
    assert np.abs(k * model.torques(rows)[::2] - sag).max() > 1e-4 * scale


def paper_campaign(seed: int = 1):
    """The paper's FANUC campaign (scenarios/paper_table5.toml: 16 poses, 700 kg and four lateral
    pulls) with hidden joint offsets and link4's frame off (1-3 mm at the reflectors): the
    commands as Rows (each pose unloaded and loaded, each reflector the tracker sees) and their
    true readings in the tracker frame."""
    text = (ROOT / "scenarios" / "paper_table5.toml").read_text()
    text += f"[truth.effects.joint_offset]\noffset = {OFFSETS}\n"
    text += f'[truth.effects.link_geometry]\nlink = "link4"\noffset = {FRAME}\n'
    scn = parse_scenario(text, ROOT / "scenarios" / "paper_table5.toml", seed=seed)
    rb = truth_robot(scn)
    plans = plan_campaign(scn, rb)
    q, point, force, moment, site, mass, y = [], [], [], [], [], [], []
    names = rb.reflector_names
    for p in plans:
        for s in range(2):
            for i, _ in enumerate(names):
                if not p.visible[s, i]:
                    continue
                q.append(p.q)
                point.append(i)
                force.append(p.load.force if s else np.zeros(3))
                moment.append(p.load.moment if s else np.zeros(3))
                site.append("payload" if s else "")
                mass.append(p.mass or 0.0 if s else 0.0)
                y.append(to_tracker_frame(scn.tracker, p.reflectors_world[s, i][None])[0])
    rows = Rows(np.array(q), np.array(point), np.array(force), np.array(moment), tuple(site), np.array(mass))
    return rows, np.array(y), tuple(names), scn


def test_the_statics_model_puts_loaded_readings_where_the_bench_campaign_does():
    """The statics model (statics.py) at the truth's parameters against the bench's campaign of
    the paper's plan with hidden geometry (MjSpec edits, compiled, solved by bench/campaign): every
    reflector, unloaded and under 700 kg or a 1.2 kN pull, to the statics' tolerance once the
    registration is fitted."""
    rows, y, names, scn = paper_campaign()
    model = statics_model(ROOT / "mjcf" / "m900ib700.xml", None, names, rows, y, "m900ib700")
    theta = np.zeros(model.size)
    theta[model.lay.offset] = OFFSETS
    theta[model.lay.compliance] = np.asarray(scn.compliance) - model.compliance0
    spring = scn.compensators["compensator"]
    theta[model.lay.spring] = [spring.stiffness, spring.stiffness * spring.preload]
    k = model.bodies.index("link4")
    theta[model.lay.link.start + 6 * k : model.lay.link.start + 6 * k + 6] = FRAME
    fit = calibrate(model, rows, y, free=tuple(range(6)), theta0=theta)
    assert fit.rms < 1e-9  # m: the statics solve to ~3e-11 m
    # not empty: the loads move the reflectors by millimetres
    unloaded = Rows(rows.q, rows.point, 0 * rows.force, 0 * rows.moment, ("",) * len(rows), 0 * rows.mass)
    assert np.max(np.linalg.norm(fit.predict(unloaded) - y, axis=1)) > 1e-3


def test_loads_shrink_the_compliances_std_and_leave_them_unbiased(tmp_path, monkeypatch):
    """identify --geometry on a campaign calbench's statics simulated (a UR10 of known joint
    compliances with hidden joint offsets, each pose unloaded and under 20 kg at the probe, 20 um
    tracker): with the loaded readings, each identified compliance lies within 4 of its std of the
    truth and its std is smaller than from the unloaded readings alone (more readings of the same
    parameters, and the load's torques beside the arm's weight: the information only grows). The
    logs are read without their truth."""
    import calbench.bench.log as log_face
    from calbench.identify.cli import main
    from calbench.identify.geometry import run_geometry

    write_chain_mjcf(tmp_path / "ur10.xml", ur10(), TOOL, name="ur10")
    k = [1e-6, 1.5e-5, 1e-5, 2e-5, 2e-5, 2e-5]  # rad/(N*m)
    lines = ['robot = "ur10.xml"', "seed = 3", "[truth]", f"compliance = {k}"]
    lines += ["[truth.effects.joint_offset]", "offset = [0.0, 0.0015, -0.002, 0.0012, -0.0018, 0.0]"]
    lines += ["[tracker]", "sigma = 2e-5", "position = [3.0, 1.0, 0.5]", "[load]", "mass = 20.0"]
    for q in np.random.default_rng(4).uniform(-170, 170, (60, 6)):
        lines += ["[[pose]]", "q = [" + ", ".join(f"{v:.3f}" for v in q) + "]"]
    (tmp_path / "load.toml").write_text("\n".join(lines) + "\n")
    assert main(["simulate", str(tmp_path / "load.toml"), "--out", str(tmp_path / "load.mcap")]) == 0
    calls, real = [], log_face.read_log  # every read_log of run.py: its include_truth (True if unsaid)
    spy = lambda path, *a, **kw: calls.append(kw.get("include_truth", not a or a[0])) or real(path, *a, **kw)  # noqa: E731
    monkeypatch.setattr("calbench.identify.geometry.run.read_log", spy)
    both = run_geometry(tmp_path / "load.mcap")
    alone = run_geometry(tmp_path / "load.mcap", states=("unloaded",))
    assert calls == [False, False]
    assert both["n_loaded"] == both["n"] // 2 and alone["n_loaded"] == 0
    joints = list(ur10().joints)

    def compliances(rep):
        return {p["name"].split(".")[0]: p for p in rep["parameters"] if p["effect"] == "joint_compliance"}

    loaded, unloaded = compliances(both), compliances(alone)
    assert set(unloaded) <= set(loaded) and {"shoulder_lift_joint", "elbow_joint"} <= set(unloaded)
    for j, p in loaded.items():
        assert abs(p["value"] - k[joints.index(j)]) < 4 * p["std"], (j, p)
    for j, p in unloaded.items():
        assert loaded[j]["std"] < p["std"], (j, loaded[j], p)


def test_the_paper_plan_with_its_loads_gives_every_compliance_and_the_balancer_unbiased():
    """The complete model (statics.py) fitted to the paper's FANUC plan with hidden joint offsets
    and link4's frame (1-3 mm), every reflector unloaded and loaded, 20 um noise: the fit leaves
    the noise (chi2 within 5 of its std of the dof), all six compliances and the balancer's K_C
    and P are in the base set, and each lies within 4 of its std of the truth. Unloaded alone,
    the first joint's compliance is not in it (its axis is vertical: the weight puts no torque on
    it, the paper's section 5.1 adds lateral pulls for it)."""
    from calbench.identify.geometry import MODELS, base_set, kind, rank_rule

    sigma = 20e-6
    rows, y0, names, scn = paper_campaign(seed=2)
    y = y0 + np.random.default_rng(7).normal(0, sigma, y0.shape)
    model = statics_model(ROOT / "mjcf" / "m900ib700.xml", None, names, rows, y, "m900ib700")
    fit = calibrate(model, rows, y, MODELS["geometry+compliance"], sigma=sigma)
    dof = y.size - len(fit.free)
    assert abs(fit.chi2 - dof) < 5 * np.sqrt(2 * dof)
    truth = np.zeros(model.size)
    truth[model.lay.compliance] = np.asarray(scn.compliance) - model.compliance0
    spring = scn.compensators["compensator"]
    truth[model.lay.spring] = [spring.stiffness, spring.stiffness * spring.preload]
    seen = [i for i in fit.free if kind(model.names[i]) in ("joint_compliance", "compensator")]
    assert len(seen) == 8
    z = (fit.theta[seen] - truth[seen]) / fit.std[[fit.free.index(i) for i in seen]]
    assert np.max(np.abs(z)) < 4.0, dict(zip([model.names[i] for i in seen], z.round(2), strict=True))
    alone = np.flatnonzero(~rows.loaded)
    _, jac = model.jacobian(rows.take(alone), np.zeros(model.size))
    free = base_set(jac, model.names, MODELS["geometry+compliance"], rank_rule(model))
    assert model.names.index("j1.compliance") not in free
