"""The compensation of a long job at once: :class:`~calbench.identify.compensate.Compensator`'s
Newton on the command, stacked over the job's points on ``mujoco.batch``
(bench.statics.BatchStatics: the same equilibrium, Newton constants and tangent, with MuJoCo's
stages run in C for all points and the arithmetic in numpy on stacked arrays).

Same targets, tolerances, warm start of the equilibria (the previous step's sag), reasons and
predicted covariance as the scalar loop; it differs only in where Newton on u starts (every
point at its nominal command: the points are solved together, not one after another) and in
the exact-difference matrix of each equilibrium (BatchStatics'). tests/test_compensate.py holds
the two to each other point by point.
"""

from __future__ import annotations

import math

import numpy as np

from calbench.bench.model import LOOP_MARGIN
from calbench.bench.statics import BatchStatics, Equilibria, Load, kkt_matrix, take_load

from .job import JobPoint
from .solve import MAX_STEPS, POSITION_TOL, ROTATION_TOL, Compensator, PointResult, command_step

CHUNK = 2048  # points solved together (memory: a few MB per 1000 points)
# From this many points a job is compensated here rather than by the scalar loop (about 5 x less
# CPU a point; the two agree to 1e-8 rad, tests/test_compensate.py)
BATCH_MIN = 100


def rotation_errors(r: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(n, 3) rotation vectors of r target^T (n, 3, 3 each), world frame, for angles below pi."""
    m = r @ np.swapaxes(target, 1, 2)
    v = 0.5 * np.stack([m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1]], axis=1)
    s = np.linalg.norm(v, axis=1)  # sin(angle)
    c = 0.5 * (np.trace(m, axis1=1, axis2=2) - 1.0)
    angle = np.arctan2(s, c)
    scale = np.where(s > 1e-12, angle / np.maximum(s, 1e-300), 1.0)
    return v * scale[:, None]


class _Stacked:
    """The batch, the loads and the tool of one chunk of points."""

    def __init__(self, comp: Compensator, batch: BatchStatics, points: tuple[JobPoint, ...]):
        self.comp, self.batch = comp, batch
        rb = comp.robot
        n = len(points)
        force, moment = np.zeros((n, 3)), np.zeros((n, 3))
        sites = np.full(n, comp.site, dtype=int)
        for i, p in enumerate(points):
            if p.payload is not None:
                force[i], sites[i] = rb.weight(p.payload), rb.payload_site
            else:
                force[i], moment[i] = p.wrench[:3], p.wrench[3:]
        self.load = Load(force, moment, sites)
        self.xmat = None

    def pose(self, eq: Equilibria | None, qpos: np.ndarray | None = None):
        """Tool positions (n, 3), orientations (n, 3, 3) and Jacobians (n, 6, nv) at equilibria
        (or at poses qpos)."""
        b = self.batch
        ids = b.at(eq) if eq is not None else b.place(qpos)
        xmat = b.batch.bind("site_xmat")
        site = self.comp.site
        jp, jr = b.site_jacobian(ids, site, rotation=True)
        return (
            b.site_xpos[ids, site].copy(),
            xmat[ids, site].reshape(-1, 3, 3).copy(),
            np.concatenate([jp, jr], 1),
        )

    def tangents(self, eq: Equilibria, load: Load | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(dq/du (n, nv, N), dq/dtheta (n, nv, p)) at the equilibria (Compensator.tangents),
        and the exact matrix A (n, nv, nv) they were taken with."""
        b, comp = self.batch, self.comp
        rb = comp.robot
        a = b.stiffness(eq, load)
        d_theta = b.dforce(eq, comp.params)
        x = eq.qpos[:, rb.act_qpos] - eq.command
        d_u = np.zeros((len(eq), rb.model.nv, rb.n_act))
        d_u[:, rb.act_dof, np.arange(rb.n_act)] = comp._a + 3.0 * comp._c * x * x
        t = b.tangent(eq, np.concatenate([d_u, d_theta], axis=2), a)
        return t[:, :, : rb.n_act], t[:, :, rb.n_act :], a

    def resolve(self, u: np.ndarray, rows: np.ndarray, prev: Equilibria, a: np.ndarray) -> Equilibria:
        """The loaded equilibria at new commands u from the previous ones: started at the rigid
        pose plus the previous sag, in the previous constraint basis, with the previous exact
        matrix as the chord (a neighbouring command's: the bench's warm start)."""
        b = self.batch
        qpos0 = b.rigid(u) + (prev.qpos - b.rigid(prev.command))
        factor = np.linalg.inv(kkt_matrix(a, prev.jc_r))
        return b.newton(u, qpos0, prev.basis, take_load(self.load, rows), lam=prev.lam, factor=factor)


def _loops_ok(batch: BatchStatics, q: np.ndarray) -> np.ndarray:
    """(n,) bench.model.Robot.loop_ok of n commands, their rigid poses on the batch."""
    rb = batch.robot
    if not rb.loops:
        return np.ones(len(q), bool)
    ids = batch.place(batch.rigid(q))
    return np.all(rb.loop_conditioning_stack(batch.loop_gap(ids)[1]) >= LOOP_MARGIN, axis=1)


def compensate_batch(
    comp: Compensator, points: tuple[JobPoint, ...], chunk: int = CHUNK
) -> list[PointResult]:
    """Every point of the job (PointResult, in order), CHUNK points at a time."""
    batch = BatchStatics(comp.solver, nsim=min(max(len(points), 1), chunk), nthread=0)
    batch.watch("site_xmat")
    out: list[PointResult] = []
    for start in range(0, len(points), chunk):
        out += _chunk(comp, batch, points[start : start + chunk], start)
    return out


def _chunk(
    comp: Compensator, batch: BatchStatics, points: tuple[JobPoint, ...], first: int
) -> list[PointResult]:
    st = _Stacked(comp, batch, points)
    n, p = len(points), comp.cov.shape[0]
    q = np.array([pt.q for pt in points], dtype=float)
    idx = np.arange(n)
    reason: list[str | None] = [None] * n
    for i in np.flatnonzero(~_loops_ok(batch, q)):
        reason[i] = (
            "loop degeneracy: the nominal command is too close to a degenerate loop (bench.model.LOOP_MARGIN)"
        )
    # the targets
    if comp.target_kind == "rigid":
        pos_t, rot_t, _ = st.pose(None, batch.rigid(q))
        g_t = np.zeros((n, 6, p))
    else:
        eq0 = batch.solve(q)
        _, dth0, _ = st.tangents(eq0, None)
        pos_t, rot_t, jac0 = st.pose(eq0)
        g_t = jac0 @ dth0
        for i in np.flatnonzero(~eq0.acceptable):
            reason[i] = reason[i] or "no equilibrium at the nominal command (unloaded)"

    def error(eq: Equilibria, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pos, rot, jac = st.pose(eq)
        return np.concatenate([pos - pos_t[rows], rotation_errors(rot, rot_t[rows])], axis=1), jac

    eqn = batch.solve(q, st.load)
    dev, _ = error(eqn, idx)
    for i in np.flatnonzero(~eqn.acceptable):
        reason[i] = reason[i] or "no equilibrium at the nominal command"
    # Newton on u over the rows still iterating; its first iterate (u = q) is eqn
    u = q.copy()
    err = np.full((n, 6), np.nan)
    g = np.full((n, 6, p), np.nan)
    its = np.zeros(n, int)
    act = np.array([i for i in range(n) if reason[i] is None], dtype=int)
    eq, a = eqn.take(act), None
    for it in range(MAX_STEPS + 1):
        if not len(act):
            break
        if it:
            eq = st.resolve(u[act], act, eq, a)
        bad = ~eq.acceptable
        for i in act[bad]:
            reason[i] = "no equilibrium on the way"
        e, jac = error(eq, act)
        du, dth, a = st.tangents(eq, take_load(st.load, act))
        err[act], g[act], its[act] = e, jac @ dth - g_t[act], it
        done = (np.linalg.norm(e[:, :3], axis=1) <= POSITION_TOL) & (
            (np.linalg.norm(e[:, 3:], axis=1) <= ROTATION_TOL) | (not comp.orient)
        )
        keep = ~(done | bad)
        if it == MAX_STEPS:
            for i in act[keep]:
                reason[i] = (
                    f"Newton did not converge in {MAX_STEPS} steps (|error| {np.linalg.norm(err[i, :3]):.3g} m)"
                )
            break
        jk, ek = (jac @ du)[keep][:, comp.rows], e[keep][:, comp.rows]
        eq, a, act = eq.take(keep), a[keep], act[keep]
        u[act] += command_step(jk, ek, u[act] - q[act])
    results = []
    loops = _loops_ok(batch, u)
    for i in range(n):
        why = reason[i] or comp._unreachable(u[i], bool(loops[i]))
        gi = g[i]
        cov = np.full((3, 3), np.nan) if np.isnan(gi).any() else gi[:3] @ comp.cov @ gi[:3].T
        rot_var = float("nan") if np.isnan(gi).any() else float(np.trace(gi[3:] @ comp.cov @ gi[3:].T))
        results.append(
            PointResult(
                first + i,
                q[i],
                u[i] if why is None else q[i],
                why is None,
                why,
                int(its[i]),
                float(np.linalg.norm(err[i, :3])),
                float(np.linalg.norm(err[i, 3:])),
                float(np.linalg.norm(dev[i, :3])),
                float(np.linalg.norm(dev[i, 3:])),
                0.5 * (cov + cov.T),
                math.sqrt(max(rot_var, 0.0)) if math.isfinite(rot_var) else rot_var,
                pos_t[i],
                None if np.isnan(gi).any() else gi[:3].copy(),
            )
        )
    return results


__all__ = ["BATCH_MIN", "CHUNK", "compensate_batch", "rotation_errors"]
