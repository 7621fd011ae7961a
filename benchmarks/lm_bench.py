"""Why calbench keeps its own Levenberg–Marquardt loop (identify/core/leastsq.py): measured.

Side by side in one process, on the paper campaign's one-step identification (eight
parameters, exact statics), from the same start and with the same forward model:
* calbench's core (identify/core/leastsq.py), as `calbench identify` runs it;
* scipy.optimize.least_squares (trust-region reflective, x_scale from the start, the model's
  own Jacobian; tolerances tight enough to reach the same optimum);
* mujoco.minimize.least_squares (MuJoCo 4's bounded LM, the model's own Jacobian);
and the Monte Carlo case: a run started at the noise-free estimate with its model value and
Jacobian already known (what `calbench montecarlo` does 1000 times).

Prints JSON: model evaluations, seconds and the largest difference of the estimates from
calbench's, in standard deviations. Usage: python benchmarks/lm_bench.py [--repeats 3]
"""

from __future__ import annotations

import argparse
import io
import json
import time
from pathlib import Path

import numpy as np
import scipy.optimize
from steps import say

from calbench.bench.campaign import simulate
from calbench.bench.model import Robot
from calbench.bench.scenario import load_scenario
from calbench.identify.core import Whitener, from_campaign
from calbench.identify.methods import OneStep, generic_start, sanitize_start, to_phi, to_theta, two_step

ROOT = Path(__file__).resolve().parent.parent
PAPER = ROOT / "scenarios" / "paper_table5.toml"


def problem(seed: int):
    scn = load_scenario(PAPER)
    robot = Robot.from_file(scn.robot)
    obs = from_campaign(simulate(scn, np.random.default_rng(seed)))
    white = Whitener.from_observations(obs)
    start, _ = sanitize_start(two_step(robot, obs).theta, generic_start(robot, obs), robot.layout)
    return robot, obs, white, start


def library_runs(est: OneStep, obs, white, start, ours) -> dict:
    """scipy and mujoco on the same problem in phi = [k, K_C, K_C s0] scaled by |phi(start)|."""
    model = est.model
    lay = est.robot.layout
    yw = white.vec(obs.dp)
    phi0 = to_phi(start, lay)
    scale = np.abs(phi0)
    cache: dict = {}

    def fj(z):
        key = z.tobytes()
        if key not in cache:
            f, j = model.evaluate(to_theta(z * scale, lay))
            cache.clear()
            cache[key] = (white.vec(f), white.mat(j))
        return cache[key]

    n_eval = {"n": 0}

    def resid(z):
        n0 = model.stats["evaluations"]
        fw, _ = fj(z)
        n_eval["n"] += model.stats["evaluations"] - n0
        return fw - yw

    def jac(z, *_):
        n0 = model.stats["evaluations"]
        th = to_theta(z * scale, lay)
        _, jw = fj(z)
        n_eval["n"] += model.stats["evaluations"] - n0
        # d theta / d phi for the compensator pair, then the scaling
        from calbench.identify.methods import dtheta_dphi

        return jw @ dtheta_dphi(z * scale, lay) * scale if th is not None else None

    out = {}
    sd = np.sqrt(np.diag(ours.cov))
    for name, run in (
        (
            "scipy_trf",
            lambda: (
                scipy.optimize.least_squares(
                    resid, phi0 / scale, jac=jac, method="trf", xtol=1e-12, ftol=1e-12, gtol=1e-12
                ).x
            ),
        ),
        ("mujoco_minimize", lambda: _mujoco(resid, jac, phi0 / scale)),
    ):
        n_eval["n"] = 0
        t = time.perf_counter()
        z = run()
        dt = time.perf_counter() - t
        th = to_theta(z * scale, lay)
        out[name] = {
            "evaluations": n_eval["n"],
            "seconds": dt,
            "max_abs_difference_in_sigma": float(np.nanmax(np.abs(th - ours.theta) / sd)),
        }
    return out


def _mujoco(resid, jac, z0):
    """mujoco.minimize passes points as columns (n, k) and wants residuals as columns."""
    from mujoco import minimize

    def r2(z):
        z = np.asarray(z).reshape(len(z0), -1)
        return np.column_stack([resid(z[:, i]) for i in range(z.shape[1])])

    x, _ = minimize.least_squares(
        z0,
        r2,
        jacobian=lambda z, r: jac(np.asarray(z).ravel()),
        verbose=0,
        output=io.StringIO(),
        xtol=1e-12,
        gtol=1e-12,
    )
    return np.asarray(x).ravel()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="one seed")
    args = ap.parse_args()
    if args.quick:
        args.repeats = 1
    out: dict = {"identify": [], "montecarlo_run": []}
    for seed in range(args.repeats):
        say("lm_bench", f"seed {seed + 1}/{args.repeats}: calbench, scipy and mujoco.minimize")
        robot, obs, white, start = problem(seed)
        est = OneStep(robot, obs)
        t = time.perf_counter()
        n0 = est.model.stats["evaluations"]
        ours = est.fit(obs.dp, white, start, start_method="two-step")
        row = {
            "seed": seed,
            "calbench": {
                "evaluations": est.model.stats["evaluations"] - n0,
                "seconds": time.perf_counter() - t,
            },
        }
        row.update(library_runs(OneStep(robot, obs, est.model), obs, white, start, ours))
        out["identify"].append(row)
        # the Monte Carlo case: start at a known estimate with its evaluation in hand
        theta0 = ours.theta
        f0, j0 = est.model.evaluate(theta0)
        _, _, white2, _ = problem(seed + 100)
        obs2 = from_campaign(simulate(load_scenario(PAPER), np.random.default_rng(seed + 100)))
        n0 = est.model.stats["evaluations"]
        t = time.perf_counter()
        r2 = est.fit(
            obs2.dp,
            white2,
            theta0,
            scale=np.abs(to_phi(theta0, robot.layout)),
            start_eval=(f0, j0),
            final_eval=False,
            step_tol=1e-2,
        )
        mc = {
            "seed": seed + 100,
            "calbench": {
                "evaluations": est.model.stats["evaluations"] - n0,
                "seconds": time.perf_counter() - t,
            },
        }
        mc.update(
            library_runs(
                OneStep(robot, obs2, est.model), obs2, white2, theta0, est.fit(obs2.dp, white2, theta0)
            )
        )
        out["montecarlo_run"].append(mc)
        del r2
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
