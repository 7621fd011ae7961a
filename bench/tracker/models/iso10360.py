"""``model = "iso10360"``: a laser tracker whose error is mostly systematic, as real ones are.

A tracker's error is not white noise. Its angle encoders' eccentricity and graduation, the
beam's offsets and tilts, the axes' wobble and the distance meter's nonlinearity give errors that
vary smoothly with direction and range (the NIST geometric error model of trackers, Muralikrishnan
et al., and their review "Laser trackers for large-scale dimensional metrology", Precision
Engineering 44, 2016: calibration removes such errors down to the noise, averaging removes only
the noise); and the instrument, its stand and the air drift with temperature over a campaign's
hours. Two readings of one reflector a few millimetres apart, taken minutes apart, therefore share
most of their error, and a deflection (their difference, paper eq. 2) is far more accurate than
the single-point specification says. This model makes that quantitative. A reading of the point
y (tracker frame, range rho, line of sight u) at time t is

    y_measured = y + A(y) z(y) + G(y) w(t) + e

* the systematic field A(y) z(y): z is a Gaussian random field, drawn once per campaign, of four
  independent unit components with the kernel
      kappa(y, y') = exp(-|u - u'|^2 / (2 L_angle^2) - (rho - rho')^2 / (2 L_range^2))
  (|u - u'| the chord between the lines of sight, ~ the angle between them: a squared-exponential
  kernel on R^3 restricted to the sphere, so positive definite; the range factor likewise), and
  A(y) = s [sd u, st (I - u u^T)] maps it onto the distance and transverse directions, so that at
  one point its covariance is s^2 (sd^2 u u^T + st^2 (I - u u^T)), the spec model's shape;
* the drift G(y) w(t): a rigid motion and scale change of the tracker frame, G(y) = [a I, -b [y]x,
  b y] (translation, small rotation, scale), w a 7-component Wiener process (per sqrt hour) that
  starts at the campaign's first reading: a drift is what has changed since then;
* e: independent noise, covariance random^2 (sd^2 u u^T + st^2 (I - u u^T)) (what each
  ``/tracker/measurement`` carries, bench.tracker.noise_covariance);
with sd = a_d + b_d rho and st = a_t + b_t rho the ``distance`` and ``transverse`` laws and
s^2 = 1 - random^2: field plus noise make, at one point, exactly the spec model's single-point
covariance. Covariance between readings k, l:

    C_kl = kappa(y_k, y_l) A_k A_l^T + min(t_k, t_l) G_k G_l^T + [k = l] random^2 C_spec(y_k)

Defaults, and where each comes from:
* ``distance`` [10 um, 0.3 um/m] and ``transverse`` [15 um, 6 um/m]: the maximum permissible
  errors of the Leica AT960/AT500 (ISO 10360-10:2021 Annex D: ADM +-(10 um + 0.3 um/m),
  transverse +-(15 um + 6 um/m)), read as 1 sigma like the spec model reads them. The manual says
  typical results are half the MPE: halve them for an instrument known to be typical.
* ``random`` 0.25: a static reflector averaged for ~2 s repeats to a few um at a few metres
  (0.25 (15 + 6 x 4) = 10 um transverse at 4 m): an assumption, to be replaced by the
  instrument's measured repeatability.
* ``correlation_angle`` 10 deg and ``correlation_range`` 1 m: the geometric error terms above are
  low harmonics of the azimuth and elevation (correlation over tens of degrees) and the distance
  meter's errors vary over decimetres to metres; the defaults take the short end, which makes
  deflections LESS accurate (a correlation length L leaves |d| / L of a field over a deflection d:
  2 mm at 4 m over 10 deg is 3e-3 of the field).
* ``drift`` [5 um, 1 um/m] per sqrt(hour): a workshop's air drifting ~0.3 K per hour moves a
  steel tripod's head (1.2 m, 12e-6/K) by ~4 um; 1 K moves the refractive index of air by ~1 ppm
  (Edlen), which the tracker's weather station compensates to a fraction, and an angular drift
  of ~1 urad per hour adds as much across the beam. Over the ~6 min between a pose's unloaded and
  loaded readings (bench/scenario/timeline.py) that is ~3 um per axis.

What is neglected, and why: the estimator weights each pose's deflections by their exact
covariance under this model (bench.tracker.deflection_covariance: loaded and unloaded readings, every
reflector of the pose, repeats, the drift between them) but treats different poses as
independent. For the drift that is exact when each pose is measured in one stretch of time
(a Wiener process has independent increments; bench/shopfloor/logcsv.py insists on it for imported
readings) up to a term (deflection) x (drift since the start), ~1e-9 m; for the field the
covariance between two poses' deflections is of order (|d| / L)^2 of the field's variance, ~1e-5
of a deflection's variance with the defaults.

Units: SI (m, s); the Wiener process's unit time is one hour.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from calbench.bench.core import Table
from calbench.bench.tracker import TrackerModel, TrackerSpec

from .spec import describe_laws, spec_covariance

HOUR = 3600.0
DRIFT_DIM = 7


def _geometry(y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    rho = np.linalg.norm(y, axis=1)
    if np.any(rho == 0):
        raise ValueError("a point at the tracker origin has no line of sight")
    return y / rho[:, None], rho


def field_factors(spec: TrackerSpec, y: np.ndarray) -> np.ndarray:
    """A(y) (n, 3, 4): the systematic field's map from its four unit components."""
    u, rho = _geometry(np.asarray(y, dtype=float))
    s = np.sqrt(max(1.0 - spec.random**2, 0.0))
    sd = s * (spec.distance[0] + spec.distance[1] * rho)
    st = s * (spec.transverse[0] + spec.transverse[1] * rho)
    a = np.empty((len(u), 3, 4))
    a[:, :, 0] = sd[:, None] * u
    a[:, :, 1:] = st[:, None, None] * (np.eye(3) - u[:, :, None] * u[:, None, :])
    return a


def field_kernel(spec: TrackerSpec, ya: np.ndarray, yb: np.ndarray) -> np.ndarray:
    """kappa (na, nb) between tracker-frame points (module docstring)."""
    ua, ra = _geometry(np.asarray(ya, dtype=float))
    ub, rb = _geometry(np.asarray(yb, dtype=float))
    chord2 = np.maximum(2.0 - 2.0 * ua @ ub.T, 0.0)
    dr2 = (ra[:, None] - rb[None, :]) ** 2
    return np.exp(-chord2 / (2 * spec.correlation_angle**2) - dr2 / (2 * spec.correlation_range**2))


def drift_factors(spec: TrackerSpec, y: np.ndarray) -> np.ndarray:
    """G(y) (n, 3, 7): translation (a), rotation (b, -[y]x) and scale (b, y) of the frame."""
    y = np.asarray(y, dtype=float)
    a, b = spec.drift
    g = np.zeros((len(y), 3, DRIFT_DIM))
    g[:, :, :3] = a * np.eye(3)
    g[:, 0, 4], g[:, 0, 5] = b * y[:, 2], -b * y[:, 1]  # -[y]x: omega x y
    g[:, 1, 3], g[:, 1, 5] = -b * y[:, 2], b * y[:, 0]
    g[:, 2, 3], g[:, 2, 4] = b * y[:, 1], -b * y[:, 0]
    g[:, :, 6] = b * y
    return g


def correlated_covariance(
    spec: TrackerSpec, ya: np.ndarray, ta: np.ndarray, yb: np.ndarray, tb: np.ndarray
) -> np.ndarray:
    """(na, 3, nb, 3): the field's and the drift's covariance between readings at tracker-frame
    points ya, yb taken at times ta, tb (s since the campaign's first reading)."""
    fa, fb = field_factors(spec, ya), field_factors(spec, yb)
    ga, gb = drift_factors(spec, ya), drift_factors(spec, yb)
    kappa = field_kernel(spec, ya, yb)
    tmin = np.minimum(np.asarray(ta, float)[:, None], np.asarray(tb, float)[None, :]) / HOUR
    return np.einsum("kl,kia,lja->kilj", kappa, fa, fb) + np.einsum(
        "kl,kia,lja->kilj", np.maximum(tmin, 0.0), ga, gb
    )


def correlated_marginal(spec: TrackerSpec, y: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(n, 3, 3): the field's and the drift's share of single readings' error covariance (at
    tracker-frame points y, times t in s since the first reading)."""
    y = np.asarray(y, dtype=float)
    fa, ga = field_factors(spec, y), drift_factors(spec, y)
    t = np.maximum(np.asarray(t, dtype=float), 0.0) / HOUR
    return np.einsum("kia,kja->kij", fa, fa) + t[:, None, None] * np.einsum("kia,kja->kij", ga, ga)


def marginal_covariance(spec: TrackerSpec, y: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(n, 3, 3): the whole error covariance of single readings (field, drift by then, noise);
    what a fit that treats readings as independent should weight them by (the registration)."""
    return correlated_marginal(spec, y, t) + spec.random**2 * spec_covariance(spec, y)


def draw_correlated(spec: TrackerSpec, y: np.ndarray, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(n, 3): one campaign's field and drift at readings of the points y (n, 3, tracker frame)
    taken at times t (n,) (s since the first reading). Readings of the same point share the
    field's value, readings at the same time the drift's. Consumes rng as: field (P x 4
    normals for the P distinct points, in first-seen order), then drift (D x 7 for the D
    distinct times, in increasing order)."""
    y, t = np.asarray(y, dtype=float), np.asarray(t, dtype=float)
    pts, where = np.unique(y, axis=0, return_inverse=True)
    order = np.argsort(np.unique(where, return_index=True)[1])  # distinct points, first-seen order
    pts = pts[order]
    where = np.argsort(order)[where.reshape(-1)]
    lam, vec = np.linalg.eigh(field_kernel(spec, pts, pts))
    z = (vec * np.sqrt(np.clip(lam, 0.0, None))) @ rng.standard_normal((len(pts), 4))
    field = np.einsum("pia,pa->pi", field_factors(spec, pts), z)[where]
    times, at = np.unique(np.maximum(t, 0.0), return_inverse=True)
    steps = np.sqrt(np.diff(np.concatenate([[0.0], times])) / HOUR)[:, None]
    w = np.cumsum(steps * rng.standard_normal((len(times), DRIFT_DIM)), axis=0)[at.reshape(-1)]
    return field + np.einsum("kia,ka->ki", drift_factors(spec, y), w)


class Iso10360Tracker(TrackerModel):
    """The model of this module's docstring: K of bench/tracker/base.py's eq. (2) is the field's
    and the drift's :func:`correlated_covariance`, C of eq. (1) ``random^2`` times the spec form."""

    name = "iso10360"
    summary = "σ growing with range, correlated between nearby readings"
    keys = ("random", "correlation_angle", "correlation_range", "drift")
    correlated = True
    uses_times = True  # the drift

    def parse(self, c: Table, degrees: bool) -> dict[str, Any]:
        out: dict[str, Any] = {}
        if c.has("random"):
            out["random"] = c.number("random", positive=True)
            if out["random"] > 1:
                raise c.fail(
                    "random", "the share of the 1-sigma that is independent noise, in (0, 1]", out["random"]
                )
        if c.has("correlation_angle"):
            angle = c.number("correlation_angle", positive=True)
            out["correlation_angle"] = math.radians(angle) if degrees else float(angle)
        if c.has("correlation_range"):
            out["correlation_range"] = c.number("correlation_range", positive=True)
        if c.has("drift"):
            out["drift"] = tuple(float(x) for x in c.vector("drift", 2, nonneg=True))
        return out

    def header(self, spec: TrackerSpec, degrees: bool) -> dict[str, Any]:
        angle = spec.correlation_angle
        return {
            "random": float(spec.random),
            "correlation_angle": round(math.degrees(angle), 10) if degrees else float(angle),
            "correlation_range": float(spec.correlation_range),
            "drift": [float(x) for x in spec.drift],
        }

    def covariance(self, spec: TrackerSpec, y: np.ndarray) -> np.ndarray:
        return spec.random**2 * spec_covariance(spec, y)

    def correlated_covariance(self, spec, ya, ta, yb, tb) -> np.ndarray:
        return correlated_covariance(spec, ya, ta, yb, tb)

    def correlated_marginal(self, spec: TrackerSpec, y: np.ndarray, t: np.ndarray) -> np.ndarray:
        return correlated_marginal(spec, y, t)

    def draw_correlated(self, spec, y, t, rng) -> np.ndarray:
        return draw_correlated(spec, y, t, rng)

    def describe(self, spec: TrackerSpec) -> str:
        a, b = spec.drift
        return (
            f"iso10360, 1σ {describe_laws(spec)} of range, {spec.random:.3g} of it independent noise, "
            f"the rest a field correlated over {math.degrees(spec.correlation_angle):.3g}° and "
            f"{spec.correlation_range:.3g} m, and a drift of {a * 1e6:.3g} µm + {b * 1e6:.3g} µm/m per √h"
        )


MODEL = Iso10360Tracker()


__all__ = [
    "HOUR",
    "field_factors",
    "field_kernel",
    "drift_factors",
    "correlated_covariance",
    "correlated_marginal",
    "marginal_covariance",
    "draw_correlated",
    "Iso10360Tracker",
    "MODEL",
]
