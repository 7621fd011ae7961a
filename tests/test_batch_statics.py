"""The batched statics (bench/statics/batched.py) against the one definition, bench/statics/equilibrium.py.

Configuration by configuration: the same residual and Jacobians to rounding, the same equilibria
to the solver's tolerance, the same tangents to the finite-difference matrix's accuracy, the
same acceptance; and results that do not depend on how the configurations were grouped or on
the thread count (the candidate generator's determinism rests on it).

Tolerances. Rounding: the stacked arithmetic sums in another order than the scalar one, so
quantities agree to a few ulps of their own scale (1e-12 relative leaves ~10^4 ulps). Equilibria:
each solve stops at max|r| <= tol x gravity scale and |B^T c| <= LOOP_TOL; two such solutions of
the same equations differ by at most K^-1 applied to the difference of their residuals, so the
bound is |K^-1|_inf (|r_1| + |r_2|) per configuration, with K^-1 the exact KKT inverse (a factor 2
for the linearisation). Tangents: both are the IFT with a forward-difference matrix (step 1e-7)
taken at equilibria that differ by that bound; 1e-6 relative is the accuracy the design's
information needs (issue 16).
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from conftest import K_TRUE, MJCF, TABLE5, fanuc_params
from robots import serial_mjcf

from calbench.bench.model import Params, Robot, constraint_basis, constraint_basis_stack, loop_gap
from calbench.bench.statics import (
    BatchStatics,
    Load,
    StaticsError,
    StaticsSolver,
    ift_tangent,
    kkt_matrix,
    statics_options,
    take_load,
)

PARAMS = fanuc_params(K_TRUE, 2.6e6, 0.83)
N = 40


@pytest.fixture(scope="module")
def robot():
    rb = Robot.from_file(MJCF)
    rb.set_params(PARAMS)
    return rb


@pytest.fixture(scope="module")
def commands(robot):
    """Table 5 and random commands in the joint ranges, the parallelogram kept regular."""
    rng = np.random.default_rng(16)
    lim = robot.limits()
    q = lim[:, 0] + (lim[:, 1] - lim[:, 0]) * rng.random((4 * N, 6))
    q = np.vstack([TABLE5, [x for x in q if robot.loop_ok(x)]])
    return q[:N]


@pytest.fixture(scope="module")
def loads(robot, commands):
    """700 kg hanging on half of them, a 1200 N horizontal pull plus a moment on the rest."""
    w = np.zeros((len(commands), 6))
    w[::2, :3] = robot.weight(700.0)
    w[1::2] = [900.0, -700.0, 0.0, 300.0, -200.0, 100.0]
    return Load(w[:, :3], w[:, 3:], robot.payload_site)


@pytest.fixture(scope="module")
def solved(robot, commands, loads):
    """Both solvers on every configuration: unloaded cold, loaded warm."""
    solver = StaticsSolver(robot)
    bs = BatchStatics(solver, nsim=8, nthread=1)  # grows on demand
    e0 = bs.solve(commands)
    a0 = bs.stiffness(e0, None)
    e1 = bs.solve(commands, loads, warm=e0, warm_stiffness=a0)
    scalar = []
    for i, q in enumerate(commands):
        s0 = solver.solve(q)
        scalar.append((s0, solver.solve(q, take_load(loads, i), warm=s0)))
    return bs, e0, a0, e1, scalar


def _kkt_inverse(solver, e, load):
    robot = solver.robot
    robot.set_command(e.command)
    with statics_options(robot):
        res = solver.residual(e.qpos, load, e.lam, e.basis)
        a = solver.stiffness_fd(e.qpos, load, e.lam, e.basis, res.r)
    return np.linalg.inv(kkt_matrix(a, res.jc_r))


def test_site_jacobians_are_mujocos(robot, commands):
    """The Jacobians formed from the joint frames equal mj_jacSite (an independent computation)."""
    bs = BatchStatics(StaticsSolver(robot), nsim=len(commands), nthread=1)
    ids = np.arange(len(commands))
    qpos = np.array([robot.rigid_qpos(q) for q in commands]) + 0.01
    bs.forward(ids, qpos, mujoco.mjtStage.mjSTAGE_POS)
    m, d = robot.model, mujoco.MjData(robot.model)
    jp, jr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    for site in [robot.payload_site, *robot.reflector_sites, *robot.loops[0]]:
        bp, br = bs.site_jacobian(ids, int(site), rotation=True)
        for i in ids:
            d.qpos[:] = qpos[i]
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            mujoco.mj_jacSite(m, d, jp, jr, int(site))
            np.testing.assert_allclose(bp[i], jp, rtol=0, atol=1e-12 * np.abs(jp).max())
            np.testing.assert_allclose(br[i], jr, rtol=0, atol=1e-12)


def test_residual_and_basis_are_the_scalar_ones(robot, commands, loads):
    solver = StaticsSolver(robot)
    bs = BatchStatics(solver, nsim=len(commands), nthread=1)
    ids = np.arange(len(commands))
    rng = np.random.default_rng(3)
    qpos = np.array([robot.rigid_qpos(q) for q in commands]) + 1e-3 * rng.standard_normal(
        (len(ids), robot.model.nv)
    )
    bs.set_commands(ids, commands)
    basis = bs.basis(ids, qpos)
    lam = 1e4 * rng.standard_normal((len(ids), basis.shape[2]))
    res = bs.residual(ids, qpos, loads, lam, basis)
    for i in ids:
        robot.set_command(commands[i])
        with statics_options(robot):
            b = solver.basis(qpos[i])
            # same constraint directions (the basis itself may differ by a rotation in its plane)
            np.testing.assert_allclose(basis[i] @ basis[i].T, b @ b.T, rtol=0, atol=1e-12)
            r = solver.residual(qpos[i], take_load(loads, i), lam[i], basis[i])
            c, _ = loop_gap(robot, robot.data)
        scale = np.abs(r.r).max()
        np.testing.assert_allclose(res.r[i], r.r, rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(res.c_r[i], r.c_r, rtol=0, atol=1e-15)
        np.testing.assert_allclose(res.jc_r[i], r.jc_r, rtol=0, atol=1e-12)
        assert res.gap[i] == pytest.approx(np.linalg.norm(c), rel=1e-12, abs=1e-18)


def test_constraint_basis_stack_matches_the_scalar_construction(robot, commands):
    d = mujoco.MjData(robot.model)
    jcs = []
    for q in commands:
        d.qpos[:] = robot.rigid_qpos(q)
        mujoco.mj_fwdPosition(robot.model, d)
        jcs.append(loop_gap(robot, d)[1])
    stack = constraint_basis_stack(np.array(jcs))
    for jc, b in zip(jcs, stack):
        np.testing.assert_allclose(b, constraint_basis(jc), rtol=0, atol=1e-12)
        np.testing.assert_allclose(b.T @ b, np.eye(b.shape[1]), atol=1e-14)


def test_equilibria_are_the_scalar_ones_to_the_solver_tolerance(robot, loads, solved):
    bs, e0, a0, e1, scalar = solved
    solver = bs.solver
    nv = robot.model.nv
    assert e0.converged.all() and e1.converged.all()
    assert e0.acceptable.all() and e1.acceptable.all()
    for i, (s0, s1) in enumerate(scalar):
        for batch, one, load in ((e0, s0, None), (e1, s1, take_load(loads, i))):
            kinv = _kkt_inverse(solver, one, load)
            bound = 2 * (
                np.abs(kinv[:nv, :nv]).sum(axis=1).max() * (batch.residual[i] + one.residual)
                + np.abs(kinv[:nv, nv:]).sum(axis=1).max() * (batch.loop_violation[i] + one.loop_violation)
            )
            assert np.abs(batch.qpos[i] - one.qpos).max() <= bound, (i, bound)
            assert batch.acceptable[i] == one.acceptable
            assert batch.equilibrium(i, robot.act_qpos).acceptable == one.acceptable
            # the same physical loop force (bases may differ by a rotation in their plane)
            f_b, f_s = batch.basis[i] @ batch.lam[i], one.basis @ one.lam
            assert np.abs(f_b - f_s).max() <= 1e-6 * np.abs(f_s).max()
    # the warm start pays: loaded solves take fewer steps than cold ones
    assert np.median(e1.iterations) < np.median(e0.iterations)


def test_tangents_and_dforce_are_the_scalar_ones(robot, loads, solved):
    bs, e0, a0, e1, scalar = solved
    a1 = bs.stiffness(e1, loads)
    for eq, a, states, load in (
        (e0, a0, [s[0] for s in scalar], None),
        (e1, a1, [s[1] for s in scalar], loads),
    ):
        df = bs.dforce(eq, PARAMS)
        tan = bs.tangent(eq, df, a)
        for i, one in enumerate(states):
            robot.set_command(one.command)
            robot.data.qpos[:] = one.qpos
            mujoco.mj_fwdPosition(robot.model, robot.data)
            ref_df = robot.dforce_dtheta(PARAMS)
            np.testing.assert_allclose(df[i], ref_df, rtol=1e-9, atol=1e-9 * np.abs(ref_df).max())
            ref = bs.solver.tangent(one, take_load(load, i), ref_df)
            np.testing.assert_allclose(tan[i], ref, rtol=0, atol=1e-6 * np.abs(ref).max())


def test_stacked_kkt_and_tangent_equal_the_scalar_ones_slice_by_slice():
    rng = np.random.default_rng(0)
    a = rng.standard_normal((5, 8, 8)) + 8 * np.eye(8)
    j = rng.standard_normal((5, 2, 8))
    df = rng.standard_normal((5, 8, 3))
    k = kkt_matrix(a, j)
    t = ift_tangent(k, df)
    for i in range(5):
        assert np.array_equal(k[i], kkt_matrix(a[i], j[i]))
        np.testing.assert_allclose(t[i], ift_tangent(k[i], df[i]), rtol=1e-13, atol=1e-13)


def test_grouping_and_threads_do_not_change_the_results(robot, commands, solved):
    """Bit for bit: a configuration's solve depends on nothing but its own data."""
    _, e0, *_ = solved
    bs = BatchStatics(StaticsSolver(robot), nsim=len(commands), nthread=2)
    half = len(commands) // 2
    parts = [bs.solve(commands[:half]), bs.solve(commands[half:])]
    for name in ("qpos", "lam", "residual", "iterations"):
        assert np.array_equal(np.concatenate([getattr(p, name) for p in parts]), getattr(e0, name)), name


def test_a_degenerate_parallelogram_is_reported_not_raised(robot):
    """q3 - q2 = -120 deg puts the crank along the upper arm: the scalar solver raises (or does
    not converge); the batched one marks that configuration unacceptable and solves the others."""
    q = np.radians([[0, 30, -90, 0, 0, 0], [0, 30, 0, 0, 0, 0]])
    solver = StaticsSolver(robot)
    try:
        assert not solver.solve(q[0]).acceptable
    except StaticsError:
        pass
    e = BatchStatics(solver, nsim=2, nthread=1).solve(q)
    assert e.acceptable.tolist() == [False, True]


def test_stacked_rigid_poses_and_loop_conditioning_are_the_robots(robot, commands):
    """Robot.rigid_qpos_stack and loop_conditioning_stack row by row against the scalar rules,
    with the gaps and loop Jacobians from the batch, on commands that include degenerate loops
    (q3 - q2 swept through -120 deg, where the parallelogram folds)."""
    q = np.vstack([commands, np.radians([[0, 30, a, 0, 0, 0] for a in np.linspace(-100, -80, 9)])])
    bs = BatchStatics(StaticsSolver(robot), nsim=4, nthread=1)
    qpos = bs.rigid(q)
    jc = bs.loop_gap(bs.place(qpos))[1]
    cond = robot.loop_conditioning_stack(jc)
    for i, x in enumerate(q):
        np.testing.assert_allclose(qpos[i], robot.rigid_qpos(x), rtol=0, atol=1e-15)
        np.testing.assert_allclose(cond[i], robot.loop_conditioning(x), rtol=0, atol=1e-12)
    flags = [robot.loop_ok(x) for x in q]
    assert not all(flags) and any(flags)


def test_a_robot_without_loops_solves_as_the_scalar_statics():
    """No loop: no constraint rows (nc = 0); the equilibria are the scalar ones within the same
    bound (K^-1 applied to the two residuals, no loop term)."""
    rb = Robot.from_xml(serial_mjcf())
    rb.set_params(Params(np.array([2.0, 1.0, 3.0, 5.0]) * 1e-6))
    solver = StaticsSolver(rb)
    q = np.radians([[0.0, 20.0, -30.0, 40.0], [60.0, -10.0, 70.0, -90.0], [-120.0, 45.0, 10.0, 170.0]])
    load = Load(np.tile(rb.weight(50.0), (len(q), 1)), np.zeros((len(q), 3)), rb.payload_site)
    e = BatchStatics(solver, nsim=4, nthread=1).solve(q, load)
    assert e.basis.shape == (len(q), 0, 0) and e.converged.all()
    for i in range(len(q)):
        one = solver.solve(q[i], take_load(load, i))
        kinv = _kkt_inverse(solver, one, take_load(load, i))
        bound = 2 * np.abs(kinv).sum(axis=1).max() * (e.residual[i] + one.residual)
        assert np.abs(e.qpos[i] - one.qpos).max() <= bound


def test_a_diverging_newton_stops_before_mujoco_sees_it(robot, tmp_path, monkeypatch):
    """A Newton step to NaN or past MuJoCo's bound on a position ends that configuration
    unconverged (batched) or raises StaticsError (scalar) before mj_forward sees it: MuJoCo
    would warn "simulation is unstable", reset the data to qpos0 and write MUJOCO_LOG.TXT into
    the user's folder (found through identify's profile check on a noisy weak plan). A stiffness
    matrix of 1e-300 makes the first step fly off."""
    monkeypatch.chdir(tmp_path)
    said: list[str] = []
    before = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(said.append)
    try:
        solver = StaticsSolver(robot)
        bs = BatchStatics(solver, nsim=2, nthread=1)
        q = TABLE5[:2]
        e0 = bs.solve(q)
        nv = robot.model.nv
        flat = 1e-300 * np.eye(nv)

        def tiny(rows, qp, lm, r, stalled, iteration):
            return np.broadcast_to(flat, (len(rows), nv, nv)).copy(), np.zeros(len(rows), bool)

        e = bs.newton(q, e0.qpos + 1e-3, e0.basis, None, lam=e0.lam, stiffness=tiny)
        assert not e.converged.any() and np.isinf(e.residual).all()
        s0 = solver.solve(q[0])
        robot.set_command(q[0])
        with statics_options(robot), pytest.raises(StaticsError, match="diverged"):
            solver.newton(s0.qpos + 1e-3, s0.lam, s0.basis, None, lambda point: flat)
        assert bs.solve(q).converged.all()  # the batch is usable afterwards
    finally:
        mujoco.set_mju_user_warning(before)
    assert said == [] and not (tmp_path / "MUJOCO_LOG.TXT").exists()
