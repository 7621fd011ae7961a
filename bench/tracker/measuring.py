"""The tracker's readings of a whole campaign: what each reads, on the campaign's timeline.

A campaign reads every (pose, state, repeat) in plan order, each at its time (s since the
campaign's first reading: bench/scenario/timeline.py's ``reading_times``, the campaign clock's
step durations), so that a tracker whose error drifts in time (bench/tracker/models/iso10360.py)
is simulated on the same timeline the log is stamped with and identification reads back.

:func:`measure_campaign` draws the readings. A tracker whose readings are independent (isotropic,
spec) gives each reading bench.tracker.measure's, one after the other in plan order (the
generator consumed exactly as it always was: same scenario and seed, same log). A correlated
model (TrackerModel.correlated, iso10360) first draws the campaign's shared error, once, at the
true points of every visible reading (TrackerModel.draw_correlated: bench/tracker/base.py's eq.
1), then each reading's independent error as above, and the two are added.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from calbench.bench.core import STATES

from .base import TrackerSpec
from .instrument import Measurement, measure, to_tracker_frame

Key = tuple[int, str, int]  # (pose, state, repeat)


def measure_campaign(
    spec: TrackerSpec,
    points_world: Sequence[np.ndarray],
    visible: Sequence[np.ndarray],
    repeats: Sequence[int],
    rng: np.random.Generator | None,
    times: dict[Key, float] | None = None,
) -> dict[Key, Measurement]:
    """Every reading of a campaign (module docstring): ``points_world[j]`` (2, n, 3) the true
    reflector positions of pose j unloaded and loaded, ``visible[j]`` (2, n) which the tracker
    sees, ``repeats[j]`` readings per state; ``times`` as bench.scenario.reading_times (needed
    by a model whose error depends on them, TrackerModel.uses_times). ``rng`` None: the exact
    readings (:func:`measure`'s), no shared error either."""
    keys = [(j, s, r) for j, n in enumerate(repeats) for s in STATES for r in range(int(n))]
    extra: dict[Key, np.ndarray] = {}
    model = spec.error_model
    if model.correlated and rng is not None:
        if times is None and model.uses_times:
            raise ValueError(f"the {model.name} tracker needs the readings' times")
        rows, pts, tms = [], [], []
        for key in keys:
            j, s, _ = key
            si = STATES.index(s)
            vis = np.flatnonzero(visible[j][si])
            rows.append((key, vis))
            pts.append(to_tracker_frame(spec, points_world[j][si][vis]))
            tms.append(np.full(len(vis), np.nan if times is None else times[key]))
        err = model.draw_correlated(spec, np.concatenate(pts), np.concatenate(tms), rng)
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


__all__ = ["measure_campaign"]
