"""The identifiability tolerances: every threshold that decides what a campaign determines.

Each one measures a different thing; where two rooms ask the same question they use the same
constant from here.

Rank of a fit (identify/core/leastsq.py's truncated-SVD steps and covariance; the one-step, the
tracker registration, discovery's fits; identify/core/identifiability.py's rank). The matrix is
the whitened Jacobian (rows over the tracker's covariance) with its columns normalised to unit
length, so units and parameter sizes drop out; its singular values s_1 >= ... >= s_p.

* ``RANK_TOL`` = 1e-6: a direction with s_i <= RANK_TOL s_1 is numerically absent (the rank is the
  number above it). Seeing it would need measurements 1e6 times more precise than the
  best-determined direction (sub-picometre at 20 um). Measured on the FANUC: a structurally lost
  direction (k1 under vertical loads, the compensator with one q2) comes out at 1e-16, the
  identifiable directions of the paper plan at >= 0.17 s_1: not critical anywhere in between.
* ``DISCOVER_RANK_TOL`` = 1e-5: the same question for discovery's candidate fits, whose augmented
  models add effects nearly aliased with the base parameters; ten times stricter, so that the
  search steps along no direction seen only at the edge of the numbers. On the logs of
  scenarios/paper_table5.toml, scenarios/kr270_balancer_realistic.toml and the paper plan with
  four hidden effects, 1e-6 in its place gives the same discovery report to the last digit;
  it is kept apart because no study has shown it harmless on the aliased candidates.
* ``ZERO_COLUMN_TOL`` = 1e-12: a column below this fraction of the largest (before
  normalisation) is a parameter with no effect at all on the readings (identifiability's
  reason "no pose loads motor i").

The numerical null space (the directions below the rank tolerance):

* ``NULL_TOL`` = 1e-3: a parameter whose unit vector has a component larger than this in the
  null space is not identifiable (its value is mixed with an unseen direction).

Determination, the statistical question after the fit (the tracker's noise in the covariance):

* ``MAX_RELATIVE_STD`` = 1: a parameter whose standard deviation exceeds its own size is not
  determined (the data tell neither its size nor that it is not zero). Not tuned: below it the
  estimate is at least one standard deviation from zero.
* ``RELATIVE_RANK_TOL`` = 1e-8: discovery's determination (identify/discover/uncertainty.py) takes
  the SVD of the whitened Jacobian in relative coordinates (each column times its parameter's
  size, not normalised), so its spread of singular values carries the parameters' relative
  precision, not only their directions; a direction below 1e-8 of the largest there is null.
  A different matrix from the rank's, hence a different value.

Geometry (identify/geometry/fit.py), absolute readings of one point, unwhitened:

* ``GEOMETRY_RANK_TOL`` = 1e-9: the base set of the geometric parameters is chosen on the
  Jacobian with unit columns but no tracker weighting (the readings are absolute positions, m
  and rad parameters together); a parameter enters when it raises the rank counted above
  GEOMETRY_RANK_TOL s_1, and a column below GEOMETRY_RANK_TOL of the median column (a rotation
  about an axis through the probe) is rounding noise, no parameter. The classic redundancies it
  removes (parallel axes, a link's z-rotation against the next joint offset) are exact linear
  dependences, at rounding level; the value is the one the geometry fit was built and validated
  with (issue 25: UR10 held-out RMS), kept as it is.
"""

from __future__ import annotations

RANK_TOL = 1e-6
DISCOVER_RANK_TOL = 1e-5
ZERO_COLUMN_TOL = 1e-12
NULL_TOL = 1e-3
MAX_RELATIVE_STD = 1.0
RELATIVE_RANK_TOL = 1e-8
GEOMETRY_RANK_TOL = 1e-9

__all__ = [
    "DISCOVER_RANK_TOL",
    "GEOMETRY_RANK_TOL",
    "MAX_RELATIVE_STD",
    "NULL_TOL",
    "RANK_TOL",
    "RELATIVE_RANK_TOL",
    "ZERO_COLUMN_TOL",
]
