"""The candidate-set NPZ (`design --export-candidates`, `design --from-candidates`), issue 16.

Arrays written by calbench (only ``q`` and ``blocks`` are required on reading, so any other
tool's candidates can be optimised by calbench, and calbench's by any other tool):

* ``q`` (N, n): commanded joint angles, degrees, one per actuated joint (the FANUC's 6).
* ``blocks`` (N, m, p): candidate i's regressor R_i, so that sum_i R_i^T R_i over a plan is its
  Fisher information. Rows: the x, y, z deflection of each reflector (m = 9 for 3; rows of
  reflectors a candidate cannot see are zero). Columns: the p parameters theta_k / theta0_k
  of the robot's layout (bench/model/params.py; the FANUC's 8: k1..k6, K_C, s0). Each row is
  WHITENED by the tracker noise (R = L^-1 J with L L^T the covariance of a deflection, i.e.
  of two readings: sqrt(2) x 20 um per axis on the paper scenario), and each column is SCALED BY theta0 (J = d deflection / d(theta / theta0)). So an
  entry is "how many noise sigmas this reflector coordinate moves when parameter k changes by
  100 % of its prior value".
  Column scales (RMS over all rows of the 10^4 candidates of scenarios/paper_table5.toml):
  k1 71.3, k2 29.3, k3 48.1, k4 22.0, k5 35.3, k6 6.1, K_C 1.9, s0 6.1; the diagonal of the mean
  information R^T R spans 3.5 (K_C) to 5100 (k1), that of one candidate 0 to 5.1e4.
* ``wrench`` (N, 6), ``load_kind`` (N,) "vertical" | "lateral", ``theta0`` (p,), ``param_names``
  (p,), ``note``: what the arrays mean.

``--normalise`` divides each column by its RMS scale s (certificate.normalise_blocks; written
as ``column_scale``, so blocks * column_scale restores the raw ones). The mean information then
has a unit diagonal, which tools that divide by diagonal entries need (FIGAROH 1.0.2's SOCP
fails with ZeroDivisionError on the raw blocks). Every plan's log det moves by the same
-2 sum ln s_k, so the D-optimal plan does not change; A (trace) plans do.

Reading validates the file as user input: a missing array, a wrong shape or a non-finite entry
raises InputError naming the file and the array (exit status 2 on the command line).
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calbench.bench.core import InputError

from .certificate import normalise_blocks
from .feasibility import LOAD_KINDS

NOTE = (
    "blocks[i] = whitened regressor of candidate i (rows: reflector deflections divided by their "
    "noise, 2 tracker readings) w.r.t. theta/theta0 (columns); sum_i blocks[i].T @ blocks[i] over a "
    "plan = its Fisher information; q in degrees; wrench world-frame N, N*m at the payload site"
)
NORMALISED_NOTE = (
    "; NORMALISED: blocks = raw blocks / column_scale (each column's RMS over all rows), "
    "so the mean information has a unit diagonal; every plan's log det shifts by "
    "-2 sum(log(column_scale)): the D-optimal plan is unchanged (A plans are not)"
)


@dataclass(frozen=True)
class CandidateFile:
    """Candidates read from an NPZ: only q and blocks are required."""

    path: Path
    q: np.ndarray  # (N, n) rad
    blocks: np.ndarray  # (N, m, p)
    wrench: np.ndarray | None  # (N, 6) N, N*m
    kind: np.ndarray | None  # (N,) 0 vertical, 1 lateral
    theta0: np.ndarray | None  # (p,)
    column_scale: np.ndarray | None  # (p,) when the blocks were normalised

    def __len__(self) -> int:
        return len(self.q)


def write_candidates(path, q, blocks, wrench, kind, theta0, param_names, normalise: bool = False) -> None:
    """The NPZ of the module docstring (q in rad here, degrees in the file)."""
    extra = {}
    note = NOTE
    if normalise:
        blocks, s = normalise_blocks(blocks)
        extra["column_scale"] = s
        note += NORMALISED_NOTE
    np.savez_compressed(
        path,
        q=np.degrees(q),
        blocks=blocks,
        wrench=wrench,
        load_kind=np.array([LOAD_KINDS[k] for k in kind]),
        theta0=theta0,
        param_names=np.array(param_names),
        note=np.array(note),
        **extra,
    )


def _array(z, path, name, expected, required=True):
    if name not in z.files:
        if required:
            raise InputError(
                path,
                name,
                f"an array {name!r}: {expected}",
                "missing; arrays present: " + (", ".join(z.files) or "none"),
            )
        return None
    try:
        a = z[name]
    except ValueError as exc:  # object arrays (allow_pickle=False)
        raise InputError(path, name, expected, str(exc)) from None
    return a


def _finite(path, name, a, expected):
    if a.dtype.kind not in "iuf":
        raise InputError(path, name, expected, f"dtype {a.dtype}")
    a = a.astype(float)
    bad = ~np.isfinite(a)
    if bad.any():
        row = int(np.argwhere(bad)[0][0])
        raise InputError(path, name, expected, f"NaN or inf (first at row {row})")
    return a


def read_candidates(path: str | Path) -> CandidateFile:
    """Read and validate a candidate NPZ (see the module docstring)."""
    path = Path(path)
    try:
        z = np.load(path, allow_pickle=False)
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise InputError(
            path, "(file)", "a readable NPZ archive with arrays q and blocks", str(exc)
        ) from None
    if not isinstance(z, np.lib.npyio.NpzFile):
        raise InputError(
            path, "(file)", "an NPZ archive (numpy.savez) with arrays q and blocks", "a single array"
        )
    with z:
        q_exp = "N x n finite joint angles in degrees (one per actuated joint)"
        b_exp = "N x m x p finite numbers, N as in q"
        q = _finite(path, "q", _array(z, path, "q", q_exp), q_exp)
        if q.ndim != 2 or min(q.shape) < 1:
            raise InputError(path, "q", q_exp, f"shape {q.shape}")
        n = q.shape[0]
        blocks = _finite(path, "blocks", _array(z, path, "blocks", b_exp), b_exp)
        if blocks.ndim != 3 or blocks.shape[0] != n or min(blocks.shape) < 1:
            raise InputError(
                path, "blocks", b_exp.replace("N as in q", f"N = {n} as in q"), f"shape {blocks.shape}"
            )
        p = blocks.shape[2]
        w_exp = f"{n} x 6 finite forces and moments (N, N*m)"
        wrench = _array(z, path, "wrench", w_exp, required=False)
        if wrench is not None:
            wrench = _finite(path, "wrench", wrench, w_exp)
            if wrench.shape != (n, 6):
                raise InputError(path, "wrench", w_exp, f"shape {wrench.shape}")
        k_exp = f"{n} strings, each one of " + ", ".join(LOAD_KINDS)
        kinds = _array(z, path, "load_kind", k_exp, required=False)
        kind = None
        if kinds is not None:
            if kinds.shape != (n,) or kinds.dtype.kind != "U" or not np.isin(kinds, LOAD_KINDS).all():
                raise InputError(path, "load_kind", k_exp, f"shape {kinds.shape}, dtype {kinds.dtype}")
            kind = (kinds == "lateral").astype(int)
        optional = {}
        for name in ("theta0", "column_scale"):
            exp = f"{p} finite positive numbers (one per column of blocks)"
            a = _array(z, path, name, exp, required=False)
            if a is not None:
                a = _finite(path, name, a, exp)
                if a.shape != (p,) or not np.all(a > 0):
                    raise InputError(
                        path, name, exp, f"shape {a.shape}" if a.shape != (p,) else "a value <= 0"
                    )
            optional[name] = a
    return CandidateFile(
        path, np.radians(q), blocks, wrench, kind, optional["theta0"], optional["column_scale"]
    )


__all__ = ["CandidateFile", "NOTE", "read_candidates", "write_candidates"]
