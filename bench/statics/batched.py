"""Exact static equilibria of many commands at once: bench/statics/equilibrium.py stacked on mujoco.batch.

The equilibrium is bench/statics/equilibrium.py's, unchanged: paper eq. (17), r(q, lam) = g(q) + J_c^T B lam
= 0 with the loop B^T c(q) = 0 held hard, under :func:`bench.statics.statics_options`; Newton's
constants (``tol``, ``max_iter``, ``fd_step`` of the :class:`~bench.statics.StaticsSolver` it is
built on, ``LOOP_TOL``, ``CONTRACTION``), :func:`~bench.statics.kkt_matrix`,
:func:`~bench.statics.ift_tangent` and the acceptance rule
(:func:`~bench.statics.equilibrium_acceptable`) are that module's. Only the arithmetic is
stacked over n configurations: MuJoCo's position and velocity stages and the site Jacobians
run in C for all n at once on ``mujoco.batch.Batch``'s thread pool (bit-identical to a loop of
mj_fwdPosition / mj_jacSite), the residuals, Newton steps and KKT solves in numpy on (n, ...)
arrays. Why: one scalar equilibrium costs ~0.27 ms, nearly all of it per-call Python and numpy
overhead around ~2 us of MuJoCo; stacked, that overhead is paid once per iteration for all n.

Where it deliberately differs from :meth:`StaticsSolver.solve` (the equilibrium is the same to
the solver's tolerance; tests/test_batch_statics.py checks it configuration by configuration):

* the Newton matrix is the exact forward-difference A (:meth:`BatchStatics.stiffness`, nv + 1
  stacked residuals, as :meth:`StaticsSolver.stiffness_fd`), not MuJoCo's inverse-dynamics
  derivative (mjd_inverseFD has no batched form): assembled at the start and whenever a step
  stalls, a chord otherwise (:meth:`StaticsSolver.newton` with ``refresh=1``);
* a warm start (a loaded state from its unloaded equilibrium) reuses the warm solve's pose and
  constraint basis and the exact matrix AT the warm solution, which the caller has anyway for
  the tangent, rather than the warm solve's last chord matrix;
* a configuration whose iterate is not finite or whose KKT matrix is singular does not raise
  StaticsError: its residual is reported as infinite, so it is not ``acceptable``.

The batch runs a copy of the robot's model taken at construction (its parameters and options as
they are then): after ``Robot.set_params``, :meth:`BatchStatics.sync` its ``Robot.PARAM_FIELDS``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import mujoco
import mujoco.batch
import numpy as np

from calbench.bench.model import constraint_basis_stack

from .equilibrium import (
    CONTRACTION,
    LOOP_TOL,
    MJ_MAXVAL,
    Equilibrium,
    Load,
    StaticsSolver,
    equilibrium_acceptable,
    ift_tangent,
    kkt_matrix,
    statics_options,
)

_POS = int(mujoco.mjtStage.mjSTAGE_POS)
# (rows, qpos, lam, r, stalled, iteration) -> (A (k, nv, nv), give-up mask (k,)): BatchStatics.newton's
StackedStiffness = Callable[
    [np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, int], "tuple[np.ndarray, np.ndarray]"
]
_VEL = int(mujoco.mjtStage.mjSTAGE_VEL)


def take_load(load: Load | None, rows) -> Load | None:
    """The rows of a stacked load: force and moment (n, 3) (a (3,) one applies to every row) at
    one site or at a site per row (n,)."""
    if load is None:
        return None
    f, m, site = np.asarray(load.force, float), np.asarray(load.moment, float), np.asarray(load.site)
    return Load(
        f[rows] if f.ndim == 2 else f, m[rows] if m.ndim == 2 else m, site[rows] if site.ndim else load.site
    )


@dataclass(frozen=True)
class StackedResidual:
    """:class:`bench.statics.Residual` of n configurations, with what the solve reports."""

    r: np.ndarray  # (n, nv) g + J_c^T B lam, N*m
    c_r: np.ndarray  # (n, nc) B^T c, m
    jc_r: np.ndarray  # (n, nc, nv) B^T J_c
    gap: np.ndarray  # (n,) |c|, m
    gravity: np.ndarray  # (n,) max |qfrc_bias|, N*m


@dataclass(frozen=True)
class Equilibria:
    """n solved static poses, the stacked :class:`bench.statics.Equilibrium` (same units)."""

    qpos: np.ndarray  # (n, nq)
    command: np.ndarray  # (n, n_act)
    lam: np.ndarray  # (n, nc) in the basis
    basis: np.ndarray  # (n, 3L, nc)
    residual: np.ndarray  # (n,) max |r|, N*m; inf where the solve failed
    gravity_scale: np.ndarray  # (n,) max |qfrc_bias| at the solution, N*m
    loop_violation: np.ndarray  # (n,) |c|, m
    iterations: np.ndarray  # (n,) Newton steps
    converged: np.ndarray  # (n,) bool: Newton's own criterion met
    r: np.ndarray = field(repr=False)  # (n, nv) residual vector at the solution
    jc_r: np.ndarray = field(repr=False)  # (n, nc, nv) B^T J_c at the solution
    stalls: np.ndarray = field(repr=False, default=None)  # (n,) exact matrices re-assembled on a stall

    def __len__(self) -> int:
        return len(self.qpos)

    @property
    def acceptable(self) -> np.ndarray:
        """(n,) bool: bench.statics' acceptance rule, configuration by configuration."""
        return equilibrium_acceptable(self.residual, self.gravity_scale, self.loop_violation)

    def take(self, rows) -> Equilibria:
        return Equilibria(
            **{
                k: None if getattr(self, k) is None else getattr(self, k)[rows]
                for k in self.__dataclass_fields__
            }
        )

    def equilibrium(self, i: int, act_qpos: np.ndarray) -> Equilibrium:
        """Configuration i as a scalar Equilibrium (without a Newton factor)."""
        return Equilibrium(
            qpos=self.qpos[i].copy(),
            command=self.command[i].copy(),
            deflection=self.qpos[i, act_qpos] - self.command[i],
            lam=self.lam[i].copy(),
            residual=float(self.residual[i]),
            gravity_scale=float(self.gravity_scale[i]),
            loop_violation=float(self.loop_violation[i]),
            iterations=int(self.iterations[i]),
            stalls=int(self.stalls[i]) if self.stalls is not None else 0,
            basis=self.basis[i].copy(),
        )


class BatchStatics:
    """The statics of one StaticsSolver's robot on a mujoco.batch of ``nsim`` configurations
    (grown on demand), ``nthread`` threads (0: all CPUs). Not thread-safe."""

    def __init__(self, solver: StaticsSolver, nsim: int = 256, nthread: int = 0, gravity: bool = True):
        self.solver = solver
        self.robot = solver.robot
        self.gravity = gravity
        self.nthread = nthread
        m = self.robot.model
        self.nv = m.nv
        self._chain = dof_chains(m)
        jtype = m.jnt_type[m.dof_jntid]
        self._hinge = jtype == int(mujoco.mjtJoint.mjJNT_HINGE)
        # hinges and slides: Jacobians from the joint frames of the forward pass (site_jacobian)
        self._own_jacobian = bool(np.all(self._hinge | (jtype == int(mujoco.mjtJoint.mjJNT_SLIDE))))
        self._watched: list[str] = []
        self._make(max(1, nsim))

    def watch(self, *names: str) -> None:
        """Bind more MjData outputs of the batch (mujoco.batch fills a field only once it is
        bound, and a grown batch is a new one): read them with ``self.batch.bind(name)``."""
        self._watched += [n for n in names if n not in self._watched]
        for n in names:
            self.batch.bind(n)

    def _make(self, nsim: int) -> None:
        with statics_options(self.robot, self.gravity):
            self.batch = mujoco.batch.Batch(self.robot.model, nsim, self.nthread)
        b = self.batch
        b.bind("qvel")[:] = 0.0
        self._qpos = b.bind("qpos")
        self._spring = b.expand("qpos_spring")
        self._passive = b.bind("qfrc_passive")
        self._bias = b.bind("qfrc_bias")
        self.site_xpos = b.bind("site_xpos")
        self.ten_j, self.ten_length = b.bind("ten_J"), b.bind("ten_length")  # bound before any call
        self._xaxis, self._xanchor = b.bind("xaxis"), b.bind("xanchor")
        for name in self._watched:
            b.bind(name)
        self.nsim = nsim

    def sync(self, *fields: str) -> None:
        """Copy model fields (e.g. Robot.PARAM_FIELDS after Robot.set_params) from the robot's
        live model into every simulation: the batch runs a copy taken at construction."""
        for name in fields:
            self.batch.expand(name)[:] = getattr(self.robot.model, name)

    def reserve(self, n: int) -> None:
        """Room for n configurations (a new batch when the current one is smaller)."""
        if n > self.nsim:
            self._make(max(n, 2 * self.nsim))

    # -- building blocks over simulations ``ids`` (commands set by set_commands) ---------------
    def set_commands(self, ids: np.ndarray, q: np.ndarray) -> None:
        """Commanded angles become each configuration's spring reference (Robot.set_command)."""
        self._spring[np.ix_(ids, self.robot.act_qpos)] = q

    def forward(self, ids: np.ndarray, qpos: np.ndarray, stage: int = _VEL) -> None:
        """qpos (len(ids), nq) into the batch and MuJoCo's stages up to ``stage`` for them."""
        self._qpos[ids] = qpos
        self.batch.forward(ids, stage=stage)

    def site_jacobian(self, ids: np.ndarray, site: int, rotation: bool = False):
        """d site position / d q (n, 3, nv) (and the rotational one) at the poses in the batch
        (position stage current), mj_jacSite's. For hinge and slide joints it is formed here
        from the forward pass's joint frames, column j = a_j x (p - o_j) (hinge) or a_j
        (slide) for the dofs on the site's chain, rotation a_j (hinge): no further MuJoCo call
        (mujoco.batch's jac re-runs the kinematics per configuration, which would double a
        residual's cost); tests/test_batch_statics.py checks it against mj_jacSite."""
        m = self.robot.model
        body = int(m.site_bodyid[site])
        p = self.site_xpos[ids, site]
        if not self._own_jacobian:
            jp, jr = self.batch.jac(body, p, ids)
            return (jp, jr) if rotation else jp
        dofs = np.flatnonzero(self._chain[body])
        jnt = m.dof_jntid[dofs]
        axis = self._xaxis[ids][:, jnt]  # (n, k, 3)
        hinge = self._hinge[dofs]
        col = np.where(hinge[None, :, None], _cross(axis, p[:, None, :] - self._xanchor[ids][:, jnt]), axis)
        jp = np.zeros((len(ids), 3, m.nv))
        jp[:, :, dofs] = col.transpose(0, 2, 1)
        if not rotation:
            return jp
        jr = np.zeros((len(ids), 3, m.nv))
        jr[:, :, dofs] = (axis * hinge[None, :, None]).transpose(0, 2, 1)
        return jp, jr

    def joint_axes(self, ids: np.ndarray, joints) -> np.ndarray:
        """World axes (n, k, 3) of the joints at the poses in the batch (position stage current)."""
        return self._xaxis[ids][:, joints]

    def loop_gap(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """bench.loop.loop_gap stacked: c (n, 3L) and J_c (n, 3L, nv), loop by loop."""
        xs = self.site_xpos[ids]
        gaps, jacs = [], []
        for a, b in self.robot.loops:
            gaps.append(xs[:, a] - xs[:, b])
            jacs.append(self.site_jacobian(ids, a) - self.site_jacobian(ids, b))
        if not gaps:  # a serial robot
            return np.zeros((len(ids), 0)), np.zeros((len(ids), 0, self.nv))
        if len(gaps) == 1:
            return gaps[0], jacs[0]
        return np.concatenate(gaps, axis=1), np.concatenate(jacs, axis=1)

    def basis(self, ids: np.ndarray, qpos: np.ndarray) -> np.ndarray:
        """bench.loop.constraint_basis at each configuration (n, 3L, nc)."""
        self.forward(ids, qpos, _POS)
        return constraint_basis_stack(self.loop_gap(ids)[1])

    def residual(
        self, ids: np.ndarray, qpos: np.ndarray, load: Load | None, lam: np.ndarray, basis: np.ndarray
    ) -> StackedResidual:
        """StaticsSolver.residual of each configuration (batch left at qpos)."""
        self.forward(ids, qpos)
        g = self._passive[ids] - self._bias[ids]
        if load is not None:
            n = len(ids)
            force, moment = np.broadcast_to(load.force, (n, 3)), np.broadcast_to(load.moment, (n, 3))
            sites = np.asarray(load.site)
            for site in np.unique(sites):
                rows = slice(None) if sites.ndim == 0 else sites == site
                jp, jr = self.site_jacobian(ids[rows], int(site), rotation=True)
                g[rows] += np.einsum("nij,ni->nj", jp, force[rows]) + np.einsum(
                    "nij,ni->nj", jr, moment[rows]
                )
        c, jc = self.loop_gap(ids)
        jc_r = np.einsum("nkr,nkv->nrv", basis, jc)
        r = g + np.einsum("nrv,nr->nv", jc_r, lam)
        return StackedResidual(
            r,
            np.einsum("nkr,nk->nr", basis, c),
            jc_r,
            np.sqrt(np.einsum("nk,nk->n", c, c)),
            np.abs(self._bias[ids]).max(axis=1),
        )

    def stiffness_at(
        self,
        ids: np.ndarray,
        qpos: np.ndarray,
        load: Load | None,
        lam: np.ndarray,
        basis: np.ndarray,
        r0: np.ndarray,
    ) -> np.ndarray:
        """StaticsSolver.stiffness_fd stacked: A = d r / d q (n, nv, nv) by forward differences
        (the solver's fd_step), r0 the residual at qpos. The batch is left at the last column."""
        h = self.solver.fd_step
        a = np.empty((len(ids), self.nv, self.nv))
        for j in range(self.nv):
            qp = qpos.copy()
            qp[:, j] += h
            a[:, :, j] = (self.residual(ids, qp, load, lam, basis).r - r0) / h
        return a

    # -- whole solves --------------------------------------------------------------------------
    def stiffness(self, eq: Equilibria, load: Load | None) -> np.ndarray:
        """The exact A at each equilibrium (n, nv, nv): the tangent's matrix, and the chord
        matrix of a warm start from it."""
        ids = self._ids(len(eq))
        self.set_commands(ids, eq.command)
        return self.stiffness_at(ids, eq.qpos, load, eq.lam, eq.basis, eq.r)

    def tangent(self, eq: Equilibria, dforce: np.ndarray, a: np.ndarray) -> np.ndarray:
        """dq/dtheta (n, nv, p) by :func:`bench.statics.ift_tangent`, a = :meth:`stiffness`."""
        return ift_tangent(kkt_matrix(a, eq.jc_r), dforce)[:, : self.nv]

    def place(self, qpos: np.ndarray, stage: int = _POS) -> np.ndarray:
        """Poses (n, nq) into the first n simulations, stages up to ``stage`` (kinematics for
        bound fields, Jacobians and rays); returns their simulation ids."""
        ids = self._ids(len(qpos))
        self.forward(ids, qpos, stage)
        return ids

    def rigid(self, q: np.ndarray) -> np.ndarray:
        """Robot.rigid_qpos of n commands (n, nq), the loop gaps checked on the batch."""

        def gaps(qpos: np.ndarray) -> np.ndarray:
            ids = self.place(qpos)  # may grow the batch: read its fields after
            xs = self.site_xpos[ids]
            return np.concatenate([xs[:, a] - xs[:, b] for a, b in self.robot.loops], axis=1)

        return self.robot.rigid_qpos_stack(q, gaps)

    def at(self, eq: Equilibria, stage: int = _POS) -> np.ndarray:
        """:meth:`place` the equilibria, with their commands as the springs' references."""
        self.set_commands(self._ids(len(eq)), eq.command)
        return self.place(eq.qpos, stage)

    def dforce(self, eq: Equilibria, params) -> np.ndarray:
        """d g / d theta at fixed q (n, nv, p) at each equilibrium: Robot.dforce_dtheta_stack."""
        ids = self.at(eq)
        return self.robot.dforce_dtheta_stack(
            params, eq.qpos, eq.command, self.ten_j[ids], self.ten_length[ids]
        )

    def sites(self, eq: Equilibria, sites) -> tuple[np.ndarray, np.ndarray]:
        """Positions (n, k, 3) and d position / d q (n, k, 3, nv) of k sites at each equilibrium."""
        ids = self.at(eq)
        pos = self.site_xpos[ids][:, sites]
        jac = np.stack([self.site_jacobian(ids, int(s)) for s in sites], axis=1)
        return pos, jac

    def solve(
        self,
        q: np.ndarray,
        load: Load | None = None,
        warm: Equilibria | None = None,
        warm_stiffness: np.ndarray | None = None,
        qpos0: np.ndarray | None = None,
    ) -> Equilibria:
        """Static equilibria at the commands q (n, n_act) under gravity and an optional load
        (force and moment (n, 3) or (3,), one site), the stacked :meth:`StaticsSolver.solve`.

        Cold: from the rigid poses (or qpos0), the exact matrix assembled there. Warm (e.g. the
        loaded states from their unloaded equilibria ``warm``, row by row): from the warm poses
        with their bases and the chord matrix built from ``warm_stiffness`` (:meth:`stiffness`
        of ``warm``), which differs from the new exact one by the load's curvature only."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        ids = self._ids(len(q))
        factor = None
        if warm is not None:
            qpos, basis = warm.qpos.copy(), warm.basis
            if warm_stiffness is not None:
                factor = _inverse(kkt_matrix(warm_stiffness, warm.jc_r))[0]
        else:
            qpos = self.rigid(q) if qpos0 is None else np.array(qpos0, float)
            basis = self.basis(ids, qpos)
        return self.newton(q, qpos, basis, load, factor=factor)

    def _ids(self, n: int) -> np.ndarray:
        self.reserve(n)
        return np.arange(n)

    def newton(
        self,
        q: np.ndarray,
        qpos: np.ndarray,
        basis: np.ndarray,
        load: Load | None,
        *,
        lam: np.ndarray | None = None,
        factor: np.ndarray | None = None,
        stiffness: StackedStiffness | None = None,
        max_iter: int | None = None,
    ) -> Equilibria:
        """:meth:`StaticsSolver.newton` stacked over the rows of q (n, n_act), from qpos and lam
        (default zero), refresh=1: the matrix is assembled on the first step (unless ``factor``,
        KKT inverses (n, K, K), is given) and whenever a step stalled; a chord otherwise.

        ``stiffness(rows, qpos, lam, r, stalled, iteration)`` gives A = d r / d q (k, nv, nv) for
        those rows (their iterates, residual vectors and stall flags; the batch holds the
        iterates' forward pass) and a (k,) mask of rows it gives up on
        (they end unconverged, as the scalar provider returning None); default: the exact
        forward-difference matrix (:meth:`stiffness_at`)."""
        ids = self._ids(len(q))
        self.set_commands(ids, q)
        s = self.solver
        max_iter = s.max_iter if max_iter is None else max_iter
        n, nv = len(ids), self.nv
        nc = basis.shape[2]
        qpos = np.array(qpos, dtype=float)
        lam = np.zeros((n, nc)) if lam is None else np.array(lam, dtype=float)
        if factor is None:
            factor = np.empty((n, nv + nc, nv + nc))
            fresh = np.zeros(n, bool)
        else:
            factor = np.array(factor, dtype=float)
            fresh = np.ones(n, bool)
        if stiffness is None:

            def stiffness(rows, qp, lm, r, stalled, iteration):
                return (
                    self.stiffness_at(ids[rows], qp, take_load(load, rows), lm, basis[rows], r),
                    np.zeros(len(rows), bool),
                )

        res = self.residual(ids, qpos, load, lam, basis)
        force_tol = s.tol * np.maximum(1.0, res.gravity)  # the gravity scale at the start
        # what each configuration ends with
        out_r, out_jc = res.r.copy(), res.jc_r.copy()
        out_norm = np.abs(res.r).max(axis=1)
        out_gap, out_grav = res.gap.copy(), res.gravity.copy()
        its = np.zeros(n, int)
        stalls = np.zeros(n, int)
        converged = np.zeros(n, bool)
        prev = np.full(n, np.inf)
        act = np.arange(n)  # rows still iterating
        for it in range(max_iter + 1):
            norm = np.abs(res.r).max(axis=1)
            out_r[act], out_jc[act], out_norm[act] = res.r, res.jc_r, norm
            out_gap[act], out_grav[act] = res.gap, res.gravity
            done = (norm <= force_tol[act]) & (np.abs(res.c_r).max(axis=1, initial=0.0) <= LOOP_TOL)
            converged[act[done]] = True
            bad = ~np.isfinite(norm)
            out_norm[act[bad]] = np.inf
            keep = ~(done | bad)
            if it == max_iter or not keep.any():
                break
            act, res, norm = act[keep], _rows(res, keep), norm[keep]
            stalled = norm > CONTRACTION * prev[act]
            need = stalled | ~fresh[act]
            if need.any():
                rows = act[need]
                a, give_up = stiffness(rows, qpos[rows], lam[rows], res.r[need], stalled[need], it)
                factor[rows], singular = _inverse(kkt_matrix(a, res.jc_r[need]))
                stalls[rows] += stalled[need]
                fresh[rows] = True
                out_norm[rows[singular]] = np.inf  # a singular KKT matrix: no equilibrium here
                drop = singular | give_up
                if drop.any():
                    ok = np.ones(len(act), bool)
                    ok[np.flatnonzero(need)[drop]] = False
                    act, res, norm = act[ok], _rows(res, ok), norm[ok]
                    if not len(act):
                        break
            prev[act] = norm
            step = -np.einsum("nij,nj->ni", factor[act], np.concatenate([res.r, res.c_r], axis=1))
            qpos[act] += step[:, :nv]
            lam[act] += step[:, nv:]
            its[act] += 1
            # a step to NaN or past MuJoCo's bound: no equilibrium here (MuJoCo would warn, write
            # MUJOCO_LOG.TXT into the user's folder and reset the world to qpos0)
            sane = np.all(np.abs(qpos[act]) < MJ_MAXVAL, axis=1)  # False for NaN too
            if not sane.all():
                out_norm[act[~sane]] = np.inf
                act = act[sane]
                if not len(act):
                    break
            res = self.residual(ids[act], qpos[act], take_load(load, act), lam[act], basis[act])
        return Equilibria(
            qpos=qpos,
            command=q,
            lam=lam,
            basis=basis,
            residual=out_norm,
            gravity_scale=out_grav,
            loop_violation=out_gap,
            iterations=its,
            converged=converged,
            r=out_r,
            jc_r=out_jc,
            stalls=stalls,
        )


def dof_chains(model: mujoco.MjModel) -> np.ndarray:
    """(nbody, nv) bool: the dofs that move body b (those of b and of its ancestors)."""
    out = np.zeros((model.nbody, model.nv), bool)
    for b in range(model.nbody):
        a = b
        while a > 0:
            adr, num = model.body_dofadr[a], model.body_dofnum[a]
            out[b, adr : adr + num] = True
            a = model.body_parentid[a]
    return out


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross products over the last axis (np.cross spends ~50 us on argument handling)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def _rows(res: StackedResidual, rows) -> StackedResidual:
    return StackedResidual(res.r[rows], res.c_r[rows], res.jc_r[rows], res.gap[rows], res.gravity[rows])


def _inverse(k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Stacked inverses and a (n,) mask of the singular matrices (their rows left as NaN)."""
    try:
        return np.linalg.inv(k), np.zeros(len(k), bool)
    except np.linalg.LinAlgError:
        out = np.full_like(k, np.nan)
        singular = np.zeros(len(k), bool)
        for i in range(len(k)):
            try:
                out[i] = np.linalg.inv(k[i])
            except np.linalg.LinAlgError:
                singular[i] = True
        return out, singular


__all__ = ["BatchStatics", "Equilibria", "StackedResidual", "take_load"]
