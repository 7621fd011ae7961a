"""When things happen in a simulated campaign, and how long and how large a campaign is.

The clock
---------
A campaign log is stamped as the campaign would run on a real robot, from the scenario's
``start_time`` (ISO 8601 with a UTC offset; default :data:`DEFAULT_START`, a fixed date, so the
same scenario and seed still give the same log, byte for byte). Every message is in causal
order, and each pose takes (assumed durations, the numbers a tracker drift model can build on):

=========================  ==========================================================  =========
step                       what happens                                                seconds
=========================  ==========================================================  =========
``/campaign/pose``         the command is sent; the robot drives there at reduced       MOVE_S 60
(unloaded)                 speed and settles
``/tracker/measurement``   one reading of every reflector: the tracker turns to each    10 per
(unloaded, per repeat)     one, locks on, averages ~2 s (stable probing)                reflector
``/campaign/wrench``,      the payload is hung from the crane hook (or the pull is      LOAD_S 300
``/campaign/pose`` loaded  rigged) and the structure settles
``/tracker/measurement``   as above                                                     10 per
(loaded, per repeat)                                                                    reflector
``/campaign/pose_done``    the load is taken off: the pose is finished                 UNLOAD_S 180
=========================  ==========================================================  =========

A message is stamped when its step ends (a reading when it is complete); the truth of a state
right after its last reading. With three reflectors and one repeat a pose takes 10 min, the
paper's 16-pose plan 2 h 40 min. Times are integers in ns since 1970 (UTC), as MCAP wants.
:func:`reading_times` (:func:`schedule` for poses in any order) gives the same clock's reading
times in s since the campaign's first reading: what a tracker whose error drifts in time is
simulated on (bench/tracker/measuring.py).

The size
--------
:func:`estimate` gives the campaign's readings, simulated run time on this machine, log size and
real duration; :func:`check_size` refuses (InputError, exit 2) a campaign that would run longer
than :data:`MAX_SECONDS` or write more than :data:`MAX_LOG_BYTES`, saying the estimate, unless
forced. Measured on the 2-core machine with the paper robot (3 reflectors): about 0.2 ms of
simulation per reading (16 poses x 2 states x 1000 repeats: 6.9 s); the log takes ~36 bytes per
reflector and reading, ~4.3 kB per pose (commands, load, truth, the Foxglove view) and ~50 kB
once (schemas, scenario, MJCF). The estimate rounds each up (:data:`SECONDS_PER_READING`,
:data:`BYTES_PER_REFLECTOR_READING`, :data:`BYTES_PER_POSE`, :data:`BYTES_FIXED`), so it is an
upper bound of the log's size (tests/test_interrupt.py).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, date, datetime, timedelta
from typing import Any

from calbench.bench.core import STATES, InputError, duration

DEFAULT_START = datetime(2025, 1, 6, 8, 0, 0, tzinfo=UTC)  # a Monday, 08:00 UTC
MOVE_S = 60.0
READING_PER_REFLECTOR_S = 10.0
LOAD_S = 300.0
UNLOAD_S = 180.0
NS = 1_000_000_000
# the latest start a campaign may have: MCAP tools commonly hold times as int64 ns (year 2262)
LATEST = datetime(2200, 1, 1, tzinfo=UTC)

SECONDS_PER_READING = 3e-4  # simulated, this machine, rounded up from 0.2 ms
SECONDS_PER_POSE = 0.01  # the pose's two equilibria and checks
SECONDS_PER_FIT = 0.05  # one Monte Carlo run's identification (paper plan: ~0.02 s)
BYTES_PER_REFLECTOR_READING = 50  # compressed log, rounded up from ~36
BYTES_PER_POSE = 6_000  # rounded up from ~4.3 kB
BYTES_FIXED = 64_000  # rounded up from ~50 kB
MAX_SECONDS = 600.0  # refuse what would run more than 10 min without --force
MAX_LOG_BYTES = 1e9  # or write more than 1 GB


def start_ns(when: datetime) -> int:
    """ns since 1970 (UTC) of an aware datetime."""
    delta = when - datetime(1970, 1, 1, tzinfo=UTC)
    return (delta.days * 86_400 + delta.seconds) * NS + delta.microseconds * 1000


def parse_start_time(value: Any, file: object, key: str = "start_time") -> datetime:
    """A scenario's ``start_time``: a TOML date-time or an ISO 8601 string, with a UTC offset
    (or Z), between 1970 and 2200. InputError otherwise."""
    what = "an ISO 8601 date-time with a UTC offset, e.g. 2025-01-06T08:00:00Z"
    when = value
    if isinstance(value, str):
        try:
            when = datetime.fromisoformat(value.strip().replace("Z", "+00:00"))
        except ValueError:
            raise InputError(file, key, what, value) from None
    if not isinstance(when, datetime):
        got = value.isoformat() if isinstance(value, date) else value
        raise InputError(file, key, what, got)
    if when.tzinfo is None or when.utcoffset() is None:
        raise InputError(file, key, what + " (the offset says which clock)", when.isoformat())
    if not datetime(1970, 1, 1, tzinfo=UTC) <= when < LATEST:
        raise InputError(file, key, f"a date-time between 1970 and {LATEST.year}", when.isoformat())
    return when.astimezone(UTC)


class CampaignClock:
    """The clock of one campaign log: advances by the step durations above as the writer is
    called (see the module docstring); an explicit time (an imported log) moves it there."""

    def __init__(self, start: int):
        self.start = int(start)
        self.now = int(start)

    def advance(self, seconds: float) -> int:
        self.now += int(round(seconds * NS))
        return self.now

    def at(self, t: int | None) -> int:
        """``t`` when given (and the clock follows it), else the current time."""
        if t is not None:
            self.now = max(self.now, int(t))
            return int(t)
        return self.now


def reading_seconds(n_reflectors: int) -> float:
    return READING_PER_REFLECTOR_S * max(int(n_reflectors), 1)


Key = tuple[int, str, int]  # (pose, state, repeat)


def schedule(poses: Sequence[tuple[int, int, int]], n_reflectors: int) -> dict[Key, float]:
    """Time of every reading of a campaign that measures ``poses`` = (pose, unloaded readings,
    loaded readings) in this order, in s since its first reading: per pose, move (MOVE_S), the
    unloaded readings (reading_seconds each, stamped when complete), hang the load (LOAD_S), the
    loaded readings, take the load off (UNLOAD_S): the clock above, on which a tracker whose error
    drifts (bench/tracker/models/iso10360.py) is simulated and identified."""
    per = reading_seconds(n_reflectors)
    out: dict[Key, float] = {}
    t = 0.0
    for pose, *counts in poses:
        t += MOVE_S
        for state, n in zip(STATES, counts):
            if state == "loaded":
                t += LOAD_S
            for r in range(int(n)):
                t += per
                out[(pose, state, r)] = t
        t += UNLOAD_S
    first = min(out.values(), default=0.0)
    return {k: v - first for k, v in out.items()}


def reading_times(repeats: Sequence[int], n_reflectors: int) -> dict[Key, float]:
    """:func:`schedule` of a simulated campaign: every pose of the plan, ``repeats[j]`` readings
    per state."""
    return schedule([(j, n, n) for j, n in enumerate(repeats)], n_reflectors)


@dataclass(frozen=True)
class Estimate:
    """How big a campaign is: its readings, what simulating it costs here, what it would take
    on a real robot."""

    poses: int
    readings: int
    seconds: float  # simulation on this machine
    log_bytes: float
    real_seconds: float  # the campaign on a robot, by the clock above
    runs: int = 1  # Monte Carlo runs (no log written)

    def words(self) -> str:
        if self.runs > 1:
            return (
                f"{self.runs:,} runs of {self.readings:,} readings: ~{duration(self.seconds)} "
                "to simulate and identify here"
            )
        return (
            f"{self.readings:,} readings: ~{duration(self.seconds)} to simulate here and "
            f"~{size(self.log_bytes)} of log; on a real robot ~{duration(self.real_seconds)}"
        )


def estimate(repeats: Sequence[int], n_reflectors: int) -> Estimate:
    """The estimate of a campaign whose poses have these ``repeats`` (readings per state)."""
    readings = 2 * sum(int(r) for r in repeats)
    n = len(repeats)
    return Estimate(
        poses=n,
        readings=readings,
        seconds=SECONDS_PER_READING * readings + SECONDS_PER_POSE * n,
        log_bytes=BYTES_FIXED
        + BYTES_PER_POSE * n
        + BYTES_PER_REFLECTOR_READING * max(n_reflectors, 1) * readings,
        real_seconds=n * (MOVE_S + LOAD_S + UNLOAD_S) + readings * reading_seconds(n_reflectors),
    )


def montecarlo_estimate(repeats: Sequence[int], n_reflectors: int, runs: int) -> Estimate:
    """A Monte Carlo study: the plan is solved once, then each run draws every reading and
    identifies; no log is written."""
    one = estimate(repeats, n_reflectors)
    return Estimate(
        one.poses,
        one.readings,
        SECONDS_PER_POSE * one.poses + runs * (SECONDS_PER_READING * one.readings + SECONDS_PER_FIT),
        0.0,
        one.real_seconds,
        int(runs),
    )


def check_size(est: Estimate, file: object, key: str) -> None:
    """Refuse what would run more than MAX_SECONDS or write more than MAX_LOG_BYTES (InputError
    naming ``key`` and saying the estimate); callers skip it when forced (--force)."""
    if est.seconds <= MAX_SECONDS and est.log_bytes <= MAX_LOG_BYTES:
        return
    limit = duration(MAX_SECONDS) + ("" if est.runs > 1 else f" and {size(MAX_LOG_BYTES)} of log")
    raise InputError(
        file,
        key,
        f"a {'study' if est.runs > 1 else 'campaign'} this machine "
        f"finishes in reasonable time (at most {limit}; --force runs it anyway)",
        Said(est.words()),
    )


class Said(str):
    """Text an InputError shows as it is (its repr is the text)."""

    def __repr__(self) -> str:
        return str(self)


def repeats_key(repeats: Sequence[int]) -> str:
    """The scenario key to blame for a campaign's size: the pose with the most repeats."""
    i = max(range(len(repeats)), key=lambda k: repeats[k]) if repeats else 0
    return f"pose[{i}].repeats" if repeats and repeats[i] > 1 else "pose"


def size(nbytes: float) -> str:
    for unit, b in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if nbytes >= b:
            v = nbytes / b
            return f"{v:,.0f} {unit}" if v >= 100 else f"{v:.3g} {unit}"
    return f"{nbytes:.0f} B"


def iso(t_ns: int) -> str:
    """ns since 1970 as ISO 8601 UTC (for messages and tests)."""
    when = datetime(1970, 1, 1, tzinfo=UTC) + timedelta(microseconds=t_ns // 1000)
    return when.isoformat().replace("+00:00", "Z")


__all__ = [
    "DEFAULT_START",
    "MOVE_S",
    "READING_PER_REFLECTOR_S",
    "LOAD_S",
    "UNLOAD_S",
    "CampaignClock",
    "Estimate",
    "estimate",
    "montecarlo_estimate",
    "check_size",
    "repeats_key",
    "parse_start_time",
    "start_ns",
    "reading_seconds",
    "schedule",
    "reading_times",
    "duration",
    "size",
    "iso",
    "MAX_SECONDS",
    "MAX_LOG_BYTES",
]
