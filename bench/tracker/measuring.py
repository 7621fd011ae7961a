"""The tracker's readings of a whole campaign: when each is taken and what it reads.

A campaign reads every (pose, state, repeat) in plan order; :func:`reading_times` says when
(s since the campaign's first reading), by the campaign clock's step durations (bench/scenario/timeline.py:
moving to a pose, each reading, hanging the load, taking it off), so that a tracker whose error
drifts in time (bench/tracker/iso10360.py) is simulated on the same timeline the log is stamped with and
identification reads back.

:func:`measure_campaign` draws the readings. For the isotropic and spec trackers each reading is
bench.tracker.measure's, one after the other in plan order (the generator consumed exactly as it
always was: same scenario and seed, same log). For the iso10360 tracker the campaign's
systematic field and drift are drawn first, once, at the true points of every visible reading
(bench.iso10360.draw_correlated), then each reading's independent noise as above, and the two are
added.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from calbench.bench.scenario import LOAD_S, MOVE_S, UNLOAD_S, TrackerSpec, reading_seconds

from .instrument import Measurement, measure, to_tracker_frame
from .iso10360 import draw_correlated

STATES = ("unloaded", "loaded")
Key = tuple[int, str, int]  # (pose, state, repeat)


def schedule(poses: Sequence[tuple[int, int, int]], n_reflectors: int) -> dict[Key, float]:
    """Time of every reading of a campaign that measures ``poses`` = (pose, unloaded readings,
    loaded readings) in this order, in s since its first reading: per pose, move (MOVE_S), the
    unloaded readings (reading_seconds each, stamped when complete), hang the load (LOAD_S), the
    loaded readings, take the load off (UNLOAD_S)."""
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


def measure_campaign(
    spec: TrackerSpec,
    points_world: Sequence[np.ndarray],
    visible: Sequence[np.ndarray],
    repeats: Sequence[int],
    rng: np.random.Generator,
    times: dict[Key, float] | None = None,
) -> dict[Key, Measurement]:
    """Every reading of a campaign (module docstring): ``points_world[j]`` (2, n, 3) the true
    reflector positions of pose j unloaded and loaded, ``visible[j]`` (2, n) which the tracker
    sees, ``repeats[j]`` readings per state; ``times`` as :func:`reading_times` (needed by the
    iso10360 tracker)."""
    keys = [(j, s, r) for j, n in enumerate(repeats) for s in STATES for r in range(int(n))]
    extra: dict[Key, np.ndarray] = {}
    if spec.model == "iso10360":
        if times is None:
            raise ValueError("the iso10360 tracker needs the readings' times")
        rows, pts, tms = [], [], []
        for key in keys:
            j, s, _ = key
            si = STATES.index(s)
            vis = np.flatnonzero(visible[j][si])
            rows.append((key, vis))
            pts.append(to_tracker_frame(spec, points_world[j][si][vis]))
            tms.append(np.full(len(vis), times[key]))
        err = draw_correlated(spec, np.concatenate(pts), np.concatenate(tms), rng)
        at = 0
        for key, vis in rows:
            e = np.zeros((len(visible[key[0]][0]), 3))
            e[vis] = err[at : at + len(vis)]
            extra[key] = e
            at += len(vis)
    out: dict[Key, Measurement] = {}
    for key in keys:
        j, s, _ = key
        si = STATES.index(s)
        m = measure(spec, points_world[j][si], visible[j][si], rng)
        if key in extra:
            pos = m.position + extra[key]
            pos.setflags(write=False)
            m = Measurement(pos, m.covariance, m.visible)
        out[key] = m
    return out


__all__ = ["schedule", "reading_times", "measure_campaign"]
