"""The simulated laser tracker: frames, line-of-sight visibility, measurement, deflections.

The tracker frame has its origin at ``TrackerSpec.position`` and is rotated by ``yaw`` about
world z (or by ``TrackerSpec.rotation``, a registered tracker's full orientation). Measurements
are reported in that frame, as a real tracker would report them; the error model lives there too
(it only depends on the line of sight from the tracker origin): whatever it is, this module asks
the spec's model (bench/tracker/base.py) for it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from .base import TrackerSpec

OCCLUSION_TOL = 1e-6  # m: a hit closer than the site by more than this occludes it
BLOCKING_GROUPS = np.array([1, 1, 1, 0, 0, 0], dtype=np.uint8)  # geom groups >= 3 never block


@dataclass(frozen=True)
class Measurement:
    """One tracker reading of n reflectors, in the tracker frame.

    ``position`` and ``covariance`` rows of reflectors that are not visible are NaN.
    """

    position: np.ndarray  # (n, 3) m
    covariance: np.ndarray  # (n, 3, 3) m^2
    visible: np.ndarray  # (n,) bool


def _points(points: np.ndarray) -> np.ndarray:
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"points must have shape (n, 3), got {p.shape}")
    return p


def tracker_rotation(spec: TrackerSpec) -> np.ndarray:
    """World-from-tracker rotation: ``spec.rotation`` when set (a registered tracker), else a
    yaw of ``spec.yaw`` radians about world z."""
    if spec.rotation is not None:
        return np.asarray(spec.rotation, dtype=float)
    c, s = np.cos(spec.yaw), np.sin(spec.yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def to_tracker_frame(spec: TrackerSpec, points_world: np.ndarray) -> np.ndarray:
    """Express world points (n, 3) in the tracker frame: R^T (p - position)."""
    p = _points(points_world)
    return (p - spec.position) @ tracker_rotation(spec)


def to_world_frame(spec: TrackerSpec, points_tracker: np.ndarray) -> np.ndarray:
    """Express tracker-frame points (n, 3) in the world frame: R p + position."""
    p = _points(points_tracker)
    return p @ tracker_rotation(spec).T + spec.position


def noise_covariance(spec: TrackerSpec, points_tracker: np.ndarray) -> np.ndarray:
    """Covariance (n, 3, 3) of a reading's independent error at tracker-frame points: what a
    ``/tracker/measurement`` carries; the spec's model's (C of bench/tracker/base.py's eq. 1).

    Isotropic: sigma^2 I. Spec: sd^2 u u^T + st^2 (I - u u^T), with u the unit line of sight,
    sd = a_d + b_d*range along it (distance meter) and st = a_t + b_t*range across it (angles).
    iso10360: random^2 times the spec form, the rest of its error being correlated between
    readings (bench/tracker/models/iso10360.py).
    """
    return spec.error_model.covariance(spec, _points(points_tracker))


@dataclass(frozen=True)
class MeanReading:
    """The mean of repeated readings of n reflectors in one state, in the world frame.

    Rows of reflectors never seen are NaN in ``position`` and ``covariance``.
    """

    position: np.ndarray  # (n, 3) m, world frame
    covariance: np.ndarray  # (n, 3, 3) m^2, covariance of the mean, world frame
    seen: np.ndarray  # (n,) bool: seen in at least one reading
    count: np.ndarray  # (n,) number of readings averaged


def mean_reading(spec: TrackerSpec, readings) -> MeanReading:
    """Average repeated tracker-frame readings (objects with ``position`` (n,3),
    ``covariance`` (n,3,3) and ``visible`` (n,), rows in the same reflector order) and
    express the mean in the world frame.

    With N_r readings of reflector r (visible, finite position) the mean is
    p_r = R (1/N_r sum_i p_ri) + t and, the readings being independent, its covariance
    R (1/N_r^2 sum_i C_ri) R^T (sigma^2/N_r per axis for an isotropic tracker); R, t are
    the tracker's pose (:func:`tracker_rotation`, ``spec.position``). Paper eq. (2) differences
    two such means. This is the one place both identification and the viewer average.
    """
    readings = list(readings)
    if not readings:
        raise ValueError("mean_reading needs at least one reading")
    n = len(readings[0].visible)
    pos, vis = _stacked(readings, n)
    # sums in reading order (cumsum is sequential, and adding 0.0 where a row is not seen
    # changes nothing): the same bits as adding reading after reading
    s = np.cumsum(np.where(vis[..., None], pos, 0.0), axis=0)[-1]
    cov = np.array([np.asarray(m.covariance, dtype=float) for m in readings])
    c = np.cumsum(np.where(vis[..., None, None], cov, 0.0), axis=0)[-1]
    cnt = vis.sum(axis=0).astype(float)
    seen = cnt > 0
    rot = tracker_rotation(spec)
    mean = np.full((n, 3), np.nan)
    cov = np.full((n, 3, 3), np.nan)
    mean[seen] = (s[seen] / cnt[seen, None]) @ rot.T + np.asarray(spec.position, dtype=float)
    cov[seen] = rot @ (c[seen] / cnt[seen, None, None] ** 2) @ rot.T
    return MeanReading(mean, cov, seen, cnt.astype(int))


def _stacked(readings: Sequence, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Positions (K, n, 3) of ``readings`` and where each row is seen (visible and finite)."""
    try:
        pos = np.array([np.asarray(m.position, dtype=float) for m in readings])
    except ValueError:
        pos = None
    if pos is None or pos.shape[1:] != (n, 3):
        for m in readings:
            shape = np.shape(m.position)
            if shape != (n, 3):
                raise ValueError(f"every reading must have {n} rows, got shape {shape}")
    vis = np.array([np.asarray(m.visible, dtype=bool) for m in readings]) & np.all(np.isfinite(pos), axis=2)
    return pos, vis


def deflection_covariance(
    spec: TrackerSpec,
    unloaded: Sequence,
    loaded: Sequence,
    rows: np.ndarray,
    times: tuple[Sequence[float], Sequence[float]] | None,
) -> np.ndarray:
    """(m, 3, m, 3): covariance of one pose's deflections dp_r = mean(loaded readings of r) -
    mean(unloaded readings of r) for the reflector rows ``rows`` (seen in both states), tracker
    frame: bench/tracker/base.py's eq. (3). ``unloaded`` and ``loaded`` are the readings
    (``position`` (n, 3), ``covariance`` (n, 3, 3) of the independent error, ``visible`` (n,));
    ``times`` their times (s since the campaign's first reading), needed by a model whose
    correlated part depends on them (TrackerModel.uses_times: iso10360's drift).

    Every model: the readings' own covariances, sum C / N^2 per state (paper eq. 2, as
    :func:`mean_reading`). A correlated model adds sum_kl c_k c_l K_kl of its correlated part
    over every pair of the pose's readings (c = +-1/N_sr, the weight of reading k in dp_r)."""
    rows = np.asarray(rows, dtype=int)
    m = len(rows)
    out = np.zeros((m, 3, m, 3))
    terms, pts, tms, coef, row_of = [], [], [], [], []
    for sign, reads, tt in (
        (-1.0, unloaded, None if times is None else times[0]),
        (1.0, loaded, None if times is None else times[1]),
    ):
        if not len(reads):
            continue
        n = len(reads[0].visible)
        pos, seen = _stacked(reads, n)
        seen = seen[:, rows]  # (K, m)
        count = seen.sum(axis=0)
        cov = np.array([np.asarray(r.covariance, dtype=float)[rows] for r in reads])  # (K, m, 3, 3)
        with np.errstate(divide="ignore", invalid="ignore"):
            terms.append(np.where(seen[..., None, None], cov / (count[:, None, None] ** 2), 0.0))
        k, j = np.nonzero(seen)  # reading by reading, row by row: the order of the sum below
        pts.append(pos[k, rows[j]])
        tms.append(np.full(len(k), np.nan) if tt is None else np.asarray(tt, dtype=float)[k])
        coef.append(sign / count[j])
        row_of.append(j)
    if terms:
        # every reading's own covariance, summed in order (cumsum is sequential; 0.0 where a row
        # is not seen changes nothing): sum C / N^2 per state
        own = np.cumsum(np.concatenate(terms), axis=0)[-1]  # (m, 3, 3)
        out[np.arange(m), :, np.arange(m), :] = own
    pts = np.concatenate(pts) if pts else np.zeros((0, 3))
    tms = np.concatenate(tms) if tms else np.zeros(0)
    coef = np.concatenate(coef) if coef else np.zeros(0)
    row_of = np.concatenate(row_of) if row_of else np.zeros(0, int)
    model = spec.error_model
    if not model.correlated or not len(pts):
        return out
    if times is None and model.uses_times:
        raise ValueError(f"the {model.name} tracker model needs the readings' times")
    w = np.zeros((m, len(pts)))
    w[row_of, np.arange(len(pts))] = coef
    c = model.correlated_covariance(spec, pts, tms, pts, tms)
    return out + np.einsum("rk,kilj,sl->risj", w, c, w)


def visible_sites(model: mujoco.MjModel, data: mujoco.MjData, spec: TrackerSpec, site_ids) -> np.ndarray:
    """Line-of-sight test (n,) bool from the tracker to each site at the pose held in ``data``.

    Casts ``mj_ray`` from the tracker position toward each site (``data.site_xpos`` must be
    current). A site is hidden iff a geom in groups 0-2 is hit more than ``OCCLUSION_TOL``
    before it. Static (world) geoms block; as in ``mj_ray``, fully transparent geoms
    (alpha 0) do not. A tracker inside a geom is not detected.
    """
    ids = np.atleast_1d(np.asarray(site_ids, dtype=int))
    if np.any((ids < 0) | (ids >= model.nsite)):
        raise ValueError(f"site ids must be in 0..{model.nsite - 1}, got {ids.tolist()}")
    origin, unit, dist = sight_lines(spec, data.site_xpos[ids])
    geomid = np.full(1, -1, dtype=np.int32)
    hit = np.array([mujoco.mj_ray(model, data, origin, u, BLOCKING_GROUPS, 1, -1, geomid) for u in unit])
    return unoccluded(hit, dist)


def sight_lines(spec: TrackerSpec, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rays of :func:`visible_sites` to world points (..., 3): the tracker position (3,), unit
    directions (..., 3) and distances (...). A point within OCCLUSION_TOL of the tracker gets
    the direction +z (any ray will do: :func:`unoccluded` sees it regardless)."""
    origin = np.asarray(spec.position, dtype=float).copy()
    d = np.asarray(points, dtype=float) - origin
    dist = np.sqrt(np.einsum("...i,...i->...", d, d))
    near = dist <= OCCLUSION_TOL
    unit = np.where(near[..., None], [0.0, 0.0, 1.0], d / np.where(near, 1.0, dist)[..., None])
    return origin, unit, dist


def unoccluded(hit: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """The visibility rule (elementwise): mj_ray's first hit along a sight line (-1: none) is
    not more than OCCLUSION_TOL before the site at ``dist``, or the site is at the tracker."""
    hit = np.asarray(hit, dtype=float)
    return (dist <= OCCLUSION_TOL) | (hit < 0) | (hit >= dist - OCCLUSION_TOL)


def measure(
    spec: TrackerSpec, points_world: np.ndarray, visible: np.ndarray, rng: np.random.Generator | None
) -> Measurement:
    """Noisy tracker-frame readings of the true ``points_world``.

    Noise is drawn only for visible points, by the spec's model (TrackerModel.draw: one
    standard-normal (m, 3) block for the m visible points in order, coloured by the Cholesky
    factor of :func:`noise_covariance`). So the generator's consumption depends on how many
    points are visible, and the same generator state gives identical output. Invisible rows are
    NaN in position and covariance. ``rng`` None: the exact reading (the true points, no noise)
    still carrying :func:`noise_covariance` as its covariance, what the noise-free analyses
    (Cramer-Rao bounds, noise-free estimates) weight by.
    """
    p = to_tracker_frame(spec, points_world)
    vis = np.asarray(visible)
    if vis.dtype != bool or vis.shape != (len(p),):
        raise ValueError(f"visible must be a bool array of shape ({len(p)},)")
    position = np.full_like(p, np.nan)
    covariance = np.full((len(p), 3, 3), np.nan)
    if vis.any() and rng is None:
        position[vis] = p[vis]
        covariance[vis] = noise_covariance(spec, p[vis])
    elif vis.any():
        err, cov = spec.error_model.draw(spec, p[vis], rng)
        position[vis] = p[vis] + err
        covariance[vis] = cov
    vis = vis.copy()
    for a in (position, covariance, vis):
        a.setflags(write=False)
    return Measurement(position=position, covariance=covariance, visible=vis)
