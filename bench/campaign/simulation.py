"""A campaign in memory: the one code path from a scenario to its readings.

:func:`simulate` solves every pose (bench/campaign/plan.py), then reads the whole campaign with
the tracker (bench.tracker.measure_campaign: one generator consumed in plan order, (pose,
state, repeat) by (pose, state, repeat), each reading at its time on the campaign's timeline,
bench.scenario.reading_times) and adds the truth's measurement-side effects (a
``tracker_drift``) to the loaded readings. What it returns, a :class:`Campaign`, is what every
user of a simulated campaign reads: the log writer (bench/campaign/run.py's ``run_campaign``),
the observations in memory (identify/core/observations.py's ``from_campaign``), the Monte Carlo,
the studies and the predicted accuracy. So the same scenario and generator give the same
readings, to the last bit, on every path.

:func:`remeasure` reads a solved campaign again with another generator (the Monte Carlo's runs:
the physics is solved once). A generator of None gives the exact readings: the true points, no
noise, each with the covariance the tracker's model gives it (what the noise-free analyses,
Cramer-Rao bounds and noise-free estimates, weight by).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from calbench.bench.core import STATES, ProgressSink
from calbench.bench.log import LogHeader
from calbench.bench.model import Robot
from calbench.bench.model.effects import ObservationRows, effect_from_truth
from calbench.bench.scenario import Scenario, reading_times
from calbench.bench.tracker import Measurement, TrackerSpec, measure_campaign, tracker_rotation

from .plan import PosePlan, check_campaign_size, plan_campaign, truth_robot

Key = tuple[int, str, int]  # (pose, state, repeat), as bench.scenario.reading_times


@dataclass(frozen=True)
class Campaign:
    """A simulated campaign: the solved plan, every reading, their times, the log's header.

    ``readings[(pose, state, repeat)]`` is the tracker's reading (tracker frame, m; invisible
    rows NaN) with the truth's measurement-side effects already added, exactly what the log's
    ``/tracker/measurement`` carries; ``times`` the same keys' times (s since the campaign's
    first reading). ``header`` is the log's header (the nominal MJCF's text, the reflectors, the
    payload site, the tracker, the seed). ``robot`` and the plans' equilibria are the truth: a
    user that stands for identification reads only the readings, the commands, the loads and
    the header (identify/core/observations.py's ``from_campaign``). ``exact``: noise-free
    readings (generator None)."""

    scenario: Scenario
    robot: Robot  # the true robot (truth_robot): the plans were solved on it
    header: LogHeader
    plans: tuple[PosePlan, ...]
    readings: Mapping[Key, Measurement]
    times: Mapping[Key, float]
    exact: bool = False

    @property
    def tracker(self) -> TrackerSpec:
        return self.scenario.tracker

    @property
    def reflectors(self) -> tuple[str, ...]:
        return tuple(self.header.reflectors)

    def pose_readings(self, index: int, state: str) -> list[Measurement]:
        """The readings of pose ``index`` (its place in the plan) in ``state``, repeat by repeat."""
        return [self.readings[(index, state, r)] for r in range(self.scenario.poses[index].repeats)]

    def pose_times(self, index: int, state: str) -> list[float]:
        """:meth:`pose_readings`'s times (s since the campaign's first reading)."""
        return [self.times[(index, state, r)] for r in range(self.scenario.poses[index].repeats)]


def log_header(scn: Scenario, robot: Robot) -> LogHeader:
    """What the log of the scenario's campaign says before its first pose (bench/log/writer.py)."""
    return LogHeader(
        scenario_name=scn.name,
        scenario_text=scn.text,
        scenario_filename=scn.path.name,
        robot_filename=Path(scn.robot).name,
        mjcf_text=Path(scn.robot).read_text(),
        reflectors=list(robot.reflector_names),
        payload_site=robot.payload_name,
        n_joints=robot.n_act,
        tracker=scn.tracker.to_dict(),
        seed=int(scn.seed),
        start_time=scn.start_time,
    )


def reading_drift(scn: Scenario, index: int, reflectors: list[str]) -> np.ndarray | None:
    """(n, 3) m, tracker frame: what the truth's measurement-side effects (bench/model/effects/,
    e.g. `tracker_drift`) add to pose ``index``'s loaded readings of ``reflectors``; None when
    the truth has none. The robot and the noise are untouched."""
    rot = tracker_rotation(scn.tracker)
    total = None
    for name, table in scn.effects.items():
        effect, params = effect_from_truth(name, table)
        if effect.measurement_side:
            term = effect.deflection_term(params, ObservationRows(tuple((index, r) for r in reflectors), rot))
            total = term if total is None else total + term
    return None if total is None else total @ rot  # world -> tracker frame: R^T x


def _read(
    scn: Scenario,
    plans: tuple[PosePlan, ...],
    reflectors: list[str],
    times: Mapping[Key, float],
    rng: np.random.Generator | None,
) -> dict[Key, Measurement]:
    """Every reading of the solved campaign (module docstring), the drift added."""
    measured = measure_campaign(
        scn.tracker,
        [p.reflectors_world for p in plans],
        [p.visible for p in plans],
        [p.repeats for p in scn.poses],
        rng,
        dict(times),
    )
    for plan, pose in zip(plans, scn.poses):
        shift = reading_drift(scn, plan.index, reflectors)
        if shift is None:
            continue
        for r in range(pose.repeats):  # invisible rows stay NaN
            key = (plan.index, STATES[1], r)
            measured[key] = replace(measured[key], position=measured[key].position + shift)
    return measured


def simulate(
    scn: Scenario,
    rng: np.random.Generator | None,
    *,
    robot: Robot | None = None,
    progress: ProgressSink | None = None,
    force: bool = False,
) -> Campaign:
    """The scenario's campaign in memory (module docstring), its readings drawn from ``rng``
    (``np.random.default_rng(scn.seed)`` is the log's; None: exact readings). ``robot``: the
    scenario's true robot when the caller has it (:func:`truth_robot`'s). A campaign beyond
    bench/scenario/timeline.py's size limits is refused (InputError) unless ``force``; a bad pose
    too (bench/campaign/plan.py). ``progress`` hears of every solved pose (the caller starts it)."""
    robot = robot or truth_robot(scn)
    if not force:
        check_campaign_size(scn, robot)
    plans = tuple(plan_campaign(scn, robot, progress))
    names = list(robot.reflector_names)
    times = reading_times([p.repeats for p in scn.poses], len(names))
    readings = _read(scn, plans, names, times, rng)
    return Campaign(scn, robot, log_header(scn, robot), plans, readings, times, rng is None)


def remeasure(campaign: Campaign, rng: np.random.Generator | None) -> Campaign:
    """The same solved campaign read again, its readings drawn from ``rng`` (None: exact)."""
    readings = _read(campaign.scenario, campaign.plans, list(campaign.reflectors), campaign.times, rng)
    return replace(campaign, readings=readings, exact=rng is None)


__all__ = ["Campaign", "Key", "log_header", "reading_drift", "remeasure", "simulate"]
