"""Discovery, part 1: the candidate library and fitting a model with effects in the loop.

The LIBRARY is every effect that bench/model/effects/'s ``@register_effect`` puts in discovery, with the
structural options it declares there for the robot: `link_compliance` on the robot's
calbench:links (the FANUC's upper arm and forearm), `joint_nonlinearity` on every actuated
joint, `base_compliance`, `compensator` where calbench:compensator_sites names its mounts,
`tracker_drift` (measurement side), with their priors. These are the same effects the bench puts
in the simulated truth. Nothing here chooses between them: identify/discover/workflow.py does
(search.py, decide.py) and knows nothing about any single effect. Adding a candidate =
registering an effect in bench/model/effects/.

FITTING. A candidate model is the user's MJCF with the effects applied (`apply_effects`); its
parameters are the robot's theta (bench/model/params.py; the FANUC's [k1..k6, K_C, s0]) followed by
every effect's own parameters, in order. :class:`AugmentedForward` is the exact forward model of
identify/core/forward.py (same KKT-Newton statics, warm starts, implicit-function Jacobian) with
these generalisations:

* parameters are written by ``Robot.set_params`` and then each effect's ``Effect.set_params``
  (no recompilation); an effect that owns a base quantity (the compensator added to a model
  without one) overrides it, and the overridden base columns come out exactly zero;
* an effect writes only spring values (bench/model/effects/'s rule, tests/test_discover.py), so the
  springs' part of the KKT stiffness matrix is analytic for every spring of the model and the
  rest (A_base: gravity's and the load's geometric stiffness, the loop's curvature) never
  depends on a parameter: it is not re-taken when an effect's parameters change;
* dg/dtheta at fixed q (the right-hand side of the implicit function theorem): the base
  columns are ``Robot.dforce_dtheta``'s (exactly zero where an effect owns the quantity); an
  effect's columns by the chain rule through the spring values it writes (their derivatives by
  central differences of set_params once per theta, the force's derivative in them analytic
  in q), equal to central differences of MuJoCo's passive force to ~1e-10 (the fallback);
* measurement-side effects add their term to the deflections after the statics.

:func:`fit` is identify/core/leastsq.py's Levenberg-Marquardt on the whitened residual (the
maximum-likelihood estimate for the tracker's Gaussian noise), with bounds by an active set
and minimum-norm steps: an effect parameter that the plan cannot separate from the base
parameters (e.g. in-plane forearm bending, exactly a k3 through the parallelogram) is left
where it is, so that it never costs the base model anything, and any base parameter still
unidentifiable is held as in identify/methods/onestep.py.
"""

from __future__ import annotations

import time
from pathlib import Path

import mujoco
import numpy as np

from calbench.bench.model import ParamLayout, Robot
from calbench.bench.model.effects import (
    DISCOVERY_OPTIONS,
    Effect,
    ObservationRows,
    apply_effects,
    discovery_library,
    priors,
)
from calbench.bench.tracker import tracker_rotation
from calbench.identify.core import (
    DISCOVER_RANK_TOL,
    Fit,
    ForwardModel,
    PoseDesign,
    Whitener,
    analyze,
    at_bounds,
    covariance,
    design_from_observations,
    levenberg_marquardt,
)

# --------------------------------------------------------------------------- the library

COST_TOL = 1e-3  # chi2 units: a step gaining (or promising) less ends the fit
# every spring value of a model: what Robot.set_params and the effects may write (bench/model/effects/'s
# rule), synced into the batched statics' copy of the model after each write
SPRING_FIELDS = (
    "jnt_stiffness",
    "jnt_stiffnesspoly",
    "tendon_stiffness",
    "tendon_stiffnesspoly",
    "tendon_lengthspring",
)
STALL_LIMIT = 8  # Newton iterations a stalling step may re-assemble A_base + S (analytic S)
# the base parameters' bounds: ParamLayout.lower / .upper (bench/model/params.py)


DISCOVERY_EFFECTS = tuple(DISCOVERY_OPTIONS)  # the effects @register puts in discovery's library


def library(robot: Robot) -> list[Effect]:
    """Every candidate effect with its structural options on this robot (bench/model/effects/'s
    registry)."""
    return discovery_library(robot)


def label(effect: Effect) -> str:
    return effect.name + (f"[{effect.detail}]" if effect.detail else "")


def effect_priors(effect: Effect) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(start, lower bound, upper bound, size) of an effect's parameters (bench/model/effects/)."""
    pri = priors(effect)
    return tuple(np.array([getattr(p, k) for p in pri], float) for k in ("start", "lower", "upper", "size"))


def param_names(layout: ParamLayout, effects: list[Effect]) -> list[str]:
    return list(layout.names) + [f"{label(e)}.{n}" for e in effects for n in e.param_names]


def param_units(layout: ParamLayout, effects: list[Effect]) -> list[str]:
    return list(layout.units) + [u for e in effects for u in e.units]


# --------------------------------------------------------------------------- forward model


class AugmentedForward(ForwardModel):
    """identify/core/forward.py's exact forward model with effect parameters appended to theta.

    Two generalisations of the base model's speed-ups, both exact:

    * the springs' part S of the KKT stiffness matrix is taken from the model as written (every
      joint spring's polynomial a + 2 b x + 3 c x^2 on its dof; every tendon's
      (K + 2 b x + 3 c x^2) t t^T + F H_L, the compensators and a tendon an effect added): the
      effects may write only spring values (bench/model/effects/'s rule), so A_base = A_fd - S never
      depends on any parameter and is not re-taken when an effect's parameters change (the base
      model re-takes it);
    * measurement-side effects add their deflection term and its Jacobian (central
      differences of the term: exact for the linear ones) after the statics, and contribute
      nothing to dg/dtheta.

    Its warm evaluations run stacked on bench/statics/batched.py as the base model's do (every
    spring value synced into the batch's copy of the model, S and dg/dtheta by the same
    formulas over all (pose, state) rows at once), unless a spring is outside the analytic S
    (an elasto-plastic spring, a dead band): then pose by pose.
    """

    sync_fields = SPRING_FIELDS

    def __init__(
        self,
        robot: Robot,
        design: list[PoseDesign],
        effects: list[Effect],
        readings: ObservationRows | None = None,
        **kw,
    ):
        m = robot.model
        # every tendon is a potential spring (S and the length Hessians cover all of them)
        self._spring_tendons = np.arange(m.ntendon)
        super().__init__(robot, design, **kw)
        self.effects = list(effects)
        self.sizes = [len(e.param_names) for e in self.effects]
        nb = self.n_base
        self.n_params = nb + sum(self.sizes)
        self.offsets = list(nb + np.cumsum([0] + self.sizes[:-1])) if self.effects else []
        self._fd_size = np.ones(self.n_params)
        if self.effects:
            self._fd_size[nb:] = np.concatenate([effect_priors(e)[3] for e in self.effects])
        self._overridden: np.ndarray | None = None
        self._dsprings: tuple[bytes, np.ndarray] | None = None
        self.readings = readings
        if any(e.measurement_side for e in self.effects) and readings is None:
            raise ValueError("a measurement-side effect needs the observation rows (ObservationRows)")
        hinge = np.flatnonzero(
            np.isin(m.jnt_type, (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE))
        )
        self._jnt = hinge
        self._jnt_qpos = m.jnt_qposadr[hinge]
        self._jnt_diag = m.jnt_dofadr[hinge] * (m.nv + 1)
        self._ten_rows = [(int(m.ten_J_rowadr[t]), int(m.ten_J_rownnz[t])) for t in self._spring_tendons]
        # an elasto-plastic spring or a dead band is outside the analytic S: re-take A_base
        self._analytic = not (np.any(m.jnt_springyield) or np.any(m.tendon_springyield))

    def write(self, theta: np.ndarray) -> None:
        super().write(theta)
        for e, off, n in zip(self.effects, self.offsets, self.sizes):
            e.set_params(self.robot, theta[off : off + n])

    # -- the springs, analytically -----------------------------------------------------------
    def _moments(self) -> np.ndarray:
        """(T, nv) every tendon's moment dL/dq at the pose held in data (MuJoCo 4's sparse
        ten_J made dense); the base model's holds the compensators only."""
        m, d = self.robot.model, self.robot.data
        out = np.zeros((len(self._spring_tendons), self.nv))
        for i, (adr, nnz) in enumerate(self._ten_rows):
            out[i, m.ten_J_colind[adr : adr + nnz]] = d.ten_J[adr : adr + nnz]
        return out

    def _deadband(self) -> bool:
        return bool(
            np.any(self.robot.model.tendon_lengthspring[:, 0] != self.robot.model.tendon_lengthspring[:, 1])
        )

    def _spring_part(self, theta, t: np.ndarray, h_len) -> np.ndarray:
        """S: d(spring forces)/dq at the pose held in data, from the spring values written in
        the model (whatever wrote them: the base parameters or an effect); t (T, nv), h_len
        (T, nv, nv): every tendon's moment and length Hessian."""
        if not self._analytic or self._deadband():
            return self._fallback_spring_part(theta, t, h_len)
        m, d = self.robot.model, self.robot.data
        s = np.zeros((self.nv, self.nv))
        for i, tid in enumerate(self._spring_tendons):
            k, (b, c) = float(m.tendon_stiffness[tid]), m.tendon_stiffnesspoly[tid]
            if k == 0.0 and b == 0.0 and c == 0.0:
                continue
            x = float(d.ten_length[tid]) - float(m.tendon_lengthspring[tid][0])
            s -= (k + 2 * b * x + 3 * c * x * x) * (t[i][:, None] * t[i]) + (
                k * x + b * x * x + c * x**3
            ) * h_len[i]
        x = d.qpos[self._jnt_qpos] - m.qpos_spring[self._jnt_qpos]
        poly = m.jnt_stiffnesspoly[self._jnt]
        s.flat[self._jnt_diag] -= m.jnt_stiffness[self._jnt] + 2 * poly[:, 0] * x + 3 * poly[:, 1] * x * x
        return s

    def _fallback_spring_part(self, theta, t, h_len) -> np.ndarray:
        """The base model's S (actuated springs and compensators from theta) on the
        compensators' rows of the all-tendon moments: the rest stays in A_base, re-taken."""
        idx = [int(np.flatnonzero(self._spring_tendons == tid)[0]) for tid in self.robot.tendons]
        return super()._spring_part(theta, t[idx], h_len[idx])

    def _stacked(self, refresh: bool) -> bool:
        """Stacked whenever S is analytic: A_base then never depends on a parameter (``refresh``
        is moot), and the batch sees every spring value (``sync_fields``)."""
        if not (self.batched and self._analytic and not self._deadband()):
            return False
        self.stall_limit = STALL_LIMIT  # as _solve: S is exact at every iterate
        return True

    def _moments_stack(self, ten_j: np.ndarray) -> np.ndarray:
        """:meth:`_moments` of n configurations (n, T, nv) from their stacked ten_J."""
        m = self.robot.model
        out = np.zeros((len(ten_j), len(self._spring_tendons), self.nv))
        for i, (adr, nnz) in enumerate(self._ten_rows):
            out[:, i, m.ten_J_colind[adr : adr + nnz]] = ten_j[:, adr : adr + nnz]
        return out

    def _joint_offsets(self, qpos: np.ndarray, q: np.ndarray) -> np.ndarray:
        """(n, J) every hinge's and slide's position less its spring reference (the commands q
        on the actuated joints, Robot.set_command) for n configurations."""
        m, robot = self.robot.model, self.robot
        ref = np.repeat(m.qpos_spring[None], len(qpos), axis=0)
        ref[:, robot.act_qpos] = q
        return qpos[:, self._jnt_qpos] - ref[:, self._jnt_qpos]

    def _springs_stack(self, theta, bs, ids, qpos, q, h_len) -> np.ndarray:
        """:meth:`_spring_part` of n configurations at once (the batch holds their forward pass)."""
        m, tt = self.robot.model, self._spring_tendons
        t = self._moments_stack(bs.ten_j[ids])
        k, (b, c) = m.tendon_stiffness[tt], m.tendon_stiffnesspoly[tt].T
        x = bs.ten_length[ids][:, tt] - m.tendon_lengthspring[tt][:, 0]
        s = -np.einsum("nc,nci,ncj->nij", k + 2 * b * x + 3 * c * x * x, t, t)
        s -= np.einsum("nc,ncij->nij", k * x + b * x * x + c * x**3, h_len)
        xj = self._joint_offsets(qpos, q)
        poly = m.jnt_stiffnesspoly[self._jnt]
        dof = m.jnt_dofadr[self._jnt]
        s[:, dof, dof] -= m.jnt_stiffness[self._jnt] + 2 * poly[:, 0] * xj + 3 * poly[:, 1] * xj * xj
        return s

    def _dforce_stack(self, theta, bs, ids, qpos, q) -> np.ndarray:
        """:meth:`_dforce` of n configurations at once (n, nv, n_params), the same formulas."""
        m, nb, nv = self.robot.model, self.n_base, self.nv
        n = len(ids)
        out = np.zeros((n, nv, self.n_params))
        out[:, :, :nb] = super()._dforce_stack(theta, bs, ids, qpos, q)
        out[:, :, np.flatnonzero(self._base_overridden(theta))] = 0.0
        if self.n_params == nb:
            return out
        nj, nt = m.njnt, len(self._spring_tendons)
        dsp = np.zeros((n, nv, self._spring_values().size))
        x = self._joint_offsets(qpos, q)
        dof, jnt = m.jnt_dofadr[self._jnt], self._jnt
        dsp[:, dof, jnt] = -x
        dsp[:, dof, nj + 2 * jnt] = -x * x
        dsp[:, dof, nj + 2 * jnt + 1] = -(x**3)
        if nt:
            tt = self._spring_tendons
            t = self._moments_stack(bs.ten_j[ids]).transpose(0, 2, 1)  # (n, nv, T)
            k, (b, c) = m.tendon_stiffness[tt], m.tendon_stiffnesspoly[tt].T
            xt = (bs.ten_length[ids][:, tt] - m.tendon_lengthspring[tt][:, 0])[:, None, :]
            base, i = 3 * nj, np.arange(nt)
            dsp[:, :, base + i] = -(xt * t)
            dsp[:, :, base + nt + 2 * i] = -(xt * xt * t)
            dsp[:, :, base + nt + 2 * i + 1] = -(xt**3 * t)
            half = 0.5 * (k + 2 * b * xt + 3 * c * xt * xt) * t
            dsp[:, :, base + 3 * nt + 2 * i] = half
            dsp[:, :, base + 3 * nt + 2 * i + 1] = half
        out[:, :, nb:] = dsp @ self._spring_jacobian(theta)
        return out

    def _solve(self, des, load, eq, theta, refresh: bool):
        analytic = self._analytic and not self._deadband()
        # S is exact at every iterate, so a stalling step (a stiff cubic term) is worth a fresh
        # matrix there rather than a re-taken A_base
        self.stall_limit = STALL_LIMIT if analytic else ForwardModel.stall_limit
        return super()._solve(des, load, eq, theta, refresh and not analytic)

    # -- dg/dtheta and the measurement side ----------------------------------------------------
    def _spring_values(self) -> np.ndarray:
        """Every spring value of the model, flat: joint stiffness and polynomial, then every
        tendon's stiffness, polynomial and rest length (lo, hi)."""
        m, tt = self.robot.model, self._spring_tendons
        return np.concatenate(
            [
                m.jnt_stiffness,
                m.jnt_stiffnesspoly.ravel(),
                m.tendon_stiffness[tt],
                m.tendon_stiffnesspoly[tt].ravel(),
                m.tendon_lengthspring[tt].ravel(),
            ]
        )

    def _spring_jacobian(self, theta) -> np.ndarray:
        """d(spring values)/d(effect parameters) (n_springs, n_effect_params), at theta: the
        effects write only spring values (bench/model/effects/), and how they do does not depend on
        the configuration, so it is taken once per theta (central differences of set_params)."""
        key = theta.tobytes()
        if self._dsprings is not None and self._dsprings[0] == key:
            return self._dsprings[1]
        nb = self.n_base
        out = np.zeros((self._spring_values().size, self.n_params - nb))
        for e, off, n in zip(self.effects, self.offsets, self.sizes):
            if e.measurement_side:
                continue
            for i in range(off, off + n):
                h = 1e-6 * (abs(theta[i]) if theta[i] != 0 else self._fd_size[i])
                p = theta[off : off + n].copy()
                try:
                    p[i - off] = theta[i] + h
                    e.set_params(self.robot, p)
                    sp = self._spring_values()
                    p[i - off] = theta[i] - h
                    e.set_params(self.robot, p)
                    sm, step = self._spring_values(), 2 * h
                except ValueError:  # at a bound: one-sided
                    p[i - off] = theta[i]
                    e.set_params(self.robot, p)
                    sm = self._spring_values()
                    p[i - off] = theta[i] + h
                    e.set_params(self.robot, p)
                    sp, step = self._spring_values(), h
                out[:, i - nb] = (sp - sm) / step
            e.set_params(self.robot, theta[off : off + n])
        self._dsprings = (key, out)
        return out

    def _dforce_dsprings(self) -> np.ndarray:
        """d(spring generalised forces)/d(spring values) (nv, n_springs) at the pose in data:
        joints -(x, x^2, x^3) on their dof; a tendon -(x, x^2, x^3) t and, per rest-length end,
        half of (K + 2 b x + 3 c x^2) t (x = length - rest, t = dL/dq)."""
        m, d = self.robot.model, self.robot.data
        nj, nt = m.njnt, len(self._spring_tendons)
        out = np.zeros((self.nv, self._spring_values().size))
        x = d.qpos[self._jnt_qpos] - m.qpos_spring[self._jnt_qpos]
        dof = m.jnt_dofadr[self._jnt]
        out[dof, self._jnt] = -x
        out[dof, nj + 2 * self._jnt] = -x * x
        out[dof, nj + 2 * self._jnt + 1] = -(x**3)
        if nt:
            t = self._moments()
            k = m.tendon_stiffness[self._spring_tendons]
            b, c = m.tendon_stiffnesspoly[self._spring_tendons].T
            xt = d.ten_length[self._spring_tendons] - m.tendon_lengthspring[self._spring_tendons][:, 0]
            base = 3 * nj
            i = np.arange(nt)
            out[:, base + i] = -(xt * t.T)
            out[:, base + nt + 2 * i] = -(xt * xt * t.T)
            out[:, base + nt + 2 * i + 1] = -(xt**3 * t.T)
            half = 0.5 * (k + 2 * b * xt + 3 * c * xt * xt) * t.T
            out[:, base + 3 * nt + 2 * i] = half
            out[:, base + 3 * nt + 2 * i + 1] = half
        return out

    def _dforce(self, theta) -> np.ndarray:
        """dg/dtheta at fixed q (the solution current in data): the base columns from
        ``Robot.dforce_dtheta`` (zero where an effect owns the quantity); a robot-side effect's
        through the spring values it writes (chain rule: analytic in q, the spring values'
        derivatives once per theta); a measurement-side effect's zero."""
        nb = self.n_base
        out = np.zeros((self.nv, self.n_params))
        out[:, :nb] = super()._dforce(theta)
        out[:, :nb][:, self._base_overridden(theta)] = 0.0
        if self.n_params > nb:
            if self._analytic and not self._deadband():
                out[:, nb:] = self._dforce_dsprings() @ self._spring_jacobian(theta)
            else:
                out[:, nb:] = self._dforce_fd(theta)[:, nb:]
        return out

    def _dforce_fd(self, theta) -> np.ndarray:
        """The effect columns by central differences of MuJoCo's passive force (any effect:
        the fallback where the springs are not all analytic). Data restored on return."""
        m, d = self.robot.model, self.robot.data
        out = np.zeros((self.nv, self.n_params))
        for e, off, n in zip(self.effects, self.offsets, self.sizes):
            if e.measurement_side:
                continue
            for i in range(off, off + n):
                h = 1e-6 * (abs(theta[i]) if theta[i] != 0 else self._fd_size[i])
                tp, tm = theta.copy(), theta.copy()
                tp[i] += h
                tm[i] -= h
                try:
                    self.write(tp)
                    mujoco.mj_fwdVelocity(m, d)
                    fp = d.qfrc_passive.copy()
                    self.write(tm)
                    mujoco.mj_fwdVelocity(m, d)
                    fm = d.qfrc_passive.copy()
                except ValueError:  # at a bound: one-sided
                    self.write(theta)
                    mujoco.mj_fwdVelocity(m, d)
                    fm, tm = d.qfrc_passive.copy(), theta
                    self.write(tp)
                    mujoco.mj_fwdVelocity(m, d)
                    fp = d.qfrc_passive.copy()
                out[:, i] = (fp - fm) / (tp[i] - tm[i])
        self.write(theta)
        mujoco.mj_fwdVelocity(m, d)
        return out

    def measurement_term(self, theta) -> tuple[np.ndarray, np.ndarray]:
        """The measurement-side effects' term (M, 3) and its Jacobian (M, 3, n_params)."""
        term = np.zeros((self.n_obs, 3))
        jac = np.zeros((self.n_obs, 3, self.n_params))
        for e, off, n in zip(self.effects, self.offsets, self.sizes):
            if not e.measurement_side:
                continue
            p = np.asarray(theta[off : off + n], dtype=float)
            term += e.deflection_term(p, self.readings)
            for i in range(n):
                h = self._fd_size[off + i]
                dp = np.zeros(n)
                dp[i] = h
                jac[:, :, off + i] = (
                    e.deflection_term(p + dp, self.readings) - e.deflection_term(p - dp, self.readings)
                ) / (2 * h)
        return term, jac

    def evaluate(self, theta, jacobian: bool = True):
        dp, jac = super().evaluate(theta, jacobian)
        if any(e.measurement_side for e in self.effects):
            term, dterm = self.measurement_term(np.asarray(theta, dtype=float))
            dp = dp + term
            if jacobian:
                jac = jac + dterm
        return dp, jac

    def _base_overridden(self, theta) -> np.ndarray:
        """(n_base,) bool: base parameters an effect writes over (the compensator effect on a
        model that has it owns K_C and s0), found once by writing changed base values and
        reading the model back."""
        if self._overridden is None:
            nb = self.n_base
            probe = theta.copy()
            probe[:nb] *= 1.5
            self.write(probe)
            back = self.layout.theta(self.robot.params())
            self._overridden = ~np.isclose(back, probe[:nb], rtol=1e-9, atol=0.0)
            self.write(theta)
        return self._overridden

    def equilibria(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """(unloaded qpos, loaded qpos) of every pose at the last evaluation."""
        return [(a.qpos.copy(), b.qpos.copy()) for a, b in (self._cache or [])]


# --------------------------------------------------------------------------- fitting


def build(model_source, effects: list[tuple[Effect, np.ndarray]], obs) -> tuple[Robot, AugmentedForward]:
    """The candidate robot (user's MJCF + effects) and its forward model for the observations.
    Raises ValueError / NotImplementedError when an effect does not apply to this MJCF."""
    if effects:
        robot = apply_effects(model_source, effects)
    else:
        robot = (
            Robot.from_file(model_source)
            if isinstance(model_source, Path)
            or (isinstance(model_source, str) and "<mujoco" not in model_source)
            else Robot.from_xml(model_source)
        )
    readings = ObservationRows(tuple(obs.labels), tracker_rotation(obs.tracker))
    fm = AugmentedForward(robot, design_from_observations(robot, obs), [e for e, _ in effects], readings)
    return robot, fm


def whitened(model: AugmentedForward, white: Whitener, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(L^-1 f, L^-1 J) of the model at theta, flattened to (3M,) and (3M, P)."""
    f, j = model.evaluate(theta)
    return white.vec(f), white.mat(j)


def fit_augmented(
    model: AugmentedForward,
    dp: np.ndarray,
    white: Whitener,
    start: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    hold: np.ndarray | None = None,
    *,
    step_tol: float = 1e-3,
    max_iter: int = 30,
    start_eval: tuple[np.ndarray, np.ndarray] | None = None,
    cost_tol: float = COST_TOL,
) -> Fit:
    """Maximum-likelihood fit of the base + effect parameters (identify/core/leastsq.py's core, with
    minimum-norm steps: directions the plan cannot see are left where they are; bounds by an
    active set and projection). Stops when a step promises or gains less than cost_tol-scale
    chi2 (``max(step_tol^2, 10 cost_tol)`` promised, cost_tol gained; COST_TOL by default).

    hold: parameters never estimated. The fitted model's number of free parameters is the rank
    of the Jacobian on the rest (what the data determine), used for dof, chi2 and BIC.
    start_eval: :func:`whitened` already evaluated at ``start`` (saves one evaluation).
    """
    t0 = time.perf_counter()
    npar = model.n_params
    theta0 = np.array(start, dtype=float)
    hold = np.zeros(npar, bool) if hold is None else np.asarray(hold, bool).copy()
    scale = np.where(np.abs(theta0) > 0, np.abs(theta0), model._fd_size)
    yw = white.vec(dp)
    n0 = model.stats["evaluations"]
    sol = levenberg_marquardt(
        lambda th: whitened(model, white, th),
        yw,
        theta0,
        scale,
        lower=lower,
        upper=upper,
        hold=hold,
        gain_tol=max(step_tol**2, 10 * cost_tol),
        cost_tol=cost_tol,
        rank_tol=DISCOVER_RANK_TOL,
        max_iter=max_iter,
        start_eval=start_eval,
    )
    theta = sol.x
    at_low, at_high = at_bounds(theta, lower, upper)
    free = ~hold & ~at_low & ~at_high
    jw = sol.j_w * scale
    cov, rank = covariance(jw, free, scale, DISCOVER_RANK_TOL)
    ident = np.zeros(npar, bool)
    idx = np.flatnonzero(free)
    if idx.size:
        ident[idx] = analyze(jw[:, idx], tuple(str(i) for i in idx)).identifiable
    resid_w = sol.r_w.reshape(-1, 3)
    resid = white.unwhiten(resid_w)
    predicted = white.unwhiten(sol.f_w)
    return Fit(
        theta,
        cov,
        ident,
        resid,
        resid_w,
        sol.cost,
        sol.r_w.size,
        rank,
        sol.iterations,
        model.stats["evaluations"] - n0,
        sol.converged,
        time.perf_counter() - t0,
        names=tuple(param_names(model.layout, model.effects)),
        units=tuple(param_units(model.layout, model.effects)),
        predicted=predicted,
        at_bound=~free & ~hold,
        start=theta0,
        effects=list(model.effects),
        model=model,
        robot=model.robot,
        extra={"jw": sol.j_w},
    )


__all__ = [
    "DISCOVERY_EFFECTS",
    "library",
    "label",
    "effect_priors",
    "param_names",
    "param_units",
    "AugmentedForward",
    "Fit",
    "build",
    "fit_augmented",
    "whitened",
]
