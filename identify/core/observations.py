"""What identification may know: the measured deflections and the known inputs of each pose.

Paper eq. (2): only positions are measured, so the observation of pose j and reflector r is
the deflection

    dp_jr = mean(loaded readings of r) - mean(unloaded readings of r)     (world frame, m)

The means are :func:`bench.tracker.mean_reading`'s, the viewer's too. Their covariance is
bench.tracker.deflection_covariance's (bench/tracker/base.py, eq. 3), one block per pose over
all its reflectors: for a tracker whose readings are independent (isotropic, spec)
Cov(mean loaded) + Cov(mean unloaded) per reflector (each reading is used in exactly one dp);
for a correlated one (TrackerModel.correlated: iso10360) also the error that the pose's readings
share, which correlates its loaded and unloaded readings and its reflectors (the readings'
times, from the log, give iso10360's drift). Poses are independent
(identify/core/whitening.py). A reflector counts only when it is visible in both states of the pose.
The known inputs are the commanded angles q, the applied wrench (force, moment, site) and the
tracker pose from the log header.

Nothing here reads a ``/truth/`` topic or the ``ground_truth`` record: :func:`from_log` takes a
:class:`bench.log.CampaignLog`, and the caller reads it with ``include_truth=False``;
:func:`from_campaign` reads of a campaign simulated in memory only what its log would carry.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from calbench.bench.campaign import Campaign
from calbench.bench.core import STATES, InputError
from calbench.bench.log import CampaignLog
from calbench.bench.tracker import TrackerSpec, deflection_covariance, mean_reading, tracker_rotation


@dataclass(frozen=True)
class PoseObservation:
    """One complete pose: known inputs and the measured deflections of its reflectors."""

    index: int  # pose index in the plan
    q: np.ndarray  # (N,) rad, commanded, one per actuated joint
    force: np.ndarray  # (3,) N, world frame, applied in the loaded state
    moment: np.ndarray  # (3,) N*m, world frame
    site: str  # MJCF site the wrench acts at
    reflectors: tuple[str, ...]  # reflectors seen in both states (rows of dp)
    dp: np.ndarray  # (n, 3) m, world frame
    cov: np.ndarray  # (n, 3, 3) m^2, each reflector's own (the diagonal blocks)
    cov_block: np.ndarray | None = None  # (n, 3, n, 3) m^2, all of the pose; None: no correlation

    def block(self) -> np.ndarray:
        """The pose's covariance as a (3n, 3n) matrix (rows: reflectors, then x y z)."""
        n = len(self.reflectors)
        if self.cov_block is not None:
            return self.cov_block.reshape(3 * n, 3 * n)
        out = np.zeros((n, 3, n, 3))
        for i in range(n):
            out[i, :, i, :] = self.cov[i]
        return out.reshape(3 * n, 3 * n)

    def subset(self, rows: Sequence[int]) -> PoseObservation:
        rows = list(rows)
        block = None if self.cov_block is None else self.cov_block[np.ix_(rows, range(3), rows, range(3))]
        return replace(
            self,
            reflectors=tuple(self.reflectors[i] for i in rows),
            dp=self.dp[rows],
            cov=self.cov[rows],
            cov_block=block,
        )


@dataclass
class Observations:
    """All usable observations of a campaign plus what was lost."""

    poses: list[PoseObservation]
    tracker: TrackerSpec
    noise_sigma: float  # the tracker's nominal per-axis sigma (m), for reports
    n_planned: int
    lost_poses: list[int] = field(default_factory=list)
    truncated: bool = False
    source: str = ""

    # -- stacked views (row order: poses in order, reflectors in order) ---------------------
    @property
    def labels(self) -> list[tuple[int, str]]:
        return [(p.index, r) for p in self.poses for r in p.reflectors]

    @property
    def dp(self) -> np.ndarray:
        return np.concatenate([p.dp for p in self.poses]) if self.poses else np.zeros((0, 3))

    @property
    def cov(self) -> np.ndarray:
        return np.concatenate([p.cov for p in self.poses]) if self.poses else np.zeros((0, 3, 3))

    def n_obs(self) -> int:
        return sum(len(p.reflectors) for p in self.poses)

    def subset(self, keep: Iterable[tuple[int, str]]) -> Observations:
        """A copy holding only the (pose, reflector) rows in ``keep`` (e.g. outliers dropped)."""
        keep = set(keep)
        poses = []
        for p in self.poses:
            rows = [i for i, r in enumerate(p.reflectors) if (p.index, r) in keep]
            if rows:
                poses.append(p.subset(rows))
        return Observations(
            poses,
            self.tracker,
            self.noise_sigma,
            self.n_planned,
            list(self.lost_poses),
            self.truncated,
            self.source,
        )


def pose_observation(
    index: int,
    q,
    force,
    moment,
    site: str,
    names: Sequence[str],
    unloaded: Sequence,
    loaded: Sequence,
    spec: TrackerSpec,
    times: tuple[Sequence[float], Sequence[float]] | None = None,
) -> PoseObservation:
    """dp and its covariance for one pose from its readings in both states (eq. 2); the
    readings' rows are in ``names`` order; ``times`` (s since the campaign's first reading, per
    reading) are needed by a tracker whose error depends on them (TrackerModel.uses_times)."""
    m0 = mean_reading(spec, unloaded)
    m1 = mean_reading(spec, loaded)
    rows = np.flatnonzero(m0.seen & m1.seen)
    rot = tracker_rotation(spec)
    block = np.einsum(
        "ia,ranb,jb->rinj", rot, deflection_covariance(spec, unloaded, loaded, rows, times), rot
    )
    n = len(rows)
    return PoseObservation(
        index=int(index),
        q=np.asarray(q, dtype=float),
        force=np.asarray(force, dtype=float),
        moment=np.asarray(moment, dtype=float),
        site=str(site),
        reflectors=tuple(names[i] for i in rows),
        dp=m1.position[rows] - m0.position[rows],
        cov=block[np.arange(n), :, np.arange(n), :],
        cov_block=block if spec.error_model.correlated else None,
    )


def _no_pose(path) -> InputError:
    return InputError(
        path,
        "/tracker/measurement",
        "at least one complete pose with a reflector seen unloaded and loaded",
        "none",
    )


def from_campaign(campaign: Campaign) -> Observations:
    """Observations of a campaign simulated in memory (bench.campaign.simulate): the same rows
    :func:`from_log` reads from its log without truth (readings, commands, loads, the tracker),
    the readings' times from the campaign's timeline. Reads nothing of the truth (the plans'
    equilibria, the true robot). Raises InputError, as :func:`from_log`, when no pose has a
    reflector seen in both states."""
    scn = campaign.scenario
    spec = campaign.tracker
    names = list(campaign.reflectors)
    poses: list[PoseObservation] = []
    for plan in campaign.plans:
        ob = pose_observation(
            plan.index,
            plan.q,
            plan.load.force,
            plan.load.moment,
            campaign.header.payload_site,
            names,
            *(campaign.pose_readings(plan.index, s) for s in STATES),
            spec,
            tuple(campaign.pose_times(plan.index, s) for s in STATES),
        )
        if len(ob.reflectors):
            poses.append(ob)
    if not poses:
        raise _no_pose(scn.path)
    return Observations(poses, spec, float(spec.sigma), len(scn.poses), [], False, str(scn.path))


def from_log(log: CampaignLog) -> Observations:
    """Observations of every complete pose of a campaign log (read without truth).

    The reader (bench/log/read.py, the only maker of a CampaignLog) already guarantees that a
    complete pose has one command in both states, its load and one reflector list in all its
    readings. Raises InputError when no pose has a reflector seen in both states.
    """
    path = log.path
    spec = log.tracker_spec()
    poses: list[PoseObservation] = []
    first = log.first_reading_time  # a pose at a time below: a log of any size
    timed = first is not None
    t0 = first if first is not None else 0
    for p in log.complete_poses:
        q = log.poses[p].unloaded
        u = log.readings(p, "unloaded")
        ld = log.readings(p, "loaded")
        if not u or not ld:
            continue  # nothing measured: contributes nothing
        names = u[0].reflectors
        w = log.wrenches[p]
        times = ([(r.time - t0) / 1e9 for r in u], [(r.time - t0) / 1e9 for r in ld]) if timed else None
        ob = pose_observation(p, q, w.force, w.moment, w.site, names, u, ld, spec, times)
        if len(ob.reflectors):
            poses.append(ob)
    if not poses:
        raise _no_pose(path)
    n_planned = max(int(log.n_poses_planned), len(log.complete_poses))
    lost = sorted(set(range(n_planned)) - set(log.complete_poses))
    return Observations(poses, spec, float(spec.sigma), n_planned, lost, bool(log.truncated), str(path))


__all__ = ["PoseObservation", "Observations", "from_campaign", "from_log", "pose_observation"]
