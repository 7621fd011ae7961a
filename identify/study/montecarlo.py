"""Monte Carlo of the estimators: the same campaign re-measured with N noise seeds.

The campaign is simulated once (bench.campaign.simulate: the true reflector positions and
visibility of every pose, read exactly); each run reads it again with its own generator
(bench.campaign.remeasure, seeded by (scenario seed, run)), builds its observations
(identify/core/observations.py's from_campaign, the rows a log gives) and runs the full estimators on them, methods of the family's
one list (identify/methods/registry.py): by default (`--method both`) the one-step estimator
and the paper's two-step method, unweighted step 2 (eq. 21) and step-1-covariance-weighted;
with `--method all` also the two-step at its self-consistent sagged pose
(identify/methods/twostep_iterated.py; every run starts at the noise-free sag, its pose rows and
equilibria, with the noise-free Newton Jacobian as its chord; ~5x the one-step per run).

Time: `calbench montecarlo` announces the duration from :func:`measure_montecarlo` (the set-up
and PROBE_RUNS runs on noise seeds no run uses, timed at its start); OBSERVATION_SECONDS_PER_RUN
and the methods' seconds_per_run are only :func:`estimated_seconds`'s fallback. Each method sets itself up
once on the exact readings (its ``repeats``: the noise-free estimate and a run function that
may reuse what it found) and the runs call that function; the noise-free estimates of the cheap
methods (``noise_free_always``) are reported even when they are not run.

Per parameter and method it reports: bias / empirical std (with its sampling error 1/sqrt(N)),
empirical std / mean reported std, and empirical variance / Cramer-Rao bound, the CRB being the
inverse Fisher information J^T Sigma^-1 J at the TRUE parameters on the exact model (a forward
model of its own, its first evaluation solved at the truth: its CRB std agree with central
differences of the model to 1e-7 on the paper campaign, where the one-step's model warm from the
noise-free fit, used before, was off by 2e-6). The sampling error of a variance ratio is about
sqrt(2/(N-1)).

Speed: every one-step run starts at the noise-free estimate (the one-step estimate of the
noise-free observations, itself started from their two-step estimate: no truth involved) whose
model value and Jacobian are evaluated once and reused, so a run costs one evaluation of the
exact model and its IFT Jacobian when the stopping rule (identify/methods/onestep.py's
MC_STEP_TOL) is met at the second step. The truth enters only the CRB and the statistics.

Execution: the runs go out in blocks of RUNS_PER_TASK as tasks (identify/runtime/executor.py: this
process, a local Dask cluster or the user's). A task carries the scenario's and the MJCF's texts
(identify/runtime/portable.py); each process builds the shared set-up above once and starts every run
from a copy of the same estimator state, and run r's noise comes from the generator seeded by
(seed, r) alone, so the numbers are bit-identical whatever ran them and in whatever order.
"""

from __future__ import annotations

import contextlib
import functools
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calbench.bench.campaign import (
    Campaign,
    check_campaign_size,
    remeasure,
    simulate,
    truth_params,
    truth_robot,
)
from calbench.bench.core import InputError, ProgressSink, sink
from calbench.bench.model import Robot, display_name, free_length_note, load_robot
from calbench.bench.scenario import Scenario, check_size, montecarlo_estimate
from calbench.identify.core import (
    ForwardModel,
    Observations,
    Whitener,
    design_from_observations,
    from_campaign,
)
from calbench.identify.methods import (
    BOTH,
    MethodResult,
    NotApplicable,
    all_methods,
    linear_plan,
    method_named,
    method_names,
    select_methods,
    two_step,
    two_step_applies,
)
from calbench.identify.runtime import Executor, InProcess, Interrupted, PortableScenario

RUNS_PER_TASK = 50  # a task of ~0.5-1 s: Dask's ~5 ms of scheduling per task stays < 1 %
# in-process seconds per run on the paper campaign (measured here) for the noise and the
# observations; each method states its own (Method.seconds_per_run): the executor's choice only
OBSERVATION_SECONDS_PER_RUN = 0.004


def true_theta(scn: Scenario, robot: Robot) -> np.ndarray:
    return robot.layout.theta(truth_params(scn, robot))


def two_step_ok(robot: Robot) -> bool:
    """Whether the paper's two-step method applies to the robot (identify/methods/twostep.py)."""
    try:
        two_step_applies(robot)
    except NotApplicable:
        return False
    return True


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
    # method -> (runs, 2): its solver's iterations and model evaluations per run
    iterations: dict[str, np.ndarray] = field(default_factory=dict)

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
    campaign: Campaign  # solved once, read exactly; each run remeasures it
    robot: Robot
    obs0: Observations
    runs: dict[str, Callable[[Observations, Whitener], MethodResult]]  # method -> one run
    theta_true: np.ndarray
    crb: np.ndarray
    noise_free: dict[str, np.ndarray]
    seconds: float


@functools.lru_cache(maxsize=4)
def _setup(job: MonteCarloJob) -> _Setup:
    t0 = time.perf_counter()
    scn = job.scenario.scenario(job.seed)
    exact = simulate(scn, None, force=True)  # the size is the caller's to check (--force)
    robot = Robot.from_file(scn.robot)  # the estimator's own model: geometry only
    for name in job.methods:
        method_named(name).check(robot)  # NotApplicable when the robot is outside a method
    obs0 = from_campaign(exact)
    white0 = Whitener.from_observations(obs0)
    theta_true = true_theta(scn, robot)

    noise_free: dict[str, np.ndarray] = {}
    runs = {}
    for m in all_methods():
        if m.name not in job.methods:
            if not m.noise_free_always:
                continue
            try:
                m.check(robot)
            except NotApplicable:
                continue
        rep = m.repeats(robot, obs0, white0)
        noise_free[m.name] = rep.noise_free.theta
        if m.name in job.methods:
            runs[m.name] = rep.run
    if two_step_ok(robot) and exact.robot.model.nq == robot.model.nq:  # hidden effects add joints
        # diagnostic: the linear model at the true (sagged) unloaded configuration -- what is left
        # of the two-step's model error is H00 (eq. 18) and the nonlinearity over the deflection
        lp_true = linear_plan(robot, obs0, {p.index: p.equilibria[0].qpos for p in exact.plans})
        noise_free["two-step at the true sagged configuration"] = two_step(
            robot, obs0, False, lp=lp_true, white=white0
        ).theta
    # Cramer-Rao bound at the truth, on the exact model (a forward model of its own)
    _, jt = ForwardModel(robot, design_from_observations(robot, obs0)).evaluate(theta_true)
    jtw = white0.mat(jt) * theta_true  # scaled columns
    crb = np.linalg.pinv(jtw.T @ jtw) * np.outer(theta_true, theta_true)
    return _Setup(scn, exact, robot, obs0, runs, theta_true, crb, noise_free, time.perf_counter() - t0)


def run_block(job: MonteCarloJob, first: int, stop: int) -> dict:
    """Runs first..stop-1 of the job: the task function, the same in-process and on a worker.

    Run r draws its noise from the generator seeded by (job.seed, r) and every method starts
    from the same state (its ``repeats``), so its result depends on nothing but (job, r)."""
    s = _setup(job)
    n, p = stop - first, s.robot.layout.n
    est_out = {m: np.full((n, p), np.nan) for m in job.methods}
    std_out = {m: np.full((n, p), np.nan) for m in job.methods}
    iters = {m: np.zeros((n, 2), dtype=int) for m in job.methods}
    times = {m: 0.0 for m in job.methods}
    failed = {m: 0 for m in job.methods}
    for k, r in enumerate(range(first, stop)):
        rng = np.random.default_rng([job.seed, r])
        obs = from_campaign(remeasure(s.campaign, rng))
        if obs.labels != s.obs0.labels:
            raise RuntimeError("visibility changed between runs")  # cannot happen: fixed plan
        white = Whitener.from_observations(obs)
        for meth in job.methods:
            t = time.perf_counter()
            try:
                res = s.runs[meth](obs, white)
            except (np.linalg.LinAlgError, NotApplicable):
                # this run's estimate left the robot's statics (e.g. the iterated two-step's sag at a
                # spring that makes the stiffness singular): the method failed on this run, the
                # other runs and methods stand (NaN: counted as not identified, and as failed)
                failed[meth] += 1
                times[meth] += time.perf_counter() - t
                continue
            times[meth] += time.perf_counter() - t
            est_out[meth][k] = res.theta
            std_out[meth][k] = res.std
            iters[meth][k] = (res.iterations, res.evaluations)
    return {"estimates": est_out, "stds": std_out, "times": times, "iterations": iters, "failed": failed}


def check_montecarlo_size(scn: Scenario, runs: int) -> None:
    """InputError when one campaign of the scenario, or ``runs`` of them, is estimated to be too
    large (bench/scenario/timeline.py's limits, as `simulate`'s)."""
    truth_rb = truth_robot(scn)
    check_campaign_size(scn, truth_rb)  # one campaign
    repeats, n_refl = [p.repeats for p in scn.poses], len(truth_rb.reflector_names)
    check_size(montecarlo_estimate(repeats, n_refl, runs), "--runs", "runs")


def montecarlo_methods(choice: str, scn: Scenario) -> tuple[str, ...]:
    """The methods `calbench montecarlo --method choice` runs on the scenario's robot
    (identify/methods/registry.py: ``both`` those that apply to it); InputError when its MJCF
    does not load or a method chosen by name does not apply."""
    robot = load_robot(scn.path, "robot", path=scn.robot)
    return select_methods(choice, robot, scn.robot)


PROBE_RUNS = 2  # runs timed at the start of `calbench montecarlo` to estimate the rest


@dataclass(frozen=True)
class WorkEstimate:
    """What a job costs, measured on a few of its pieces at its start: the set-up each process
    builds once, and the in-process seconds per piece (a Monte Carlo run)."""

    setup_seconds: float
    seconds_per_piece: float
    probed: int  # pieces timed

    def seconds(self, pieces: int) -> float:
        """In-process work of ``pieces`` pieces (the set-up apart)."""
        return pieces * self.seconds_per_piece


def measure_montecarlo(
    scn: Scenario, methods, seed: int | None = None, probe: int = PROBE_RUNS
) -> WorkEstimate:
    """The Monte Carlo's set-up (built here, then reused by the in-process runs) and the time of
    ``probe`` runs on noise seeds of their own (the runs' seeds are untouched), each method
    with one BLAS thread as the runs have: the per-run cost on this machine, now."""
    from calbench.identify.runtime import blas_threads

    job = MonteCarloJob(
        PortableScenario.from_scenario(scn), tuple(methods), scn.seed if seed is None else int(seed)
    )
    t0 = time.perf_counter()
    s = _setup(job)
    t1 = time.perf_counter()
    with blas_threads(1):
        for r in range(probe):  # noise seeds no run uses: (seed, 2^31 + r)
            obs = from_campaign(remeasure(s.campaign, np.random.default_rng([job.seed, 2**31 + r])))
            white = Whitener.from_observations(obs)
            for meth in job.methods:
                try:
                    s.runs[meth](obs, white)
                except (np.linalg.LinAlgError, NotApplicable):
                    pass
    t2 = time.perf_counter()
    return WorkEstimate(t1 - t0, (t2 - t1) / max(probe, 1), probe)


@dataclass(frozen=True)
class PendingMonteCarlo:
    """A Monte Carlo checked and priced, ready to run (:func:`prepare_montecarlo`): the
    scenario, the runs, the methods that run, and the cost measured on probe runs."""

    scenario: Scenario
    runs: int
    methods: tuple[str, ...]
    cost: WorkEstimate

    @property
    def tasks(self) -> int:
        """Blocks of RUNS_PER_TASK runs: the pieces an executor runs."""
        return -(-self.runs // RUNS_PER_TASK)

    def seconds(self) -> float:
        """In-process work of every run (the set-up apart)."""
        return self.cost.seconds(self.runs)


def prepare_montecarlo(
    scn: Scenario, runs: int, choice: str = BOTH, seed: int | None = None, force: bool = False
) -> PendingMonteCarlo:
    """`calbench montecarlo` before it runs: ``runs`` >= 2, the size limits (unless ``force``),
    the methods ``choice`` names for the scenario's robot (:func:`montecarlo_methods`), and the
    cost of a run measured here (:func:`measure_montecarlo`, whose set-up the runs in this
    process reuse). InputError on any of them."""
    if runs < 2:
        raise InputError("--runs", "runs", "an integer >= 2", runs)
    if not force:
        check_montecarlo_size(scn, runs)
    methods = montecarlo_methods(choice, scn)
    return PendingMonteCarlo(scn, runs, methods, measure_montecarlo(scn, methods, seed))


def estimated_seconds(runs: int, methods=None) -> float:
    """In-process time of ``runs`` runs of ``methods`` (default: all of them; each method's
    seconds_per_run, measured), for the executor choice."""
    methods = method_names() if methods is None else methods
    return runs * (OBSERVATION_SECONDS_PER_RUN + sum(method_named(m).seconds_per_run for m in methods))


def run_montecarlo(
    scn: Scenario,
    runs: int,
    methods=None,
    progress: ProgressSink | None = None,
    seed: int | None = None,
    executor: Executor | None = None,
) -> MonteCarlo:
    """N runs of the estimators on the scenario's campaign (``methods``: names, default those
    of `montecarlo --method both` that apply to its robot); see the module docstring. Every method must apply to the robot (NotApplicable
    otherwise: e.g. the two-step's TwoStepError).

    The runs go to ``executor`` (identify/runtime/executor.py; default: this process) in blocks of
    RUNS_PER_TASK. Ctrl-C raises :class:`Interrupted` carrying the Monte Carlo of the runs that
    finished."""
    t_wall = time.perf_counter()
    methods = montecarlo_methods(BOTH, scn) if methods is None else tuple(methods)
    job = MonteCarloJob(PortableScenario.from_scenario(scn), methods, scn.seed if seed is None else int(seed))
    s = _setup(job)
    lay = s.robot.layout
    executor = executor or InProcess()
    blocks = [(job, a, min(a + RUNS_PER_TASK, runs)) for a in range(0, runs, RUNS_PER_TASK)]
    estimates = {m: np.full((runs, lay.n), np.nan) for m in methods}
    stds = {m: np.full((runs, lay.n), np.nan) for m in methods}
    times = {m: 0.0 for m in methods}
    failed = {m: 0 for m in methods}
    iters = {m: np.zeros((runs, 2), dtype=int) for m in methods}
    done = np.zeros(runs, bool)
    bar = sink(progress)
    bar.start(runs, "Monte Carlo")

    def result(keep: np.ndarray) -> MonteCarlo:
        return MonteCarlo(
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
            {m: v[keep] for m, v in iters.items()},
        )

    try:
        with contextlib.closing(executor.run(run_block, blocks)) as results:  # closed: nothing left running
            for i, out in results:
                _, a, b = blocks[i]
                for m in methods:
                    estimates[m][a:b] = out["estimates"][m]
                    stds[m][a:b] = out["stds"][m]
                    times[m] += out["times"][m]
                    failed[m] += out["failed"][m]
                    iters[m][a:b] = out["iterations"][m]
                done[a:b] = True
                bar.update(executor.progress_label(f"runs {int(done.sum())}/{runs}"), step=b - a)
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
            f"  {'parameter':<24}{'bias/sd':>9}{'sd/rep.sd':>11}{'var/CRB':>9}{'MSE/CRB':>9}"
            f"{'noise-free err/CRBsd':>22}"
        )
        for p in d["parameters"]:
            name = display_name(p["name"])
            if "bias_over_sigma" not in p:
                lines.append(f"  {name:<24}  not identified")
                continue
            nfe = p["noise_free_error_over_crb_std"]
            g = lambda x: f"{x:.3f}" if abs(x) < 1e4 else f"{x:.2e}"  # noqa: E731
            lines.append(
                f"  {name:<24}{g(p['bias_over_sigma']):>9} {g(p['empirical_over_reported_std']):>10}"
                f" {g(p['variance_over_crb']):>9} {g(p['mse_over_crb']):>9}"
                f"{(g(nfe) if nfe is not None else 'n/a'):>22}"
            )
    names = [p["name"] for d in s["methods"].values() for p in d["parameters"]]
    lines += ["", *LEGEND]
    note = free_length_note(names)
    if note:
        lines.append(f"  {note}")
    return "\n".join(lines)


LEGEND = (
    'Columns (docs/identification.md, "Monte Carlo"), per parameter over the runs:',
    "  bias/sd               (mean - truth) / the runs' spread: a bias in units of the spread (0 +- 1/sqrt(N))",
    "  sd/rep.sd             the runs' spread / the std the method reports: 1 when its reported std is honest",
    "  var/CRB               the runs' variance / the Cramer-Rao bound at the truth: 1 = efficient, > 1 wasted",
    "  MSE/CRB               mean squared error / the CRB: spread and bias together; a huge ratio",
    "                        with a small sd/rep.sd is heavy tails (the two-step's s0 = (s0 K_C) / K_C",
    "                        divides by a noisy K_C): robust_std_over_crb_std in the JSON ignores them",
    "  noise-free err/CRBsd  the estimate on exact readings minus the truth, in CRB stds: the method's",
    "                        own model error (n/a: that estimate did not identify the parameter)",
    "  methods: one-step (exact statics), two-step (paper eqs. 19-22, step 2 unweighted as eq. 21),",
    "  two-step-weighted (step 2 weighted by step 1's covariance), two-step-iterated (two-step at its",
    "  self-consistent sagged pose; --method all); not identified: fewer than two runs identified it",
)


__all__ = [
    "OBSERVATION_SECONDS_PER_RUN",
    "check_montecarlo_size",
    "montecarlo_methods",
    "run_montecarlo",
    "prepare_montecarlo",
    "PendingMonteCarlo",
    "run_block",
    "estimated_seconds",
    "measure_montecarlo",
    "WorkEstimate",
    "PROBE_RUNS",
    "MonteCarlo",
    "MonteCarloJob",
    "format_summary",
    "true_theta",
    "two_step_ok",
    "RUNS_PER_TASK",
]
