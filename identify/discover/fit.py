"""Discovery, part 1: the candidate library and fitting a model with effects in the loop.

The LIBRARY is every effect that bench/effects.py's ``@register`` puts in discovery, with the
structural options it declares there for the robot: `link_compliance` on the robot's
calbench:links (the FANUC's upper arm and forearm), `joint_nonlinearity` on every actuated
joint, `base_compliance`, `compensator` where calbench:compensator_sites names its mounts, with
their priors. These
are the same MjSpec edits the bench puts in the simulated truth. Nothing here chooses between
them: identify/discover/workflow.py does, through identify/discover/stats.py, and knows nothing
about any single effect. Adding a candidate = registering an effect in bench/effects.py.

FITTING. A candidate model is the user's MJCF with the effects applied (`apply_effects`); its
parameters are the robot's theta (bench/params.py; the FANUC's [k1..k6, K_C, s0]) followed by
every effect's own parameters, in order. :class:`AugmentedForward` is the exact forward model of
identify/forward.py (same KKT-Newton statics, warm starts, implicit-function Jacobian) with
three generalisations:

* parameters are written by ``Robot.set_params`` and then each effect's ``Effect.set_params``
  (no recompilation); an effect that owns a base quantity (the compensator added to a model
  without one) overrides it, and the overridden base columns come out exactly zero;
* dg/dtheta at fixed q (the right-hand side of the implicit function theorem): the base
  columns are ``Robot.dforce_dtheta``'s (exactly zero where an effect owns the quantity), the
  effect columns central differences of MuJoCo's passive force: generic (any registered
  effect), 2 velocity-stage calls per effect parameter and equilibrium, relative error ~1e-10;
* the KKT matrix's non-analytic part A_base (which holds the effects' springs) is re-taken by
  finite differences whenever the effect parameters change.

:func:`fit` is identify/leastsq.py's Levenberg-Marquardt on the whitened residual (the
maximum-likelihood estimate for the tracker's Gaussian noise), with bounds by an active set
and minimum-norm steps: an effect parameter that the plan
cannot separate from the base parameters (e.g. in-plane forearm bending, exactly a k3 through
the parallelogram) is held at its start, so that it never costs the base model anything, and
any base parameter still unidentifiable is held as in identify/onestep.py.
"""
from __future__ import annotations

import time
from pathlib import Path

import mujoco
import numpy as np

from calbench.bench.effects import DISCOVERY_OPTIONS, Effect, apply_effects, discovery_library, priors
from calbench.bench.robot import Robot

from calbench.bench.params import ParamLayout

from ..forward import ForwardModel, PoseDesign, design_from_observations
from ..identifiability import analyze
from ..leastsq import Fit, at_bounds, covariance, levenberg_marquardt
from ..whitening import Whitener

# --------------------------------------------------------------------------- the library

DISCOVER_RANK_TOL = 1e-5     # singular value (column-normalised) below which a direction is unseen
COST_TOL = 1e-3              # chi2 units: a step gaining (or promising) less ends the fit
# the base parameters' bounds: ParamLayout.lower / .upper (bench/params.py)


DISCOVERY_EFFECTS = tuple(DISCOVERY_OPTIONS)   # the effects @register puts in discovery's library


def library(robot: Robot) -> list[Effect]:
    """Every candidate effect with its structural options on this robot (bench/effects.py's
    registry)."""
    return discovery_library(robot)


def label(effect: Effect) -> str:
    return effect.name + (f"[{effect.detail}]" if effect.detail else "")


def effect_priors(effect: Effect) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(start, lower bound, upper bound, size) of an effect's parameters (bench/effects.py)."""
    pri = priors(effect)
    return tuple(np.array([getattr(p, k) for p in pri], float) for k in ("start", "lower", "upper", "size"))


def param_names(layout: ParamLayout, effects: list[Effect]) -> list[str]:
    return list(layout.names) + [f"{label(e)}.{n}" for e in effects for n in e.param_names]


def param_units(layout: ParamLayout, effects: list[Effect]) -> list[str]:
    return list(layout.units) + [u for e in effects for u in e.units]


# --------------------------------------------------------------------------- forward model

class AugmentedForward(ForwardModel):
    """identify/forward.py's exact forward model with effect parameters appended to theta."""

    def __init__(self, robot: Robot, design: list[PoseDesign], effects: list[Effect], **kw):
        super().__init__(robot, design, **kw)
        self.effects = list(effects)
        self.sizes = [len(e.param_names) for e in self.effects]
        nb = self.n_base
        self.n_params = nb + sum(self.sizes)
        self._fd_size = np.ones(self.n_params)
        if self.effects:
            self._fd_size[nb:] = np.concatenate([effect_priors(e)[3] for e in self.effects])
        self._overridden: np.ndarray | None = None

    def write(self, theta: np.ndarray) -> None:
        super().write(theta)
        off = self.n_base
        for e, n in zip(self.effects, self.sizes):
            e.set_params(self.robot, theta[off: off + n])
            off += n

    def _dforce(self, theta) -> np.ndarray:
        """dg/dtheta at fixed q (position stage of the solution current in data; restored on
        return): the base columns from ``Robot.dforce_dtheta`` (zero where an effect owns the
        quantity), the effects' by central differences of the passive force."""
        m, d = self.robot.model, self.robot.data
        nb = self.n_base
        out = np.zeros((self.nv, self.n_params))
        out[:, :nb] = super()._dforce(theta)
        out[:, :nb][:, self._base_overridden(theta)] = 0.0
        for i in range(nb, self.n_params):
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
            except ValueError:                          # at a bound: one-sided
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
        robot = (Robot.from_file(model_source) if isinstance(model_source, Path) or
                 (isinstance(model_source, str) and "<mujoco" not in model_source)
                 else Robot.from_xml(model_source))
    fm = AugmentedForward(robot, design_from_observations(robot, obs), [e for e, _ in effects])
    return robot, fm


def fit(model: AugmentedForward, dp: np.ndarray, white: Whitener, start: np.ndarray,
        lower: np.ndarray, upper: np.ndarray, hold: np.ndarray | None = None, *, step_tol: float = 1e-3,
        max_iter: int = 30) -> Fit:
    """Maximum-likelihood fit of the base + effect parameters (identify/leastsq.py's core, with
    minimum-norm steps: directions the plan cannot see are left where they are; bounds by an
    active set and projection). Stops when a step promises or gains less than COST_TOL-scale
    chi2 (``max(step_tol^2, 10 COST_TOL)`` promised, COST_TOL gained).

    hold: parameters never estimated. The fitted model's number of free parameters is the rank
    of the Jacobian on the rest (what the data determine), used for dof, chi2 and BIC.
    """
    t0 = time.perf_counter()
    npar = model.n_params
    theta0 = np.array(start, dtype=float)
    hold = np.zeros(npar, bool) if hold is None else np.asarray(hold, bool).copy()
    scale = np.where(np.abs(theta0) > 0, np.abs(theta0), model._fd_size)
    yw = white.vec(dp)
    n0 = model.stats["evaluations"]
    last: dict = {}

    def evaluate(th):
        f, j = model.evaluate(th)
        last["f"] = f
        return white.vec(f), white.mat(j)

    sol = levenberg_marquardt(evaluate, yw, theta0, scale, lower=lower, upper=upper, hold=hold,
                              gain_tol=max(step_tol ** 2, 10 * COST_TOL), cost_tol=COST_TOL,
                              rank_tol=DISCOVER_RANK_TOL, max_iter=max_iter)
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
    return Fit(theta, cov, ident, resid, resid_w, sol.cost, sol.r_w.size, rank, sol.iterations,
               model.stats["evaluations"] - n0, sol.converged, time.perf_counter() - t0,
               names=tuple(param_names(model.layout, model.effects)),
               units=tuple(param_units(model.layout, model.effects)),
               predicted=last["f"], at_bound=~free & ~hold, start=theta0, effects=list(model.effects),
               model=model, robot=model.robot)


__all__ = ["DISCOVERY_EFFECTS", "library", "label", "effect_priors",
           "param_names", "param_units", "AugmentedForward", "Fit", "build", "fit"]
