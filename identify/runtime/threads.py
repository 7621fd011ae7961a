"""BLAS threads for the design's small dense algebra (issue 16).

The exchange and the approximate designs multiply 8 x 8 blocks and N x 64 arrays: too small for
OpenBLAS's threads to pay for their synchronisation, and on a loaded 2-core machine those threads
fight the other processes (the exchange slowed from 0.8 s to 8.7 s at load 9). ``blas_threads(n)``
limits the BLAS pools to n threads for a ``with`` block (threadpoolctl), None leaves them alone.
benchmarks/certificate_bench.py measures both side by side.
"""

from __future__ import annotations

from contextlib import nullcontext

from threadpoolctl import threadpool_limits


def blas_threads(n: int | None = 1):
    """Context manager: at most n BLAS threads inside (None: unchanged)."""
    return nullcontext() if n is None else threadpool_limits(limits=int(n), user_api="blas")


__all__ = ["blas_threads"]
