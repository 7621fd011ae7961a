"""Memory a piece of work will need, against what the machine has: inputs too big to fit are
refused up front with the estimate (as campaigns too long to simulate are:
bench/scenario/timeline.py), not after minutes of swapping or an out-of-memory kill.

Each verb that holds something in proportion to its input states its budget next to the code
that holds it (docs/reliability.md, "Memory budgets", lists them with the measured peaks) and
asks :func:`check_memory` before it starts.
"""

from __future__ import annotations

import os

from .errors import InputError


def available_bytes() -> int | None:
    """Memory the machine can give this process now (Linux: MemAvailable; elsewhere the free
    physical pages), or None when unknown."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, OSError, ValueError):
        return None


def nbytes_text(n: float) -> str:
    """A byte count for people: 1.5 GB, 230 MB."""
    for unit, b in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= b:
            return f"{n / b:.3g} {unit}"
    return f"{n:.0f} B"


class Estimated(str):
    """An estimate an InputError shows as it is (its repr is the text)."""

    def __repr__(self) -> str:
        return str(self)


def check_memory(need: float, file: object, key: str, what: str) -> None:
    """InputError naming ``file`` and ``key`` when ``need`` bytes (the estimate for ``what``,
    e.g. "4,000,000 rows at 100 B") exceed the memory available now."""
    have = available_bytes()
    if have is None or need <= have:
        return
    raise InputError(
        file,
        key,
        f"an input whose work fits in this machine's memory ({nbytes_text(have)} available)",
        Estimated(f"{what}: ~{nbytes_text(need)}"),
    )


__all__ = ["available_bytes", "check_memory", "nbytes_text"]
