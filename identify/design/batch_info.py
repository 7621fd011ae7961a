"""Feasibility and exact information of a chunk of candidate commands at once (issue 16).

The rules and the information are identify/design/candidates.py's (its module docstring defines
both; :class:`~.candidates.Feasibility` decides the rules, stacked, and :class:`~.candidates.InfoEngine`
holds the prior, the tracker model and the statics solver); this module evaluates them for
many commands per call instead of one, because one at a time costs ~2 ms per candidate of
Python and numpy overhead around a few microseconds of MuJoCo:

* the rigid poses' kinematics and collisions on mujoco.batch (one call for the chunk);
* the equilibria, exact stiffness matrices and IFT tangents by bench/statics/batched.py, each
  loaded state warm-started from its own unloaded equilibrium with the exact matrix there
  (the one its tangent needs anyway), so each state is solved and differentiated once;
* the equilibrium rules on the batched poses: collision, the §3.3 clearance, visibility by
  mj_ray through mujoco.batch's ``ray``;
* the whitened blocks in stacked numpy.

Cheapest rejection first: every equilibrium rule must hold in BOTH states, so a command that
fails one at its unloaded equilibrium fails for every load and its loaded states are never
solved. The result equals the scalar chunk (candidates.scalar_block, InfoEngine.pose per
candidate): same candidates, blocks within the statics' tolerance (tests/test_design_batch.py).
"""

from __future__ import annotations

import time
from collections import defaultdict

import mujoco
import mujoco.batch
import numpy as np

from calbench.bench.model import LOOP_MARGIN
from calbench.bench.statics import BatchStatics, Equilibria, Load
from calbench.bench.tracker import BLOCKING_GROUPS, sight_lines, unoccluded

from .engine import InfoEngine
from .feasibility import COMMAND_RULES, RULES, horizontal_clearance, lateral_wrench

_POS = int(mujoco.mjtStage.mjSTAGE_POS)


class _Collider:
    """The collision model's contacts (Feasibility.collides, within the clearance) for many
    poses: its position stage, which runs mj_collision, on a mujoco.batch."""

    def __init__(self, model: mujoco.MjModel, nthread: int):
        self.model, self.nthread = model, nthread
        self.nsim = 0

    def collides(self, qpos: np.ndarray) -> np.ndarray:
        n = len(qpos)
        if n > self.nsim:
            self.nsim = max(n, 2 * self.nsim, 64)
            self.batch = mujoco.batch.Batch(self.model, self.nsim, self.nthread)
            self._qpos, self._ncon = self.batch.bind("qpos"), self.batch.bind("ncon")
        if n == 0:
            return np.zeros(0, bool)
        self._qpos[:n] = qpos
        self.batch.forward(np.arange(n), stage=_POS)
        return self._ncon[:n] > 0


class BatchInfo:
    """InfoEngine.pose for a chunk of commands, on ``nthread`` threads (0: all CPUs)."""

    def __init__(self, engine: InfoEngine, nthread: int = 0):
        self.eng = engine
        self.statics = BatchStatics(engine.solver, nsim=256, nthread=nthread)
        self.statics.watch("xpos", "xipos")
        self.collider = _Collider(engine.feas.cmodel, nthread)
        self.sites = engine.robot.reflector_sites
        self.seconds: dict[str, float] = defaultdict(float)  # wall time per phase of block()
        self._clock = 0.0

    def _phase(self, name: str) -> None:
        """Charge the time since the last call to ``name`` (benchmarks/candidates_bench.py)."""
        now = time.perf_counter()
        self.seconds[name] += now - self._clock
        self._clock = now

    # -- rules ---------------------------------------------------------------------------------
    def first_command_violation(self, q: np.ndarray) -> np.ndarray:
        """(n,) index into COMMAND_RULES of each command's first violated rule, -1 if none.
        The collision model runs only where the cheaper rules passed."""
        rb, feas, bs = self.eng.robot, self.eng.feas, self.statics
        qpos = bs.rigid(q)
        ids = bs.place(np.where(np.isfinite(qpos), qpos, 0.0))  # a loop that did not close: degenerate
        wrist = bs.batch.bind("xpos")[ids][:, feas.wrist]
        jc = np.where(np.isfinite(qpos).all(axis=1)[:, None, None], bs.loop_gap(ids)[1], np.nan)
        loop_ok = np.all(rb.loop_conditioning_stack(jc) >= LOOP_MARGIN, axis=1)
        collides = np.zeros(len(q), bool)
        bad = feas.command_violations(q, wrist, collides, loop_ok)
        rest = ~bad.any(axis=1)
        collides[rest] = self.collider.collides(qpos[rest])
        bad[:, COMMAND_RULES.index("self_collision")] = collides
        return np.where(bad.any(axis=1), bad.argmax(axis=1), -1)

    def state(self, eq: Equilibria) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """What the equilibrium rules need of each state: acceptable (n,), collides (n,),
        clearance (n,) m and the reflectors seen (n, k). Rows that are not acceptable (a failed
        solve: the pose may not be finite) are not evaluated further (they fail anyway)."""
        n, k = len(eq), len(self.sites)
        ok = eq.acceptable
        collides, clearance, visible = np.zeros(n, bool), np.zeros(n), np.zeros((n, k), bool)
        if ok.any():
            sub = eq.take(ok)
            ids = self.statics.place(sub.qpos)  # may grow the batch: take it after
            feas, b = self.eng.feas, self.statics.batch
            clearance[ok] = horizontal_clearance(
                b.bind("xipos")[ids][:, feas.masses],
                b.bind("xanchor")[ids][:, feas.hinges],
                b.bind("xaxis")[ids][:, feas.hinges],
            )
            origin, unit, dist = sight_lines(self.eng.scn.tracker, self.statics.site_xpos[ids][:, self.sites])
            hit = b.ray(origin, unit, geomgroup=BLOCKING_GROUPS, flg_static=True, bodyexclude=-1, ids=ids)[0]
            visible[ok] = unoccluded(hit, dist)
            collides[ok] = self.collider.collides(sub.qpos)
        return ok, collides, clearance, visible

    def violations(self, *states) -> np.ndarray:
        """(n,) bool: some equilibrium rule fails over the given states (each :meth:`state`)."""
        stacked = [np.stack(x, axis=1) for x in zip(*states)]
        return self.eng.feas.equilibrium_violations(*stacked, require_all_visible=True)[0].any(axis=1)

    # -- information ---------------------------------------------------------------------------
    def site_gradients(
        self, eq: Equilibria, load: Load | None, a: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Reflector positions (n, k, 3) and d position / d theta (n, k, 3, p) at each
        equilibrium (InfoEngine._site_jac): the IFT tangent with the exact matrix ``a``."""
        bs = self.statics
        tangent = bs.tangent(eq, bs.dforce(eq, self.eng.params0), a)
        pos, jac = bs.sites(eq, self.sites)
        return pos, jac @ tangent[:, None]

    def blocks(self, p0, g0, p1, g1) -> np.ndarray:
        """Whitened, normalised regressors (n, 3k, p) from both states (InfoEngine.pose)."""
        n, k = p0.shape[:2]
        jac = (g1 - g0) * self.eng.theta0
        linv = np.linalg.inv(np.linalg.cholesky(self.eng.sigma_dp_blocks(p0, p1)))
        return np.einsum("nij,njp->nip", linv, jac.reshape(n, 3 * k, self.eng.n_params))

    # -- the chunk -----------------------------------------------------------------------------
    def block(self, q, signs, u_lat, u_vert, p_vertical: float, p_lateral: float) -> dict:
        """candidates.scalar_block for a chunk of raw commands, batched: the feasible candidates
        as (q, wrench, kind, block) in command order, the count of rejections by first rule,
        and how many commands passed the command rules with a load."""
        eng, st, rb = self.eng, self.eng.settings, self.eng.robot
        q = np.asarray(q, float)
        rejected = {r: 0 for r in RULES}
        self._clock = time.perf_counter()
        first = self.first_command_violation(q)
        self._phase("command rules")
        for r, c in zip(COMMAND_RULES, np.bincount(first[first >= 0], minlength=len(COMMAND_RULES))):
            rejected[r] += int(c)
        vertical = np.concatenate([rb.weight(eng.scn.load_mass), np.zeros(3)])
        cmd, wrench, kind = [], [], []  # one row per (command, load), loads in order
        commands = []
        for i in np.flatnonzero(first < 0):
            loads = []
            if u_vert[i] < p_vertical:
                loads.append((vertical, 0))
            if u_lat[i] < p_lateral and st.lateral_force > 0:
                loads.append((lateral_wrench(q[i, 0], signs[i], st.lateral_force), 1))
            if loads:
                commands.append(i)
                for w, kd in loads:
                    cmd.append(len(commands) - 1)
                    wrench.append(w)
                    kind.append(kd)
        out = {"candidates": [], "rejected": rejected, "passed": len(commands)}
        if not commands:
            return out
        cmd, wrench, kind = np.array(cmd), np.array(wrench), np.array(kind)
        qc = q[commands]
        bs = self.statics
        # unloaded equilibria and their rules: a failure there rejects every load of the command
        e0 = bs.solve(qc)
        self._phase("unloaded equilibria")
        s0 = self.state(e0)
        good0 = ~self.violations(s0)
        self._phase("equilibrium rules")
        rows = np.flatnonzero(good0[cmd])
        rejected["visibility"] += len(cmd) - len(rows)  # equilibrium rules, as the scalar chunk counts
        if not len(rows):
            return out
        keep = np.flatnonzero(good0)
        a0 = np.zeros((len(qc), bs.nv, bs.nv))
        a0[keep] = bs.stiffness(e0.take(keep), None)
        self._phase("stiffness matrices")
        # loaded equilibria, warm from their unloaded ones, and the rules over both states
        src = cmd[rows]
        load = Load(wrench[rows, :3], wrench[rows, 3:], rb.payload_site)
        e1 = bs.solve(qc[src], load, warm=e0.take(src), warm_stiffness=a0[src])
        self._phase("loaded equilibria")
        s1 = self.state(e1)
        ok = ~self.violations(tuple(x[src] for x in s0), s1)
        self._phase("equilibrium rules")
        rejected["visibility"] += int((~ok).sum())
        if not ok.any():
            return out
        rows, src = rows[ok], src[ok]
        e1, load = e1.take(ok), Load(load.force[ok], load.moment[ok], load.site)
        # tangents at both states, once each (an unloaded one serves all its loads)
        used = np.unique(src)
        a1 = bs.stiffness(e1, load)
        self._phase("stiffness matrices")
        p0, g0 = self.site_gradients(e0.take(used), None, a0[used])
        at = np.searchsorted(used, src)
        p1, g1 = self.site_gradients(e1, load, a1)
        blocks = self.blocks(p0[at], g0[at], p1, g1)
        self._phase("tangents and blocks")
        qr = q[commands][src]
        out["candidates"] = [(qr[j], wrench[r], int(kind[r]), blocks[j]) for j, r in enumerate(rows)]
        return out


__all__ = ["BatchInfo"]
