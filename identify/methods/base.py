"""The estimator family: what every identification method is, and what it returns.

An estimator turns one campaign's observations into the elastostatic parameters theta of the
robot's layout (bench/model/params.py: k1..kN, then K_C, s0 per compensator, SI units):

    theta_hat, Cov(theta_hat) = estimator(robot, obs)

where ``obs`` is what a real campaign holds (identify/core/observations.py: the measured
deflections dp_jr, their tracker covariances, the known loads; never the truth) and the robot
is the user's MJCF, read for its geometry only. Each method is one :class:`Method`: its
``--method`` name, the function that estimates (returning a :class:`MethodResult`), which
robots it models (``applies``) and, optionally, how the Monte Carlo repeats it cheaply on noisy
copies of one campaign (``repeat``, default: the full estimate on every run). The one list of
methods is identify/methods/registry.py's: the built-in table, then every method registered at
run time (docs/architecture.md, "How to add an estimator").

Every consumer reads the same :class:`MethodResult`: `calbench identify`'s report
(identify/report/identification.py), the Monte Carlo (identify/study/montecarlo.py) and the
studies (identify/study/campaign.py, through the report).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from calbench.bench.model import Robot
from calbench.identify.core import Observations, Whitener


class NotApplicable(ValueError):
    """The robot is outside what a method models; the message says why and what to use instead."""


@dataclass
class MethodResult:
    """One estimate of the robot's parameters from one campaign (SI units).

    ``theta`` is NaN and ``cov``'s row and column are NaN where the method does not determine
    the parameter (``identifiable`` False, the reason in ``reasons`` under its name). ``residual``
    is measured minus predicted deflection per observation row (M, 3), m; ``residual_w`` the
    same whitened by the tracker covariance, so that ``chi2`` = sum residual_w^2 with ``dof``
    degrees of freedom. ``converged`` is None for a closed-form solve. ``details`` is what the
    method adds to the identification report's JSON (its own keys, e.g. the two-step's "step1"
    and "step2", the one-step's "start" and "converged"); ``iterations`` and ``evaluations``
    count its solver's steps and forward-model evaluations (0 for a closed form).
    """

    method: str
    names: tuple[str, ...]
    units: tuple[str, ...]
    theta: np.ndarray  # (P,)
    cov: np.ndarray  # (P, P)
    identifiable: np.ndarray  # (P,) bool
    reasons: dict[str, str]
    residual: np.ndarray  # (M, 3), m
    residual_w: np.ndarray  # (M, 3)
    chi2: float
    dof: int
    converged: bool | None = None
    iterations: int = 0
    evaluations: int = 0
    details: dict = field(default_factory=dict)

    def __post_init__(self):
        p = len(self.names)
        self.theta = np.asarray(self.theta, dtype=float)
        self.cov = np.asarray(self.cov, dtype=float)
        self.identifiable = np.asarray(self.identifiable, dtype=bool)
        self.residual = np.asarray(self.residual, dtype=float).reshape(-1, 3)
        self.residual_w = np.asarray(self.residual_w, dtype=float).reshape(-1, 3)
        for what, got, want in (
            ("units", (len(self.units),), (p,)),
            ("theta", self.theta.shape, (p,)),
            ("cov", self.cov.shape, (p, p)),
            ("identifiable", self.identifiable.shape, (p,)),
            ("residual_w", self.residual_w.shape, self.residual.shape),
        ):
            if got != want:
                raise ValueError(f"{self.method}: {what} has shape {got}, expected {want}")

    @property
    def std(self) -> np.ndarray:
        """(P,) standard deviations, NaN where not determined."""
        d = np.diag(self.cov)
        return np.sqrt(np.where(np.isfinite(d) & (d >= 0), d, np.nan))


@dataclass(frozen=True)
class IdentifyOptions:
    """What `calbench identify` may ask of a method beyond the observations; a method ignores
    what it has no use for."""

    check_profile: bool = False  # is chi2 quadratic over the reported std (identify/core/profile.py)


@dataclass
class Repeats:
    """A method set up for many noisy copies of one campaign (the Monte Carlo): its estimate on
    the exact readings, and ``run(obs, white)`` for each copy (``white`` the copy's whitener,
    shared by the methods). ``run`` may reuse what the noise-free estimate found (a start, a
    linearisation), never the truth."""

    noise_free: MethodResult
    run: Callable[[Observations, Whitener], MethodResult]


EstimateFn = Callable[[Robot, Observations, IdentifyOptions], MethodResult]
RepeatFn = Callable[[Robot, Observations, Whitener], Repeats]


@dataclass(frozen=True)
class Method:
    """One identification method, as every verb sees it.

    ``name``: the ``--method`` value; ``summary``: its phrase in ``--method``'s help;
    ``estimate(robot, obs, options)``: the estimate; ``applies(robot)``: raises
    :class:`NotApplicable` when the robot is outside the method (None: every robot), with
    ``requirement`` the one phrase of what it needs (the "expected" of the user's error);
    ``repeat(robot, obs0, white0)``: the Monte Carlo's set-up on the exact readings (None: the
    full estimate on every run); ``group``: the `montecarlo --method` choice that runs it
    (default its name: the two-step's step-2 variants share one); ``offered``: whether
    `calbench identify --method` and a study's ``campaign.method`` offer it;
    ``seconds_per_run``: its in-process time per Monte Carlo run (the executor's choice only);
    ``noise_free_always``: the Monte Carlo reports its noise-free model error even when it is
    not run (a cheap method); ``in_both``: `montecarlo --method both` (the default) runs it
    when it applies (`all` runs every method that applies).
    """

    name: str
    estimate: EstimateFn
    summary: str = ""
    applies: Callable[[Robot], object] | None = None
    requirement: str = ""
    repeat: RepeatFn | None = None
    group: str = ""
    offered: bool = True
    seconds_per_run: float = 0.01
    noise_free_always: bool = False
    in_both: bool = True

    @property
    def choice(self) -> str:
        """The `montecarlo --method` value that runs this method."""
        return self.group or self.name

    def check(self, robot: Robot) -> None:
        """NotApplicable when the robot is outside the method."""
        if self.applies is not None:
            self.applies(robot)

    def repeats(self, robot: Robot, obs0: Observations, white0: Whitener) -> Repeats:
        """The Monte Carlo's set-up on the exact readings ``obs0`` (see :class:`Repeats`)."""
        if self.repeat is not None:
            return self.repeat(robot, obs0, white0)
        options = IdentifyOptions()
        return Repeats(
            self.estimate(robot, obs0, options), lambda obs, white: self.estimate(robot, obs, options)
        )
