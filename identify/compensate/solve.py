"""Newton on the command: the joint command at which the identified model's LOADED tool lands
on its target (issue 26; the compensation the paper's introduction motivates).

For a nominal command q and the job's load W, the target is the tool's pose

* ``unloaded`` (default): at the equilibrium of the same (identified) model at q without W:
  the deflection the process load causes is removed, which is what a loaded/unloaded
  deflection campaign identifies;
* ``rigid``: at the rigid configuration of q (no gravity, no deflection): the self-weight sag
  is removed too, which rests on the absolute sag (the compensator's preload), poorly known
  from a deflection campaign; the predicted error says so.

The command u solves e(u) = [p(q*(u)) - p_t; log(R(q*(u)) R_t^T)] = 0, where q*(u) is the loaded
static equilibrium (bench.statics: the loop closed exactly, the compensator, gravity and W at
the tool point). Its Jacobian is the tool Jacobian times the implicit-function tangent of the
equilibrium (bench.statics.ift_tangent): the command enters the force balance only through the
drive springs, d g / d u_i = K_i on motor i's dof (paper eq. 1, the spring rests at the
command). A robot of fewer than six axes cannot hold the orientation as well: it is solved
for the position alone (least squares; the orientation error is reported). Newton converges quadratically; it stops at 1e-8 m and 1e-8 rad (the contract's
1 um and 1 urad with two orders to spare; the statics themselves are exact to ~3e-11 m).

The predicted error after compensation is first order in the parameter error: the true robot
at u puts the tool at p(u, theta) - target(theta) ~ G (theta - theta_hat), G = dp/dtheta at
the loaded equilibrium minus (unloaded target) dp/dtheta at the target's equilibrium, both by
the same implicit-function tangent with d g / d theta (bench.model.Robot.dforce_dtheta). With
the identification's full covariance Sigma, the tool position's covariance is G Sigma G^T.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from calbench.bench.core import StaticsError
from calbench.bench.model import Params
from calbench.bench.scenario import JOINT_LIMIT_TOL
from calbench.bench.statics import Equilibrium, Load, StaticsSolver, statics_options

from .job import JobPoint
from .toolpoint import ToolRobot, rotation_error, tool_jacobian, tool_pose

TARGETS = ("unloaded", "rigid")
POSITION_TOL = 1e-8  # m
ROTATION_TOL = 1e-8  # rad
MAX_STEPS = 20


@dataclass(frozen=True)
class Target:
    """Where the tool must be: position (m), orientation, and its sensitivity to theta (3, p)."""

    position: np.ndarray
    rotation: np.ndarray
    dpos_dtheta: np.ndarray
    drot_dtheta: np.ndarray


@dataclass(frozen=True)
class PointResult:
    """One job point's compensation (SI; angles in rad)."""

    index: int
    nominal: np.ndarray
    command: np.ndarray  # the compensated command; the nominal one when not reached
    converged: bool
    reason: str | None  # why the point cannot be reached (None when it is)
    iterations: int
    position_error_m: float  # the model's own |p - target| at the command (nan when not reached)
    orientation_error_rad: float
    predicted_deviation_m: float  # the model's |p - target| at the nominal command (uncompensated)
    predicted_orientation_deviation_rad: float
    position_covariance: np.ndarray  # (3, 3) m^2, of the true tool position after compensation
    orientation_std_rad: float  # sqrt of the trace of the rotation's covariance
    target_position: np.ndarray
    dpos_dtheta: np.ndarray | None = None  # (3, p): G, the true error after is G (theta - theta_hat)

    @property
    def predicted_error_std_m(self) -> float:
        return float(math.sqrt(max(np.trace(self.position_covariance), 0.0)))


def command_step(jac: np.ndarray, err: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """Newton steps (n, N) on the commands, stacked: J du = -e (J (n, m, N) from the tangent,
    e (n, m)), and, where J has more columns than rank (a redundant robot, or one of fewer than
    six axes solved for the position only), the correction u - q (``shift``) pulled towards zero
    in J's null space, so that the command found is the smallest correction: unique, whatever
    the start (the path's warm start, or the nominal command)."""
    pinv = np.linalg.pinv(jac)
    null = np.eye(jac.shape[2]) - pinv @ jac
    return -np.einsum("nij,nj->ni", pinv, err) - np.einsum("nij,nj->ni", null, shift)


class Compensator:
    """The identified model (``params``, covariance ``cov``) on a robot with its tool site."""

    def __init__(self, tool: ToolRobot, params: Params, cov: np.ndarray, target: str = "unloaded"):
        if target not in TARGETS:
            raise ValueError(f"target must be one of {TARGETS}, got {target!r}")
        self.robot, self.site = tool
        self.params = params
        self.cov = np.asarray(cov, dtype=float)
        self.target_kind = target
        self.robot.set_params(params)
        self.solver = StaticsSolver(self.robot)
        m = self.robot.model
        self._a = m.jnt_stiffness[self.robot.act_joint].copy()
        self._c = m.jnt_stiffnesspoly[self.robot.act_joint, 1].copy()
        # a robot of fewer than six axes cannot hold the orientation too: the position only
        self.orient = self.robot.n_act >= 6
        self.rows = slice(0, 6 if self.orient else 3)

    # -- pieces ----------------------------------------------------------------------------
    def load(self, p: JobPoint) -> Load:
        if p.payload is not None:
            return Load.mass(self.robot, p.payload)
        return Load(np.array(p.wrench[:3]), np.array(p.wrench[3:]), self.site)

    def equilibrium(self, u: np.ndarray, load: Load | None, sag: np.ndarray | None = None) -> Equilibrium:
        """The static equilibrium at command u, Newton started at the rigid pose plus ``sag``
        (an earlier equilibrium's qpos minus its rigid pose: a warm start)."""
        start = None if sag is None else self.robot.rigid_qpos(u) + sag
        eq = self.solver.solve(u, load, qpos0=start)
        if not eq.acceptable:
            raise StaticsError(
                f"no equilibrium at command {np.degrees(u).round(3).tolist()} deg "
                f"(residual {eq.residual:.3g} N*m after {eq.iterations} steps)"
            )
        return eq

    def tangents(self, eq: Equilibrium, load: Load | None) -> tuple[np.ndarray, np.ndarray]:
        """(dq/du (nv, N), dq/dtheta (nv, p)) at an equilibrium, one KKT matrix for both."""
        rb = self.robot
        rb.set_command(eq.command)
        with statics_options(rb):
            self.solver.forward(eq.qpos, velocity=False)
            d_theta = rb.dforce_dtheta(self.params)
        x = eq.deflection
        d_u = np.zeros((rb.model.nv, rb.n_act))
        # g_i = -(a x + c x^3) with x = q_i - u_i (MuJoCo's stiffness polynomial; c only from a
        # truth's joint_nonlinearity): d g_i / d u_i = a + 3 c x^2
        d_u[rb.act_dof, np.arange(rb.n_act)] = self._a + 3.0 * self._c * x * x
        t = self.solver.tangent(eq, load, np.hstack([d_u, d_theta]))
        return t[:, : rb.n_act], t[:, rb.n_act :]

    def target(self, q: np.ndarray) -> Target:
        p = self.cov.shape[0]
        if self.target_kind == "rigid":
            pos, rot = tool_pose(self.robot, self.site, self.robot.rigid_qpos(q))
            return Target(pos, rot, np.zeros((3, p)), np.zeros((3, p)))
        eq = self.equilibrium(q, None)
        pos, rot = tool_pose(self.robot, self.site, eq.qpos)
        _, dq = self.tangents(eq, None)
        jac = tool_jacobian(self.robot, self.site, eq.qpos)
        return Target(pos, rot, jac[:3] @ dq, jac[3:] @ dq)

    def error(self, eq: Equilibrium, tgt: Target) -> np.ndarray:
        pos, rot = tool_pose(self.robot, self.site, eq.qpos)
        return np.concatenate([pos - tgt.position, rotation_error(rot, tgt.rotation)])

    # -- one point -------------------------------------------------------------------------
    def sag(self, eq: Equilibrium) -> np.ndarray:
        """qpos minus the rigid pose of its command: what warm-starts a nearby solve."""
        return eq.qpos - self.robot.rigid_qpos(eq.command)

    def point(
        self, index: int, p: JobPoint, u0: np.ndarray | None = None, sag: np.ndarray | None = None
    ) -> tuple[PointResult, Equilibrium | None]:
        """Compensate one point from the command guess u0 (default: the nominal command) and
        the warm start ``sag`` (:meth:`equilibrium`)."""
        q = np.asarray(p.q, dtype=float)
        load = self.load(p)
        nan3 = np.full((3, 3), np.nan)
        if not self.robot.loop_ok(q):
            why = "loop degeneracy: the nominal command is too close to a degenerate loop (bench.model.LOOP_MARGIN)"
            return self._unreached(index, q, why, 0, nan3), None
        try:
            tgt = self.target(q)
            dev = self.error(self.equilibrium(q, load, sag), tgt)
        except StaticsError as exc:
            return self._unreached(index, q, f"no equilibrium at the nominal command: {exc}", 0, nan3), None
        u = q.copy() if u0 is None else np.asarray(u0, dtype=float).copy()
        eq, it = None, 0
        try:
            while True:
                eq = self.equilibrium(u, load, sag)
                sag = self.sag(eq)
                e = self.error(eq, tgt)
                du, dth = self.tangents(eq, load)
                jac = tool_jacobian(self.robot, self.site, eq.qpos)
                done = np.linalg.norm(e[:3]) <= POSITION_TOL and (
                    np.linalg.norm(e[3:]) <= ROTATION_TOL or not self.orient
                )
                if done or it == MAX_STEPS:
                    break
                u = u + command_step((jac @ du)[None, self.rows], e[None, self.rows], (u - q)[None])[0]
                it += 1
        except (StaticsError, np.linalg.LinAlgError) as exc:
            return self._unreached(index, q, f"no equilibrium on the way: {exc}", it, nan3, dev, tgt), None
        g_pos = jac[:3] @ dth - tgt.dpos_dtheta
        g_rot = jac[3:] @ dth - tgt.drot_dtheta
        cov = g_pos @ self.cov @ g_pos.T
        rot_std = float(math.sqrt(max(np.trace(g_rot @ self.cov @ g_rot.T), 0.0)))
        reason = (
            None
            if done
            else f"Newton did not converge in {MAX_STEPS} steps (|error| {np.linalg.norm(e[:3]):.3g} m)"
        )
        if reason is None:
            reason = self._unreachable(u)
        res = PointResult(
            index,
            q,
            u if reason is None else q,
            reason is None,
            reason,
            it,
            float(np.linalg.norm(e[:3])),
            float(np.linalg.norm(e[3:])),
            float(np.linalg.norm(dev[:3])),
            float(np.linalg.norm(dev[3:])),
            0.5 * (cov + cov.T),
            rot_std,
            tgt.position,
            g_pos,
        )
        return res, eq if reason is None else None

    def _unreachable(self, u: np.ndarray, loop_ok: bool | None = None) -> str | None:
        """Why command u cannot be sent (a joint limit, a degenerate loop), or None; ``loop_ok``
        if already known (bench.model.Robot.loop_ok of u)."""
        rb = self.robot
        for j, (lo, hi) in enumerate(rb.limits()):
            if not lo - JOINT_LIMIT_TOL <= u[j] <= hi + JOINT_LIMIT_TOL:
                return (
                    f"joint limit: the compensated q{j + 1} = {math.degrees(u[j]):.4f} deg is outside "
                    f"[{math.degrees(lo):.3f}, {math.degrees(hi):.3f}] deg"
                )
        if not (rb.loop_ok(u) if loop_ok is None else loop_ok):
            return "loop degeneracy: the compensated command is too close to a degenerate loop (bench.model.LOOP_MARGIN)"
        return None

    def _unreached(self, index, q, reason, it, cov, dev=None, tgt=None) -> PointResult:
        nan = float("nan")
        return PointResult(
            index,
            q,
            q,
            False,
            reason,
            it,
            nan,
            nan,
            nan if dev is None else float(np.linalg.norm(dev[:3])),
            nan if dev is None else float(np.linalg.norm(dev[3:])),
            cov,
            nan,
            np.full(3, np.nan) if tgt is None else tgt.position,
        )

    # -- a path ----------------------------------------------------------------------------
    def path(self, points: tuple[JobPoint, ...]) -> list[PointResult]:
        """Every point in order, each started from the previous point's correction (u - q) and
        its equilibrium's deflection: neighbouring points of a path deflect alike."""
        out: list[PointResult] = []
        shift, sag = None, None
        for i, p in enumerate(points):
            u0 = None if shift is None else np.asarray(p.q) + shift
            res, eq = self.point(i, p, u0, sag)
            out.append(res)
            if res.converged and eq is not None:
                shift = res.command - res.nominal
                sag = self.sag(eq)
        return out


__all__ = ["command_step", "TARGETS", "POSITION_TOL", "ROTATION_TOL", "Compensator", "PointResult", "Target"]
