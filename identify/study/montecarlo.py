"""Monte Carlo of the estimators: the same campaign re-measured with N noise seeds.

The campaign's physics is solved once (bench.campaign.plan_campaign: true reflector positions
and visibility of every pose); each run redraws the tracker noise with bench.tracker.measure
(generator seeded by (scenario seed, run)), builds the observations exactly as from a log
(identify/core/observations.py) and runs the full estimators on them: the one-step estimator and the
paper's two-step method, unweighted step 2 (eq. 21) and step-1-covariance-weighted, and the
two-step at its self-consistent sagged pose (identify/methods/twostep_iterated.py; every run starts
at the noise-free sag, with the noise-free Newton Jacobian as its chord).

Per parameter and method it reports: bias / empirical std (with its sampling error 1/sqrt(N)),
empirical std / mean reported std, and empirical variance / Cramer-Rao bound, the CRB being the
inverse Fisher information J^T Sigma^-1 J at the TRUE parameters on the exact model. The
sampling error of a variance ratio is about sqrt(2/(N-1)).

Speed: every one-step run starts at the noise-free estimate (the one-step estimate of the
noise-free observations, itself started from their two-step estimate: no truth involved) whose
model value and Jacobian are evaluated once and reused, so a run costs one evaluation of the
exact model and its IFT Jacobian when the stopping rule (step < 1e-3 sigma) is met at the second
step. The truth enters only the CRB and the statistics.

Execution: the runs go out in blocks of RUNS_PER_TASK as tasks (identify/runtime/executor.py: this
process, a local Dask cluster or the user's). A task carries the scenario's and the MJCF's texts
(identify/runtime/portable.py); each process builds the shared set-up above once and starts every run
from a copy of the same estimator state, and run r's noise comes from the generator seeded by
(seed, r) alone, so the numbers are bit-identical whatever ran them and in whatever order.
"""

from __future__ import annotations

import contextlib
import copy
import functools
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calbench.bench.campaign import (
    PosePlan,
    drifted,
    plan_campaign,
    reading_drift,
    scenario_params,
    truth_robot,
)
from calbench.bench.core import ProgressSink, sink
from calbench.bench.model import Robot
from calbench.bench.scenario import Scenario, reading_times
from calbench.bench.statics import BatchStatics, StaticsSolver
from calbench.bench.tracker import Measurement, measure_campaign, noise_covariance, to_tracker_frame
from calbench.identify.core import Observations, Whitener, pose_observation
from calbench.identify.methods import (
    OneStep,
    TwoStepError,
    fit_from,
    generic_start,
    linear_plan,
    sanitize_start,
    to_phi,
    two_step,
    two_step_applies,
    two_step_iterated,
)
from calbench.identify.runtime import Executor, InProcess, Interrupted, PortableScenario

METHODS = ("one-step", "two-step", "two-step-weighted", "two-step-iterated")
MC_STEP_TOL = 1e-2  # sigma: see identify/methods/onestep.py, stopping rule
RUNS_PER_TASK = 50  # a task of ~0.5-1 s: Dask's ~5 ms of scheduling per task stays < 1 %
# in-process seconds per run on the paper campaign (measured here: noise and observations, then
# each estimator), for the choice of executor only
SECONDS_PER_RUN = {
    "observations": 0.004,
    "one-step": 0.007,
    "two-step": 0.002,
    "two-step-weighted": 0.002,
    "two-step-iterated": 0.26,
}


def true_theta(scn: Scenario, robot: Robot) -> np.ndarray:
    return robot.layout.theta(scenario_params(scn, robot))


def two_step_ok(robot: Robot) -> bool:
    """Whether the paper's two-step method applies to the robot (identify/methods/twostep.py)."""
    try:
        two_step_applies(robot)
    except TwoStepError:
        return False
    return True


def campaign_observations(
    scn: Scenario, robot: Robot, plans: list[PosePlan], rng: np.random.Generator | None
) -> Observations:
    """Observations of a solved campaign: noisy readings (rng; bench.tracker.measure_campaign,
    the generator consumed as by bench.campaign.run_campaign) or exact ones (rng None, with the
    tracker's covariances still attached as weights), on the campaign's timeline. The truth's
    measurement-side effects (a tracker drift) shift the loaded readings as in the log."""
    spec = scn.tracker
    names = list(robot.reflector_names)
    repeats = [p.repeats for p in scn.poses]
    times = reading_times(repeats, len(names))
    if rng is not None:
        measured = measure_campaign(
            spec, [p.reflectors_world for p in plans], [p.visible for p in plans], repeats, rng, times
        )
    poses = []
    for plan, pose in zip(plans, scn.poses):
        readings = []
        for s, state in enumerate(("unloaded", "loaded")):
            reps = []
            shift = reading_drift(scn, plan.index, names) if s == 1 else None
            for r in range(pose.repeats):
                if rng is None:
                    p = to_tracker_frame(spec, plan.reflectors_world[s])
                    vis = plan.visible[s]
                    pos = np.where(vis[:, None], p, np.nan)
                    cov = np.full((len(p), 3, 3), np.nan)
                    if vis.any():
                        cov[vis] = noise_covariance(spec, p[vis])
                    reps.append(drifted(Measurement(pos, cov, vis), shift))
                else:
                    reps.append(drifted(measured[(plan.index, state, r)], shift))
            readings.append(reps)
        site = robot.model.site(plan.load.site).name
        when = tuple(
            [times[(plan.index, state, r)] for r in range(pose.repeats)] for state in ("unloaded", "loaded")
        )
        ob = pose_observation(
            plan.index,
            plan.q,
            plan.load.force,
            plan.load.moment,
            site,
            names,
            readings[0],
            readings[1],
            spec,
            when,
        )
        if len(ob.reflectors):
            poses.append(ob)
    return Observations(poses, spec, float(spec.sigma), len(scn.poses), [], False, str(scn.path))


@dataclass
class MonteCarlo:
    scenario: str
    runs: int
    truth: np.ndarray
    crb: np.ndarray
    estimates: dict[str, np.ndarray]  # method -> (runs, P), NaN where not identified
    stds: dict[str, np.ndarray]  # method -> (runs, P) reported
    times: dict[str, float]
    noise_free: dict[str, np.ndarray]  # method -> (P,) estimate on exact data (model error)
    setup_time: float
    names: tuple[str, ...] = ()  # the parameters (the robot's layout)
    units: tuple[str, ...] = ()
    executor: str = "in this process"  # where the runs ran (identify/runtime/executor.py)
    wall_seconds: float = float("nan")
    failed: dict[str, int] = field(default_factory=dict)  # method -> runs it failed on (an error)

    def summary(self) -> dict:
        n = self.runs
        crb_sd0 = np.sqrt(np.diag(self.crb))
        model_error = {
            meth: {
                name: (None if not np.isfinite(v) else float((v - t) / sd))
                for name, v, t, sd in zip(self.names, est, self.truth, crb_sd0)
            }
            for meth, est in self.noise_free.items()
        }
        out = {
            "scenario": self.scenario,
            "runs": n,
            "sampling_error": {
                "bias_over_sigma": 1 / np.sqrt(n),
                "variance_ratio": float(np.sqrt(2 / max(n - 1, 1))),
                "std_ratio": float(np.sqrt(1 / (2 * max(n - 1, 1)))),
            },
            "setup_seconds": self.setup_time,
            "wall_seconds": self.wall_seconds,
            "executor": self.executor,
            "noise_free_error_over_crb_std": model_error,
            "crb_std": {n_: float(v) for n_, v in zip(self.names, crb_sd0)},
            "methods": {},
        }
        crb_sd = np.sqrt(np.diag(self.crb))
        for meth, est in self.estimates.items():
            sd = self.stds[meth]
            rows = []
            for i, name in enumerate(self.names):
                col = est[:, i]
                ok = np.isfinite(col)
                if ok.sum() < 2:
                    rows.append({"name": name, "unit": self.units[i], "identified_runs": int(ok.sum())})
                    continue
                c = col[ok]
                emp_sd = float(c.std(ddof=1))
                mean = float(c.mean())
                rep = float(np.sqrt(np.mean(sd[ok, i] ** 2)))
                z = (c - self.truth[i]) / sd[ok, i]
                rows.append(
                    {
                        "name": name,
                        "unit": self.units[i],
                        "truth": float(self.truth[i]),
                        "identified_runs": int(ok.sum()),
                        "mean": mean,
                        "bias": mean - float(self.truth[i]),
                        "bias_over_sigma": (mean - float(self.truth[i])) / emp_sd,
                        "empirical_std": emp_sd,
                        "reported_std": rep,
                        "empirical_over_reported_std": emp_sd / rep,
                        "crb_std": float(crb_sd[i]),
                        "variance_over_crb": emp_sd**2 / float(crb_sd[i]) ** 2,
                        "mse_over_crb": float(np.mean((c - self.truth[i]) ** 2)) / float(crb_sd[i]) ** 2,
                        # heavy tails (the two-step's s0 = (s0 K_C) / K_C): a spread that ignores them
                        "robust_std_over_crb_std": float(1.4826 * np.median(np.abs(c - np.median(c))))
                        / float(crb_sd[i]),
                        "fraction_abs_z_over_4": float(np.mean(np.abs(z) > 4)),
                        "noise_free_error_over_crb_std": float(
                            (self.noise_free[meth][i] - self.truth[i]) / crb_sd[i]
                        )
                        if np.isfinite(self.noise_free[meth][i])
                        else None,
                    }
                )
            out["methods"][meth] = {
                "seconds": self.times[meth],
                "failed_runs": self.failed.get(meth, 0),
                "seconds_per_run": self.times[meth] / n,
                "parameters": rows,
            }
        return out


@dataclass(frozen=True)
class MonteCarloJob:
    """What a block of runs needs, on any machine: the scenario's texts, estimators, base seed."""

    scenario: PortableScenario
    methods: tuple[str, ...]
    seed: int


@dataclass
class _Setup:
    """What every run of a job shares, built once per process (see the module docstring)."""

    scn: Scenario
    truth_rb: Robot
    plans: list[PosePlan]
    robot: Robot
    obs0: Observations
    lp: object  # the two-step's linear plan (None when it does not apply)
    est: OneStep  # after the noise-free fit: every run starts from a copy of it
    theta0: np.ndarray
    scale: np.ndarray
    f0: np.ndarray
    j0: np.ndarray
    theta_true: np.ndarray
    crb: np.ndarray
    noise_free: dict[str, np.ndarray]
    seconds: float
    sag0: tuple | None = None  # the iterated two-step's noise-free sag and Newton Jacobian


@functools.lru_cache(maxsize=4)
def _setup(job: MonteCarloJob) -> _Setup:
    t0 = time.perf_counter()
    scn = job.scenario.scenario(job.seed)
    truth_rb = truth_robot(scn)
    plans = plan_campaign(scn, truth_rb)
    robot = Robot.from_file(scn.robot)  # the estimator's own model: geometry only
    lay = robot.layout
    if any(m != "one-step" for m in job.methods):
        two_step_applies(robot)
    obs0 = campaign_observations(scn, truth_rb, plans, None)
    white0 = Whitener.from_observations(obs0)
    est = OneStep(robot, obs0)
    theta_true = true_theta(scn, robot)

    noise_free: dict[str, np.ndarray] = {}
    sag0 = None
    generic = generic_start(robot, obs0)
    start, method0, lp = generic, "generic", None
    if two_step_ok(robot):
        lp = linear_plan(robot, obs0)
        two0 = two_step(robot, obs0, False, lp=lp, white=white0)
        noise_free["two-step"] = two0.theta
        noise_free["two-step-weighted"] = two_step(robot, obs0, True, lp=lp, white=white0).theta
        # diagnostic: the linear model at the true (sagged) unloaded configuration -- what is left
        # of the two-step's model error is H00 (eq. 18) and the nonlinearity over the deflection
        lp_true = linear_plan(robot, obs0, {p.index: p.equilibria[0].qpos for p in plans})
        noise_free["two-step at the true sagged configuration"] = two_step(
            robot, obs0, False, lp=lp_true, white=white0
        ).theta
        if "two-step-iterated" in job.methods:
            # the iterated method's self-consistent sag on exact data: every run starts there,
            # with its Newton Jacobian as the chord (identify/methods/twostep_iterated.py)
            it0 = two_step_iterated(robot, obs0)
            noise_free["two-step-iterated"] = it0.theta
            sag0 = (it0.step2["sag_rad"], it0.step2["jacobian"])
        start, _ = sanitize_start(two0.theta, generic, lay)
        method0 = "two-step"
    nf = fit_from(est, obs0.dp, white0, start, generic, method0)
    noise_free["one-step"] = nf.theta
    theta0 = np.where(np.isfinite(nf.theta), nf.theta, start)
    scale = np.abs(to_phi(theta0, lay))
    f0, j0 = est.model.evaluate(theta0)
    # Cramer-Rao bound at the truth (exact model), on a copy: the runs' start state stays f0's
    _, jt = _fresh(est).model.evaluate(theta_true)
    jtw = white0.mat(jt) * theta_true  # scaled columns
    crb = np.linalg.pinv(jtw.T @ jtw) * np.outer(theta_true, theta_true)
    return _Setup(
        scn,
        truth_rb,
        plans,
        robot,
        obs0,
        lp,
        est,
        theta0,
        scale,
        f0,
        j0,
        theta_true,
        crb,
        noise_free,
        time.perf_counter() - t0,
        sag0,
    )


def _fresh(est: OneStep) -> OneStep:
    """A copy of the estimator in the state it was left in (its forward model warm-starts from
    its last solution, so a run's last bits would depend on the runs before it). Its workspaces
    are shared, not copied: the robot and the statics solvers (bench/statics/equilibrium.py,
    bench/statics/batched.py), whose MuJoCo model parameters, state and buffers every evaluation
    rewrites, and the observations (read-only); what is copied is the warm-start cache."""
    shared = [est.robot, est.obs] + [
        v for v in vars(est.model).values() if isinstance(v, (StaticsSolver, BatchStatics))
    ]
    return copy.deepcopy(est, {id(o): o for o in shared})


def run_block(job: MonteCarloJob, first: int, stop: int) -> dict:
    """Runs first..stop-1 of the job: the task function, the same in-process and on a worker.

    Run r draws its noise from the generator seeded by (job.seed, r) and starts from the same
    estimator state, so its result depends on nothing but (job, r)."""
    s = _setup(job)
    n, p = stop - first, s.robot.layout.n
    est_out = {m: np.full((n, p), np.nan) for m in job.methods}
    std_out = {m: np.full((n, p), np.nan) for m in job.methods}
    times = {m: 0.0 for m in job.methods}
    failed = {m: 0 for m in job.methods}
    iters = []
    for k, r in enumerate(range(first, stop)):
        rng = np.random.default_rng([job.seed, r])
        obs = campaign_observations(s.scn, s.truth_rb, s.plans, rng)
        if obs.labels != s.obs0.labels:
            raise RuntimeError("visibility changed between runs")  # cannot happen: fixed plan
        white = Whitener.from_observations(obs)
        for meth in job.methods:
            t = time.perf_counter()
            try:
                if meth == "one-step":
                    est = _fresh(s.est)
                    n_eval = est.model.stats["evaluations"]
                    res = est.fit(
                        obs.dp,
                        white,
                        s.theta0,
                        scale=s.scale,
                        start_eval=(s.f0, s.j0),
                        final_eval=False,
                        step_tol=MC_STEP_TOL,
                        start_method="noise-free estimate",
                    )
                    iters.append((res.iterations, est.model.stats["evaluations"] - n_eval))
                elif meth == "two-step-iterated":
                    res = two_step_iterated(s.robot, obs, start=s.sag0[0], jacobian=s.sag0[1])
                else:
                    res = two_step(s.robot, obs, meth == "two-step-weighted", lp=s.lp, white=white)
            except (np.linalg.LinAlgError, TwoStepError):
                # this run's estimate left the robot's statics (e.g. the iterated two-step's sag at a
                # spring that makes the stiffness singular): the method failed on this run, the
                # other runs and methods stand (NaN: counted as not identified, and as failed)
                failed[meth] += 1
                times[meth] += time.perf_counter() - t
                continue
            times[meth] += time.perf_counter() - t
            est_out[meth][k] = res.theta
            std_out[meth][k] = np.sqrt(np.diag(res.cov))
    return {"estimates": est_out, "stds": std_out, "times": times, "iterations": iters, "failed": failed}


def estimated_seconds(runs: int, methods=METHODS) -> float:
    """In-process time of ``runs`` runs (SECONDS_PER_RUN, measured), for the executor choice."""
    return runs * (SECONDS_PER_RUN["observations"] + sum(SECONDS_PER_RUN[m] for m in methods))


def run_montecarlo(
    scn: Scenario,
    runs: int,
    methods=METHODS,
    progress: ProgressSink | None = None,
    seed: int | None = None,
    executor: Executor | None = None,
) -> MonteCarlo:
    """N runs of the estimators on the scenario's campaign; see the module docstring. The
    two-step methods need a robot the two-step applies to (TwoStepError otherwise).

    The runs go to ``executor`` (identify/runtime/executor.py; default: this process) in blocks of
    RUNS_PER_TASK. Ctrl-C raises :class:`Interrupted` carrying the Monte Carlo of the runs that
    finished."""
    t_wall = time.perf_counter()
    methods = tuple(methods)
    job = MonteCarloJob(PortableScenario.from_scenario(scn), methods, scn.seed if seed is None else int(seed))
    s = _setup(job)
    lay = s.robot.layout
    executor = executor or InProcess()
    blocks = [(job, a, min(a + RUNS_PER_TASK, runs)) for a in range(0, runs, RUNS_PER_TASK)]
    estimates = {m: np.full((runs, lay.n), np.nan) for m in methods}
    stds = {m: np.full((runs, lay.n), np.nan) for m in methods}
    times = {m: 0.0 for m in methods}
    failed = {m: 0 for m in methods}
    iters: dict[int, list] = {}
    done = np.zeros(runs, bool)
    bar = sink(progress)
    bar.start(runs, "Monte Carlo")

    def result(keep: np.ndarray) -> MonteCarlo:
        mc = MonteCarlo(
            str(scn.path),
            int(keep.sum()),
            s.theta_true,
            s.crb,
            {m: v[keep] for m, v in estimates.items()},
            {m: v[keep] for m, v in stds.items()},
            times,
            s.noise_free,
            s.seconds,
            lay.names,
            lay.units,
            executor.choice.describe(),
            time.perf_counter() - t_wall,
            dict(failed),
        )
        mc.iterations = np.array([it for i in sorted(iters) for it in iters[i]])
        return mc

    try:
        with contextlib.closing(executor.run(run_block, blocks)) as results:  # closed: nothing left running
            for i, out in results:
                _, a, b = blocks[i]
                for m in methods:
                    estimates[m][a:b] = out["estimates"][m]
                    stds[m][a:b] = out["stds"][m]
                    times[m] += out["times"][m]
                    failed[m] += out["failed"][m]
                iters[i] = out["iterations"]
                done[a:b] = True
                bar.update(f"runs {int(done.sum())}/{runs}", step=b - a)
    except KeyboardInterrupt:
        raise Interrupted(result(done), int(done.sum()), runs) from None
    return result(done)


def format_summary(s: dict) -> str:
    lines = [
        f"Monte Carlo: {s['runs']} runs of {Path(s['scenario']).name} "
        f"(sampling error: bias/sigma +-{s['sampling_error']['bias_over_sigma']:.3f}, "
        f"variance ratio +-{s['sampling_error']['variance_ratio']:.3f})"
    ]
    for meth, d in s["methods"].items():
        fails = f"; failed on {d['failed_runs']} runs (left out)" if d.get("failed_runs") else ""
        lines.append(f"\n{meth}  ({d['seconds']:.2f} s, {1e3 * d['seconds_per_run']:.1f} ms/run{fails})")
        lines.append(
            f"  {'parameter':<22}{'bias/sd':>9}{'sd/rep.sd':>11}{'var/CRB':>9}{'MSE/CRB':>9}"
            f"{'noise-free err/CRBsd':>22}"
        )
        for p in d["parameters"]:
            if "bias_over_sigma" not in p:
                lines.append(f"  {p['name']:<22}  not identified")
                continue
            nfe = p["noise_free_error_over_crb_std"]
            g = lambda x: f"{x:.3f}" if abs(x) < 1e4 else f"{x:.2e}"  # noqa: E731
            lines.append(
                f"  {p['name']:<22}{g(p['bias_over_sigma']):>9} {g(p['empirical_over_reported_std']):>10}"
                f" {g(p['variance_over_crb']):>9} {g(p['mse_over_crb']):>9}"
                f"{(g(nfe) if nfe is not None else 'n/a'):>22}"
            )
    return "\n".join(lines)


__all__ = [
    "campaign_observations",
    "run_montecarlo",
    "run_block",
    "estimated_seconds",
    "MonteCarlo",
    "MonteCarloJob",
    "format_summary",
    "true_theta",
    "two_step_ok",
    "RUNS_PER_TASK",
]
