"""Whitening the observations: the one place the estimators meet the tracker's covariance.

Every estimator minimises |L^-1 (dp - f(theta))|^2 with L L^T = Cov(dp) (maximum likelihood for
Gaussian errors). Cov(dp) is block diagonal by pose: a pose's deflections (all its reflectors,
3 rows each) are correlated when the tracker's error is (bench/tracker/models/iso10360.py: the drift between
the unloaded and loaded readings is common to every reflector; its systematic field is shared by
nearby readings), different poses are independent (bench/tracker/models/iso10360.py says why and what that
neglects). For an isotropic or spec tracker each block is itself block diagonal by reflector, and
its Cholesky factor is exactly the per-reflector one, so estimates are those of a per-reflector
whitening.

:class:`Whitener` holds L^-1 per pose and applies it to stacked deflections (M, 3), Jacobians
(M, 3, P) and whitened residuals (back to metres). Blocks of equal size are stacked, so a
campaign of equal poses is whitened by one batched product. A whitened residual's three rows of
one reflector are then standard normal (chi2(3) for the outlier test) whatever the correlation:
L^-1 makes all of them independent.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.linalg import solve_triangular


class Whitener:
    """L^-1 of each diagonal block of Cov(dp); rows in observation order (poses in order, their
    reflectors in order, x y z)."""

    def __init__(self, blocks: Sequence[np.ndarray]):
        """``blocks``: the covariance (3 n_j, 3 n_j) of each pose's deflections, in m^2."""
        self.sizes = [int(b.shape[0]) for b in blocks]
        if any(b.shape != (s, s) or s % 3 for b, s in zip(blocks, self.sizes)):
            raise ValueError("every block must be square with 3 rows per reflector")
        self.offsets = np.concatenate([[0], np.cumsum(self.sizes)]).astype(int)
        self.n = int(self.offsets[-1])
        self.chol = [np.linalg.cholesky(b) for b in blocks]
        self.linv = [solve_triangular(c, np.eye(len(c)), lower=True) for c in self.chol]
        groups: dict[int, list[int]] = {}
        for j, s in enumerate(self.sizes):
            groups.setdefault(s, []).append(j)
        self._groups = [
            (
                np.array(js),
                np.stack([self.linv[j] for j in js]),
                np.stack([self.chol[j] for j in js]),
                np.stack([np.arange(self.offsets[j], self.offsets[j + 1]) for j in js]),
            )
            for s, js in groups.items()
        ]

    @classmethod
    def per_reflector(cls, cov: np.ndarray) -> Whitener:
        """From per-reflector covariances (M, 3, 3): no correlation between reflectors."""
        return cls(list(np.asarray(cov, dtype=float)))

    @classmethod
    def from_observations(cls, obs) -> Whitener:
        """The blocks of identify.observations.Observations (each pose's ``cov_block``)."""
        return cls([p.block() for p in obs.poses])

    def _apply(self, x: np.ndarray, which: int) -> np.ndarray:
        out = np.empty_like(x)
        for _, mats, chols, idx in self._groups:
            m = mats if which == 0 else chols
            out[idx] = np.einsum("gij,gj...->gi...", m, x[idx])
        return out

    def vec(self, x: np.ndarray) -> np.ndarray:
        """Whitened (3M,) of deflections (M, 3) (or already flat (3M,))."""
        return self._apply(np.asarray(x, dtype=float).reshape(self.n), 0)

    def mat(self, j: np.ndarray) -> np.ndarray:
        """Whitened (3M, P) of a Jacobian (M, 3, P) (or (3M, P))."""
        j = np.asarray(j, dtype=float)
        return self._apply(j.reshape(self.n, j.shape[-1]), 0)

    def unwhiten(self, r_w: np.ndarray) -> np.ndarray:
        """(M, 3) in metres from whitened residuals (3M,) or (M, 3): L r_w."""
        return self._apply(np.asarray(r_w, dtype=float).reshape(self.n), 1).reshape(-1, 3)


__all__ = ["Whitener"]
